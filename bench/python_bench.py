#!/usr/bin/python3
"""python-bench: a 2 M-point frame into a numpy array from Python, against the C++ client
library doing the same (bench/client_frame.cc: the frame into a std::vector<Point>) in the
same run, embedded and through hvdb-server; the `hvdb` command line's query loop, which only
counts the points (no array), as a lower bound; and the peak memory of the Python process
while it fetches (issue 22).

usage: PYTHONPATH=build/python /usr/bin/python3 bench/python_bench.py [--out python.json]
       [--points 2000000] [--repetitions 5] [--build build]

Each repetition is a fresh process on both sides (open or connect, query, close), so both pay
the same set-up; times are medians. Embedded, both use the smallest block cache (8 MiB), so
that the Python process's peak memory is the array's and not the cache's (the data stays in
the OS page cache: warm reads on both sides). The frame is a sphere of 2 M surfels (random colours),
bulk-loaded once into a temporary data directory. Writes JSON in the figure format of the
other benchmarks (bench/README.md) with the targets and whether they are met.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

CHILD = r"""
import resource, sys, time, json
import hvdb
mode, where = sys.argv[1], sys.argv[2]
def rss_kib():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * (resource.getpagesize() // 1024)
base = rss_kib()
t0 = time.perf_counter()
db = hvdb.open(where, cache_mb=8) if mode == "embedded" else hvdb.connect(where)
pts = db.frame("big", frame=0)
ms = (time.perf_counter() - t0) * 1e3
# VmHWM: this process's resident peak (ru_maxrss would carry the parent's over fork+exec).
with open("/proc/self/status") as f:
    peak = next(int(l.split()[1]) for l in f if l.startswith("VmHWM:"))
print(json.dumps({"ms": ms, "points": len(pts), "array_bytes": pts.nbytes,
                  "base_kib": base, "peak_kib": peak}))
db.close()
"""


def sphere(n, seed=1):
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    y = 1 - 2 * i / n
    r = np.sqrt(1 - y * y)
    phi = 2.39996323 * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=1), \
        rng.integers(0, 256, (n, 3)).astype(np.uint8)


def figure(name, unit, samples, params, targets=()):
    s = sorted(samples)
    f = {"name": name, "unit": unit, "median": statistics.median(s), "min": s[0], "max": s[-1],
         "repetitions": len(s), "params": params, "targets": []}
    for op, value, what in targets:
        met = f["median"] <= value if op == "<=" else f["median"] >= value
        f["targets"].append({"op": op, "value": value, "source": "issue 22 goal", "what": what,
                             "met": met})
    return f


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default="python.json")
    ap.add_argument("--points", type=int, default=2_000_000)
    ap.add_argument("--repetitions", type=int, default=5)
    ap.add_argument("--build", default="build")
    args = ap.parse_args()
    import hvdb
    cli = os.path.join(args.build, "client", "hvdb")
    peer = os.path.join(args.build, "bench", "client-frame")
    server_bin = os.path.join(args.build, "server", "hvdb-server")
    env = dict(os.environ)
    env["PYTHONPATH"] = os.path.join(args.build, "python")
    figures = []
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, "data")
        pos, rgb = sphere(args.points)
        with hvdb.open(data) as db:
            db.create("big", fps=30)
            db.load("big", 0, hvdb.points(pos, color=rgb, frame=0))
        array_mib = args.points * 64 / 2**20

        def run(mode, where):
            py, cc, stream, mem = [], [], [], []
            for _ in range(args.repetitions):
                r = subprocess.run([sys.executable, "-c", CHILD, mode, where], env=env,
                                   capture_output=True, text=True, check=True)
                c = json.loads(r.stdout)
                assert c["points"] == args.points, c
                py.append(c["ms"])
                mem.append((c["peak_kib"] - c["base_kib"]) * 1024 / c["array_bytes"])
                flag = (["--data", where, "--cache-mb", "8"] if mode == "embedded"
                        else ["--server", where])
                t = subprocess.run([peer] + flag + ["big", "0"], capture_output=True,
                                   text=True, check=True)
                j = json.loads(t.stdout)
                assert j["points"] == args.points, j
                cc.append(j["ms"])
                t = subprocess.run([cli] + flag + ["window", "big", "--box", "-1e9", "1e9",
                                                   "-1e9", "1e9", "-1e9", "1e9", "0", "0",
                                                   "--json"],
                                   capture_output=True, text=True, check=True)
                j = json.loads(t.stdout)
                assert j["points"] == args.points, j
                stream.append(j["elapsed_ms"])
            params = {"mode": mode, "points": args.points, "array_mib": round(array_mib, 1)}
            figures.append(figure("python_frame_ms", "ms", py, params))
            figures.append(figure("cpp_client_frame_ms", "ms", cc, params))
            figures.append(figure("cli_stream_count_ms", "ms", stream, params))
            ratios = [p / c for p, c in zip(py, cc)]
            figures.append(figure("python_vs_cpp_time", "ratio", ratios, params,
                                  [("<=", 1.2, "a 2 M-point frame into numpy vs into a "
                                    "std::vector through the C++ client, same query")]))
            figures.append(figure("python_vs_cli_stream_time", "ratio",
                                  [p / c for p, c in zip(py, stream)], params))
            figures.append(figure("python_peak_memory_vs_array", "ratio", mem, params,
                                  [("<=", 1.2, "peak RSS growth while fetching / the "
                                    "array's size")]))
            print(f"{mode:9s}: python {statistics.median(py):7.1f} ms, C++ client into a vector "
                  f"{statistics.median(cc):7.1f} ms (ratio {statistics.median(ratios):.2f}), "
                  f"CLI streaming without an array {statistics.median(stream):.1f} ms; "
                  f"peak memory {statistics.median(mem):.2f}x the {array_mib:.0f} MiB array")

        run("embedded", data)
        port_file = os.path.join(tmp, "port")
        server = subprocess.Popen([server_bin, "--data", data, "--listen", "127.0.0.1:0",
                                   "--listen", "unix:", "--port-file", port_file,
                                   "--log-level", "warn"])
        try:
            for _ in range(300):
                if os.path.exists(port_file) and open(port_file).read().strip():
                    break
                time.sleep(0.05)
            run("server", "127.0.0.1:" + open(port_file).read().strip())
        finally:
            server.terminate()
            server.wait()
    targets = [dict(t, figure=f["name"], params=f["params"], measured=f["median"])
               for f in figures for t in f["targets"]]
    met = sum(t["met"] for t in targets)
    doc = {"benchmark": "python", "machine": {"nproc": os.cpu_count()}, "figures": figures,
           "targets": targets, "targets_met": met, "targets_missed": len(targets) - met}
    with open(args.out, "w") as f:
        json.dump(doc, f, indent=2)
    print(f"targets: {met} met, {len(targets) - met} missed\nwrote {args.out}")


if __name__ == "__main__":
    main()
