"""hvdb from Python: 3D video (coloured Gaussian points over time) as numpy arrays.

    import hvdb
    with hvdb.open("./data") as db:              # or hvdb.connect("127.0.0.1:7878", token=...)
        pts = db.frame("walk", t=0.4)           # a structured array of hvdb.POINT_DTYPE
        print(len(pts), pts["position"].mean(axis=0))

Embedded (`open`) and remote (`connect`) databases behave the same: both run the C++ client
library that the `hvdb` command line runs. Queries return numpy structured arrays whose
records are the stored 64-byte points (see POINT_DTYPE); writes go through transactions
that commit atomically on exit and leave no trace when the block raises. Errors are
exceptions named after the engine's status codes (NotFound, InvalidArgument, ...), with the
same message as the command line. The GIL is released while the library waits on disk or
on the network.
"""

import math
import numbers

import numpy as np

from . import _hvdb

__all__ = [
    "POINT_DTYPE", "FLAG_HAS_NORMAL", "FLAG_HAS_COVARIANCE",
    "open", "connect", "Database", "Transaction",
    "points", "read_ply", "write_ply", "read_splats", "write_splats", "normals", "times", "to_open3d", "from_open3d",
    "Error", "NotFound", "InvalidArgument", "Corruption", "IOError", "Unavailable",
    "LimitExceeded", "AlreadyExists", "Cancelled", "Internal", "PermissionDenied", "Overloaded",
    "Unsupported", "NotLeader",
]

# ---- The point record -----------------------------------------------------------------------

_OFF = _hvdb.POINT_OFFSETS
#: The stored point (docs/FORMAT.md, "Point record"), 64 bytes, little-endian:
#: id (uint64, 0 on insert: the engine assigns one), position (3 float32, metres),
#: frame (uint32; time t = frame / fps), cov (6 float32: the spatial covariance's upper
#: triangle xx xy xz yy yz zz, m^2), normal_oct (2 int16, octahedral unit normal: see
#: normals()), label (uint32, 32 selection bits), color (3 uint8, sRGB), flags (uint8:
#: FLAG_HAS_NORMAL, FLAG_HAS_COVARIANCE), camera (uint16, source camera id), reserved.
POINT_DTYPE = np.dtype({
    "names": ["id", "position", "frame", "cov", "normal_oct", "label", "color", "flags",
              "camera", "reserved"],
    "formats": ["<u8", ("<f4", (3,)), "<u4", ("<f4", (6,)), ("<i2", (2,)), "<u4",
                ("u1", (3,)), "u1", "<u2", "<u2"],
    "offsets": [_OFF[n] for n in ("id", "position", "frame", "cov", "normal_oct", "label",
                                  "color", "flags", "camera", "reserved")],
    "itemsize": _hvdb.POINT_SIZE,
})
FLAG_HAS_NORMAL = 1
FLAG_HAS_COVARIANCE = 2

# ---- Errors ---------------------------------------------------------------------------------


class Error(Exception):
    """An hvdb error; `code` names the engine's status code."""
    code = "Unknown"


class NotFound(Error, LookupError):
    """No such dataset, frame, point or file."""
    code = "NotFound"


class InvalidArgument(Error, ValueError):
    """A parameter out of range; the message says which and why."""
    code = "InvalidArgument"


class Corruption(Error):
    """A checksum or invariant failed; the message names file and block."""
    code = "Corruption"


class IOError(Error, OSError):  # noqa: A001 (named after the status code, as hvdb.IOError)
    """The operating system refused (disk full, permission, connection lost, ...)."""
    code = "IOError"


class Unavailable(IOError):
    """The server cannot be reached, or the connection to it broke."""


class LimitExceeded(Error):
    """A configured bound (frames per slice, points per image, ...) would be passed."""
    code = "LimitExceeded"


class AlreadyExists(Error):
    code = "AlreadyExists"


class Cancelled(Error):
    code = "Cancelled"


class Internal(Error):
    code = "Internal"


class PermissionDenied(Error, PermissionError):
    """The server needs a token (or another one) for this."""
    code = "PermissionDenied"


class Overloaded(Error):
    """The server is at a limit of concurrent requests; retry later."""
    code = "Overloaded"


class Unsupported(Error):
    code = "Unsupported"


class NotLeader(Error):
    """A write sent to a reading server; the message names the writer's address."""
    code = "NotLeader"


_CLASSES = {c.code: c for c in (NotFound, InvalidArgument, Corruption, IOError, LimitExceeded,
                                AlreadyExists, Cancelled, Internal, PermissionDenied, Overloaded,
                                Unsupported, NotLeader)}


def _raise_status(code, message):
    raise _CLASSES.get(code, Error)(message)


_hvdb._set_status_hook(_raise_status)

# ---- Argument checks (before anything is sent or written) ----------------------------------

_FAR = 1e30


def _number(name, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(float(v)):
        raise InvalidArgument(f"{name}: expected a finite number, got {v!r}")
    return float(v)


def _range(name, v):
    if v is None:
        return (-_FAR, _FAR)
    try:
        lo, hi = v
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name}: expected (low, high), got {v!r}") from None
    lo, hi = _number(name, lo), _number(name, hi)
    if lo > hi:
        raise InvalidArgument(f"{name}: low {lo} is above high {hi}")
    return (lo, hi)


def _level(level):
    # Only the type here: a level past the dataset's coarsest is refused by the database
    # (storage's one rule for every query and render), with the dataset's range.
    if isinstance(level, bool) or not isinstance(level, numbers.Integral) or not 0 <= level < 2**31:
        raise InvalidArgument(f"level: expected an integer in 0..2^31-1, got {level!r}")
    return int(level)


def _uint32(name, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 0 <= v < 2**32:
        raise InvalidArgument(f"{name}: expected an integer in 0..2^32-1, got {v!r}")
    return int(v)


def _bit(name, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 0 <= v <= 31:
        raise InvalidArgument(f"{name}: expected a label bit 0..31, got {v!r}")
    return int(v)


def _vector(name, v, n):
    try:
        vals = [float(x) for x in v]
    except (TypeError, ValueError):
        raise InvalidArgument(f"{name}: expected {n} numbers, got {v!r}") from None
    if len(vals) != n or not all(math.isfinite(x) for x in vals):
        raise InvalidArgument(f"{name}: expected {n} finite numbers, got {v!r}")
    return vals


def _window(x=None, y=None, z=None, t=None):
    rx, ry, rz, rt = _range("x", x), _range("y", y), _range("z", z), _range("t", t)
    if t is None:
        rt = (0.0, _FAR)
    return ("window", [rx[0], ry[0], rz[0], rt[0]], [rx[1], ry[1], rz[1], rt[1]])


def _slice(normal, offset, thickness, clip, max_frames):
    n = _vector("normal", normal, 4)
    if not any(n):
        raise InvalidArgument("normal: must not be zero")
    off = _number("offset", offset)
    th = _number("thickness", thickness)
    if th < 0:
        raise InvalidArgument(f"thickness: must be >= 0, got {th}")
    lo = hi = None
    if clip is not None:
        _, lo, hi = _window(**clip)
    return ("slice", n, off, th, lo, hi, _uint32("max_frames", max_frames))


def _check_points(name, pts):
    if not isinstance(pts, np.ndarray) or pts.dtype != POINT_DTYPE:
        raise InvalidArgument(f"{name}: expected a numpy array of hvdb.POINT_DTYPE "
                              f"(hvdb.points(...) makes one), got "
                              f"{getattr(pts, 'dtype', type(pts).__name__)}")
    if pts.ndim != 1:
        raise InvalidArgument(f"{name}: expected a 1-D array, got shape {pts.shape}")
    if len(pts) and not np.isfinite(pts["position"]).all():
        bad = int(np.flatnonzero(~np.isfinite(pts["position"]).all(axis=1))[0])
        raise InvalidArgument(f"{name}: point {bad} has a non-finite position "
                              f"{pts['position'][bad].tolist()}")
    if len(pts) and not np.isfinite(pts["cov"]).all():
        raise InvalidArgument(f"{name}: a covariance holds a non-finite value")
    return np.ascontiguousarray(pts)


# ---- Building and converting points ---------------------------------------------------------


def points(position, color=None, normal=None, frame=0, cov=None, label=0, camera=0):
    """A POINT_DTYPE array from columns: position (N x 3 metres); color (N x 3 uint8 sRGB, or
    floats in [0, 1]); normal (N x 3, unit, stored octahedrally); frame (int or N ints);
    cov (N x 6: xx xy xz yy yz zz, m^2); label and camera (int or N ints)."""
    pos = np.asarray(position, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3:
        raise InvalidArgument(f"position: expected an N x 3 array, got shape {pos.shape}")
    if not np.isfinite(pos).all():
        bad = int(np.flatnonzero(~np.isfinite(pos).all(axis=1))[0])
        raise InvalidArgument(f"position: point {bad} is not finite: {pos[bad].tolist()}")
    n = len(pos)
    out = np.zeros(n, dtype=POINT_DTYPE)
    out["position"] = pos
    if color is not None:
        c = np.asarray(color)
        if c.shape != (n, 3):
            raise InvalidArgument(f"color: expected shape ({n}, 3), got {c.shape}")
        if np.issubdtype(c.dtype, np.floating):
            if not np.isfinite(c).all() or c.min(initial=0) < 0 or c.max(initial=0) > 1:
                raise InvalidArgument("color: float colours must be finite and in [0, 1]")
            c = np.rint(c * 255)
        elif c.min(initial=0) < 0 or c.max(initial=0) > 255:
            raise InvalidArgument("color: integer colours must be in 0..255")
        out["color"] = c.astype(np.uint8)
    if normal is not None:
        nm = np.asarray(normal, dtype=np.float32)
        if nm.shape != (n, 3) or not np.isfinite(nm).all():
            raise InvalidArgument(f"normal: expected {n} x 3 finite values, got {nm.shape}")
        out["normal_oct"] = _hvdb.encode_normals(nm)
        out["flags"] |= FLAG_HAS_NORMAL
    if cov is not None:
        cv = np.asarray(cov, dtype=np.float32)
        if cv.shape != (n, 6) or not np.isfinite(cv).all():
            raise InvalidArgument(f"cov: expected {n} x 6 finite values, got {cv.shape}")
        out["cov"] = cv
        out["flags"] |= FLAG_HAS_COVARIANCE
    for name, v in (("frame", frame), ("label", label), ("camera", camera)):
        a = np.asarray(v)
        if a.ndim not in (0, 1) or (a.ndim == 1 and len(a) != n):
            raise InvalidArgument(f"{name}: expected one value or {n}")
        limit = 2**16 if name == "camera" else 2**32
        if not np.issubdtype(a.dtype, np.integer) or a.min(initial=0) < 0 or \
                a.max(initial=0) >= limit:
            raise InvalidArgument(f"{name}: expected integers in 0..{limit - 1}")
        out[name] = a
    return out


def normals(pts):
    """The unit normals of a POINT_DTYPE array, N x 3 float32 (zero where a point has none)."""
    n = _hvdb.decode_normals(np.ascontiguousarray(pts["normal_oct"]))
    n[(pts["flags"] & FLAG_HAS_NORMAL) == 0] = 0
    return n


def times(pts, fps):
    """Each point's time in seconds: frame / fps."""
    return pts["frame"] / float(fps)


def read_ply(path, scale=1.0, skip_invalid=False):
    """Reads a PLY point cloud (as `hvdb import` does) into a POINT_DTYPE array; `scale`
    multiplies positions (0.01 for centimetres).

    A point with a NaN or infinite coordinate raises InvalidArgument (naming the file, the
    first such point and how many there are) unless skip_invalid: then they are left out and
    the result is a pair (points, skipped), skipped being how many were left out."""
    pts, skipped = _hvdb.read_ply(str(path), _number("scale", scale), bool(skip_invalid))
    return (pts, skipped) if skip_invalid else pts


def read_splats(path):
    """Reads a Gaussian-splat file (3DGS PLY, SPZ, GLB or .splat, told apart by content) as
    (points, gaussians): a POINT_DTYPE array (position, the covariance of each splat's scales
    and rotation, the colour of its DC term) and the dict of Database.gaussians. Extra vertex
    properties of a PLY are read over (gaussians["ignored"] names them)."""
    pts, g, ignored = _hvdb.read_splats(str(path))
    g["ignored"] = list(ignored)
    return pts, g


def write_splats(path, pts, gaussians, format="3dgs"):
    """Writes points and their gaussians dict as a splat file: format "3dgs" (the Inria
    PLY; what read_splats read comes back byte for byte), "spz", "splat" or "glb"."""
    _hvdb.write_splats(str(path), _check_points("points", pts), gaussians, str(format))


def write_ply(path, pts, ascii=False):
    """Writes a POINT_DTYPE array as PLY (binary unless ascii), as `hvdb window --out` does."""
    _hvdb.write_ply(str(path), _check_points("points", pts), bool(ascii))


def to_open3d(pts):
    """An open3d.geometry.PointCloud of the points: positions, colours, and normals where
    every point has one."""
    import open3d as o3d
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(pts["position"].astype(np.float64))
    cloud.colors = o3d.utility.Vector3dVector(pts["color"].astype(np.float64) / 255.0)
    if len(pts) and ((pts["flags"] & FLAG_HAS_NORMAL) != 0).all():
        cloud.normals = o3d.utility.Vector3dVector(normals(pts).astype(np.float64))
    return cloud


def from_open3d(cloud, t=None, frame=0, fps=None):
    """A POINT_DTYPE array from an open3d.geometry.PointCloud (positions, colours, normals).
    Its frame is `frame`, or round(t * fps) when t (seconds) and fps are given."""
    if t is not None:
        if fps is None:
            raise InvalidArgument("t: give fps too (frame = round(t * fps)), or frame=")
        frame = int(round(_number("t", t) * _number("fps", fps)))
    pos = np.asarray(cloud.points)
    color = np.asarray(cloud.colors) if cloud.has_colors() else None
    normal = np.asarray(cloud.normals) if cloud.has_normals() else None
    return points(pos, color=color, normal=normal, frame=frame)


# ---- Databases ------------------------------------------------------------------------------


def open(path="./data", cache_mb=256):  # noqa: A001 (as hvdb.open, like io.open)
    """The database in data directory `path`, embedded in this process (created on the first
    dataset created). One process opens a directory at a time."""
    return Database(_hvdb._Database.open(str(path), int(cache_mb)))


def connect(address="127.0.0.1:7878", token=None, wire="records"):
    """The hvdb-server at HOST:PORT (or unix:PATH). token: the server's access token
    (default: $HVDB_TOKEN). wire: how query results travel: "records" (the stored records;
    shared memory on this machine), "columns", "draco" or "hvdb7" (compressed, docs/CODEC.md).
    Raises Unavailable when it cannot be reached."""
    import os
    if token is None:
        token = os.environ.get("HVDB_TOKEN", "")
    if wire not in ("records", "columns", "draco", "hvdb7"):
        raise InvalidArgument(f"wire: {wire!r} is not records, columns, draco or hvdb7")
    try:
        return Database(_hvdb._Database.connect(str(address), str(token), str(wire)))
    except IOError as e:
        raise Unavailable(f"cannot reach hvdb-server at {address}: {e}") from None


def _watch_events(w, timeout):
    try:
        while True:
            ev = w.next(1e9 if timeout is None else float(timeout))
            if ev is None:
                return
            yield ev
            if w.ended:
                return
    finally:
        w.close()


class Database:
    """A database: embedded on a data directory (hvdb.open) or an hvdb-server (hvdb.connect).
    A context manager: closes on exit."""

    def __init__(self, impl):
        self._db = impl
        self._remote, self._where = impl.remote, impl.where

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self):
        return f"hvdb.Database({'server' if self.remote else 'embedded'} {self.where})"

    def _drain(self, q):
        try:
            return self._results(q.all)
        finally:
            q.close()

    def _call(self, fn, *args):
        if self._db is None:
            raise InvalidArgument("the database is closed")
        try:
            return getattr(self._db, fn)(*args)
        except IOError as e:
            if self._remote and not isinstance(e, Unavailable):
                raise Unavailable(str(e)) from None
            raise

    def close(self):
        """Closes the database (embedded: releases the directory; remote: the connection)."""
        if self._db is not None:
            self._db.close()
            self._db = None

    @property
    def remote(self):
        """True for a server, False for a data directory."""
        return self._remote

    @property
    def where(self):
        """The data directory, or HOST:PORT of the server."""
        return self._where

    # -- datasets --
    def datasets(self):
        """The datasets' names, sorted."""
        return self._call("datasets")

    def info(self, dataset):
        """A dataset's facts: fps, space_time_scale, frame_count, bounds, point_count,
        last_lsn, cameras."""
        return self._call("describe", dataset)

    def create(self, dataset, fps=30.0, space_time_scale=1.0, gaussians=False):
        """Creates an empty dataset at `fps` frames per second; returns its info.
        gaussians=True: a Gaussian-splat dataset, whose points also keep 3DGS records
        (opacity, spherical harmonics; see gaussians() and read_splats())."""
        return self._call("create", dataset, _number("fps", fps),
                          _number("space_time_scale", space_time_scale), bool(gaussians))

    def drop(self, dataset):
        """Deletes a dataset and all its data."""
        self._call("drop", dataset)

    def stats(self, dataset=""):
        """Storage statistics of one dataset (or all), with the block cache (embedded) or the
        server's counters (remote)."""
        return self._call("stats", dataset)

    def compact(self, dataset, frames=None):
        """Rewrites frames into the cold tier now (lossless, about a fifth of the bytes):
        frames=(first, last), inclusive, or None for every frame. Returns what was done:
        frames, already (compressed before), points, bytes_before, bytes_after."""
        if frames is None:
            return self._call("compact", dataset, 0, 0xFFFFFFFF)
        first, last = frames
        return self._call("compact", dataset, _uint32("first", first), _uint32("last", last))

    # -- queries --
    def _query(self, dataset, region, level, progressive=False, temporal_lod=True,
               label_mask=0):
        return self._call("query", dataset, region, _level(level), bool(progressive),
                          bool(temporal_lod), _uint32("label_mask", label_mask))

    def window(self, dataset, x=None, y=None, z=None, t=None, level=0, label_mask=0,
               temporal_lod=True, gaussians=False):
        """The points in a 4D box: x, y, z in metres, t in seconds, each (low, high),
        inclusive, or None for all. level: the finest level of detail returned (0: all
        points; each level up about half). label_mask: only points with (label & mask) != 0.
        Returns a POINT_DTYPE array; with gaussians=True, (points, their 3DGS records as
        gaussians() gives them: opacity, sh, ...)."""
        q = self._query(dataset, _window(x, y, z, t), level, temporal_lod=temporal_lod,
                        label_mask=label_mask)
        pts = self._drain(q)
        return (pts, self.gaussians(dataset, pts)) if gaussians else pts

    def frame(self, dataset, t=None, frame=None, level=0, label_mask=0, gaussians=False):
        """The points of one frame: at time t (seconds) or by index `frame` (with
        gaussians=True, and their 3DGS records, as window())."""
        if (t is None) == (frame is None):
            raise InvalidArgument("frame: give t (seconds) or frame (an index), not both")
        if frame is not None:
            fps = self.info(dataset)["fps"]
            t = _uint32("frame", frame) / fps
        t = _number("t", t)
        return self.window(dataset, t=(t, t), level=level, label_mask=label_mask,
                           gaussians=gaussians)

    def hyperslice(self, dataset, normal, offset, thickness=0.0, level=0, clip=None,
                   max_frames=0, label_mask=0):
        """The points within `thickness` of the hyperplane normal . (x, y, z, s t) = offset
        (thesis eqs. 8.1-8.3), projected onto it: positions and covariances are the
        projected ones. clip: a dict of window ranges (x=, y=, z=, t=) that bounds it;
        max_frames: the frames it may read (0: the server's default)."""
        region = _slice(normal, offset, thickness, clip, max_frames)
        return self._drain(self._query(dataset, region, level, label_mask=label_mask))

    def stream(self, dataset, x=None, y=None, z=None, t=None, level=0, progressive=True,
               normal=None, offset=0.0, thickness=0.0, label_mask=0):
        """Yields (points, level) batches as they arrive, coarse levels first with
        progressive. A window by default; a hyperslice when `normal` is given. Arguments are
        checked and the query is opened here, before the first batch. Stopping the loop
        (break, Ctrl-C) cancels the query; the database stays usable."""
        region = (_slice(normal, offset, thickness, None, 0) if normal is not None
                  else _window(x, y, z, t))
        q = self._query(dataset, region, level, progressive=progressive,
                        label_mask=label_mask)
        return self._batches(q)

    def _batches(self, q):
        try:
            while True:
                batch = self._results(q.next)
                if batch is None:
                    return
                yield batch
        finally:
            q.close()

    def _results(self, fn):
        """Runs a query's next()/all() with the same error translation as _call."""
        try:
            return fn()
        except IOError as e:
            if self.remote and not isinstance(e, Unavailable):
                raise Unavailable(str(e)) from None
            raise

    # -- writes --
    def load(self, dataset, frame, pts, gaussians=None):
        """Bulk-loads points into a frame (fast, atomic per frame, durable on return; not
        undoable). Returns the number of points loaded. A Gaussian-splat dataset's points
        come with their records: `gaussians`, a dict as read_splats() gives (sh, opacity_logit,
        log_scale, rotation, one row per point)."""
        return self._call("bulk_load", dataset, _uint32("frame", frame),
                          _check_points("points", pts), gaussians)

    def gaussians(self, dataset, pts):
        """The 3DGS records of points of a Gaussian-splat dataset (by their ids), one row
        per point: a dict of float32 arrays opacity (n, activated), opacity_logit (n),
        log_scale (n, 3), rotation (n, 4: w x y z), sh (n, 3, (d+1)^2: per channel, the DC term
        first), with sh_degree, antialiased and derived (how many points had no record and
        got the Gaussian derived from their covariance and colour)."""
        return self._call("gaussians", dataset, _check_points("points", pts))

    def transaction(self, dataset):
        """`with db.transaction(ds) as tx:` collects inserts, deletes, label changes and
        transforms, and commits them atomically when the block ends; an exception in the
        block sends nothing. tx.lsn is the commit's number afterwards (for undo)."""
        return Transaction(self, dataset)

    def undo(self, dataset, lsn):
        """Reverts commit `lsn` (commits its inverse); returns that commit's info."""
        return self._call("revert", dataset, _uint64("lsn", lsn))

    def redo(self, dataset, undo_lsn):
        """Re-applies what an undo reverted: reverts the undo's commit."""
        return self._call("revert", dataset, _uint64("undo_lsn", undo_lsn))

    def watch(self, dataset, from_lsn=None, timeout=None):
        """Yields the dataset's changes as they are committed, each a dict: lsn, kind ("commit",
        "revert", "bulk"), frames, points (added), removed (and reverts, for a revert). With
        from_lsn, the changes after it come first (from the log), then a {"kind": "live"} event,
        then the new ones; without, "live" comes first. Ends after a "dropped" event, or after a
        "lagged" one (the reader fell behind: resume with from_lsn=event["lsn"]), or when no
        event came for `timeout` seconds (None: waits for ever; Ctrl-C stops it). Embedded, it
        sees the changes made through this process; remote, every change the server makes."""
        w = self._call("watch", dataset, None if from_lsn is None else _uint64("from_lsn", from_lsn))
        return _watch_events(w, timeout)

    # -- editing operators (thesis ch. 9) --
    def select(self, dataset, bit, x=None, y=None, z=None, t=None, mode="replace"):
        """Marks the points of a box in label bit `bit` (mode: replace, add, subtract,
        intersect). Returns matched, selected and the commit's lsn."""
        return self._call("select", dataset, _window(x, y, z, t), _bit("bit", bit), str(mode))

    def graphcut(self, dataset, foreground_bit, background_bit, out_bit, x=None, y=None,
                 z=None, t=None):
        """4D graph-cut selection of the object marked by the foreground strokes (label bit)
        against the background strokes, inside the box; the result goes to out_bit."""
        return self._call("graphcut", dataset, _window(x, y, z, t),
                          _bit("foreground_bit", foreground_bit),
                          _bit("background_bit", background_bit), _bit("out_bit", out_bit))

    def copy(self, dataset, bit, clipboard, x=None, y=None, z=None, t=None):
        """Copies the points carrying `bit` (inside the box) to a named clipboard."""
        return self._call("copy", dataset, _bit("bit", bit), _window(x, y, z, t),
                          str(clipboard), False)

    def cut(self, dataset, bit, clipboard, x=None, y=None, z=None, t=None):
        """copy, then deletes those points in one commit (its lsn is returned)."""
        return self._call("copy", dataset, _bit("bit", bit), _window(x, y, z, t),
                          str(clipboard), True)

    def paste(self, dataset, clipboard, matrix=None, translate=(0.0, 0.0, 0.0, 0.0)):
        """Inserts a clipboard's points as new points, moved by the 4x4 `matrix` over
        (x, y, z, t) and `translate` (metres, seconds)."""
        a = np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64)
        if a.shape != (4, 4) or not np.isfinite(a).all():
            raise InvalidArgument(f"matrix: expected a finite 4 x 4 array, got {a.shape}")
        return self._call("paste", dataset, str(clipboard), a.ravel().tolist(),
                          _vector("translate", translate, 4))

    # -- rendering --
    def render(self, dataset, t, look_at, fov=50.0, size=(640, 480), mode="auto",
               level=0, renderer="auto", depth=False, up=(0.0, -1.0, 0.0),
               view_dependent=False, texture=False, billboards=False, shadow=None, info=False):
        """Renders frame time t (seconds) from a look-at camera (EWA splatting, thesis 5.1.2):
        look_at = (ex, ey, ez, tx, ty, tz), eye and target in metres, up = (0, -1, 0) as in
        `hvdb render`. Returns an H x W x 3 uint8 sRGB image; with depth=True a pair
        (image, depth) with depth H x W float32 metres (inf where empty); with info=True one
        more element, a dict of the reply's facts: "mode" (what drew: "visibility",
        "probabilistic", "textured" or "billboards"), "mode_choice" (why), "renderer",
        "points", "render_ms". mode="auto" draws the frame's best picture: its billboards where
        stored, else its photos (textured), else the points (visibility); "visibility" or
        "probabilistic" draw the points. texture=True (mode="textured") colours the view from
        the frame's stored photos over the points' depth (thesis 6.3; NotFound when the frame
        has none); billboards=True (mode="billboards") draws the frame's billboards instead of
        its points (ingested with --filter billboard; NotFound when the frame has none).
        shadow = {"light": (x, y, z), "casters": BIT, "directional": False, "strength": 0.6}
        casts the shadows of the points carrying label BIT from a point light at (x, y, z), or
        with directional=True from a light infinitely far in direction (x, y, z), onto the rest
        (thesis 9.4; `hvdb render --shadow-light`); InvalidArgument for a bit over 31 or a point
        light inside the casters."""
        la = _vector("look_at", look_at, 6)
        w, h = size
        w, h = _uint32("size", w), _uint32("size", h)
        if not (1 <= w <= 4096 and 1 <= h <= 4096):
            raise InvalidArgument(f"size: {w} x {h} is outside 1..4096 per side")
        fov = _number("fov", fov)
        if not 0 < fov < 180:
            raise InvalidArgument(f"fov: must be in (0, 180) degrees, got {fov}")
        tt = _number("t", t)
        light, directional, casters, strength = [], False, 0, 0.6
        if shadow is not None:
            if not isinstance(shadow, dict) or "light" not in shadow or "casters" not in shadow:
                raise InvalidArgument('shadow: expected {"light": (x, y, z), "casters": BIT, '
                                      '"directional": False, "strength": 0.6}')
            unknown = set(shadow) - {"light", "casters", "directional", "strength"}
            if unknown:
                raise InvalidArgument(f"shadow: unknown keys {sorted(unknown)}")
            light = _vector("shadow.light", shadow["light"], 3)
            casters = _uint32("shadow.casters", shadow["casters"])
            directional = bool(shadow.get("directional", False))
            strength = _number("shadow.strength", shadow.get("strength", 0.6))
        r = self._call("render", dataset, _window(t=(tt, tt)), la[:3], la[3:],
                       _vector("up", up, 3), fov, w, h, str(mode), _level(level),
                       str(renderer), bool(depth), bool(view_dependent), bool(texture),
                       bool(billboards), light, directional, casters, strength)
        facts = {k: r[k] for k in ("mode", "mode_choice", "renderer", "points", "render_ms")}
        if not depth:
            img = r["image"]
            img = img[:, :, :3] if img.shape[2] == 4 else img
            return (img, facts) if info else img
        rgba = r["rgba"]
        alpha = rgba[:, :, 3:4]
        straight = np.where(alpha > 0, rgba[:, :, :3] / np.maximum(alpha, 1e-12), 0)
        out = (_to_srgb8(straight), r["depth"])
        return out + (facts,) if info else out


def _uint64(name, v):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not 0 <= v < 2**64:
        raise InvalidArgument(f"{name}: expected a non-negative integer, got {v!r}")
    return int(v)


def _to_srgb8(linear):
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.rint(s * 255).astype(np.uint8)




class Transaction:
    """Operations collected in a `with db.transaction(ds) as tx:` block and committed as one
    atomic transaction when it ends (nothing is sent if the block raises). Regions are boxes:
    x, y, z (metres) and t (seconds) ranges, None for all; label_mask restricts to points with
    (label & mask) != 0."""

    def __init__(self, db, dataset):
        self._db, self._dataset, self._ops = db, dataset, []
        self.lsn = None
        self.result = None

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.commit()
        return False

    def insert(self, pts):
        """Inserts points (a POINT_DTYPE array; id 0 lets the engine assign one). The array
        is copied: changing it afterwards does not change what is committed."""
        self._ops.append(("insert", np.array(_check_points("points", pts), copy=True)))

    def delete(self, x=None, y=None, z=None, t=None, label_mask=0):
        """Deletes the points of a box (and, with label_mask, carrying those bits)."""
        self._ops.append(("delete", _window(x, y, z, t), _uint32("label_mask", label_mask)))

    def set_label(self, bits, value=True, x=None, y=None, z=None, t=None, label_mask=0):
        """Sets (value=True) or clears the label `bits` of the points of a box."""
        self._ops.append(("label", _window(x, y, z, t), _uint32("label_mask", label_mask),
                          _uint32("bits", bits), bool(value)))

    def transform(self, matrix=None, translate=(0.0, 0.0, 0.0, 0.0), x=None, y=None, z=None,
                  t=None, label_mask=0):
        """Moves the points of a box by X' = matrix X + translate over (x, y, z, t)."""
        a = np.eye(4) if matrix is None else np.asarray(matrix, dtype=np.float64)
        if a.shape != (4, 4) or not np.isfinite(a).all():
            raise InvalidArgument(f"matrix: expected a finite 4 x 4 array, got {a.shape}")
        self._ops.append(("transform", _window(x, y, z, t), _uint32("label_mask", label_mask),
                          a.ravel().tolist(), _vector("translate", translate, 4)))

    def commit(self):
        """Commits now (the with block does this); returns lsn, inserted, removed."""
        if self.result is not None:
            raise InvalidArgument("transaction: already committed")
        if not self._ops:
            self.result = {"lsn": 0, "inserted": 0, "removed": 0}
        else:
            self.result = self._db._call("commit", self._dataset, self._ops)
        self.lsn = self.result["lsn"]
        return self.result
