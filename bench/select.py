#!/usr/bin/env python3
"""A served selection of tens of thousands of points (issue: edits at the machine's limit).

  /usr/bin/python3 bench/select.py [--build build] [--runs 5] [--out bench/results/select.json]

Each run imports the real CMU Panoptic video (16 frames, ~1.19 M points) into a fresh data
directory with `hvdb import`, starts `hvdb-server` on it, and through the Python client
selects the points of frame 5 right of x = -0.4 m (57 046 points, as a marquee over the person
does) into a fresh label bit, 15 times (replace mode: each select also scans every frame for
the points already carrying its bit, which label summaries make a look at tree headers). The
first select of a fresh server and the median of selects 4..15 (warm) are the run's figures.

Beside them, in the same run and process (embedded, `hvdb.open`): the scan a replace-mode
select makes for a bit the data does not carry (label summaries: no tree and no bucket read),
and the full-resolution scan of every frame, which is what that scan read before summaries
(every block, every record tested). Medians over runs are reported; each run's figures under
`runs`.
"""
import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PANOPTIC = os.path.join(ROOT, "..", "shared", "data", "cmu-panoptic-kinoptic-171026-pose3",
                        "kinoptic_ptclouds", "ptcloud_hd*.ply")
FPS = 29.97
FRAME = 5


def one_run(build, hvdb):
    files = sorted(glob.glob(PANOPTIC))
    if len(files) != 16:
        sys.exit(f"select: the Panoptic sequence is missing ({PANOPTIC})")
    tmp = tempfile.mkdtemp(prefix="hvdb-select-")
    data = os.path.join(tmp, "data")
    cli = os.path.join(build, "client", "hvdb")

    def run(*args):
        subprocess.run([cli, "--data", data] + [str(a) for a in args], check=True,
                       capture_output=True)

    run("create", "panoptic", "--fps", FPS)
    run("import", "panoptic", "--frame", 0, "--units-scale", 0.01, *files)
    port_file = os.path.join(tmp, "port")
    srv = subprocess.Popen([os.path.join(build, "server", "hvdb-server"), "--data", data,
                            "--listen", "127.0.0.1:0", "--port-file", port_file],
                           stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 30
        while not (os.path.exists(port_file) and open(port_file).read().split()):
            if time.time() > deadline or srv.poll() is not None:
                sys.exit("select: hvdb-server did not start")
            time.sleep(0.05)
        db = hvdb.connect("127.0.0.1:" + open(port_file).read().split()[0])
        t = FRAME / FPS
        ms, selected = [], 0
        for bit in range(15):
            t0 = time.perf_counter()
            r = db.select("panoptic", bit, x=(-0.4, 1e9), t=(t, t), mode="replace")
            ms.append((time.perf_counter() - t0) * 1e3)
            selected = r["selected"]
        db.close()
    finally:
        srv.terminate()
        srv.wait()
    # The embedded scans, on the same data (the server has let go of it).
    emb = hvdb.open(data)
    def scan(mask):
        walls = []
        for _ in range(7):
            t0 = time.perf_counter()
            pts = emb.window("panoptic", label_mask=mask)
            walls.append((time.perf_counter() - t0) * 1e3)
        return statistics.median(walls), len(pts["id"])
    masked_ms, masked_n = scan(1 << 20)
    full_ms, full_n = scan(0)
    emb.close()
    subprocess.run(["rm", "-rf", tmp], check=False)
    return {"selected": selected, "first_select_ms": round(ms[0], 1),
            "warm_select_ms_median": round(statistics.median(ms[3:]), 1),
            "masked_scan_ms": round(masked_ms, 2), "masked_scan_points": masked_n,
            "full_scan_ms": round(full_ms, 1), "full_scan_points": full_n}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "select.json"))
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.build, "python"))
    import hvdb  # noqa: E402 (the build's module)
    runs = []
    for i in range(a.runs):
        runs.append(one_run(a.build, hvdb))
        print(f"run {i + 1}/{a.runs}: {runs[-1]}", flush=True)
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    out = {"command": "/usr/bin/python3 bench/select.py", "cpus": os.cpu_count(),
           "medians": med,
           "masked_scan_vs_full_scan": round(med["masked_scan_ms"] / med["full_scan_ms"], 4),
           "runs": runs}
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
    print(json.dumps(out["medians"], indent=2))


if __name__ == "__main__":
    main()
