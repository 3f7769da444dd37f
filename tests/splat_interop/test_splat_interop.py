"""hvdb's Gaussian-splat files against the ecosystem's own converters, both ways.

The tools are npm packages pinned in tests/splat_interop/package-lock.json (installed by
scripts/setup.sh --all, integrity checked): PlayCanvas's splat-transform 2.7.1 (its SPZ goes
through Adobe's build of the reference spz library) and spz-js 1.2.5. For every SH degree 0-3, a
synthetic scene (anisotropic splats, varied opacity, fixed seed) is imported into a Gaussian
dataset with the `hvdb` command line, then

  hvdb -> tool: each hvdb export (3DGS PLY, SPZ versions 2-4, .splat) is read by the tool and
                written as a PLY, which must equal the scene within the format's quantisation;
  tool -> hvdb: what the tool writes from the scene's PLY (SPZ versions 3 and 4, GLB, PLY; spz-js:
                SPZ version 2) is imported by hvdb and exported as a 3DGS PLY, which must equal
                the scene within the same bounds.

spz-js keeps the PLY's axes inside SPZ where the reference library (and splat-transform, and
hvdb) convert to SPZ's y-up, z-back axes: its files agree with hvdb's mirrored (see mirrored).

splat-transform 2.7.1 writes GLB but does not read it, so hvdb's GLB is checked against the
GLB it writes instead: the same attributes and values (rotations compared normalised: hvdb stores
the unit quaternions the extension asks for).
Binaries and paths come from CTest's environment (tests/CMakeLists.txt)."""
import json
import os
import shutil
import struct
import subprocess

import numpy as np
import pytest

CLI = os.environ.get("HVDB_CLI", "")
NODE = os.environ.get("HVDB_NODE", "/usr/bin/node")
HERE = os.path.dirname(os.path.abspath(__file__))
SPLAT_TRANSFORM = os.path.join(HERE, "node_modules", "@playcanvas", "splat-transform", "bin",
                               "cli.mjs")
SPZ_JS = os.path.join(HERE, "spzjs.mjs")
C0 = 0.28209479177387814
N = 1500


def rest_names(degree):
    return [f"f_rest_{i}" for i in range(3 * ((degree + 1) ** 2 - 1))]


def scene(degree, seed):
    """A synthetic 3DGS scene as the PLY's columns: within every format's range (positions
    under SPZ's 2048 m at 12 fraction bits, SH coefficients under SPZ's clamp at 1)."""
    rng = np.random.default_rng(seed)
    c = {}
    for k, v in zip("xyz", rng.uniform(-50, 50, (3, N))):
        c[k] = v
    for k in ("nx", "ny", "nz"):
        c[k] = np.zeros(N)
    for i, v in enumerate(rng.uniform(-1.7, 1.7, (3, N))):
        c[f"f_dc_{i}"] = v
    for name in rest_names(degree):
        c[name] = rng.uniform(-0.9, 0.9, N)
    c["opacity"] = rng.uniform(-6, 6, N)
    for i, v in enumerate(rng.uniform(-7, 0.5, (3, N))):
        c[f"scale_{i}"] = v
    rot = rng.uniform(-1, 1, (4, N)) * rng.uniform(0.3, 3, N)  # unnormalised, as trainers store
    for i in range(4):
        c[f"rot_{i}"] = rot[i]
    return {k: np.asarray(v, dtype="<f4") for k, v in c.items()}


def write_ply(path, cols):
    names = list(cols)
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % N +
              "".join(f"property float {k}\n" for k in names) + "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode())
        f.write(np.stack([cols[k] for k in names], 1).astype("<f4").tobytes())


def read_ply(path):
    """The float vertex properties of a binary little-endian PLY, by name."""
    data = open(path, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode().splitlines()
    assert "format binary_little_endian 1.0" in lines, f"{path}: {lines[:3]}"
    props = [ln.split() for ln in lines if ln.startswith("property")]
    assert all(p[1] == "float" for p in props), f"{path}: non-float properties {props}"
    count = int(next(ln.split()[2] for ln in lines if ln.startswith("element vertex")))
    a = np.frombuffer(data, "<f4", count * len(props), end).reshape(count, len(props))
    return {p[2]: a[:, i] for i, p in enumerate(props)}


def run(cmd):
    r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} failed ({r.returncode}): {r.stderr}"
    return r.stdout


def hvdb(data, *args):
    return run([CLI, "--data", data, *args])


def splat_transform(*args):
    run([NODE, SPLAT_TRANSFORM, "-q", "-w", *args])


# SPZ coefficient signs between the PLY's axes (x right, y down, z forward) and SPZ's (x right,
# y up, z back), per coefficient of a channel: the reference's flipSh (formats/gaussian_spz.cc).
FLIP_SH = [-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1]


def mirrored(cols, degree):
    """The scene as a reader that ignores SPZ's axis convention sees it: y and z negated, the
    quaternion's y and z, and the SH coefficients odd in y or z. spz-js 1.2.5 stores a PLY's
    values in SPZ as they are (it predates the reference library's RUB convention of 2025, which
    splat-transform and hvdb follow), so its files and readings are this, by design."""
    m = dict(cols)
    for k in ("y", "z", "rot_2", "rot_3"):
        m[k] = -cols[k]
    per_channel = (degree + 1) ** 2 - 1
    for j, name in enumerate(rest_names(degree)):
        m[name] = FLIP_SH[j % per_channel] * cols[name]
    return m


def sigmoid(x):
    return 1 / (1 + np.exp(-x.astype(np.float64)))


def unit_quaternions(c):
    q = np.stack([c[f"rot_{i}"] for i in range(4)], 1).astype(np.float64)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# The bounds of each format's quantisation (SPZ: formats/gaussian_spz.cc and the reference's
# packing; position at 12 fraction bits, log scale in 1/16 steps, 8-bit alpha and colour at
# SPZ's 0.15 colour scale, SH in 5 bits for degree 1 and 4 above, smallest-three rotation in
# 10 bits; SPZ version 2 stores x y z in 8 bits and derives w).
BOUNDS = {
    "exact": dict(position=0, scale=0, alpha=0, dc=0, sh1=0, sh=0, rot=0, rot_w=0),
    "glb": dict(position=0, scale=3e-6, alpha=1e-6, dc=0, sh1=0, sh=0, rot=1e-6, rot_w=1e-6),
    "spz": dict(position=2**-13 + 1e-6, scale=1 / 32 + 1e-5, alpha=0.5 / 255 + 1e-6,
                dc=0.5 / 255 / 0.15 + 1e-5, sh1=4.5 / 128 + 1e-6, sh=8.5 / 128 + 1e-6,
                rot=0.003, rot_w=0.003),
    "spz2": dict(position=2**-13 + 1e-6, scale=1 / 32 + 1e-5, alpha=0.5 / 255 + 1e-6,
                 dc=0.5 / 255 / 0.15 + 1e-5, sh1=4.5 / 128 + 1e-6, sh=8.5 / 128 + 1e-6,
                 rot=1 / 127.5, rot_w=0.12),  # x y z within 0.5/127.5, renormalised
    # .splat: float positions and linear scales; colour and alpha in 8 bits after activation,
    # so a DC coefficient within 0.5/255 / C0; the normalised quaternion in 8 bits, 1/128 a
    # component, which renormalising (the comparison's) can double.
    "splat": dict(position=0, scale=2e-6, alpha=0.5 / 255 + 1e-6, dc=0.5 / 255 / C0 + 1e-5,
                  sh1=None, sh=None, rot=2 / 128, rot_w=2 / 128),
}


def assert_within(want, got, degree, bounds, what):
    b = BOUNDS[bounds]
    assert len(got["x"]) == N, f"{what}: {len(got['x'])} splats, want {N}"

    def check(name, a, g, bound):
        err = float(np.max(np.abs(np.asarray(a, np.float64) - np.asarray(g, np.float64))))
        assert err <= bound, f"{what}: {name} differs by {err:.3g} (bound {bound:.3g})"

    for k in "xyz":
        check(k, want[k], got[k], b["position"])
    for i in range(3):
        s = want[f"scale_{i}"].astype(np.float64)
        check(f"scale_{i}", s, got[f"scale_{i}"], b["scale"] * np.maximum(1, np.abs(s)).max()
              if bounds in ("glb", "splat") else b["scale"])
        check(f"f_dc_{i}", want[f"f_dc_{i}"], got[f"f_dc_{i}"], b["dc"])
    check("sigmoid(opacity)", sigmoid(want["opacity"]), sigmoid(got["opacity"]), b["alpha"])
    qw, qg = unit_quaternions(want), unit_quaternions(got)
    qg *= np.where(np.sum(qw * qg, axis=1, keepdims=True) < 0, -1, 1)  # q, -q: one rotation
    check("rot_0 (w, normalised)", qw[:, 0], qg[:, 0], b["rot_w"])
    check("rot_1..3 (normalised)", qw[:, 1:], qg[:, 1:], b["rot"])
    if b["sh1"] is None:
        return
    per_channel = (degree + 1) ** 2 - 1
    got_rest = [k for k in got if k.startswith("f_rest_")]
    assert len(got_rest) == 3 * per_channel, f"{what}: {len(got_rest)} f_rest, degree {degree}"
    for j, name in enumerate(rest_names(degree)):
        check(name, want[name], got[name], b["sh1"] if j % per_channel < 3 else b["sh"])


@pytest.fixture(scope="module")
def tools():
    assert CLI, "run through CTest (HVDB_CLI)"
    for path in (SPLAT_TRANSFORM, NODE):
        assert os.path.exists(path), (
            f"{path} is missing: scripts/setup.sh --all installs Node.js and the pinned converters "
            "(tests/splat_interop/package-lock.json)")
    r = subprocess.run([NODE, SPLAT_TRANSFORM, "--version"], capture_output=True, text=True,
                       timeout=60)
    assert "v2.7.1" in r.stdout + r.stderr, (r.returncode, r.stdout, r.stderr)


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_hvdb_exports_read_by_the_tools(tools, tmp_path, degree):
    cols = scene(degree, seed=100 + degree)
    src = tmp_path / "scene.ply"
    write_ply(src, cols)
    data = str(tmp_path / "data")
    hvdb(data, "create", "s", "--fps", "30", "--gaussians")
    hvdb(data, "import", "s", "--frame", "0", src)
    exports = {}
    for codec, extra, bounds in (("3dgs", [], "exact"), ("spz", ["--spz-version", "3"], "spz"),
                                 ("spz", ["--spz-version", "4"], "spz"),
                                 ("spz", ["--spz-version", "2"], "spz2"),
                                 ("splat", [], "splat"), ("glb", [], None)):
        out = tmp_path / f"{codec}{''.join(extra[1:])}"
        hvdb(data, "export", "s", out, "--codec", codec, *extra)
        [name] = os.listdir(out)
        exports[out.name] = (out / name, bounds)
    # The 3DGS PLY comes back byte for byte.
    assert exports["3dgs"][0].read_bytes() == src.read_bytes()
    for key, (path, bounds) in exports.items():
        if bounds is None or key == "spz2":
            continue
        back = tmp_path / f"st_{key}.ply"
        splat_transform(path, back)
        assert_within(cols, read_ply(back), 0 if bounds == "splat" else degree, bounds,
                      f"splat-transform reading hvdb's {key}")
    # spz-js reads SPZ version 2 only (its loader refuses 3 and 4), without the axis conversion.
    back = tmp_path / "js.ply"
    run([NODE, SPZ_JS, "to-ply", exports["spz2"][0], back])
    assert_within(mirrored(cols, degree), read_ply(back), degree, "spz2",
                  "spz-js reading hvdb's SPZ v2 (mirrored: spz-js keeps the PLY's axes)")


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_tool_files_imported_by_hvdb(tools, tmp_path, degree):
    cols = scene(degree, seed=200 + degree)
    src = tmp_path / "scene.ply"
    write_ply(src, cols)
    made = []  # (file, bounds, what)
    for name, extra, bounds in (("st4.spz", [], "spz"), ("st3.spz", ["--spz-version", "3"], "spz"),
                                ("st.glb", [], "glb"), ("st.ply", [], "exact")):
        splat_transform(*extra, src, tmp_path / name)
        made.append((tmp_path / name, bounds, f"hvdb reading splat-transform's {name}"))
    run([NODE, SPZ_JS, "to-spz", src, tmp_path / "js.spz"])
    made.append((tmp_path / "js.spz", "spz2", "hvdb reading spz-js's SPZ v2"))
    mirror = {len(made) - 1}  # spz-js keeps the PLY's axes in SPZ (see mirrored)
    assert (tmp_path / "st4.spz").read_bytes()[:4] == b"NGSP"  # version 4: zstd streams
    data = str(tmp_path / "data")
    hvdb(data, "create", "s", "--fps", "30", "--gaussians")
    for frame, (path, _, _) in enumerate(made):
        hvdb(data, "import", "s", "--frame", frame, path)
    out = tmp_path / "out"
    hvdb(data, "export", "s", out, "--codec", "3dgs")
    files = sorted(os.listdir(out))
    assert len(files) == len(made), files
    for i, (name, (_, bounds, what)) in enumerate(zip(files, made)):
        want = mirrored(cols, degree) if i in mirror else cols
        assert_within(want, read_ply(out / name), degree, bounds, what)


def glb_json(path):
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data))
    size, kind = struct.unpack_from("<II", data, 12)
    assert kind == 0x4E4F534A
    return json.loads(data[20:20 + size]), data[20 + size + 8:]


def test_hvdb_glb_matches_the_tools_glb(tools, tmp_path):
    """Same attributes, accessors and values as splat-transform's GLB of the same scene."""
    cols = scene(3, seed=300)
    src = tmp_path / "scene.ply"
    write_ply(src, cols)
    splat_transform(src, tmp_path / "st.glb")
    data = str(tmp_path / "data")
    hvdb(data, "create", "s", "--fps", "30", "--gaussians")
    hvdb(data, "import", "s", "--frame", "0", src)
    hvdb(data, "export", "s", tmp_path / "out", "--codec", "glb")
    ours, our_bin = glb_json(tmp_path / "out" / "s_000000.glb")
    theirs, their_bin = glb_json(tmp_path / "st.glb")
    prim_o = ours["meshes"][0]["primitives"][0]
    prim_t = theirs["meshes"][0]["primitives"][0]
    assert set(prim_o["attributes"]) == set(prim_t["attributes"])
    assert prim_o["extensions"] == prim_t["extensions"]

    def values(j, blob, attr):
        acc = j["accessors"][j["meshes"][0]["primitives"][0]["attributes"][attr]]
        view = j["bufferViews"][acc["bufferView"]]
        comps = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
        dtype = {5126: "<f4", 5121: "u1"}[acc["componentType"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        return np.frombuffer(blob, dtype, acc["count"] * comps, start).astype(np.float64)

    for attr in prim_t["attributes"]:
        a, b = values(ours, our_bin, attr), values(theirs, their_bin, attr)
        if attr.endswith(":ROTATION"):
            # The extension stores unit quaternions; splat-transform copies the trainer's
            # unnormalised ones, hvdb normalises them (the same rotation either way).
            a, b = (x.reshape(-1, 4) / np.linalg.norm(x.reshape(-1, 4), axis=1, keepdims=True)
                    for x in (a, b))
        # Float rounding of exp and the sigmoid may differ by an ulp; the 8-bit fallback colour
        # by a step where a value lies on a rounding tie.
        bound = 1 if attr == "COLOR_0" else 2e-6 * max(1.0, float(np.max(np.abs(b))))
        err = float(np.max(np.abs(a - b)))
        assert err <= bound, f"{attr}: hvdb's GLB differs from splat-transform's by {err:.3g}"


def test_bad_tool_input_is_a_clear_error(tools, tmp_path):
    """A truncated SPZ of splat-transform's: refused, naming the file; nothing imported."""
    cols = scene(1, seed=400)
    src = tmp_path / "scene.ply"
    write_ply(src, cols)
    splat_transform(src, tmp_path / "st.spz")
    bad = tmp_path / "cut.spz"
    bad.write_bytes((tmp_path / "st.spz").read_bytes()[:-100])
    data = str(tmp_path / "data")
    hvdb(data, "create", "s", "--fps", "30", "--gaussians")
    r = subprocess.run([CLI, "--data", data, "import", "s", "--frame", "0", str(bad)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r
    assert "cut.spz" in r.stderr and "truncated" in r.stderr, r.stderr
    info = hvdb(data, "describe", "s")
    assert "0 points" in info or "points: 0" in info or " 0 frames" in info, info
