#!/usr/bin/python3
"""MPEG G-PCC (TMC13's tmc3) against hvdb7 (`hvdb-codec`) on the codec-bench's shared frames.

Both coders get the SAME points: each frame quantised exactly as hvdb7 does for qp bits
(docs/CODEC.md, "Attribute groups": origin = bounding-box minimum, step = largest extent /
(2^qp - 1), q = round((x - origin) / step)), written as integer coordinates with 8-bit colour.
Re-quantising such a cloud at the same qp is the identity (origin 0, step 1), so hvdb-codec
codes it losslessly too. tmc3 runs the CTC "lossless geometry, lossless attributes" octree
configuration with the predicting transform (cfg/octree-predt-ctc-lossless-geom-lossless-attrs
.yaml), every point kept (mergeDuplicatedPoints 0). Both decoders' outputs are checked against
the input (the multiset of positions, and of position + colour), so only lossless results count.
TMC13 is never a dependency of hvdb: build it outside the repository and pass --tmc3.

Writes JSON (bench/README.md, "MPEG G-PCC on the shared frames"): per frame and grid, both
coders' bits per input point for positions and for positions + colour, their ratio, medians of
--repetitions encode/decode wall times, and the duplicates (points sharing a voxel).
"""
import argparse
import json
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
             "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
             "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
             "float64": "f8"}


def read_ply(path):
    """The vertex element of a PLY (ascii or binary little endian) as a dict of columns."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            sys.exit(f"gpcc_compare: {path} is not a PLY file")
        fmt, props, count, in_vertex, header_lines = None, [], 0, False, 1
        while True:
            line = f.readline()
            header_lines += 1
            if not line:
                sys.exit(f"gpcc_compare: {path}: no end_header")
            tok = line.decode("ascii", "replace").split()
            if not tok:
                continue
            if tok[0] == "format":
                fmt = tok[1]
            elif tok[0] == "element":
                in_vertex = tok[1] == "vertex"
                if in_vertex:
                    count = int(tok[2])
            elif tok[0] == "property" and in_vertex:
                if tok[1] == "list":
                    sys.exit(f"gpcc_compare: {path}: list properties on vertices are not read")
                props.append((tok[2], PLY_TYPES[tok[1]]))
            elif tok[0] == "end_header":
                break
        if fmt == "binary_little_endian":
            arr = np.frombuffer(f.read(count * np.dtype([(n, "<" + t) for n, t in props]).itemsize),
                                dtype=[(n, "<" + t) for n, t in props], count=count)
            return {n: arr[n] for n, _ in props}
        if fmt == "ascii":
            arr = np.loadtxt(f, max_rows=count, ndmin=2)
            return {n: arr[:, i].astype(t) for i, (n, t) in enumerate(props)}
        sys.exit(f"gpcc_compare: {path}: PLY format {fmt} is not read (ascii or little endian)")


def load(path, scale):
    """Positions as hvdb's ReadPly makes them (float32 of the double times the scale), colours."""
    v = read_ply(path)
    xyz = np.stack([(v[a].astype(np.float64) * scale).astype(np.float32) for a in "xyz"], axis=1)
    rgb = None
    if all(c in v for c in ("red", "green", "blue")):
        rgb = np.stack([v[c].astype(np.uint8) for c in ("red", "green", "blue")], axis=1)
    return xyz, rgb


def quantise(xyz, qp):
    """hvdb7's position quantisation (codec/channels.cc Quantizer): integer grid cells."""
    x = xyz.astype(np.float64)
    lo = x.min(axis=0)
    extent = float((x.max(axis=0) - lo).max())
    top = (1 << qp) - 1
    step = extent / top if extent > 0 else 1.0
    # llround: halves away from zero; the values are >= 0.
    return np.clip(np.floor((x - lo) / step + 0.5), 0, top).astype(np.int64)


def write_ply(path, q, rgb=None):
    """Binary PLY: float x y z (exact for integers below 2^24) and, given, uchar red green blue."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if rgb is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    arr = np.empty(len(q), dtype=fields)
    for i, a in enumerate("xyz"):
        arr[a] = q[:, i]
    if rgb is not None:
        for i, c in enumerate(("red", "green", "blue")):
            arr[c] = rgb[:, i]
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(q)}"]
    head += [f"property {'float' if t == '<f4' else 'uchar'} {n}" for n, t in fields]
    head += ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(head) + "\n").encode("ascii"))
        f.write(arr.tobytes())


def rows(q, rgb=None):
    """Points as sorted rows, to compare clouds as multisets (both coders reorder points)."""
    m = q.astype(np.int64) if rgb is None else np.hstack([q.astype(np.int64), rgb.astype(np.int64)])
    return m[np.lexsort(m.T[::-1])]


def decoded_rows(path, with_colour):
    v = read_ply(path)
    xyz = np.stack([v[a].astype(np.float64) for a in "xyz"], axis=1)
    q = np.rint(xyz).astype(np.int64)
    if np.abs(xyz - q).max(initial=0) > 1e-6:
        return None  # not on the integer grid: not lossless
    rgb = None
    if with_colour:
        if not all(c in v for c in ("red", "green", "blue")):
            return None
        rgb = np.stack([v[c].astype(np.int64) for c in ("red", "green", "blue")], axis=1)
    return rows(q, rgb)


def cpu_children():
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed(cmd, log):
    """Runs cmd; (wall seconds, CPU seconds of all its threads, its output). The CPU time is
    the steadier figure on a shared machine."""
    t0, c0 = time.monotonic(), cpu_children()
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    dt, dc = time.monotonic() - t0, cpu_children() - c0
    with open(log, "a") as f:
        f.write("$ " + " ".join(cmd) + "\n" + r.stdout + "\n")
    if r.returncode != 0:
        sys.exit(f"gpcc_compare: {cmd[0]} failed ({r.returncode}); see {log}:\n{r.stdout[-2000:]}")
    return dt, dc, r.stdout


def times(args, enc, dec, log):
    """Medians over --repetitions of encode and decode, wall and CPU seconds; the encoder's
    last output."""
    runs = []
    for _ in range(args.repetitions):
        e, d = timed(enc, log), timed(dec, log)
        runs.append((e[0], e[1], d[0], d[1], e[2]))
    keys = ("encode_s", "encode_cpu_s", "decode_s", "decode_cpu_s")
    return {k: statistics.median(r[i] for r in runs) for i, k in enumerate(keys)}, runs[-1][4]


# The CTC lossless-geometry, lossless-attribute octree configuration (predicting transform),
# cat1 settings for content that is neither LiDAR nor cat3 (inferredDirectCodingMode 1,
# qtbt, planar on unless the sequence is "solid"/"dense"; here both are measured).
GEOM_FLAGS = ["--mergeDuplicatedPoints=0", "--positionQuantizationScale=1",
              "--trisoupNodeSizeLog2=0", "--neighbourAvailBoundaryLog2=8",
              "--intra_pred_max_node_size_log2=6", "--inferredDirectCodingMode=1",
              "--maxNumQtBtBeforeOt=4", "--minQtbtSizeLog2=0", "--planarModeIdcmUse=0"]
COLOUR_FLAGS = ["--convertPlyColourspace=1", "--transformType=1",
                "--numberOfNearestNeighborsInPrediction=3", "--levelOfDetailCount=12",
                "--intraLodPredictionSkipLayers=0", "--interComponentPredictionEnabled=0",
                "--adaptivePredictionThreshold=64", "--qp=4", "--qpChromaOffset=0",
                "--bitdepth=8", "--colourMatrix=8", "--attrOffset=0", "--attrScale=1",
                "--attribute=color"]


def run_tmc3(args, ply, want, with_colour, planar, work, log):
    stream, dec = os.path.join(work, "g.bin"), os.path.join(work, "g.dec.ply")
    enc = [args.tmc3, "--mode=0", f"--uncompressedDataPath={ply}",
           f"--compressedStreamPath={stream}", *GEOM_FLAGS, f"--planarEnabled={planar}"]
    if with_colour:
        enc += COLOUR_FLAGS
    dcmd = [args.tmc3, "--mode=1", f"--compressedStreamPath={stream}",
            f"--reconstructedDataPath={dec}", "--outputBinaryPly=1"]
    if with_colour:
        dcmd += ["--convertPlyColourspace=1"]
    t, out = times(args, enc, dcmd, log)
    got = decoded_rows(dec, with_colour)
    lossless = got is not None and got.shape == want.shape and bool((got == want).all())
    res = {"bytes": os.path.getsize(stream), **t,
           "decoded_points": int(len(read_ply(dec)["x"])), "lossless": lossless}
    m = re.search(r"positions bitstream size (\d+) B", out)
    if m:
        res["position_bytes_reported"] = int(m.group(1))
    m = re.search(r"colors bitstream size (\d+) B", out)
    if m:
        res["colour_bytes_reported"] = int(m.group(1))
    return res


def run_hvdb(args, ply, want, with_colour, qp, work, log):
    stream, dec = os.path.join(work, "h.hv7"), os.path.join(work, "h.dec.ply")
    attrs = "position,color" if with_colour else "position"
    enc = [args.hvdb_codec, "encode", ply, stream, "--qp", str(qp), "--qc", "8",
           "--attributes", attrs]
    dcmd = [args.hvdb_codec, "decode", stream, dec]
    t, _ = times(args, enc, dcmd, log)
    got = decoded_rows(dec, with_colour)
    lossless = got is not None and got.shape == want.shape and bool((got == want).all())
    return {"bytes": os.path.getsize(stream), **t,
            "decoded_points": int(len(read_ply(dec)["x"])), "lossless": lossless}


def data_sets(args):
    sets = []
    for f in range(args.first_frame, args.first_frame + args.frames):
        p = (f"{args.shared_data}/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/"
             f"ptcloud_hd{f:08d}.ply")
        sets.append((f"panoptic{f}", p, 0.01))
    sets.append(("bunny", f"{args.shared_data}/stanford-bunny/reconstruction/bun_zipper.ply", 1.0))
    for e in args.ply:
        if "=" not in e:
            sys.exit("gpcc_compare: --ply takes NAME=PATH")
        name, path = e.split("=", 1)
        sets.append((name, path, 1.0))
    for name, path, _ in sets:
        if not os.path.isfile(path):
            sys.exit(f"gpcc_compare: {name}: no file {path} (check --shared-data / --ply)")
    return sets


def table(report):
    """The bench/README.md table: bits per input point, hvdb7 against tmc3's better planar
    setting; colour = the growth over the same points' position-only stream, for both."""
    out = ["| data | points | grid | duplicates | positions hvdb7 / tmc3 (ratio) | "
           "+ colour hvdb7 / tmc3 (ratio) | colour alone hvdb7 / tmc3 |",
           "|---|---:|---:|---:|---|---|---|"]
    for name, S in report["sets"].items():
        for qp, G in S["grids"].items():
            p = G["position"]
            row = (f"| {name} | {S['points']:,} | {qp} | {G['duplicate_fraction']:.1%} | "
                   f"{p['hvdb7']['bpp']:.2f} / {p['tmc3_best_bpp']:.2f} "
                   f"({p['ratio_hvdb7_to_tmc3']:.3f}) |")
            if "position+colour" in G:
                c = G["position+colour"]
                row += (f" {c['hvdb7']['bpp']:.2f} / {c['tmc3_best_bpp']:.2f} "
                        f"({c['ratio_hvdb7_to_tmc3']:.3f}) | "
                        f"{c['hvdb7']['bpp'] - p['hvdb7']['bpp']:.2f} / "
                        f"{c['tmc3_best_bpp'] - p['tmc3_best_bpp']:.2f} |")
            else:
                row += " — | — |"
            out.append(row)
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--table", metavar="JSON",
                    help="only print the markdown table of an earlier run's JSON")
    ap.add_argument("--tmc3", help="TMC13's tmc3 binary (built outside hvdb)")
    ap.add_argument("--hvdb-codec", help="build/client/hvdb-codec")
    ap.add_argument("--shared-data", default=os.path.join(os.path.dirname(__file__),
                                                          "../../shared/data"))
    ap.add_argument("--frames", type=int, default=4, help="Panoptic frames from --first-frame")
    ap.add_argument("--first-frame", type=int, default=380)
    ap.add_argument("--ply", action="append", default=[],
                    help="more inputs, NAME=PATH (as codec-bench --ply: ingested frames)")
    ap.add_argument("--grids", default="10,11", help="qp values (grid bits), comma-separated")
    ap.add_argument("--repetitions", type=int, default=3, help="timing runs (median)")
    ap.add_argument("--out", default="bench/results/gpcc.json")
    ap.add_argument("--log", default=os.path.join(tempfile.gettempdir(), "gpcc_compare.log"),
                    help="the coders' output")
    args = ap.parse_args()
    if args.table:
        with open(args.table) as f:
            print(table(json.load(f)))
        return
    for b in (args.tmc3, args.hvdb_codec):
        if not (b and os.path.isfile(b) and os.access(b, os.X_OK)):
            sys.exit(f"gpcc_compare: {b} is not an executable; pass --tmc3 / --hvdb-codec")
    grids = [int(g) for g in args.grids.split(",")]
    if any(g < 1 or g > 21 for g in grids) or args.repetitions < 1 or args.frames < 0:
        sys.exit("gpcc_compare: --grids takes qp values 1..21, --repetitions at least 1, "
                 "--frames 0 or more")
    log = args.log
    open(log, "w").close()
    version = subprocess.run([args.tmc3, "--help"], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True).stdout
    m = re.search(r"version ([^\s]+)", version)
    report = {"tmc3_version": m.group(1) if m else None, "repetitions": args.repetitions,
              "config": {"tmc3_geometry": GEOM_FLAGS + ["--planarEnabled=0|1"],
                         "tmc3_colour": COLOUR_FLAGS,
                         "hvdb_codec": "--qp QP --qc 8 --attributes position[,color]"},
              "sets": {}}
    work = tempfile.mkdtemp(prefix="gpcc-")
    try:
        for name, path, scale in data_sets(args):
            xyz, rgb = load(path, scale)
            n = len(xyz)
            S = report["sets"][name] = {"path": path, "points": n, "colour": rgb is not None,
                                        "grids": {}}
            for qp in grids:
                q = quantise(xyz, qp)
                voxels = len(np.unique(q, axis=0))
                G = {"duplicates": n - voxels, "duplicate_fraction": (n - voxels) / n,
                     "occupied_voxels": voxels}
                modes = [("position", False)] + ([("position+colour", True)] if rgb is not None
                                                 else [])
                for mode, col in modes:
                    ply = os.path.join(work, "in.ply")
                    write_ply(ply, q, rgb if col else None)
                    want = rows(q, rgb if col else None)
                    t = {f"planar{p}": run_tmc3(args, ply, want, col, p, work, log) for p in (0, 1)}
                    h = run_hvdb(args, ply, want, col, qp, work, log)
                    for r in list(t.values()) + [h]:
                        r["bpp"] = 8.0 * r["bytes"] / n
                    best = min(t.values(), key=lambda r: r["bytes"])
                    G[mode] = {"tmc3": t, "hvdb7": h, "tmc3_best_bpp": best["bpp"],
                               "ratio_hvdb7_to_tmc3": h["bpp"] / best["bpp"],
                               "all_lossless": all(r["lossless"] for r in list(t.values()) + [h])}
                    print(f"{name} qp {qp} {mode}: hvdb7 {h['bpp']:.3f} bpp, tmc3 "
                          f"{t['planar0']['bpp']:.3f} (planar 0) {t['planar1']['bpp']:.3f} "
                          f"(planar 1); ratio {G[mode]['ratio_hvdb7_to_tmc3']:.3f}; dups "
                          f"{G['duplicate_fraction']:.1%}; lossless {G[mode]['all_lossless']}",
                          flush=True)
                S["grids"][str(qp)] = G
    finally:
        shutil.rmtree(work, ignore_errors=True)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(report, f, indent=1)
    print(table(report))
    bad = [(s, g, m) for s, S in report["sets"].items() for g, G in S["grids"].items()
           for m in ("position", "position+colour") if m in G and not G[m]["all_lossless"]]
    if bad:
        sys.exit(f"gpcc_compare: not lossless (see {log}): {bad}")


if __name__ == "__main__":
    main()
