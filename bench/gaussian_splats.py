#!/usr/bin/python3
"""gaussian-splats: Gaussian-splat datasets as a user runs them, whole `hvdb` processes (issue 47).

Makes a seeded synthetic 3DGS PLY (degree 3, anisotropic splats, varied opacity; --splats, default
1 M) and times, each --reps times (median, min, max of the wall clock of the process):
  import   `hvdb import DS --frame F FILE.ply` into a Gaussian-splat dataset (target: <= 1 s)
  render   `hvdb render DS ... --size 1920 1080 --out x.png`, gaussian mode (the default for such
           a dataset); with the rasteriser's own time (render_ms) and splats/s from both
  export   `hvdb export DS DIR --codec C` of one frame for C = 3dgs, spz (versions 3 and 4), glb
           and splat, the bytes written, and the `hvdb import` of each file back
  peer     npm's splat-transform 2.7.1 converting the same PLY to SPZ (version 4) and GLB, where
           scripts/setup.sh --all installed it (tests/splat_interop/node_modules)
and `hvdb describe` alone beside them (what starting the process and opening the data directory
cost at that moment). Checks that the exported 3DGS PLY is the imported file byte for byte.

Usage: bench/gaussian_splats.py [--build build] [--reps 5] [--splats 1000000]
                                [--out bench/results/gaussian_splats.json]
"""
import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile

import numpy as np

import proc_clock
from proc_clock import stats


def run(cmd):
    return proc_clock.run(cmd, "gaussian_splats")


def clocked(cmd):
    return proc_clock.clocked(cmd, "gaussian_splats")


HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def write_ply(path, n, seed=1):
    """A 3DGS PLY in the Inria layout: splats in a 4 m ball, log scales around 1.8 cm."""
    rng = np.random.default_rng(seed)
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] +
             [f"f_rest_{i}" for i in range(45)] +
             ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    a = rng.normal(size=(n, len(names))).astype("<f4")
    a[:, 0:3] *= 1.2
    a[:, 3:6] = 0
    a[:, 9:54] *= 0.2
    a[:, 55:58] = -4 + 0.5 * rng.normal(size=(n, 3))
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n" +
              "".join(f"property float {k}\n" for k in names) + "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(a.tobytes())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--splats", type=int, default=1_000_000)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "gaussian_splats.json"))
    a = ap.parse_args()
    hvdb = os.path.join(a.build, "client", "hvdb")
    work = tempfile.mkdtemp(prefix="hvdb-splats-")
    try:
        ply = os.path.join(work, "scene.ply")
        write_ply(ply, a.splats)
        data = ["--data", os.path.join(work, "data")]
        run([hvdb] + data + ["create", "s", "--fps", "30", "--gaussians"])
        imp, imp_cpu, base = [], [], []
        for i in range(a.reps):
            w, _, _ = clocked([hvdb] + data + ["describe", "s"])
            base.append(w)
            w, c, _ = clocked([hvdb] + data + ["import", "s", "--frame", str(i), ply])
            imp.append(w)
            imp_cpu.append(c)
        rend, rend_ms = [], []
        box = ["--box", "-1e9", "1e9", "-1e9", "1e9", "-1e9", "1e9", "0", "0"]
        for i in range(a.reps):
            w, _, out = clocked([hvdb] + data + ["render", "s"] + box +
                                ["--look-at", "0", "0", "-8", "0", "0", "0", "--fov", "60",
                                 "--size", "1920", "1080", "--out",
                                 os.path.join(work, "x.png"), "--json"])
            rend.append(w)
            j = json.loads(out)
            rend_ms.append(j["render_ms"])
            if j.get("mode") != "gaussian":
                sys.exit(f"gaussian_splats: render drew mode {j.get('mode')}, not gaussian")
        exports = {}
        for codec, extra in (("3dgs", []), ("spz", ["--spz-version", "3"]),
                             ("spz", ["--spz-version", "4"]), ("glb", []), ("splat", [])):
            key = codec + (f"_v{extra[1]}" if extra else "")
            walls = []
            for i in range(a.reps):
                d = os.path.join(work, f"out-{key}-{i}")
                w, _, _ = clocked([hvdb] + data + ["export", "s", d, "--codec", codec,
                                                   "--count", "1"] + extra)
                walls.append(w)
            f = os.path.join(d, os.listdir(d)[0])
            exports[key] = {"wall_s": stats(walls), "bytes": os.path.getsize(f)}
            if codec == "3dgs":
                with open(f, "rb") as x, open(ply, "rb") as y:
                    exports[key]["identical_to_input"] = x.read() == y.read()
            # Reading it back: a whole `hvdb import` of the file into a fresh frame.
            walls = []
            for i in range(a.reps):
                w, _, _ = clocked([hvdb] + data + ["import", "s", "--frame",
                                                   str(100 + 10 * len(exports) + i), f])
                walls.append(w)
            exports[key]["import_wall_s"] = stats(walls)
        # The ecosystem's converter on the same scene, where the interop tests' packages are
        # installed (scripts/setup.sh --all): splat-transform writing SPZ (version 4) and GLB.
        peer = {}
        cli = os.path.join(ROOT, "tests", "splat_interop", "node_modules", "@playcanvas",
                           "splat-transform", "bin", "cli.mjs")
        if os.path.exists(cli) and shutil.which("node"):
            for ext in ("spz", "glb"):
                walls = []
                for i in range(a.reps):
                    out = os.path.join(work, f"peer.{ext}")
                    w, _, _ = clocked(["node", cli, "-q", "-w", ply, out])
                    walls.append(w)
                peer[f"splat_transform_2.7.1_ply_to_{ext}"] = {
                    "wall_s": stats(walls), "bytes": os.path.getsize(out)}
        n = a.splats
        result = {
            "schema": "hvdb-gaussian-splats/1",
            "splats": n,
            "sh_degree": 3,
            "input_bytes": os.path.getsize(ply),
            "load_average": os.getloadavg()[0],
            "cores": os.cpu_count(),
            "describe_wall_s": stats(base),
            "import": {"wall_s": stats(imp), "cpu_s": stats(imp_cpu),
                       "target_s": 1.0, "met": statistics.median(imp) <= 1.0},
            "render_1080p": {"wall_s": stats(rend), "rasteriser_ms": stats(rend_ms),
                             "splats_per_s_whole_command": n / statistics.median(rend),
                             "splats_per_s_rasteriser": n / (statistics.median(rend_ms) / 1e3),
                             "target_splats_per_s": 10e6},
            "export": exports,
            "peer": peer or "not measured: tests/splat_interop/node_modules is not installed",
        }
        os.makedirs(os.path.dirname(a.out), exist_ok=True)
        with open(a.out, "w") as f:
            json.dump(result, f, indent=2)
        print(json.dumps(result, indent=2))
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
