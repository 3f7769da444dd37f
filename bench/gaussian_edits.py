#!/usr/bin/python3
"""Edits of a Gaussian-splat dataset timed from Python (embedded, as a user's script runs them):
a transaction that turns every splat of a frame (a quarter turn about z: new records, covariance
and SH turned, written as a segment), the same transaction moving them instead (ids and records
kept: the peer without the Gaussian work), and the undo of each, on a seeded synthetic 3DGS PLY
of --splats splats at SH degree 3, alternated. Medians of --runs; writes bench/results/gaussian_edits.json.

  PYTHONPATH=build/python /usr/bin/python3 bench/gaussian_edits.py [--splats 1000000] [--runs 5]
"""
import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "python"))
import hvdb  # noqa: E402
from test_gaussians import _ply  # noqa: E402  (the tests' seeded Inria-layout PLY)

QUARTER = [[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]


def timed_edit(db, matrix, translate, times):
    t0 = time.monotonic()
    with db.transaction("s") as tx:
        tx.transform(matrix=matrix, translate=translate)
    times["edit"].append(time.monotonic() - t0)
    t0 = time.monotonic()
    db.undo("s", tx.result["lsn"])
    times["undo"].append(time.monotonic() - t0)


def summary(times):
    return {"edit_s": round(statistics.median(times["edit"]), 3),
            "undo_s": round(statistics.median(times["undo"]), 3),
            "edit_runs_s": [round(x, 3) for x in times["edit"]],
            "undo_runs_s": [round(x, 3) for x in times["undo"]]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--splats", type=int, default=1_000_000)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "gaussian_edits.json"))
    a = ap.parse_args()
    tmp = tempfile.mkdtemp(prefix="hvdb-gaussian-edits-")
    try:
        _ply(os.path.join(tmp, "s.ply"), a.splats, 1, degree=3)
        pts, g = hvdb.read_splats(os.path.join(tmp, "s.ply"))
        with hvdb.open(os.path.join(tmp, "db")) as db:
            db.create("s", fps=30, gaussians=True)
            db.load("s", 0, pts, gaussians=g)
            # Alternated, so that both meet the same state of the buffers and merges.
            turn, move = {"edit": [], "undo": []}, {"edit": [], "undo": []}
            for _ in range(a.runs):
                timed_edit(db, QUARTER, (0, 0, 0, 0), turn)
                timed_edit(db, None, (0.1, 0, 0, 0), move)
            turn, move = summary(turn), summary(move)
        out = {"splats": a.splats, "sh_degree": 3, "runs": a.runs, "cpus": os.cpu_count(),
               "turn": turn, "move": move,
               "turn_over_move": round(turn["edit_s"] / move["edit_s"], 2)}
        print(json.dumps(out, indent=2))
        os.makedirs(os.path.dirname(a.out), exist_ok=True)
        with open(a.out, "w") as f:
            json.dump(out, f, indent=2)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
