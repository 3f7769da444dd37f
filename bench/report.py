#!/usr/bin/env python3
"""Prints the table of headline figures of an hvdb-bench JSON file as Markdown.

usage: report.py RESULTS.json

bench/README.md's "Latest figures" table is this script's output for bench/results/full.json.
Every row is one hvdb figure (median, with min..max and repetitions), the thesis's 2008 figure,
the physical limit or peer measured in the same run and hvdb's ratio to it, and the issue's
goal with whether it is met.
"""
import json
import sys


def load(path):
    with open(path) as f:
        run = json.load(f)
    return run, {f["name"]: f for f in run["figures"]}


def fmt(v, unit=""):
    if v is None:
        return "n/a"
    a = abs(v)
    if a >= 100:
        s = "%.0f" % v
    elif a >= 10:
        s = "%.1f" % v
    elif a >= 1:
        s = "%.2f" % v
    elif a >= 0.01:
        s = "%.3f" % v
    else:
        s = "%.4f" % v
    return s + (" " + unit if unit else "")


def cell(f):
    if f is None:
        return "not run"
    s = "**%s**" % (fmt(f["median"]) + "x" if f["unit"] == "ratio" else fmt(f["median"], f["unit"]))
    if f["reps"] > 1 and f["unit"] != "ratio":
        s += " (%s..%s, n=%d)" % (fmt(f["min"]), fmt(f["max"]), f["reps"])
    return s


def targets(f, source_prefix):
    out = []
    for t in (f or {}).get("targets", []):
        if t["source"].startswith(source_prefix):
            s = "%s %s %s" % ("met" if t["met"] else "**missed**", t["op"], fmt(t["value"]))
            if source_prefix == "issue":  # several issues' goals share the column: name each
                s += " (#%s)" % t["source"].split()[1]
            out.append(s)
    return "; ".join(out)


def limit(f):
    if f is None or not f.get("limit"):
        return ""
    l = f["limit"]
    kind = "seq. read" if "sequential" in l["kind"] else "memcpy"
    return "%s %s → hvdb is %.2fx" % (kind, fmt(l["ms"], "ms"), l["x_limit"])


def ratio(figs, name, label, invert=False):
    """A peer cell from a ratio figure: name is peer/hvdb (invert=False) or hvdb/peer."""
    r = figs.get(name)
    if r is None:
        return ""
    peer = figs.get(r["params"]["denominator" if invert else "numerator"])
    v = r["median"]
    if v is None or not peer:
        return ""
    hvdb_over_peer = v if invert else 1.0 / v
    if hvdb_over_peer <= 1:
        verdict = "hvdb %.1fx faster" % (1.0 / hvdb_over_peer) if peer["unit"] != "ratio" else \
            "hvdb %.2fx of it" % hvdb_over_peer
    else:
        verdict = "hvdb %.2fx slower" % hvdb_over_peer if peer["unit"] != "ratio" else \
            "hvdb %.2fx of it" % hvdb_over_peer
    if peer["unit"] == "ratio":
        return "%s %s (%s)" % (label, fmt(peer["median"], "x raw"), verdict)
    return "%s %s (%s)" % (label, fmt(peer["median"], peer["unit"]), verdict)


def main():
    run, F = load(sys.argv[1])
    cfg = run["config"]
    L = cfg["lod_levels"]
    nmax = max(range(cfg["win_min"], cfg["win_max"] + 1, cfg["win_step"]))
    pcl = max([n for n in cfg["pcl_sizes"] if n <= nmax] or [0])
    rows = []

    def row(what, name, thesis="", peers="", goal_src="issue", thesis_src="thesis"):
        f = F.get(name)
        t = thesis
        if f is not None and thesis:
            tt = targets(f, thesis_src)
            t = thesis + (" — " + tt if tt else "")
        peer_cells = [p for p in ([limit(f)] + (peers if isinstance(peers, list) else [peers])) if p]
        rows.append("| %s | %s | %s | %s | %s |" % (what, cell(f), t, "<br>".join(peer_cells),
                                                  targets(f, goal_src)))

    # 1. Table 8.2
    row("Table 8.2: coarsest level (%d) of a %s-point frame, cold" % (L, "{:,}".format(cfg["lod_points"])),
        "lod.level%d.cold" % L, "38 ms")
    row("Table 8.2: coarsest level, warm", "lod.level%d.warm" % L)
    row("Table 8.2: full frame, cold", "lod.level0.cold", "1161 ms")
    row("Table 8.2: full frame, warm", "lod.level0.warm")
    row("full frame cold / sequential read", "lod.full.cold.x_seqread")
    row("full frame warm / memcpy", "lod.full.warm.x_memcpy")
    row("progressive stream of the full frame, cold", "lod.progressive.cold")
    row("progressive stream, cold: coarsest level complete", "lod.progressive.first_level.cold")
    row("progressive stream of the full frame, warm", "lod.progressive.warm")
    row("tree file size / raw point bytes", "lod.frame.size.x_raw")
    # bulk load
    row("bulk load of a %s-point frame (durable)" % "{:,}".format(cfg["lod_points"]), "bulk.hvdb", "",
        [ratio(F, "bulk.rtree_str.x_hvdb", "R*-tree STR"), ratio(F, "bulk.pcl.x_hvdb", "PCL outofcore")])
    row("bulk load / write + fdatasync of the same bytes", "bulk.hvdb.x_write_fsync")
    row("R*-tree STR bulk load / hvdb's", "bulk.rtree_str.x_hvdb")
    row("PCL outofcore build / hvdb's", "bulk.pcl.x_hvdb")
    # 2. Figure 8.13
    w = "win.n%d" % nmax
    p = "win.n%d" % pcl
    row("Fig. 8.13: %s-point window on a %s-point frame, full resolution, warm" %
        ("{:,}".format(cfg["win_result"]), "{:,}".format(nmax)), w + ".hvdb.l0.warm", "",
        [ratio(F, w + ".hvdb.l0.warm.x_nanoflann", "nanoflann", invert=True),
         ratio(F, p + ".pcl.warm.x_hvdb", "PCL outofcore")])
    row("Fig. 8.13: same, cold", w + ".hvdb.l0.cold", "< 100 ms",
        ratio(F, p + ".pcl.cold.x_hvdb", "PCL outofcore"))
    row("PCL outofcore box query, cold / hvdb's", p + ".pcl.cold.x_hvdb")
    row("same window cold / the device reading as many random blocks at once", w + ".hvdb.l0.cold.x_blocks", "",
        "%s blocks: %s" % (fmt((F.get(w + ".hvdb.l0.cold") or {}).get("params", {}).get("blocks_read_median", 0)),
                           fmt((F.get(w + ".limit.blocks.l0.cold") or {}).get("median") or 0, "ms")))
    row("Fig. 8.13: same window at the coarsest level, warm", w + ".hvdb.l%d.warm" % L, "",
        ratio(F, p + ".pcl_lod.warm.x_hvdb", "PCL LOD query"))
    row("Fig. 8.13: coarsest level, cold", w + ".hvdb.l%d.cold" % L, "< 100 ms",
        ratio(F, p + ".pcl_lod.cold.x_hvdb", "PCL LOD query"))
    # 3. Figure 8.14
    row("Fig. 8.14: %d-point insert, mean over %s points" % (cfg["ins_set"], "{:,}".format(cfg["ins_total"])),
        "ins.nosync.set.mean", "< 110 ms")
    row("Fig. 8.14: insert, median set", "ins.nosync.set")
    row("sustained insert rate", "ins.nosync.rate")
    row("durable %d-point commit (median)" % cfg["ins_set"], "ins.durable.set", "",
        ratio(F, "ins.durable.set.x_fdatasync", "append + fdatasync", invert=True))
    row("durable commit (median) / append + fdatasync", "ins.durable.set.x_fdatasync")
    row("durable commit, mean", "ins.durable.set.mean")
    # 4. Table 8.1
    for tag, fr, pts in (("small", cfg["rt_small_frames"], cfg["rt_small_points"]),
                         ("large", cfg["rt_large_frames"], cfg["rt_large_points"])):
        t = "t81.%s." % tag
        label = "%d × %s" % (fr, "{:,}".format(pts))
        row("Table 8.1 (%s): insert one frame" % label, t + "hvdb.insert",
            "7 s (200k)" if tag == "small" else "",
            [ratio(F, t + "rtree3d.insert.x_hvdb", "R*-tree 3D/frame (STR)"),
             ratio(F, t + "rtree4d.insert.x_hvdb", "R*-tree 4D (insertion)")])
        row("Table 8.1 (%s): full-frame query, warm" % label, t + "hvdb.query.warm", "",
            [ratio(F, t + "rtree3d.query.warm.x_hvdb", "R*-tree 3D"),
             ratio(F, t + "rtree4d.query.warm.x_hvdb", "R*-tree 4D")])
        row("Table 8.1 (%s): full-frame query, cold" % label, t + "hvdb.query.cold", "",
            [ratio(F, t + "rtree3d.query.cold.x_hvdb", "R*-tree 3D"),
             ratio(F, t + "rtree4d.query.cold.x_hvdb", "R*-tree 4D")])
        row("Table 8.1 (%s): size on disk / raw bytes" % label, t + "hvdb.size.x_raw", "",
            [ratio(F, t + "rtree3d.size.x_hvdb", "R*-tree 3D"),
             ratio(F, t + "rtree4d.size.x_hvdb", "R*-tree 4D")])
    # 7. Hyperslices
    spans = ["t"] + ["span%d" % s for s in cfg["slice_spans"]]
    for s in spans:
        for lvl in (0, L):
            for mode in ("warm", "cold"):
                n = "slice.%s.l%d.%s" % (s, lvl, mode)
                if n in F:
                    fr = F[n]["params"]
                    desc = "orthogonal to t" if s == "t" else "tilted over %d frames" % fr["span_frames"]
                    row("slice %s, level %d, %s (%d frames read, %s points)" %
                        (desc, lvl, mode, fr["frames_read"], "{:,}".format(fr["result_points"])), n)

    print("| figure | hvdb (median, min..max, reps) | thesis 2008 | limit / peer, same run | issue goals (#) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(r)
    m = run["machine"]
    print()
    print("Run: `%s`, %s, %.0f s; %s CPUs %s, %.0f GiB, %s on %s (%s); load average %s at start, %s at end." % (
        run["command"], run["started"], run["duration_s"], m.get("nproc"), m.get("cpu_model"),
        m.get("memory_bytes", 0) / 2**30, m.get("disk", {}).get("fs"), m.get("disk", {}).get("device"),
        "virtual machine" if m.get("virtual_machine") else "bare metal",
        m.get("loadavg_at_start"), m.get("loadavg_at_end")))
    print("Targets: %d met, %d missed." % (run["targets_met"], run["targets_missed"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
