#!/usr/bin/python3
"""The bulk-ingest targets of issue 38, timed as a user meets them: whole commands with their
default flags, each run a fresh process (and a fresh data folder), the median of several runs.

  /usr/bin/python3 bench/ingest_targets.py [--build build] [--runs 3] [--out bench/results/ingest_targets.json]

- SJTU stage frame (8 cameras 1920x1080, ../shared/data): `hvdb-ingest run REC --dataset sjtu
  --data DIR` at full resolution and with `--stride 2` (targets 10 s and 3 s).
- 7-Scenes RGB-D (640x480, 24 frames): frames/s of the whole `hvdb-ingest run` (target 30).
- Stereo: `hvdb-ingest stereo LEFT RIGHT --out X.pfm --num-disparities N` on every shared
  Middlebury pair, against OpenCV SGBM's time from `stereo-bench` in the same run (target: 3x,
  at or below SGBM's bad-2px; the bad-pixel rates come from stereo-bench, whose hvdb matcher
  runs what the command's defaults run on these natural pairs: the parabola).

Recordings come from `ingest-bench --write-recordings`. Nothing here is a CTest test: the
figures depend on the machine (bench/results/machine.txt).
"""
import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def timed(cmd, env=None):
    t0 = time.monotonic()
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    dt = time.monotonic() - t0
    if p.returncode != 0:
        sys.exit("failed (%d): %s\n%s" % (p.returncode, " ".join(cmd), p.stderr[-2000:]))
    return dt, p.stdout


def ingest_runs(ingest, rec, extra, runs, scratch, name):
    walls, reports = [], []
    for i in range(runs):
        data = os.path.join(scratch, "data-%s-%d" % (name, i))
        report = os.path.join(scratch, "report-%s-%d.json" % (name, i))
        dt, _ = timed([ingest, "run", rec, "--dataset", name, "--data", data, "--quiet",
                       "--report", report] + extra)
        walls.append(dt)
        with open(report) as f:
            reports.append(json.load(f))
        shutil.rmtree(data, ignore_errors=True)
    return walls, reports


def stage_medians(reports):
    stages = {}
    for r in reports:
        for fr in r["frames"]:
            for k, v in fr["stage_ms"].items():
                stages.setdefault(k, []).append(v)
    return {k: round(statistics.median(v), 1) for k, v in sorted(stages.items())}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--parts", default="sjtu,rgbd,stereo")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "ingest_targets.json"))
    a = ap.parse_args()
    ingest = os.path.join(a.build, "ingest", "hvdb-ingest")
    parts = a.parts.split(",")
    scratch = tempfile.mkdtemp(prefix="ingest-targets-")
    doc = {"benchmark": "ingest_targets", "command": " ".join(sys.argv), "runs": a.runs,
           "machine": {"cpus": os.cpu_count(), "platform": platform.platform()},
           "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:
        subprocess.run([os.path.join(a.build, "bench", "ingest-bench"), "--write-recordings", scratch],
                       check=True, stdout=subprocess.DEVNULL)
        if "sjtu" in parts:
            rec = os.path.join(scratch, "rec-sjtu")
            out = {}
            for stride, target in ((1, 10.0), (2, 3.0)):
                extra = [] if stride == 1 else ["--stride", str(stride)]
                walls, reports = ingest_runs(ingest, rec, extra, a.runs, scratch, "sjtu%d" % stride)
                med = statistics.median(walls)
                out["stride%d" % stride] = {
                    "command": "hvdb-ingest run REC --dataset sjtu --data DIR" + ("" if stride == 1 else " --stride 2"),
                    "runs_s": [round(w, 3) for w in walls], "median_s": round(med, 3), "target_s": target,
                    "met": med <= target, "points": reports[0]["points"],
                    "outliers_removed": reports[0]["frames"][0]["outliers_removed"],
                    "stage_ms_median": stage_medians(reports)}
                print("sjtu stride %d: median %.2f s (target %.0f s) %s" % (stride, med, target, out["stride%d" % stride]["stage_ms_median"]))
            doc["sjtu"] = out
        if "rgbd" in parts:
            rec = os.path.join(scratch, "rec-7scenes")
            walls, reports = ingest_runs(ingest, rec, [], a.runs, scratch, "rgbd")
            frames = reports[0]["ingested"]
            fps = [frames / w for w in walls]
            med = statistics.median(fps)
            doc["rgbd"] = {"command": "hvdb-ingest run REC --dataset s --data DIR (7-Scenes, 640x480)",
                           "frames": frames, "runs_s": [round(w, 3) for w in walls],
                           "frames_per_s": [round(f, 2) for f in fps], "median_frames_per_s": round(med, 2),
                           "target_frames_per_s": 30, "met": med >= 30,
                           "stage_ms_median": stage_medians(reports)}
            print("7-scenes: median %.1f frames/s (target 30) %s" % (med, doc["rgbd"]["stage_ms_median"]))
        if "stereo" in parts:
            sb = os.path.join(scratch, "stereo.json")
            subprocess.run([os.path.join(a.build, "bench", "stereo-bench"), "--out", sb],
                           check=True, stdout=subprocess.DEVNULL)
            with open(sb) as f:
                st = json.load(f)
            pairs = []
            for s in st["scenes"]:
                left, right = s["left"], s["right"]
                cmd = [ingest, "stereo", left, right, "--out", os.path.join(scratch, "d.pfm"),
                       "--num-disparities", str(s["ndisp"])]
                walls = [timed(cmd)[0] * 1e3 for _ in range(a.runs)]
                med = statistics.median(walls)
                pairs.append({"set": s["set"], "scene": s["scene"], "ndisp": s["ndisp"],
                              "command_ms": round(med, 1), "matcher_ms_in_process": round(s["hvdb"]["ms"], 1),
                              "sgbm_ms": round(s["sgbm"]["ms"], 1), "x_sgbm": round(med / s["sgbm"]["ms"], 2),
                              "hvdb_bad2": round(s["hvdb"]["bad2"], 2), "sgbm_bad2": round(s["sgbm"]["bad2"], 2)})
            # The process's own start (loading its libraries) with nothing to do.
            start = statistics.median([timed([ingest, "stereo", "--help"])[0] * 1e3 for _ in range(5)])
            mean = lambda k: statistics.mean(p[k] for p in pairs)
            ratio = statistics.mean(p["x_sgbm"] for p in pairs)
            doc["stereo"] = {"command": "hvdb-ingest stereo LEFT RIGHT --out D.pfm --num-disparities N (defaults: --subpixel auto = parabola)",
                             "pairs": pairs, "mean_x_sgbm": round(ratio, 2),
                             "x_sgbm_of_means": round(mean("command_ms") / mean("sgbm_ms"), 2),
                             "command_ms_mean": round(mean("command_ms"), 1),
                             "matcher_ms_in_process_mean": round(mean("matcher_ms_in_process"), 1),
                             "sgbm_ms_mean": round(mean("sgbm_ms"), 1),
                             "process_start_ms": round(start, 1),
                             "hvdb_bad2_mean": round(mean("hvdb_bad2"), 2), "sgbm_bad2_mean": round(mean("sgbm_bad2"), 2),
                             "target_x_sgbm": 3.0, "met": ratio <= 3.0 and mean("hvdb_bad2") <= mean("sgbm_bad2")}
            print("stereo: whole command %.1f ms mean (%.2fx SGBM's %.1f ms; process start alone %.0f ms), "
                  "bad-2px %.2f %% vs SGBM %.2f %%" % (mean("command_ms"), ratio, mean("sgbm_ms"), start,
                                                        mean("hvdb_bad2"), mean("sgbm_bad2")))
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    with open(a.out, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    print("wrote", a.out)


if __name__ == "__main__":
    main()
