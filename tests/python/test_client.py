"""The Python client against the `hvdb` command line and the engine's rules, in both modes
(embedded and through a real hvdb-server), on the real Panoptic sequence."""
import csv
import shutil
import time
import threading

import numpy as np
import pytest

import hvdb
from conftest import DATASET, Server

FPS = 30.0


def read_csv(path):
    """`hvdb window --out X.csv` as a dict of columns, rows sorted by id."""
    with open(path) as f:
        names = next(csv.reader(f))
    # Two passes: integers exactly (ids are 64-bit), floats as float32 as they were printed.
    ints = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2,
                      usecols=[names.index(k) for k in ("id", "frame")], dtype=np.uint64)
    vals = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    order = np.argsort(ints[:, 0], kind="stable")
    cols = {k: vals[order, i] for i, k in enumerate(names)}
    cols["id"] = ints[order, 0]
    cols["frame"] = ints[order, 1]
    return cols


def assert_same_points(pts, cols):
    """Field by field: the array against the CLI's CSV of the same query."""
    pts = np.sort(pts, order="id")
    assert len(pts) == len(cols["id"])
    assert (pts["id"] == cols["id"].astype(np.uint64)).all()
    assert (pts["frame"] == cols["frame"].astype(np.uint32)).all()
    for i, axis in enumerate("xyz"):
        np.testing.assert_allclose(pts["position"][:, i], cols[axis].astype(np.float32),
                                   rtol=1e-6, atol=1e-7)
    for i, c in enumerate(("red", "green", "blue")):
        assert (pts["color"][:, i] == cols[c].astype(np.uint8)).all()
    assert (pts["label"] == cols["label"].astype(np.uint32)).all()
    assert (pts["camera"] == cols["camera"].astype(np.uint16)).all()
    assert (pts["flags"] == cols["flags"].astype(np.uint8)).all()
    for i, k in enumerate(("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")):
        np.testing.assert_allclose(pts["cov"][:, i], cols[k].astype(np.float32), rtol=1e-6,
                                   atol=1e-12)
    n = hvdb.normals(pts)
    for i, k in enumerate(("nx", "ny", "nz")):
        np.testing.assert_allclose(n[:, i], cols[k].astype(np.float32), atol=1e-4)


def test_datasets_and_info_match_the_cli(env):
    db = env.db
    assert db.datasets() == [DATASET]
    info = db.info(DATASET)
    assert info["fps"] == FPS
    assert info["frame_count"] == 16
    import json
    described = json.loads(env.cli("describe", DATASET, "--json").stdout)
    assert info["point_count"] == described["points"] > 16 * 50000
    stats = env.db.stats(DATASET)
    assert stats["datasets"][0]["points"] == described["points"]
    assert ("cache" in stats) == (env.mode == "embedded")
    assert ("server" in stats) == (env.mode == "server")


def test_compact_keeps_every_field_of_every_point(env):
    before = env.db.frame(DATASET, frame=3)
    done = env.db.compact(DATASET, frames=(3, 3))
    assert done["frames"] + done["already"] == 1
    after = env.db.frame(DATASET, frame=3)
    order = np.argsort(before["id"])
    assert (np.sort(after["id"]) == before["id"][order]).all()
    assert (after[np.argsort(after["id"])] == before[order]).all()
    assert env.db.stats(DATASET)["datasets"][0]["cold_frames"] >= 1
    with pytest.raises(hvdb.InvalidArgument, match="first frame 5 is after last frame 2"):
        env.db.compact(DATASET, frames=(5, 2))


@pytest.mark.parametrize("frame,level", [(0, 0), (7, 0), (15, 2)])
def test_frame_equals_the_cli_field_by_field(env, tmp_path, frame, level):
    pts = env.db.frame(DATASET, frame=frame, level=level)
    assert pts.dtype == hvdb.POINT_DTYPE and pts.flags["C_CONTIGUOUS"]
    assert (pts["frame"] == frame).all()
    t = frame / FPS
    out = str(tmp_path / "w.csv")
    env.cli("window", DATASET, "--box", "-1e9", "1e9", "-1e9", "1e9", "-1e9", "1e9", str(t),
            str(t), "--lod", str(level), "--out", out)
    assert_same_points(pts, read_csv(out))
    # By time, the same frame.
    by_t = env.db.frame(DATASET, t=t, level=level)
    assert np.array_equal(np.sort(by_t, order="id"), np.sort(pts, order="id"))


def test_window_and_hyperslice_equal_the_cli(env, tmp_path):
    box = dict(x=(-0.5, -0.2), y=(-1.8, -0.5), z=(-0.3, 0.5), t=(0.1, 0.2))
    pts = env.db.window(DATASET, **box)
    out = str(tmp_path / "w.csv")
    env.cli("window", DATASET, "--box", "-0.5", "-0.2", "-1.8", "-0.5", "-0.3", "0.5", "0.1",
            "0.2", "--out", out)
    cols = read_csv(out)
    assert len(pts) > 1000
    assert_same_points(pts, cols)
    p = pts["position"]
    assert (p[:, 0] >= -0.5).all() and (p[:, 0] <= -0.2).all()
    assert set(np.unique(pts["frame"])) == {3, 4, 5, 6}
    # A tilted hyperslice through space and time: projected positions and covariances.
    sl = env.db.hyperslice(DATASET, normal=(0.2, 0, 0, 1), offset=0.2, thickness=0.05)
    out = str(tmp_path / "s.csv")
    env.cli("slice", DATASET, "--normal", "0.2", "0", "0", "1", "--offset", "0.2",
            "--thickness", "0.05", "--out", out)
    assert len(sl) > 0
    assert_same_points(sl, read_csv(out))


def test_stream_goes_coarse_to_fine_and_stops_cleanly(env):
    full = env.db.frame(DATASET, frame=3)
    levels, parts = [], []
    for batch, level in env.db.stream(DATASET, t=(0.1, 0.1), progressive=True):
        levels.append(level)
        parts.append(batch)
    assert levels == sorted(levels, reverse=True) and levels[0] > 0 and levels[-1] == 0
    got = np.concatenate(parts)
    assert np.array_equal(np.sort(got, order="id"), np.sort(full, order="id"))
    # Stopping after one batch leaves the database (the connection) usable.
    for batch, level in env.db.stream(DATASET, progressive=True):
        break
    again = env.db.frame(DATASET, frame=3)
    assert len(again) == len(full)


def test_a_transaction_commits_atomically_or_leaves_no_trace(env):
    db = env.db
    before = db.info(DATASET)
    new = hvdb.points(np.array([[5.0, 5.0, 5.0], [5.1, 5.0, 5.0]]),
                      color=np.array([[255, 0, 0], [0, 255, 0]], dtype=np.uint8), frame=2)
    with pytest.raises(RuntimeError, match="changed my mind"):
        with db.transaction(DATASET) as tx:
            tx.insert(new)
            tx.delete(t=(0.0, 0.0))
            raise RuntimeError("changed my mind")
    after = db.info(DATASET)
    assert after["point_count"] == before["point_count"]
    assert after["last_lsn"] == before["last_lsn"]
    frame0 = len(db.frame(DATASET, frame=0))
    with db.transaction(DATASET) as tx:
        tx.insert(new)
        tx.delete(t=(0.0, 0.0))
        tx.set_label(0b100, x=(4.9, 5.2), t=(2 / FPS, 2 / FPS))
    assert tx.lsn > before["last_lsn"]
    # (a label change re-inserts the points it changes: they count on both sides)
    assert tx.result["inserted"] >= 2 and tx.result["removed"] >= frame0
    assert len(db.frame(DATASET, frame=0)) == 0
    marked = db.window(DATASET, x=(4.9, 5.2), label_mask=0b100)
    assert len(marked) == 2 and set(marked["color"][:, 0]) == {255, 0}
    # It survives a restart of the server (or a reopening of the directory).
    db = env.reopen()
    assert len(db.frame(DATASET, frame=0)) == 0
    assert len(db.window(DATASET, x=(4.9, 5.2))) == 2
    # Undo and redo.
    undo = db.undo(DATASET, tx.lsn)
    assert len(db.frame(DATASET, frame=0)) == frame0
    assert len(db.window(DATASET, x=(4.9, 5.2))) == 0
    db.redo(DATASET, undo["lsn"])
    assert len(db.frame(DATASET, frame=0)) == 0


def test_bad_input_is_refused_and_loses_nothing(env):
    db = env.db
    before = db.info(DATASET)
    bad = hvdb.points(np.zeros((3, 3)))
    bad["position"][1] = [np.nan, 0, 0]
    with pytest.raises(hvdb.InvalidArgument, match="point 1 has a non-finite position"):
        with db.transaction(DATASET) as tx:
            tx.insert(bad)
    with pytest.raises(hvdb.InvalidArgument, match="non-finite"):
        db.load(DATASET, 3, bad)
    with pytest.raises(hvdb.InvalidArgument, match="POINT_DTYPE"):
        db.load(DATASET, 3, np.zeros((3, 3), dtype=np.float32))
    with pytest.raises(hvdb.InvalidArgument, match="position"):
        hvdb.points(np.array([[0.0, np.inf, 0.0]]))
    with pytest.raises(hvdb.InvalidArgument, match="level"):
        db.window(DATASET, level=9)
    with pytest.raises(hvdb.InvalidArgument, match="x: low"):
        db.window(DATASET, x=(1, 0))
    with pytest.raises(hvdb.InvalidArgument, match="x: expected a finite number"):
        db.window(DATASET, x=(float("nan"), 0))
    with pytest.raises(hvdb.InvalidArgument, match="thickness"):
        db.hyperslice(DATASET, normal=(0, 0, 0, 1), offset=0, thickness=-1)
    with pytest.raises(hvdb.InvalidArgument, match="normal"):
        db.hyperslice(DATASET, normal=(0, 0, 0, 0), offset=0)
    with pytest.raises(hvdb.InvalidArgument, match="size"):
        db.render(DATASET, 0, look_at=(0, -1, -3, 0, -1, 0), size=(0, 10))
    with pytest.raises(hvdb.InvalidArgument):
        db.render(DATASET, 0, look_at=(0, -1, -3, 0, -1, 0), mode="cartoon")
    with pytest.raises(hvdb.InvalidArgument, match="bit"):
        db.select(DATASET, 32)
    with pytest.raises(hvdb.NotFound):
        db.frame("nope", frame=0)
    with pytest.raises(hvdb.NotFound):
        db.undo(DATASET, 999999)
    with pytest.raises(hvdb.AlreadyExists):
        db.create(DATASET)
    with pytest.raises(hvdb.LimitExceeded):  # a slice across more frames than allowed
        db.hyperslice(DATASET, normal=(0, 0, 0, 1), offset=0, thickness=10, max_frames=2)
    after = db.info(DATASET)
    assert after["point_count"] == before["point_count"]
    assert after["last_lsn"] == before["last_lsn"]


def test_editing_operators_like_the_cli(env):
    db = env.db
    box = dict(x=(-0.5, -0.3), t=(0.0, 0.0))
    sel = db.select(DATASET, 3, **box)
    inside = db.window(DATASET, **box)
    assert sel["selected"] == len(inside) > 0
    assert len(db.window(DATASET, t=(0.0, 0.0), label_mask=1 << 3)) == len(inside)
    cut = db.cut(DATASET, 3, "py", t=(0.0, 0.0))
    assert cut["points"] == len(inside) and cut["lsn"] > 0
    assert len(db.window(DATASET, **box)) == 0
    pasted = db.paste(DATASET, "py", translate=(0, 0, 0, 1 / FPS))
    assert pasted["inserted"] == len(inside)
    assert len(db.window(DATASET, x=(-0.5, -0.3), t=(1 / FPS, 1 / FPS), label_mask=1 << 3)) \
        == len(inside)


def test_render_equals_the_cli_image(env, tmp_path):
    import open3d as o3d
    look = (-0.4, -0.9, -3, -0.4, -0.9, 0)
    img = env.db.render(DATASET, 5 / FPS, look_at=look, fov=40, size=(160, 120),
                        renderer="cpu")
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert img.max() > 100  # the person is there
    rgb, depth = env.db.render(DATASET, 5 / FPS, look_at=look, fov=40, size=(160, 120),
                               renderer="cpu", depth=True)
    assert depth.shape == (120, 160) and depth.dtype == np.float32
    covered = np.isfinite(depth)
    assert covered.sum() > 500 and (depth[covered] > 2).all() and (depth[covered] < 4).all()
    assert np.abs(rgb.astype(int) - img.astype(int)).max() <= 1
    out = str(tmp_path / "cli.png")
    env.cli("render", DATASET, "--box", "-1e9", "1e9", "-1e9", "1e9", "-1e9", "1e9",
            str(5 / FPS), str(5 / FPS), "--look-at", *map(str, look), "--fov", "40",
            "--size", "160", "120", "--renderer", "cpu", "--out", out)
    cli = np.asarray(o3d.io.read_image(out))
    assert np.array_equal(cli[:, :, :3], img)
    # The default draws the best the frame has, and says what: here the points, no photos.
    same, facts = env.db.render(DATASET, 5 / FPS, look_at=look, fov=40, size=(160, 120),
                                renderer="cpu", info=True)
    assert np.array_equal(same, img)
    assert facts["mode"] == "visibility", facts
    assert facts["mode_choice"].startswith("auto: no photos of frame"), facts
    # This dataset holds points only (a PLY recording): a textured view is a clear NotFound.
    with pytest.raises(hvdb.NotFound, match="no photos"):
        env.db.render(DATASET, 5 / FPS, look_at=look, size=(160, 120), renderer="cpu",
                      texture=True)
    # Nor has it billboards (hvdb-ingest --filter billboard stores them).
    with pytest.raises(hvdb.NotFound, match="no billboards"):
        env.db.render(DATASET, 5 / FPS, look_at=look, size=(160, 120), renderer="cpu",
                      billboards=True)


def test_render_shadow_equals_the_cli_image(env, tmp_path):
    import open3d as o3d
    look = (-0.4, -0.9, -3, -0.4, -0.9, 0)
    t = 5 / FPS
    # The head and shoulders (y down: above -1.3 m) cast, from the sun above.
    env.db.select(DATASET, 6, y=(-10.0, -1.3), t=(t, t))
    shadow = {"light": (0.2, -1.0, 0.1), "casters": 6, "directional": True, "strength": 0.7}
    kw = dict(look_at=look, fov=40, size=(160, 120), renderer="cpu")
    plain = env.db.render(DATASET, t, **kw).astype(int)
    lit = env.db.render(DATASET, t, shadow=shadow, **kw).astype(int)
    assert (lit <= plain).all() and (lit.sum(axis=2) < plain.sum(axis=2)).sum() > 50
    out = str(tmp_path / "cli.png")
    env.cli("render", DATASET, "--box", "-1e9", "1e9", "-1e9", "1e9", "-1e9", "1e9", str(t),
            str(t), "--look-at", *map(str, look), "--fov", "40", "--size", "160", "120",
            "--renderer", "cpu", "--shadow-light", "0.2", "-1", "0.1", "--shadow-directional",
            "--shadow-casters", "6", "--shadow-strength", "0.7", "--out", out)
    cli = np.asarray(o3d.io.read_image(out))
    assert np.array_equal(cli[:, :, :3], lit)
    with pytest.raises(hvdb.InvalidArgument, match="render.shadow_casters"):
        env.db.render(DATASET, t, shadow={"light": (0, -3, 0), "casters": 40}, **kw)
    with pytest.raises(hvdb.InvalidArgument, match="shadow"):
        env.db.render(DATASET, t, shadow={"light": (0, -3), "casters": 6}, **kw)


def test_queries_run_in_threads(env):
    # The GIL is released while the library waits: threads see their own results.
    results = {}

    def fetch(f):
        results[f] = len(env.db.frame(DATASET, frame=f))

    threads = [threading.Thread(target=fetch, args=(f,)) for f in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    for f in range(4):
        assert results[f] == len(env.db.frame(DATASET, frame=f)) > 50000


def test_streams_outlive_close_and_check_arguments_at_once(env):
    db = env.db
    with pytest.raises(hvdb.InvalidArgument, match="level"):
        db.stream(DATASET, level=9)  # refused here, not at the first batch
    with pytest.raises(hvdb.NotFound):
        db.stream("nope")
    s = db.stream(DATASET, t=(0.1, 0.1), progressive=True)
    first = next(s)
    db.close()  # the open query keeps what it needs until it ends
    rest = [b for b, _ in s]
    assert len(first[0]) + sum(len(b) for b in rest) == len(env.reopen().frame(DATASET, frame=3))
    with pytest.raises(hvdb.InvalidArgument, match="closed"):
        db.info(DATASET)


def test_an_inserted_array_is_copied(env):
    db = env.db
    buf = hvdb.points(np.array([[7.0, 7.0, 7.0]]), frame=0)
    with db.transaction(DATASET) as tx:
        for f in (1, 2, 3):
            buf["frame"] = f
            tx.insert(buf)
    got = db.window(DATASET, x=(6.9, 7.1))
    assert sorted(got["frame"].tolist()) == [1, 2, 3]


def test_compressed_wire_gives_the_same_frame(env):
    """wire="hvdb7": the server codes each batch (docs/CODEC.md); the decoded frame equals the
    records one but for positions on the stream's 16-bit grid (< 2 m / 2^16 per axis)."""
    if env.mode != "server":
        with pytest.raises(hvdb.InvalidArgument):
            hvdb.connect("127.0.0.1:1", wire="gzip")
        return
    plain = np.sort(env.db.frame(DATASET, frame=3), order="id")
    with hvdb.connect(env.address, wire="hvdb7") as db:
        coded = np.sort(db.frame(DATASET, frame=3), order="id")
    assert len(coded) == len(plain) > 50000
    assert (coded["id"] == plain["id"]).all()
    assert (coded["color"] == plain["color"]).all()
    assert (coded["label"] == plain["label"]).all()
    assert np.abs(coded["position"] - plain["position"]).max() < 2.0 / 2**16


def test_a_reading_server_follows_the_writer_and_refuses_writes(seeded_dir, tmp_path):
    """Two servers on one data directory: the second serves reads, follows the first's
    commits and refuses writes with NotLeader naming the first."""
    d = str(tmp_path / "data")
    shutil.copytree(seeded_dir, d)
    writer = Server(d, name="writer")
    reader = Server(d, name="reader", follow=True)
    w, r = hvdb.connect(writer.address), hvdb.connect(reader.address)
    try:
        assert r.info(DATASET)["point_count"] == w.info(DATASET)["point_count"]
        new = hvdb.points(np.array([[5.0, 5.0, 5.0], [5.1, 5.0, 5.0]]), frame=2)
        with pytest.raises(hvdb.NotLeader, match=writer.address):
            with r.transaction(DATASET) as tx:
                tx.insert(new)
        with w.transaction(DATASET) as tx:
            tx.insert(new)
        deadline = time.time() + 10
        while r.info(DATASET)["last_lsn"] < tx.lsn and time.time() < deadline:
            time.sleep(0.05)
        assert r.info(DATASET)["last_lsn"] == tx.lsn
        assert len(r.window(DATASET, x=(4.9, 5.2))) == 2
    finally:
        w.close()
        r.close()
        reader.stop()
        writer.stop()


def test_watch_yields_each_change_in_order_and_resumes_from_an_lsn(env):
    """db.watch: the same events embedded and through a server; a resume from an LSN replays
    exactly what came after it, then goes live."""
    db = env.db
    start = db.info(DATASET)["last_lsn"]
    events = db.watch(DATASET, timeout=5)
    assert next(events) == {"lsn": start, "kind": "live", "dataset": DATASET}
    new = hvdb.points(np.array([[5.0, 5.0, 5.0], [5.1, 5.0, 5.0]]), frame=2)
    with db.transaction(DATASET) as tx:
        tx.insert(new)
    db.load(DATASET, 7, hvdb.points(np.array([[1.0, 2.0, 3.0]] * 5), frame=7))
    undo = db.undo(DATASET, tx.lsn)
    got = [next(events) for _ in range(3)]
    assert [e["kind"] for e in got] == ["commit", "bulk", "revert"]
    assert [e["lsn"] for e in got] == [tx.lsn, tx.lsn + 1, undo["lsn"]]
    assert got[0]["frames"] == [2] and got[0]["points"] == 2
    assert got[1]["frames"] == [7] and got[1]["points"] == 5
    assert got[2]["reverts"] == tx.lsn and got[2]["removed"] == 2
    events.close()
    # Resumed after the commit: the bulk load and the revert, then live.
    again = list(db.watch(DATASET, from_lsn=tx.lsn, timeout=0.5))
    assert [e["kind"] for e in again] == ["bulk", "revert", "live"]
    assert again[-1]["lsn"] == undo["lsn"]
    with pytest.raises(hvdb.InvalidArgument, match="past"):
        next(db.watch(DATASET, from_lsn=undo["lsn"] + 10))
    with pytest.raises(hvdb.NotFound, match="no_such_dataset"):
        next(db.watch("no_such_dataset"))
