"""The point record in Python: the dtype, the column builder's checks, PLY and Open3D."""
import numpy as np
import pytest

import hvdb


def test_the_dtype_is_the_stored_record():
    d = hvdb.POINT_DTYPE
    assert d.itemsize == 64
    assert d.fields["position"][1] == 8 and d.fields["frame"][1] == 20
    assert d.fields["cov"][1] == 24 and d.fields["color"][1] == 56
    assert d.fields["camera"][1] == 60


def test_points_builds_and_checks_columns():
    rng = np.random.default_rng(7)
    pos = rng.normal(size=(100, 3))
    nrm = rng.normal(size=(100, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    p = hvdb.points(pos, color=rng.random((100, 3)), normal=nrm, frame=np.arange(100),
                    label=5, camera=3)
    np.testing.assert_allclose(p["position"], pos.astype(np.float32))
    np.testing.assert_allclose(hvdb.normals(p), nrm, atol=2e-4)
    assert (p["flags"] == hvdb.FLAG_HAS_NORMAL).all()
    assert (p["frame"] == np.arange(100)).all() and (p["label"] == 5).all()
    np.testing.assert_allclose(hvdb.times(p, 10.0), np.arange(100) / 10.0)
    with pytest.raises(hvdb.InvalidArgument, match="N x 3"):
        hvdb.points(np.zeros((4, 2)))
    with pytest.raises(hvdb.InvalidArgument, match="color"):
        hvdb.points(np.zeros((2, 3)), color=np.full((2, 3), 2.0))
    with pytest.raises(hvdb.InvalidArgument, match="camera"):
        hvdb.points(np.zeros((2, 3)), camera=70000)
    with pytest.raises(hvdb.InvalidArgument, match="frame"):
        hvdb.points(np.zeros((2, 3)), frame=[1, 2, 3])


def test_ply_and_open3d_round_trips(tmp_path):
    import open3d as o3d
    rng = np.random.default_rng(3)
    nrm = rng.normal(size=(50, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    p = hvdb.points(rng.normal(size=(50, 3)),
                    color=rng.integers(0, 256, (50, 3)).astype(np.uint8), normal=nrm)
    path = str(tmp_path / "p.ply")
    hvdb.write_ply(path, p)
    back = hvdb.read_ply(path)
    np.testing.assert_allclose(back["position"], p["position"])
    assert (back["color"] == p["color"]).all()
    np.testing.assert_allclose(hvdb.normals(back), hvdb.normals(p), atol=1e-4)
    cloud = hvdb.to_open3d(p)
    assert isinstance(cloud, o3d.geometry.PointCloud) and cloud.has_normals()
    np.testing.assert_allclose(np.asarray(cloud.points), p["position"], rtol=1e-6)
    again = hvdb.from_open3d(cloud, t=0.5, fps=30)
    assert (again["frame"] == 15).all()
    np.testing.assert_allclose(again["position"], p["position"], rtol=1e-6)
    assert (again["color"] == p["color"]).all()
    # Open3D reads hvdb's PLY too.
    o3 = o3d.io.read_point_cloud(path)
    assert len(o3.points) == 50
    with pytest.raises(hvdb.NotFound):
        hvdb.read_ply(str(tmp_path / "missing.ply"))


def test_read_ply_refuses_non_finite_points_unless_skip_invalid(tmp_path):
    path = tmp_path / "holes.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\n"
                    "property float y\nproperty float z\nend_header\n"
                    "0 0 0\n1 nan 0\n0 1 0\ninf 0 1\n1 1 1\n")
    with pytest.raises(hvdb.InvalidArgument, match="skip_invalid=True") as e:
        hvdb.read_ply(path)
    assert "holes.ply: 2 of 5 vertices have a NaN or infinite coordinate" in str(e.value)
    assert "vertex 1, y = nan" in str(e.value)
    pts, skipped = hvdb.read_ply(path, skip_invalid=True)
    assert skipped == 2 and len(pts) == 3
    np.testing.assert_array_equal(pts["position"], [[0, 0, 0], [0, 1, 0], [1, 1, 1]])
    # A clean file: nothing skipped, and the default result is the array alone.
    hvdb.write_ply(tmp_path / "clean.ply", pts)
    assert len(hvdb.read_ply(tmp_path / "clean.ply")) == 3
    assert hvdb.read_ply(tmp_path / "clean.ply", 1.0, True)[1] == 0
    # What was read loads (the rest of the file imported).
    with hvdb.open(tmp_path / "data") as db:
        db.create("h", fps=30)
        assert db.load("h", 0, pts) == 3
