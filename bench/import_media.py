#!/usr/bin/python3
"""import-media: `hvdb import-media` of a real 1080p photo, end to end (issue 33).

Times the whole `hvdb` process, as a user runs it: read the PNG (SJTU free-viewpoint rig,
camera 0, 1920x1080, ../shared/data), decode it, area-average it to the default 512-texel plane
(512x288 surfels), insert them in one durable transaction. Embedded (`--data`) and through an
hvdb-server on loopback (`--server`: the file's bytes travel in the request, the server decodes).
Each mode 5 times into its own dataset (frame 0); median, min and max of the wall time.
Target (issue 33): median <= 0.5 s.

Usage: bench/import_media.py [--build build] [--reps 5] [--out bench/results/import_media.json]
"""
import argparse
import json
import os
import shutil
import subprocess
import statistics
import sys
import tempfile
import time

import proc_clock
from proc_clock import stats


def run(cmd):
    return proc_clock.run(cmd, "import_media")


def clocked(cmd):
    return proc_clock.clocked(cmd, "import_media")


HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
PHOTO = os.path.join(ROOT, "..", "shared", "data", "sjtu-fvv-multiview-rgbd", "frame_0",
                     "images", "0.png")


def timed(hvdb, where, reps):
    walls, cpus, base_walls, base_cpus, inserted = [], [], [], [], None
    for i in range(reps):
        run([hvdb] + where + ["create", f"m{i}", "--fps", "30"])
        # The same process doing nothing but open the database and describe the dataset: what
        # starting `hvdb` costs on this machine at this moment, interleaved with the imports.
        w, c, _ = clocked([hvdb] + where + ["describe", f"m{i}"])
        base_walls.append(w)
        base_cpus.append(c)
        w, c, out = clocked([hvdb] + where + ["import-media", f"m{i}", PHOTO, "--json"])
        walls.append(w)
        cpus.append(c)
        inserted = json.loads(out)["inserted"]
    return {"median_s": statistics.median(walls), "min_s": min(walls), "max_s": max(walls),
            "reps": reps, "times_s": walls, "cpu_s": stats(cpus),
            "describe_baseline_s": stats(base_walls), "describe_baseline_cpu_s": stats(base_cpus),
            "points": inserted}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "import_media.json"))
    a = ap.parse_args()
    hvdb = os.path.join(a.build, "client", "hvdb")
    server_bin = os.path.join(a.build, "server", "hvdb-server")
    tmp = tempfile.mkdtemp(prefix="hvdb-import-media-")
    server = None
    try:
        embedded = timed(hvdb, ["--data", os.path.join(tmp, "emb")], a.reps)
        os.makedirs(os.path.join(tmp, "srv"))
        port_file = os.path.join(tmp, "port")
        server = subprocess.Popen([server_bin, "--data", os.path.join(tmp, "srv"), "--listen",
                                   "127.0.0.1:0", "--port-file", port_file],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 60
        while not (os.path.exists(port_file) and open(port_file).read().endswith("\n")):
            if time.time() > deadline or server.poll() is not None:
                sys.exit("import_media: hvdb-server did not start")
            time.sleep(0.05)
        port = int(open(port_file).read())
        served = timed(hvdb, ["--server", f"127.0.0.1:{port}"], a.reps)
    finally:
        if server is not None:
            server.terminate()
            server.wait()
        shutil.rmtree(tmp, ignore_errors=True)
    result = {
        "schema": "hvdb-bench/1",
        "experiment": "import-media of a 1920x1080 PNG, whole hvdb process",
        "file": os.path.relpath(PHOTO, ROOT),
        "file_bytes": os.path.getsize(PHOTO),
        "cpus": os.cpu_count(),
        "load_average_1m": os.getloadavg()[0],
        "target_median_s": 0.5,
        "embedded": embedded,
        "server": served,
    }
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(result, f, indent=2)
    for mode in ("embedded", "server"):
        r = result[mode]
        print(f"{mode}: median {r['median_s']:.3f} s ({r['min_s']:.3f}..{r['max_s']:.3f}, "
              f"n={r['reps']}), CPU {r['cpu_s']['median']:.3f} s, {r['points']} points; "
              f"'hvdb describe' alone {r['describe_baseline_s']['median']:.3f} s "
              f"(CPU {r['describe_baseline_cpu_s']['median']:.3f} s)")
    print(f"load average {result['load_average_1m']:.1f} on {result['cpus']} CPUs")


if __name__ == "__main__":
    main()
