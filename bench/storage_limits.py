#!/usr/bin/python3
"""The storage limits of issue 35 (part 2), held over whole runs: hvdb-bench's cold window
(experiment 2, one 2 M-point frame), sustained and durable inserts (experiment 3) and small frames
on disk (experiment 9), each run a fresh hvdb-bench process on a fresh --scratch directory; the
medians over the runs, each figure beside its limit or target from the same run.

  /usr/bin/python3 bench/storage_limits.py [--build build] [--runs 5]
      [--out bench/results/storage_limits.json] [--scratch-root DIR] [-- extra hvdb-bench args]
  /usr/bin/python3 bench/storage_limits.py --from-runs   # only redo the medians from the runs

Every run's own JSON goes next to --out (storage_limits.runs/run-<i>.json). Exit status 0 also
when a target is missed: targets are results; a failing hvdb-bench exits 1.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# (figure, what it is, limit figure or None, target op, target value, where the target is from)
ROWS = [
    ("win.n2000000.hvdb.l0.cold", "cold 10 k-point window on a 2 M-point frame (ms)",
     "win.n2000000.limit.blocks.l0.cold", None, None, None),
    ("win.n2000000.hvdb.l0.cold.x_blocks",
     "cold window / the device reading as many random blocks of the tree at once", None,
     "<=", 1.5, "issue 35: as in bench/results (1.32x), on any machine of this kind"),
    ("ins.nosync.rate", "sustained inserts, 1000-point sets, merges included (M points/s)", None,
     ">=", 2.0, "issue 35"),
    ("ins.durable.set", "durable 1000-point commit, median (ms)", "ins.limit.append_fdatasync",
     None, None, None),
    ("ins.durable.set.x_fdatasync", "durable commit / append + fdatasync of its bytes", None,
     "<=", 1.5, "issue 35"),
    ("small.fixed_per_frame", "a 2 000-point frame's fixed cost on disk (KiB allocated)", None,
     "<=", 64, "issue 35"),
    ("small.x_points", "3 000 frames of 2 000 points: allocated bytes / point bytes", None,
     "<=", 1.5, "issue 35"),
]
# Per-run details worth keeping beside the medians (figure, param).
DETAILS = [
    ("win.n2000000.hvdb.l0.cold", "blocks_read_median"),
    ("win.n2000000.hvdb.l0.cold", "page_faults_median"),
    ("win.n2000000.hvdb.l0.cold", "device_read_bytes_median"),
    ("ins.nosync.rate", "wall_ms"),
    ("ins.nosync.rate", "merges"),
    ("ins.nosync.rate", "page_faults"),
    ("ins.durable.set", "page_faults_per_set_median"),
    ("small.x_points", "allocated_bytes"),
    ("small.x_points", "point_bytes"),
]


def value(fig):
    return fig["median"] if fig.get("median") is not None else fig.get("mean")


def met(op, v, target):
    return v <= target if op == "<=" else v >= target


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "storage_limits.json"))
    ap.add_argument("--scratch-root", default=os.environ.get("TMPDIR", "/tmp"),
                    help="where each run's fresh scratch directory is made (and removed)")
    ap.add_argument("--from-runs", action="store_true",
                    help="do not run hvdb-bench: take the runs' JSON files already next to --out")
    ap.add_argument("extra", nargs="*", help="more hvdb-bench arguments (after --)")
    a = ap.parse_args()
    if a.runs < 1:
        sys.exit("--runs must be at least 1")
    bench = os.path.join(a.build, "bench", "hvdb-bench")
    if not os.access(bench, os.X_OK):
        sys.exit("no %s: build it (ninja -C %s bench/hvdb-bench)" % (bench, a.build))
    runs_dir = os.path.splitext(a.out)[0] + ".runs"
    os.makedirs(runs_dir, exist_ok=True)
    runs = []
    for i in range(a.runs if not a.from_runs else 0):
        scratch = tempfile.mkdtemp(prefix="hvdb-limits-%d-" % i, dir=a.scratch_root)
        out = os.path.join(runs_dir, "run-%d.json" % i)
        cmd = [bench, "--only", "2,3,9", "--win-min", "2000000", "--win-max", "2000000",
               "--no-peers", "--no-plots", "--scratch", scratch, "--out", out] + a.extra
        load = os.getloadavg()
        t0 = time.monotonic()
        p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        if p.returncode != 0:
            sys.exit("run %d failed (%d): %s\n%s" % (i, p.returncode, " ".join(cmd),
                                                     p.stdout[-3000:]))
        with open(out) as f:
            figs = {g["name"]: g for g in json.load(f)["figures"]}
        runs.append({"figures": figs, "load_before": load, "seconds": time.monotonic() - t0,
                     "json": os.path.relpath(out, ROOT)})
        print("run %d: %.0f s, load %.2f" % (i, runs[-1]["seconds"], load[0]), flush=True)
    if a.from_runs:
        with open(a.out) as f:
            old = json.load(f)
        for i, path in enumerate(old["run_json"]):
            with open(os.path.join(ROOT, path)) as f:
                figs = {g["name"]: g for g in json.load(f)["figures"]}
            runs.append({"figures": figs, "load_before": old["load_before_each_run"][i],
                         "seconds": old["seconds_each_run"][i], "json": path})
        a.runs = len(runs)

    rows = []
    for name, what, limit, op, target, source in ROWS:
        per_run = [value(r["figures"][name]) for r in runs]
        row = {"figure": name, "what": what, "median": statistics.median(per_run),
               "runs": per_run}
        unit = runs[0]["figures"][name].get("unit")
        row["unit"] = unit
        if limit:
            lim = [value(r["figures"][limit]) for r in runs]
            row["limit_figure"] = limit
            row["limit_median"] = statistics.median(lim)
            row["limit_runs"] = lim
        if op:
            row["target"] = {"op": op, "value": target, "source": source,
                             "met": met(op, row["median"], target),
                             "runs_met": sum(met(op, v, target) for v in per_run)}
        rows.append(row)
    details = {}
    for name, param in DETAILS:
        details[name + "." + param] = [r["figures"][name]["params"].get(param) for r in runs]
    result = {
        "schema": "hvdb-storage-limits/1",
        "command": " ".join([os.path.relpath(sys.argv[0], ROOT)] + sys.argv[1:]),
        "bench_command": "hvdb-bench --only 2,3,9 --win-min 2000000 --win-max 2000000 "
                         "--no-peers --no-plots --scratch <fresh dir> " + " ".join(a.extra),
        "runs": a.runs,
        "load_before_each_run": [r["load_before"] for r in runs],
        "seconds_each_run": [r["seconds"] for r in runs],
        "run_json": [r["json"] for r in runs],
        "figures": rows,
        "details": details,
        "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    with open(a.out, "w") as f:
        json.dump(result, f, indent=1)
        f.write("\n")
    for row in rows:
        lim = " (limit %.4g)" % row["limit_median"] if "limit_median" in row else ""
        tgt = ""
        if "target" in row:
            t = row["target"]
            tgt = "  target %s %g: %s (%d/%d runs)" % (t["op"], t["value"],
                                                       "met" if t["met"] else "MISSED",
                                                       t["runs_met"], a.runs)
        print("%-40s %10.4g %s%s%s" % (row["figure"], row["median"], row["unit"], lim, tgt))
    print("wrote", a.out)


if __name__ == "__main__":
    main()
