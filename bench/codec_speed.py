#!/usr/bin/python3
"""hvdb-codec's whole commands timed: encode and decode of the 16 Panoptic frames laid side by
side as one 1.19 M-point cloud, lossless on an 11-bit grid (positions + colour), octree
(version 2, the default) against the pair hierarchy (version 1), medians of --runs runs of the
process (wall and CPU seconds). Writes bench/results/codec_speed.json.

  /usr/bin/python3 bench/codec_speed.py --hvdb-codec build/client/hvdb-codec
"""
import argparse, json, os, resource, statistics, subprocess, sys, tempfile, time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def merged_ply(shared, path):
    """The 16 frames side by side (a 4 x 4 layout, 2 m apart): one large real cloud."""
    folder = os.path.join(shared, "cmu-panoptic-kinoptic-171026-pose3", "kinoptic_ptclouds")
    files = sorted(f for f in os.listdir(folder) if f.endswith(".ply"))[:16]
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"),
                   ("nz", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1"), ("a", "u1")])
    parts = []
    for i, f in enumerate(files):
        data = open(os.path.join(folder, f), "rb").read()
        head = data[:data.index(b"end_header\n") + 11]
        n = int(head.split(b"element vertex ")[1].split(b"\n")[0])
        a = np.frombuffer(data[len(head):len(head) + n * dt.itemsize], dtype=dt).copy()
        a["x"] += 200 * (i % 4)
        a["z"] += 200 * (i // 4)
        parts.append(a)
    pts = np.concatenate(parts)
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % len(pts) +
              "".join("property float %s\n" % c for c in ("x", "y", "z", "nx", "ny", "nz")) +
              "".join("property uchar %s\n" % c for c in ("red", "green", "blue", "alpha")) +
              "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode() + pts.tobytes())
    return len(pts)


def timed(cmd):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        sys.exit("codec_speed: %s failed:\n%s" % (" ".join(cmd), r.stdout))
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hvdb-codec", required=True)
    ap.add_argument("--shared-data", default=os.path.join(HERE, "..", "..", "shared", "data"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "codec_speed.json"))
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "panoptic16.ply")
        n = merged_ply(a.shared_data, ply)
        report = {"points": n, "runs": a.runs, "grid_bits": 11, "cpus": os.cpu_count()}
        for geometry in ("octree", "pairs"):
            stream = os.path.join(tmp, geometry + ".hv7")
            enc = [a.hvdb_codec, "encode", ply, stream, "--qp", "11", "--qc", "8",
                   "--attributes", "position,color", "--geometry", geometry]
            dec = [a.hvdb_codec, "decode", stream, os.path.join(tmp, "out.ply")]
            e = [timed(enc) for _ in range(a.runs)]
            d = [timed(dec) for _ in range(a.runs)]
            ew, dw = statistics.median(w for w, _ in e), statistics.median(w for w, _ in d)
            report[geometry] = {
                "bpp": 8.0 * os.path.getsize(stream) / n,
                "encode_wall_s": ew, "encode_cpu_s": statistics.median(c for _, c in e),
                "decode_wall_s": dw, "decode_cpu_s": statistics.median(c for _, c in d),
                "encode_mpts_s": n / ew / 1e6, "decode_mpts_s": n / dw / 1e6}
            print(geometry, json.dumps(report[geometry]))
    report["targets"] = {"encode_mpts_s": 2.0, "decode_mpts_s": 10.0}
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(report, f, indent=2)
        f.write("\n")


if __name__ == "__main__":
    main()
