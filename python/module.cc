// hvdb._hvdb: the C++ half of the Python module (python/hvdb/__init__.py is the other).
//
// A thin layer over client::Backend (client/backend.h), so the embedded and the remote mode
// behave as the `hvdb` command line does in each. Results come back as numpy structured arrays
// whose records are storage's 64-byte Point (the dtype is POINT_DTYPE in __init__.py, built
// from the offsets exported here): a whole result is copied once, batch by batch, into pages
// numpy then owns (PageBuffer); a streamed batch becomes an array without a copy. The GIL is released whenever the library waits on
// disk or network; between batches pending signals are checked, so Ctrl-C stops a long query.
// Errors are Status values turned into the exception classes of __init__.py by code.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <cmath>
#include <sys/mman.h>

#include <cstddef>
#include <cstdlib>
#include <mutex>
#include <opencv2/imgproc.hpp>

#include "client/backend.h"
#include "formats/image_codec.h"
#include "formats/image_io.h"
#include "formats/ply.h"
#include "protocol/wire.h"
#include "python/common.h"
#include "python/gaussians.h"
#include "render/renderer.h"
#include "storage/point.h"

namespace py = pybind11;
using namespace pybind11::literals;

namespace hvdb::python {
namespace {

Window ToWindow(const std::array<double, 4>& lo, const std::array<double, 4>& hi) {
  Window w;
  w.lo = lo;
  w.hi = hi;
  return w;
}

// A region from Python: ("window", lo[4], hi[4]) or ("slice", normal[4], offset, thickness,
// clip_lo or None, clip_hi or None, max_frames).
Region ToRegion(const py::tuple& r) {
  std::string kind = py::cast<std::string>(r[0]);
  if (kind == "window") {
    return ToWindow(py::cast<std::array<double, 4>>(r[1]), py::cast<std::array<double, 4>>(r[2]));
  }
  Slice s;
  s.normal = py::cast<std::array<double, 4>>(r[1]);
  s.offset = py::cast<double>(r[2]);
  s.thickness = py::cast<double>(r[3]);
  if (!r[4].is_none()) {
    s.clip = ToWindow(py::cast<std::array<double, 4>>(r[4]), py::cast<std::array<double, 4>>(r[5]));
  }
  s.max_frames = py::cast<uint32_t>(r[6]);
  return s;
}

std::optional<Region> ToOptionalRegion(const py::object& r) {
  if (r.is_none()) return std::nullopt;
  return ToRegion(py::cast<py::tuple>(r));
}

py::dict InfoDict(const DatasetInfo& i) {
  py::list cams;
  for (const CameraInfo& c : i.cameras) {
    cams.append(py::dict("id"_a = c.id, "name"_a = c.name, "width"_a = c.width,
                         "height"_a = c.height, "fx"_a = c.fx, "fy"_a = c.fy, "cx"_a = c.cx,
                         "cy"_a = c.cy, "distortion"_a = c.distortion,
                         "world_from_camera"_a = c.world_from_camera));
  }
  return py::dict("name"_a = i.name, "fps"_a = i.fps, "space_time_scale"_a = i.space_time_scale,
                  "frame_count"_a = i.frame_count, "bounds_min"_a = i.bounds_min,
                  "bounds_max"_a = i.bounds_max, "point_count"_a = i.point_count,
                  "last_lsn"_a = i.last_lsn, "cameras"_a = cams, "gaussians"_a = i.gaussians);
}

py::dict CommitDict(const CommitInfo& c) {
  return py::dict("lsn"_a = c.lsn, "inserted"_a = c.inserted, "removed"_a = c.removed);
}

Selection ToSelection(const py::object& region, uint32_t label_mask) {
  Selection s;
  s.region = ToOptionalRegion(region);
  s.label_mask = label_mask;
  return s;
}

// Memory for a query's whole result, written once: anonymous pages from mmap, grown by mremap,
// which moves pages instead of copying them (a std::vector would copy at every doubling and
// peak at 1.5-3x). Pages past what is written are never touched, so never resident. (Asking
// for transparent huge pages made fetches slower here: synchronous compaction.)
class PageBuffer {
 public:
  PageBuffer() = default;
  PageBuffer(const PageBuffer&) = delete;
  PageBuffer& operator=(const PageBuffer&) = delete;
  ~PageBuffer() {
    if (data_ != nullptr) ::munmap(data_, capacity_);
  }
  void* data() const { return data_; }
  Status Reserve(size_t bytes) {
    if (bytes <= capacity_) return Status::OK();
    constexpr size_t kHuge = 2u << 20;
    size_t grown = std::max(bytes, capacity_ * 2);
    grown = (grown + kHuge - 1) / kHuge * kHuge;
    void* p = data_ == nullptr
                  ? ::mmap(nullptr, grown, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                           -1, 0)
                  : ::mremap(data_, capacity_, grown, MREMAP_MAYMOVE);
    if (p == MAP_FAILED) {
      return Status::LimitExceeded("no memory for a result of " + std::to_string(grown >> 20) +
                                   " MiB");
    }
    data_ = p;
    capacity_ = grown;
    return Status::OK();
  }

 private:
  void* data_ = nullptr;
  size_t capacity_ = 0;
};

// A database's backend and the lock every use of it takes. The database and each of its open
// queries hold it, so a query outlives close() safely: the backend (a connection, or the data
// directory's lock) goes when the last of them does. Neither backend may serve two threads at
// once (the remote one is one connection), so Python threads take turns on `mu`.
// Lock order: `mu` is never taken while holding the GIL (it is released first), because the
// render library's log handler takes the GIL during a call that holds `mu`.
struct Shared {
  std::mutex mu;
  std::unique_ptr<client::Backend> backend;
};

// One query's batches. next() returns the next batch (or None at the end) with its level.
class Query {
 public:
  Query(std::shared_ptr<Shared> shared, std::unique_ptr<client::QueryResults> r)
      : shared_(std::move(shared)), results_(std::move(r)) {}
  Query(Query&&) = default;
  ~Query() { Drop(); }

  // (array, level) or None.
  py::object Next() {
    client::QueryResults* r = results_.get();
    if (r == nullptr) return py::none();
    Batch batch;
    Result<bool> more(false);
    {
      py::gil_scoped_release release;
      // While we hold mu, a concurrent close() may take results_ but destroys it only after.
      std::lock_guard<std::mutex> l(shared_->mu);
      more = r->Next(&batch);
      if (more.ok() && !*more) Finished(r);
    }
    if (!more.ok()) {
      Drop();
      Throw(more.status());
    }
    if (!*more) {
      Drop();
      return py::none();
    }
    return py::make_tuple(ToArray(std::move(batch.points)), batch.level);
  }

  // Everything left, as one array, with one copy: each batch (the query reuses one Batch, so
  // no allocation per batch) is copied into a PageBuffer, which grows without copying; the
  // resident peak is the array plus one batch.
  py::array All() {
    auto buf = std::make_unique<PageBuffer>();
    size_t size = 0;
    Batch batch;
    for (;;) {
      client::QueryResults* r = results_.get();
      if (r == nullptr) break;
      Result<bool> more(false);
      {
        py::gil_scoped_release release;
        std::lock_guard<std::mutex> l(shared_->mu);
        more = r->Next(&batch);
        if (more.ok() && *more && !batch.points.empty()) {
          size_t n = batch.points.size();
          Status st = buf->Reserve((size + n) * sizeof(Point));
          if (st.ok()) {
            std::memcpy(static_cast<char*>(buf->data()) + size * sizeof(Point),
                        static_cast<const void*>(batch.points.data()), n * sizeof(Point));
            size += n;
          } else {
            more = st;
          }
        }
        if (more.ok() && !*more) Finished(r);
      }
      if (!more.ok()) {
        Drop();
        Throw(more.status());
      }
      if (!*more) Drop();
      if (PyErr_CheckSignals() != 0) {  // Ctrl-C: drop the query (remote: it is cancelled)
        Drop();
        throw py::error_already_set();
      }
    }
    Check(buf->Reserve(std::max<size_t>(size, 1) * sizeof(Point)));  // never a null pointer
    void* data = buf->data();
    py::capsule owner(buf.release(), [](void* p) { delete static_cast<PageBuffer*>(p); });
    return py::array(py::dtype::from_args(PointDtype()), {static_cast<py::ssize_t>(size)},
                     {static_cast<py::ssize_t>(sizeof(Point))}, data, owner);
  }

  // Stops the query (remote: cancels it on the server; the connection stays usable).
  void Close() { Drop(); }
  const std::vector<uint32_t>& frames() const { return frames_; }
  bool clipped() const { return clipped_; }

 private:
  // Called with mu held, at the end of the results.
  void Finished(client::QueryResults* r) {
    frames_ = r->frames();
    clipped_ = r->clipped();
  }
  // Destroys the results (a remote query not at its end is cancelled and drained there) under
  // mu, without the GIL. Called with the GIL held.
  void Drop() {
    if (!results_) return;
    std::unique_ptr<client::QueryResults> r = std::move(results_);
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> l(shared_->mu);
    r.reset();
  }

  std::shared_ptr<Shared> shared_;  // declared first: outlives results_
  std::unique_ptr<client::QueryResults> results_;
  std::vector<uint32_t> frames_;
  bool clipped_ = false;
};

// A watch of a dataset's changes (client::Watcher): its own connection when remote, a queue fed
// by the engine when embedded; events as dicts. hvdb.Database.watch iterates over it.
class Watch {
 public:
  Watch(std::shared_ptr<void> keep, std::unique_ptr<client::Watcher> w)
      : keep_(std::move(keep)), w_(std::move(w)) {}
  // The next event as a dict, or None if none came within timeout_s (the watch goes on) or it
  // has ended (ended() then says so). Waits in short steps so that Ctrl-C interrupts it.
  py::object Next(double timeout_s) {
    if (!w_) return py::none();
    const auto end = std::chrono::steady_clock::now() +
                     std::chrono::microseconds(static_cast<int64_t>(timeout_s * 1e6));
    ChangeEvent ev;
    for (;;) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now());
      Result<bool> got(false);
      {
        py::gil_scoped_release release;
        got = w_->Next(&ev, std::max(std::chrono::milliseconds(0),
                                     std::min(left, std::chrono::milliseconds(100))));
      }
      if (!got.ok()) {
        Close();
        Throw(got.status());
      }
      if (*got) break;
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
      if (left.count() <= 0) return py::none();
    }
    py::dict d;
    d["lsn"] = ev.lsn;
    d["kind"] = ChangeKindName(ev.kind);
    d["dataset"] = ev.dataset;
    if (ev.kind != ChangeEvent::Kind::kLive && ev.kind != ChangeEvent::Kind::kLagged &&
        ev.kind != ChangeEvent::Kind::kDropped) {
      d["frames"] = ev.frames;
      d["points"] = ev.points;
      d["removed"] = ev.removed;
      if (ev.kind == ChangeEvent::Kind::kRevert) d["reverts"] = ev.reverts;
    }
    if (ev.kind == ChangeEvent::Kind::kLagged || ev.kind == ChangeEvent::Kind::kDropped) ended_ = true;
    return d;
  }
  bool ended() const { return ended_ || !w_; }
  void Close() {
    std::unique_ptr<client::Watcher> w = std::move(w_);
    py::gil_scoped_release release;
    w.reset();  // cancels it on the server
  }

 private:
  std::shared_ptr<void> keep_;  // the backend outlives the watch
  std::unique_ptr<client::Watcher> w_;
  bool ended_ = false;
};

class Database {
 public:
  explicit Database(std::unique_ptr<client::Backend> b)
      : shared_(std::make_shared<Shared>()), remote_(b->remote()), where_(b->where()) {
    shared_->backend = std::move(b);
  }

  // Runs fn(backend) without the GIL, under the backend's lock (Shared).
  template <typename Fn>
  auto Call(Fn&& fn) {
    if (!shared_) Throw(Status::InvalidArgument("the database is closed"));
    std::shared_ptr<Shared> s = shared_;  // kept alive for the call even if closed meanwhile
    py::gil_scoped_release release;
    std::lock_guard<std::mutex> l(s->mu);
    return fn(*s->backend);
  }

  static Database Open(const std::string& dir, size_t cache_mb) {
    if (cache_mb < 8) Throw(Status::InvalidArgument("cache_mb: must be >= 8"));
    return Database(client::MakeEmbeddedBackend(dir, cache_mb << 20));
  }
  static Database Connect(const std::string& address, const std::string& token,
                          const std::string& wire) {
    client::RemoteOptions o;
    o.address = address;
    o.token = token;
    o.wire = wire;
    Database db(Take(client::MakeRemoteBackend(o)));
    // Connects now, so that a wrong address fails here and not at the first query.
    Take(db.Call([](client::Backend& b) { return b.ListDatasets(); }));
    return db;
  }

  bool remote() const { return remote_; }
  const std::string& where() const { return where_; }
  // No new calls; the backend goes once calls in flight and open queries are done.
  void Close() {
    std::shared_ptr<Shared> s = std::move(shared_);
    py::gil_scoped_release release;
    s.reset();  // possibly the last reference: closes the backend without the GIL
  }

  std::vector<std::string> Datasets() {
    return Take(Call([](client::Backend& b) { return b.ListDatasets(); }));
  }
  py::dict Create(const std::string& name, double fps, double space_time_scale, bool gaussians) {
    DatasetInfo info;
    info.name = name;
    info.fps = fps;
    info.space_time_scale = space_time_scale;
    info.gaussians = gaussians;
    return InfoDict(Take(Call([&](client::Backend& b) { return b.CreateDataset(info); })));
  }
  void Drop(const std::string& name) {
    Check(Call([&](client::Backend& b) { return b.DropDataset(name); }));
  }
  py::dict Describe(const std::string& name) {
    return InfoDict(Take(Call([&](client::Backend& b) { return b.Describe(name); })));
  }
  py::dict Stats(const std::string& name) {
    client::StatsReport r = Take(Call([&](client::Backend& b) { return b.Stats(name); }));
    py::list datasets;
    for (const auto& e : r.datasets) {
      const DatasetStats& s = e.stats;
      datasets.append(py::dict("name"_a = e.name, "last_lsn"_a = e.last_lsn,
                               "frames_with_data"_a = s.frames_with_data, "points"_a = s.points,
                               "tombstones"_a = s.tombstones,
                               "buffered_points"_a = s.buffered_points,
                               "tree_bytes"_a = s.tree_bytes, "cold_frames"_a = s.cold_frames,
                               "cold_tree_bytes"_a = s.cold_tree_bytes,
                               "cold_points"_a = s.cold_points));
    }
    py::dict out("datasets"_a = datasets);
    if (r.cache) {
      out["cache"] = py::dict("capacity_bytes"_a = r.cache->capacity_bytes,
                              "resident_blocks"_a = r.cache->resident_blocks,
                              "hits"_a = r.cache->hits, "misses"_a = r.cache->misses,
                              "prefetched"_a = r.cache->prefetched);
    }
    if (r.server) {
      py::list reqs;
      for (const auto& l : r.server->requests) {
        reqs.append(py::dict("kind"_a = l.kind, "count"_a = l.count, "p50_ms"_a = l.p50_ms,
                             "p95_ms"_a = l.p95_ms, "p99_ms"_a = l.p99_ms));
      }
      out["server"] = py::dict("connections_open"_a = r.server->connections_open,
                               "connections_total"_a = r.server->connections_total,
                               "bytes_in"_a = r.server->bytes_in,
                               "bytes_out"_a = r.server->bytes_out,
                               "cache_hit_rate"_a = r.server->cache_hit_rate, "requests"_a = reqs);
    }
    return out;
  }

  Query Start(const std::string& name, const py::tuple& region, int lod, bool progressive,
              bool temporal_lod, uint32_t label_mask) {
    QueryOptions o;
    o.lod = lod;
    o.progressive = progressive;
    o.temporal_lod = temporal_lod;
    o.label_mask = label_mask;
    Region r = ToRegion(region);
    auto results = Take(Call([&](client::Backend& b) { return b.Query(name, r, o); }));
    return Query(shared_, std::move(results));
  }

  uint64_t BulkLoad(const std::string& name, uint32_t frame, const py::array& points,
                    const py::object& gaussians) {
    std::vector<Point> pts = FromArray(points);
    std::optional<GaussianColumns> g;
    if (!gaussians.is_none()) g = GaussiansFromDict(py::cast<py::dict>(gaussians), pts.size());
    return Take(Call([&](client::Backend& b) {
      return b.BulkLoad(name, frame, std::move(pts), g ? &*g : nullptr);
    }));
  }
  // The Gaussian records of points (by id), python/gaussians.h's dict, with `derived`.
  py::dict Gaussians(const std::string& name, const py::array& points) {
    std::vector<Point> pts = FromArray(points);
    uint64_t derived = 0;
    GaussianColumns g =
        Take(Call([&](client::Backend& b) { return b.ReadGaussians(name, pts, &derived); }));
    py::dict d = GaussiansToDict(g);
    d["derived"] = derived;
    return d;
  }

  // ops: a list of tuples, applied in order as one transaction:
  //   ("insert", array)  ("delete", region|None, label_mask)
  //   ("transform", region|None, label_mask, a[16], c[4])  ("label", region|None, mask, bits, set)
  py::dict Commit(const std::string& name, const py::list& ops) {
    Transaction txn;
    for (const py::handle& h : ops) {
      py::tuple op = py::cast<py::tuple>(h);
      std::string kind = py::cast<std::string>(op[0]);
      if (kind == "insert") {
        txn.Insert(FromArray(py::cast<py::array>(op[1])));
      } else if (kind == "delete") {
        txn.DeleteSelection(ToSelection(op[1], py::cast<uint32_t>(op[2])));
      } else if (kind == "transform") {
        Affine4 map;
        map.a = py::cast<std::array<double, 16>>(op[3]);
        map.c = py::cast<std::array<double, 4>>(op[4]);
        txn.Transform(ToSelection(op[1], py::cast<uint32_t>(op[2])), map);
      } else if (kind == "label") {
        txn.SetLabel(ToSelection(op[1], py::cast<uint32_t>(op[2])), py::cast<uint32_t>(op[3]),
                     py::cast<bool>(op[4]));
      } else {
        Throw(Status::InvalidArgument("transaction: unknown operation '" + kind + "'"));
      }
    }
    return CommitDict(Take(Call([&](client::Backend& b) { return b.Commit(name, txn); })));
  }

  Watch StartWatch(const std::string& name, std::optional<uint64_t> from_lsn) {
    if (!shared_) Throw(Status::InvalidArgument("the database is closed"));
    std::shared_ptr<Shared> s = shared_;
    std::unique_ptr<client::Watcher> w =
        Take(Call([&](client::Backend& b) { return b.Watch(name, from_lsn); }));
    return Watch(s, std::move(w));
  }

  // The cold tier: frames [first, last] compressed now.
  // photos: their photos coded as video per camera instead.
  py::dict Compact(const std::string& name, uint32_t first, uint32_t last, bool photos) {
    CompactInfo c =
        Take(Call([&](client::Backend& b) { return b.Compact(name, first, last, photos); }));
    if (photos) {
      return py::dict("photo_runs"_a = c.photo_runs, "photo_pictures"_a = c.photo_pictures,
                      "photo_already"_a = c.photo_already,
                      "photo_bytes_before"_a = c.photo_bytes_before,
                      "photo_bytes_after"_a = c.photo_bytes_after,
                      "photo_min_psnr"_a = c.photo_min_psnr);
    }
    return py::dict("frames"_a = c.frames, "already"_a = c.already, "points"_a = c.points,
                    "bytes_before"_a = c.bytes_before, "bytes_after"_a = c.bytes_after);
  }

  py::dict Revert(const std::string& name, uint64_t lsn) {
    return CommitDict(Take(Call([&](client::Backend& b) { return b.Revert(name, lsn); })));
  }

  py::dict Select(const std::string& name, const py::tuple& region, int bit,
                  const std::string& mode) {
    edit::SelectRequest req;
    req.region = ToRegion(region);
    req.bit = bit;
    if (mode == "replace") {
      req.mode = edit::SelectMode::kReplace;
    } else if (mode == "add") {
      req.mode = edit::SelectMode::kAdd;
    } else if (mode == "subtract") {
      req.mode = edit::SelectMode::kSubtract;
    } else if (mode == "intersect") {
      req.mode = edit::SelectMode::kIntersect;
    } else {
      Throw(Status::InvalidArgument("mode: '" + mode +
                                    "' is not one of replace, add, subtract, intersect"));
    }
    edit::SelectResult r = Take(Call([&](client::Backend& b) { return b.Select(name, req); }));
    return py::dict("matched"_a = r.matched, "selected"_a = r.selected, "lsn"_a = r.lsn);
  }

  py::dict GraphCut(const std::string& name, const py::tuple& roi, int foreground_bit,
                    int background_bit, int out_bit) {
    edit::GraphCutRequest req;
    req.roi = ToRegion(roi);
    req.foreground_bit = foreground_bit;
    req.background_bit = background_bit;
    req.out_bit = out_bit;
    edit::GraphCutReply r = Take(Call([&](client::Backend& b) { return b.GraphCut(name, req); }));
    return py::dict("roi_points"_a = r.roi_points, "selected"_a = r.selected, "lsn"_a = r.lsn);
  }

  py::dict Copy(const std::string& name, int bit, const py::object& region,
                const std::string& clipboard, bool cut) {
    std::optional<Region> r = ToOptionalRegion(region);
    edit::CopyResult c =
        Take(Call([&](client::Backend& b) { return b.Copy(name, {bit, r, clipboard, cut}); }));
    return py::dict("points"_a = c.points, "lsn"_a = c.lsn);
  }

  py::dict Paste(const std::string& name, const std::string& clipboard,
                 const std::array<double, 16>& a, const std::array<double, 4>& c) {
    Affine4 map;
    map.a = a;
    map.c = c;
    return CommitDict(Take(Call([&](client::Backend& b) { return b.Paste(name, {clipboard, map}); })));
  }

  // A single view's image (docs/PROTOCOL.md, "Rendering"): the look-at camera of
  // `hvdb render`, the region's points at `lod`. Returns the reply's facts and either the PNG
  // decoded to H x W x 3 (or 4) uint8, or (exr=true) the EXR's linear RGBA and depth as
  // H x W x 4 and H x W float32.
  py::dict Render(const std::string& name, const py::tuple& region,
                  const std::array<double, 3>& eye, const std::array<double, 3>& target,
                  const std::array<double, 3>& up, double fov, uint32_t width, uint32_t height,
                  const std::string& mode, uint32_t lod, const std::string& renderer, bool exr,
                  bool view_dependent, bool texture, bool billboards,
                  const std::vector<double>& shadow_light, bool shadow_directional,
                  uint32_t shadow_casters, float shadow_strength) {
    render::RenderRequest req;
    req.dataset = name;
    req.region = ToRegion(region);
    render::LookAtView l;
    l.eye = eye;
    l.target = target;
    l.up = up;
    l.fov_y_deg = fov;
    l.width = width;
    l.height = height;
    req.view = l;
    // "auto" leaves mode, texture and billboards unset: the render job picks the frame's best.
    if (mode == "visibility") {
      req.mode = render::Mode::kVisibility;
    } else if (mode == "probabilistic") {
      req.mode = render::Mode::kProbabilistic;
    } else if (mode == "gaussian") {
      req.mode = render::Mode::kGaussian;
    } else if (mode == "textured") {
      texture = true;
    } else if (mode == "billboards") {
      billboards = true;
    } else if (mode != "auto") {
      Throw(Status::InvalidArgument("mode: '" + mode + "' is not auto, visibility, "
                                    "probabilistic, gaussian, textured or billboards"));
    }
    req.lod = lod;  // any level: storage refuses one past the dataset's coarsest
    req.view_dependent = view_dependent;
    if (texture) req.texture = true;
    if (billboards) req.billboards = true;
    if (!shadow_light.empty()) {  // render/job.cc checks the values (render.shadow_*)
      if (shadow_light.size() != 3) {
        Throw(Status::InvalidArgument("render.shadow_light: needs 3 values (a position, or "
                                      "with shadow_directional a direction), or none for no "
                                      "shadows"));
      }
      req.shadow_light = {shadow_light[0], shadow_light[1], shadow_light[2]};
      req.shadow_directional = shadow_directional;
      req.shadow_casters = shadow_casters;
      req.shadow_strength = shadow_strength == 0 ? 1e-30f : shadow_strength;
    }
    if (renderer == "auto") {
      req.renderer = render::RendererKind::kAuto;
    } else if (renderer == "egl") {
      req.renderer = render::RendererKind::kEgl;
    } else if (renderer == "cpu") {
      req.renderer = render::RendererKind::kCpu;
    } else {
      Throw(Status::InvalidArgument("renderer: '" + renderer + "' is not auto, egl or cpu"));
    }
    req.format = exr ? render::ImageFormat::kExr : render::ImageFormat::kPng;
    render::RenderReply reply;
    Check(Call([&](client::Backend& b) {
      return b.Render(req, [&](const render::RenderReply& r) {
        reply = r;
        return Status::OK();
      });
    }));
    py::dict d("width"_a = reply.width, "height"_a = reply.height,
               "renderer"_a = reply.renderer_used, "renderer_choice"_a = reply.renderer_choice,
               "points"_a = reply.points, "render_ms"_a = reply.render_ms,
               "mode"_a = reply.mode_used, "mode_choice"_a = reply.mode_choice);
    if (exr) {
      render::Image img = Take(formats::DecodeExr(reply.exr));
      py::array_t<float> rgba({img.height, img.width, 4u});
      py::array_t<float> depth({img.height, img.width});
      std::memcpy(rgba.mutable_data(), img.rgba.data(), img.rgba.size() * sizeof(float));
      std::memcpy(depth.mutable_data(), img.depth.data(), img.depth.size() * sizeof(float));
      d["rgba"] = rgba;
      d["depth"] = depth;
      return d;
    }
    auto decoded = formats::DecodeImage(reply.png, "render: the PNG", formats::ImageMode::kAsStored);
    if (!decoded.ok()) Throw(Status::Internal(decoded.status().message()));
    cv::Mat m = *decoded;
    int ch = m.channels();
    cv::cvtColor(m, m, ch == 4 ? cv::COLOR_BGRA2RGBA : cv::COLOR_BGR2RGB);
    py::array_t<uint8_t> img({m.rows, m.cols, ch});
    for (int y = 0; y < m.rows; ++y) {
      std::memcpy(img.mutable_data(y), m.ptr(y), static_cast<size_t>(m.cols) * ch);
    }
    d["image"] = img;
    return d;
  }

 private:
  std::shared_ptr<Shared> shared_;  // null once closed
  bool remote_;
  std::string where_;
};

// (points, how many vertices skip_invalid left out); __init__.py's read_ply shapes the result.
py::tuple ReadPly(const std::string& path, double scale, bool skip_invalid) {
  formats::ReadOptions o;
  o.scale = scale;
  o.skip_invalid = skip_invalid;
  formats::ReadStats stats;
  std::vector<Point> pts;
  {
    py::gil_scoped_release release;
    auto r = formats::ReadPly(path, o, &stats);
    if (!r.ok()) {
      py::gil_scoped_acquire acquire;
      Throw(r.status());
    }
    pts = std::move(r).value();
  }
  return py::make_tuple(ToArray(std::move(pts)), stats.skipped_non_finite);
}

void WritePly(const std::string& path, const py::array& points, bool ascii) {
  std::vector<Point> pts = FromArray(points);
  py::gil_scoped_release release;
  Status st = formats::WritePly(path, pts, ascii);
  py::gil_scoped_acquire acquire;
  Check(st);
}

}  // namespace
}  // namespace hvdb::python

PYBIND11_MODULE(_hvdb, m) {
  using namespace hvdb::python;
  m.doc() = "hvdb's C++ half; use the hvdb package";
  // The Point record's layout, for POINT_DTYPE (docs/FORMAT.md "Point record").
  m.attr("POINT_SIZE") = sizeof(hvdb::Point);
  m.attr("POINT_OFFSETS") = py::dict(
      "id"_a = offsetof(hvdb::Point, id), "position"_a = offsetof(hvdb::Point, x),
      "frame"_a = offsetof(hvdb::Point, frame), "cov"_a = offsetof(hvdb::Point, cov),
      "normal_oct"_a = offsetof(hvdb::Point, normal_oct), "label"_a = offsetof(hvdb::Point, label),
      "color"_a = offsetof(hvdb::Point, r), "flags"_a = offsetof(hvdb::Point, flags),
      "camera"_a = offsetof(hvdb::Point, camera), "reserved"_a = offsetof(hvdb::Point, reserved));

  // __init__.py's raise_status(code_name, message). Never freed: a static py::object would be
  // released after the interpreter has finalised.
  static py::object* status_hook = new py::object();
  m.def("_set_status_hook", [](py::object hook) { *status_hook = std::move(hook); });
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const StatusError& e) {
      // The hook raises the exception class of the code; its error is the one set here.
      try {
        (*status_hook)(hvdb::StatusCodeName(e.code), e.message);
      } catch (py::error_already_set& err) {
        err.restore();
      }
    }
  });

  // The render library's notes and warnings (e.g. which renderer `auto` chose) go to Python's
  // logging, logger "hvdb", instead of stderr. They are raised by calls a Python thread made
  // (with the GIL released), so taking the GIL back here is safe.
  hvdb::render::SetLogHandler([](const std::string& message) {
    py::gil_scoped_acquire acquire;
    try {
      py::object logger = py::module_::import("logging").attr("getLogger")("hvdb");
      bool note = message.rfind("note: ", 0) == 0;
      logger.attr(note ? "info" : "warning")(note ? message.substr(6) : message);
    } catch (py::error_already_set& e) {
      e.discard_as_unraisable("hvdb render log");
    }
  });

  py::class_<Query>(m, "_Query")
      .def("next", &Query::Next)
      .def("all", &Query::All)
      .def("close", &Query::Close)
      .def_property_readonly("frames", &Query::frames)
      .def_property_readonly("clipped", &Query::clipped);

  py::class_<Watch>(m, "_Watch")
      .def("next", &Watch::Next, "timeout"_a)
      .def("close", &Watch::Close)
      .def_property_readonly("ended", &Watch::ended);

  py::class_<Database>(m, "_Database")
      .def_static("open", &Database::Open, "dir"_a, "cache_mb"_a)
      .def_static("connect", &Database::Connect, "address"_a, "token"_a, "wire"_a)
      .def_property_readonly("remote", &Database::remote)
      .def_property_readonly("where", &Database::where)
      .def("close", &Database::Close)
      .def("datasets", &Database::Datasets)
      .def("create", &Database::Create, "name"_a, "fps"_a, "space_time_scale"_a,
           "gaussians"_a = false)
      .def("drop", &Database::Drop)
      .def("describe", &Database::Describe)
      .def("stats", &Database::Stats)
      .def("query", &Database::Start)
      .def("bulk_load", &Database::BulkLoad, "name"_a, "frame"_a, "points"_a,
           "gaussians"_a = py::none())
      .def("gaussians", &Database::Gaussians)
      .def("commit", &Database::Commit)
      .def("revert", &Database::Revert)
      .def("compact", &Database::Compact, "name"_a, "first"_a = 0u, "last"_a = 0xFFFFFFFFu,
           "photos"_a = false)
      .def("watch", &Database::StartWatch, "name"_a, "from_lsn"_a = py::none())
      .def("select", &Database::Select)
      .def("graphcut", &Database::GraphCut)
      .def("copy", &Database::Copy)
      .def("paste", &Database::Paste)
      .def("render", &Database::Render);

  m.def("read_ply", &ReadPly, "path"_a, "scale"_a = 1.0, "skip_invalid"_a = false);
  m.def("read_splats", &ReadSplats, "path"_a);
  m.def("write_splats", &WriteSplats, "path"_a, "points"_a, "gaussians"_a, "format"_a);
  m.def("write_ply", &WritePly, "path"_a, "points"_a, "ascii"_a = false);
  m.def("encode_normals", [](const py::array_t<float, py::array::c_style | py::array::forcecast>& n) {
    if (n.ndim() != 2 || n.shape(1) != 3) {
      Throw(hvdb::Status::InvalidArgument("normals: expected an N x 3 array"));
    }
    py::array_t<int16_t> out({n.shape(0), py::ssize_t{2}});
    for (py::ssize_t i = 0; i < n.shape(0); ++i) {
      auto e = hvdb::EncodeNormal(n.at(i, 0), n.at(i, 1), n.at(i, 2));
      out.mutable_at(i, 0) = e[0];
      out.mutable_at(i, 1) = e[1];
    }
    return out;
  });
  m.def("decode_normals", [](const py::array_t<int16_t, py::array::c_style | py::array::forcecast>& o) {
    if (o.ndim() != 2 || o.shape(1) != 2) {
      Throw(hvdb::Status::InvalidArgument("normal_oct: expected an N x 2 array"));
    }
    py::array_t<float> out({o.shape(0), py::ssize_t{3}});
    for (py::ssize_t i = 0; i < o.shape(0); ++i) {
      auto d = hvdb::DecodeNormal({o.at(i, 0), o.at(i, 1)});
      for (int k = 0; k < 3; ++k) out.mutable_at(i, k) = d[k];
    }
    return out;
  });
}
