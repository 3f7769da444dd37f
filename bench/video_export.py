#!/usr/bin/python3
"""Video export speed (issue 33 part 6: >= 10 frames/s at 1080p on the CPU renderer).

Loads the 16 CMU Panoptic frames into a fresh data directory with `hvdb import`, writes a
camera path orbiting the person at 1920x1080 (one entry per frame, the frames looped), and
times whole `hvdb render --video` runs (process start, query, render, encode, write) for MP4
and WebM. Writes the medians to bench/results/video_export.json.

  /usr/bin/python3 bench/video_export.py --hvdb build/client/hvdb [--frames 60] [--runs 5]
"""
import argparse
import glob
import json
import math
import os
import resource
import statistics
import subprocess
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "cmu-panoptic-kinoptic-171026-pose3")


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hvdb", default=os.path.join(HERE, "..", "build", "client", "hvdb"))
    ap.add_argument("--data", default=DATA, help="the Panoptic folder")
    ap.add_argument("--frames", type=int, default=60, help="images in the video")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "video_export.json"))
    a = ap.parse_args()
    plys = sorted(glob.glob(os.path.join(a.data, "kinoptic_ptclouds", "*.ply")))
    if not plys:
        raise SystemExit(f"video_export: no PLY files under {a.data}")
    load = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="hvdb-video-") as tmp:
        db = os.path.join(tmp, "data")
        base = [a.hvdb, "--data", db]
        run(base + ["create", "panoptic", "--fps", "29.97"])
        run(base + ["import", "panoptic", "--frame", "0", "--units-scale", "0.01"] + plys)
        # The person stands around (-0.4, -0.9, 0) m (y down); orbit at 3 m, 1.3 m up.
        cams = []
        for i in range(a.frames):
            ang = 2 * math.pi * i / a.frames
            eye = [-0.4 + 3 * math.sin(ang), -2.2, 3 * math.cos(ang)]
            cams.append({"look_at": {"eye": eye, "target": [-0.4, -0.9, 0], "up": [0, -1, 0],
                                     "fov_y_deg": 45, "width": 1920, "height": 1080},
                         "frame": i % len(plys)})
        path = os.path.join(tmp, "orbit.json")
        with open(path, "w") as f:
            json.dump({"cameras": cams}, f)
        results = {}
        for ext in ["mp4", "webm"]:
            out = os.path.join(tmp, "orbit." + ext)
            times, cpu, info = [], [], None
            for _ in range(a.runs):
                r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
                t0 = time.perf_counter()
                info = json.loads(run(base + ["render", "panoptic", "--path", path, "--video", out,
                                              "--fps", "30", "--renderer", "cpu", "--json"]))
                times.append(time.perf_counter() - t0)
                r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
                cpu.append(r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime)
            med = statistics.median(times)
            results[ext] = {"codec": info["codec"], "frames": info["frames"],
                            "width": info["width"], "height": info["height"],
                            "bytes": os.path.getsize(out), "seconds": times,
                            "median_seconds": med, "frames_per_second": a.frames / med,
                            # CPU time (user + sys) of the run: what it costs whatever else
                            # shares the machine.
                            "cpu_seconds": cpu, "median_cpu_seconds": statistics.median(cpu),
                            "frames_per_cpu_second": a.frames / statistics.median(cpu),
                            "render_ms_per_frame": info["render_ms"] / a.frames}
            print(f"{ext} ({info['codec']}): {a.frames} frames at 1920x1080 in {med:.2f} s "
                  f"(median of {a.runs}): {a.frames / med:.1f} frames/s, "
                  f"{os.path.getsize(out) / 1e6:.1f} MB; {statistics.median(cpu):.2f} CPU-s "
                  f"({a.frames / statistics.median(cpu):.1f} frames per CPU-second)")
    fps = min(r["frames_per_second"] for r in results.values())
    doc = {"benchmark": "video_export", "command": "hvdb render --path orbit.json --video OUT "
           "--fps 30 --renderer cpu (embedded, --data)", "frames": a.frames, "runs": a.runs,
           "cpus": os.cpu_count(), "load_average_before": load, "results": results,
           "targets": [{"name": "video export >= 10 frames/s at 1080p, CPU renderer (slowest "
                        "container)", "value": fps, "limit": 10, "met": fps >= 10}]}
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
