#!/usr/bin/env python3
"""Start-up of the user-facing binaries (issue: lean binaries; target <= 50 ms).

  /usr/bin/python3 bench/startup.py [--build build] [--runs 21] [--out bench/results/startup.json]

Times whole processes as a user runs them, each the median of --runs runs after one untimed
run (the page cache warm, as for a user's second command): `hvdb --help`, `hvdb-server --help`,
`hvdb ping` against a running hvdb-server (connect, one request, exit), `hvdb-ingest --help`
and `import hvdb` in Debian's Python. Beside each: its shared libraries and their size, and
whether it loads GDAL or OpenCV's imgcodecs (what made a command start in 130-300 ms). The
target holds for hvdb and hvdb-server; the others are figures beside them.
"""
import argparse
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "bench"))
import proc_clock  # noqa: E402

TARGET_S = 0.050


def libraries(binary):
    out = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True).stdout
    paths = [m.group(1) for m in re.finditer(r"=> (/\S+)", out)]
    names = [os.path.basename(p) for p in paths]
    return {
        "shared_libraries": len(paths),
        "shared_library_mib": round(sum(os.path.getsize(os.path.realpath(p)) for p in paths) / 2**20, 1),
        "loads_gdal": any(n.startswith("libgdal") for n in names),
        "loads_imgcodecs": any(n.startswith("libopencv_imgcodecs") for n in names),
    }


def timed(cmd, runs, env=None):
    subprocess.run(cmd, capture_output=True, env=env, check=True)  # untimed: the page cache
    walls = []
    for _ in range(runs):
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, env=env)
        walls.append(time.perf_counter() - t0)
        if r.returncode != 0:
            sys.exit(f"startup: {' '.join(cmd)} failed ({r.returncode}): {r.stderr.decode()}")
    return walls


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--runs", type=int, default=21)
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "results", "startup.json"))
    a = ap.parse_args()
    hvdb = os.path.join(a.build, "client", "hvdb")
    server = os.path.join(a.build, "server", "hvdb-server")
    ingest = os.path.join(a.build, "ingest", "hvdb-ingest")
    module_dir = os.path.join(a.build, "python")
    results = []

    def record(name, cmd, binary, env=None, target=True):
        walls = timed(cmd, a.runs, env)
        s = proc_clock.stats(walls)
        entry = {"command": name, "wall_s": s, "runs_s": walls,
                 "target": {"limit_s": TARGET_S, "met": s["median"] <= TARGET_S} if target else None}
        if binary:
            entry.update(libraries(binary))
        results.append(entry)
        print(f"{name:32s} median {s['median'] * 1e3:6.1f} ms (min {s['min'] * 1e3:.1f}, "
              f"max {s['max'] * 1e3:.1f}); {entry.get('shared_libraries', '-')} libraries, "
              f"{entry.get('shared_library_mib', '-')} MiB", flush=True)

    record("hvdb --help", [hvdb, "--help"], hvdb)
    # The peer: the same command loading what it loaded before (OpenCV's imgcodecs and GDAL's
    # ~75 libraries with it), by preloading imgcodecs into today's binary.
    imgcodecs = [p for p in re.findall(r"=> (/\S+)", subprocess.run(
        ["ldd", os.path.join(a.build, "ingest", "hvdb-ingest-all")], capture_output=True,
        text=True).stdout) if "libopencv_imgcodecs" in p]
    if imgcodecs:
        env = dict(os.environ, LD_PRELOAD=imgcodecs[0])
        record("hvdb --help, imgcodecs preloaded (before)", [hvdb, "--help"], None, env, target=False)
    record("hvdb-server --help", [server, "--help"], server)
    with tempfile.TemporaryDirectory() as scratch:
        port_file = os.path.join(scratch, "port")
        srv = subprocess.Popen([server, "--data", os.path.join(scratch, "data"), "--listen",
                                "127.0.0.1:0", "--port-file", port_file],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for _ in range(200):
                if os.path.exists(port_file) and open(port_file).read().strip():
                    break
                time.sleep(0.05)
            address = "127.0.0.1:" + open(port_file).read().strip()
            record("hvdb ping (served)", [hvdb, "--server", address, "ping"], hvdb)
        finally:
            srv.send_signal(signal.SIGTERM)
            srv.wait(timeout=30)
    if os.path.exists(ingest):
        record("hvdb-ingest --help", [ingest, "--help"], ingest, target=False)
    module = [os.path.join(module_dir, "hvdb", f) for f in os.listdir(os.path.join(module_dir, "hvdb"))
              if f.startswith("_hvdb")] if os.path.isdir(os.path.join(module_dir, "hvdb")) else []
    if module:
        env = dict(os.environ, PYTHONPATH=module_dir)
        # Python's own start and numpy's import are most of it: no target, the figure beside.
        record("python3 -c 'import hvdb'", ["/usr/bin/python3", "-c", "import hvdb"], module[0], env,
               target=False)
    doc = {"benchmark": "startup", "runs": a.runs, "target_s": TARGET_S,
           "machine": {"cpus": os.cpu_count()}, "commands": results,
           "summary": {r["command"]: {"median_ms": round(r["wall_s"]["median"] * 1e3, 1),
                                      "met": r["target"]["met"] if r["target"] else None}
                       for r in results}}
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
