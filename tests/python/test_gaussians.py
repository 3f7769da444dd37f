"""Gaussian-splat datasets from Python: splat files read and written, records loaded with their
points and read back by id, embedded and through a real hvdb-server, the same either way."""
import os

import numpy as np
import pytest

import hvdb
from conftest import Server


def _ply(path, n, seed, degree=3):
    """A 3DGS PLY in the Inria layout (seeded)."""
    rng = np.random.default_rng(seed)
    rest = 3 * ((degree + 1) ** 2 - 1)
    names = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] +
             [f"f_rest_{i}" for i in range(rest)] +
             ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    a = rng.normal(size=(n, len(names))).astype("<f4")
    a[:, 3:6] = 0
    a[:, 9 + rest + 1:9 + rest + 4] = -4 + 0.3 * rng.normal(size=(n, 3))
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n" +
              "".join(f"property float {k}\n" for k in names) + "end_header\n")
    with open(path, "wb") as f:
        f.write(header.encode() + a.tobytes())
    return a


def test_read_and_write_splats(tmp_path):
    a = _ply(tmp_path / "in.ply", 50, 1)
    pts, g = hvdb.read_splats(tmp_path / "in.ply")
    assert len(pts) == 50 and g["sh_degree"] == 3 and g["ignored"] == []
    np.testing.assert_array_equal(pts["position"], a[:, 0:3])
    np.testing.assert_array_equal(g["sh"][:, :, 0], a[:, 6:9])            # the DC terms
    np.testing.assert_array_equal(g["sh"][:, 0, 1:], a[:, 9:24])          # R's rest
    np.testing.assert_array_equal(g["opacity_logit"], a[:, 54])
    np.testing.assert_allclose(g["opacity"], 1 / (1 + np.exp(-a[:, 54].astype(np.float64))),
                               rtol=1e-6)
    np.testing.assert_array_equal(g["rotation"], a[:, 58:62])
    hvdb.write_splats(tmp_path / "out.ply", pts, g)
    assert (tmp_path / "out.ply").read_bytes() == (tmp_path / "in.ply").read_bytes()
    hvdb.write_splats(tmp_path / "out.spz", pts, g, format="spz")
    back, gb = hvdb.read_splats(tmp_path / "out.spz")
    np.testing.assert_allclose(back["position"], pts["position"], atol=1 / 2048)
    with pytest.raises(hvdb.InvalidArgument, match="log_scale"):
        hvdb.write_splats(tmp_path / "x.ply", pts, {k: v for k, v in g.items() if k != "log_scale"})
    with pytest.raises(hvdb.InvalidArgument, match="format"):
        hvdb.write_splats(tmp_path / "x.ply", pts, g, format="gltf")
    (tmp_path / "cut.ply").write_bytes((tmp_path / "in.ply").read_bytes()[:-10])
    with pytest.raises(hvdb.Error, match="cut.ply"):
        hvdb.read_splats(tmp_path / "cut.ply")


def _records_of(db, name, t):
    pts = db.frame(name, t=t)
    pts = pts[np.argsort(pts["id"])]  # load order
    return pts, db.gaussians(name, pts)


def test_load_and_read_back_embedded_and_served(tmp_path):
    _ply(tmp_path / "f0.ply", 400, 2, degree=3)
    _ply(tmp_path / "f1.ply", 300, 3, degree=1)
    data = str(tmp_path / "data")
    os.makedirs(data)
    server = Server(data)
    try:
        for db in (hvdb.connect(server.address), hvdb.open(str(tmp_path / "emb"))):
            with db:
                info = db.create("s", fps=10, gaussians=True)
                assert info["gaussians"] is True
                for f, name in ((0, "f0.ply"), (1, "f1.ply")):
                    pts, g = hvdb.read_splats(tmp_path / name)
                    assert db.load("s", f, pts, gaussians=g) == len(pts)
                    got, gg = _records_of(db, "s", f / 10)
                    assert gg["derived"] == 0 and gg["sh_degree"] == g["sh_degree"]
                    for k in ("opacity_logit", "log_scale", "rotation", "sh"):
                        np.testing.assert_array_equal(gg[k], g[k])
                    np.testing.assert_array_equal(got["position"], pts["position"])
                # Both frames at once: degree 1 padded to 3 with zeros.
                both, g2 = db.window("s", gaussians=True)
                assert g2["sh"].shape == (700, 3, 16) and g2["opacity"].shape == (700,)
                # A crop of a frame as GLB, read back: positions exact (glTF's axes undone).
                crop, gc = db.frame("s", frame=0, gaussians=True)
                hvdb.write_splats(tmp_path / "crop.glb", crop, gc, format="glb")
                back, gb = hvdb.read_splats(tmp_path / "crop.glb")
                np.testing.assert_array_equal(back["position"], crop["position"])
                np.testing.assert_array_equal(gb["sh"], gc["sh"])
                # A plain dataset refuses records; a Gaussian one refuses points without them.
                db.create("plain", fps=10)
                with pytest.raises(hvdb.InvalidArgument, match="--gaussians"):
                    db.load("plain", 0, pts, gaussians=g)
                with pytest.raises(hvdb.InvalidArgument, match="Gaussian splats"):
                    db.load("s", 5, pts)
                with pytest.raises(hvdb.InvalidArgument, match="sh"):
                    db.load("s", 5, pts, gaussians={"sh": np.zeros((len(pts), 3, 5))})
                # Points of a plain dataset read as derived Gaussians.
                db.load("plain", 0, pts)
                d = db.gaussians("plain", db.window("plain"))
                assert d["derived"] == len(pts) and d["sh_degree"] == 0
    finally:
        server.stop()


def test_a_half_turn_turns_each_splat_and_undo_restores_it(tmp_path):
    """A half turn about z through a transaction, embedded and served: positions (-x, -y, z),
    quaternions left-multiplied by (0, 0, 0, 1), and each SH coefficient of the degrees 1-3 kept
    or negated as its basis function is even or odd in (x, y) (closed form, not the fitted
    matrices); undo brings every record back bit for bit, copy and paste keep them."""
    _ply(tmp_path / "f.ply", 250, 7, degree=3)
    pts, g = hvdb.read_splats(tmp_path / "f.ply")
    # Per channel, degrees 1..3 (m = -l..l): y, z, x / xy, yz, 2zz-xx-yy, xz, xx-yy /
    # y(3xx-yy), xyz, y(4zz-xx-yy), z(...), x(4zz-xx-yy), z(xx-yy), x(xx-3yy).
    sign = np.array([1] + [-1, 1, -1] + [1, -1, 1, -1, 1] + [-1, 1, -1, 1, -1, 1, -1], np.float32)
    half = [[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    data = str(tmp_path / "data")
    os.makedirs(data)
    server = Server(data)
    try:
        for db in (hvdb.connect(server.address), hvdb.open(str(tmp_path / "emb"))):
            with db:
                db.create("s", fps=10, gaussians=True)
                db.load("s", 0, pts, gaussians=g)
                before, gb = _records_of(db, "s", 0)
                with db.transaction("s") as tx:
                    tx.transform(matrix=half)
                after, ga = _records_of(db, "s", 0)
                assert ga["derived"] == 0 and len(after) == len(before)
                assert after["id"].min() > before["id"].max()  # turned splats are new points
                # New ids are issued in the transform's order, not the load's: match positions.
                key = {(float(-x), float(-y), float(z)): i for i, (x, y, z) in
                       enumerate(before["position"])}
                idx = np.array([key[(float(x), float(y), float(z))] for x, y, z in after["position"]])
                np.testing.assert_allclose(ga["sh"], gb["sh"][idx] * sign, atol=2e-6)
                np.testing.assert_array_equal(ga["opacity_logit"], gb["opacity_logit"][idx])
                np.testing.assert_array_equal(ga["log_scale"], gb["log_scale"][idx])
                w, x, y, z = gb["rotation"][idx].T
                np.testing.assert_allclose(ga["rotation"], np.stack([-z, -y, x, w], axis=1),
                                           atol=1e-6)
                db.undo("s", tx.result["lsn"])
                back, gk = _records_of(db, "s", 0)
                np.testing.assert_array_equal(back["id"], before["id"])
                for k in ("opacity_logit", "log_scale", "rotation", "sh"):
                    np.testing.assert_array_equal(gk[k], gb[k])
                # Copy and paste into another frame: the same records.
                db.select("s", 3)
                db.copy("s", 3, "clip")
                db.paste("s", "clip", translate=(0, 0, 0, 0.5))
                pasted, gp = _records_of(db, "s", 0.5)
                assert gp["derived"] == 0 and len(pasted) == len(before)
                at = {tuple(map(float, p)): i for i, p in enumerate(before["position"])}
                idx = np.array([at[tuple(map(float, p))] for p in pasted["position"]])
                np.testing.assert_array_equal(gp["sh"], gb["sh"][idx])
                np.testing.assert_array_equal(gp["rotation"], gb["rotation"][idx])
    finally:
        server.stop()
