#!/usr/bin/python3
"""The cold tier's figures as the median of whole runs (issue 35).

Runs build/bench/cold-tier-bench N times (default 5), each a fresh process on a fresh scratch
directory, and writes bench/results/cold_tier.json: each figure's median over the runs beside
its target and peer, plus every run's own JSON under "runs".

    /usr/bin/python3 bench/cold_tier.py [--runs 5] [--bench build/bench/cold-tier-bench]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--reps", type=int, default=5, help="passes per figure inside a run")
    ap.add_argument("--bench", default=os.path.join(ROOT, "build/bench/cold-tier-bench"))
    ap.add_argument("--out", default=os.path.join(ROOT, "bench/results/cold_tier.json"))
    a = ap.parse_args()
    if not os.access(a.bench, os.X_OK):
        sys.exit(f"cold_tier.py: {a.bench} not found: build it (cmake --build build "
                 "--target cold-tier-bench)")
    runs = []
    for i in range(a.runs):
        with tempfile.TemporaryDirectory(prefix="hvdb-cold-") as scratch:
            out = os.path.join(scratch, "run.json")
            subprocess.run([a.bench, "--reps", str(a.reps), "--scratch",
                            os.path.join(scratch, "db"), "--out", out], check=True,
                           stdout=subprocess.DEVNULL)
            with open(out) as f:
                runs.append(json.load(f))
        r = runs[-1]
        print(f"run {i + 1}/{a.runs}: size {r['size']['ratio_to_raw_on_disk']:.3f}, "
              f"stream cold {r['stream']['compressed_cold_ms']['median']:.1f} ms "
              f"(raw cold {r['stream']['raw_cold_ms']['median']:.1f}, raw warm "
              f"{r['stream']['raw_warm_ms']['median']:.1f}), window "
              f"{r['windows']['compressed_vs_raw_cold']:.2f}x", flush=True)

    def med(path):
        vals = []
        for r in runs:
            v = r
            for k in path:
                v = v[k]
            vals.append(v)
        return statistics.median(vals)

    figures = {
        "size_ratio_to_raw_on_disk": {
            "median": med(["size", "ratio_to_raw_on_disk"]), "target": "<= 0.25",
            "bytes_per_point": med(["size", "bytes_per_point"]),
            "of_64_byte_records": med(["size", "of_64_byte_records"])},
        "compact_mpoints_per_s": {"median": med(["compact", "mpoints_per_s"])},
        "decode_kernel_mpoints_per_s_one_thread": {
            "median": med(["decode_kernel", "mpoints_per_s_one_thread"])},
        "stream_ms": {k: med(["stream", k, "median"]) for k in
                      ("raw_warm_ms", "raw_cold_ms", "compressed_cold_ms",
                       "compressed_page_cache_warm_ms", "compressed_warm_ms")},
        "stream_mpoints_per_s": {k: med(["stream", "mpoints_per_s", k]) for k in
                                 runs[0]["stream"]["mpoints_per_s"]},
        "stream_compressed_cold_vs_raw_warm": {
            "median": med(["stream", "compressed_cold_vs_raw_warm"]),
            "target": ">= 0.5"},
        "stream_compressed_page_cache_warm_vs_raw_warm": {
            "median": med(["stream", "compressed_page_cache_warm_vs_raw_warm"])},
        "stream_compressed_warm_vs_raw_warm": {
            "median": statistics.median(
                r["stream"]["raw_warm_ms"]["median"] / r["stream"]["compressed_warm_ms"]["median"]
                for r in runs), "target": ">= 0.5"},
        "stream_compressed_cold_vs_raw_cold": {
            "median": med(["stream", "compressed_cold_vs_raw_cold"])},
        "window_cold_ms": {"raw": med(["windows", "raw_cold_ms", "median"]),
                           "compressed": med(["windows", "compressed_cold_ms", "median"]),
                           "points": med(["windows", "points_median"])},
        "window_compressed_vs_raw_cold": {
            "median": med(["windows", "compressed_vs_raw_cold"]), "target": "<= 2"},
    }
    out = {"schema": "hvdb-cold-tier/1",
           "command": f"/usr/bin/python3 bench/cold_tier.py --runs {a.runs} --reps {a.reps}",
           "machine": runs[0]["machine"], "data": runs[0]["data"], "figures": figures,
           "runs": runs}
    with open(a.out, "w") as f:
        json.dump(out, f, indent=2)
        f.write("\n")
    print(json.dumps(figures, indent=2))


if __name__ == "__main__":
    main()
