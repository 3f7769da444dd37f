#include "edit/operators.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <set>

#include "storage/affine.h"
#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/env.h"

namespace hvdb::edit {

namespace {

using Key = std::pair<uint32_t, uint64_t>;  // (frame, id)

Status CheckBit(int bit, const char* what) {
  if (bit < 0 || bit > 31) {
    return Status::InvalidArgument(std::string(what) + ": label bit must be 0..31, got " +
                                   std::to_string(bit));
  }
  return Status::OK();
}

Window Everything() {
  Window w;
  w.lo = {-1e30, -1e30, -1e30, -1e30};
  w.hi = {1e30, 1e30, 1e30, 1e30};
  return w;
}

// Streams every point of the region (lod 0, no temporal subsampling) into fn; the frames the
// region covers into *frames when given.
Status ForEach(Dataset& ds, const Region& region, uint32_t label_mask,
               const std::function<void(const Point&)>& fn,
               std::vector<uint32_t>* frames = nullptr,
               const std::function<void(uint64_t bound)>& reserve = nullptr) {
  QueryOptions o;
  o.temporal_lod = false;
  o.label_mask = label_mask;
  HVDB_ASSIGN_OR_RETURN(auto cursor, ds.Query(region, o));
  if (frames != nullptr) *frames = cursor->frames();
  if (reserve) reserve(cursor->PointsBound());
  Batch b;
  for (;;) {
    HVDB_ASSIGN_OR_RETURN(bool more, cursor->Next(&b));
    if (!more) return Status::OK();
    for (const Point& p : b.points) fn(p);
  }
}

template <typename Keys>
Selection Explicit(const Keys& keys) {
  Selection s;
  s.ids.assign(keys.begin(), keys.end());
  return s;
}

bool InPolygon(const std::vector<std::array<double, 2>>& poly, double x, double y) {
  bool in = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const auto& a = poly[i];
    const auto& b = poly[j];
    if ((a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0]) {
      in = !in;
    }
  }
  return in;
}

Status CheckCamera(const CameraInfo& c) {
  if (!(c.fx > 0) || !(c.fy > 0) || !std::isfinite(c.cx) || !std::isfinite(c.cy)) {
    return Status::InvalidArgument("camera: focal lengths must be > 0 and the centre finite");
  }
  for (double v : c.world_from_camera) {
    if (!std::isfinite(v)) return Status::InvalidArgument("camera: pose is not finite");
  }
  return Status::OK();
}

}  // namespace

bool ProjectToPixel(const CameraInfo& cam, double x, double y, double z, double* u, double* v,
                    double* depth) {
  // camera_from_world of a rigid world_from_camera [R t]: [R^T, -R^T t].
  const auto& M = cam.world_from_camera;
  const double d[3] = {x - M[3], y - M[7], z - M[11]};
  double c[3];
  for (int i = 0; i < 3; ++i) c[i] = M[static_cast<size_t>(i)] * d[0] + M[static_cast<size_t>(4 + i)] * d[1] + M[static_cast<size_t>(8 + i)] * d[2];
  if (c[2] <= 1e-9) return false;
  *u = cam.fx * c[0] / c[2] + cam.cx;
  *v = cam.fy * c[1] / c[2] + cam.cy;
  *depth = c[2];
  return true;
}

Result<SelectResult> Select(Dataset& ds, const SelectRequest& req) {
  HVDB_RETURN_IF_ERROR(CheckBit(req.bit, "select"));
  const uint32_t mask = 1u << req.bit;
  SelectResult res;
  std::vector<Key> target;  // sorted below
  std::vector<uint32_t> frames;  // of the region: the frames whose flips the reply lists
  if (std::holds_alternative<std::monostate>(req.shape)) {
    HVDB_RETURN_IF_ERROR(ForEach(ds, req.region, 0, [&](const Point& p) {
      target.push_back({p.frame, p.id});
    }, &frames));
  } else if (const auto* lasso = std::get_if<Lasso>(&req.shape)) {
    HVDB_RETURN_IF_ERROR(CheckCamera(lasso->camera));
    if (lasso->polygon.size() < 3) {
      return Status::InvalidArgument("lasso: the polygon needs at least 3 vertices");
    }
    for (const auto& q : lasso->polygon) {
      if (!std::isfinite(q[0]) || !std::isfinite(q[1])) {
        return Status::InvalidArgument("lasso: polygon vertices must be finite");
      }
    }
    HVDB_RETURN_IF_ERROR(ForEach(ds, req.region, 0, [&](const Point& p) {
      double u, v, depth;
      if (ProjectToPixel(lasso->camera, p.x, p.y, p.z, &u, &v, &depth) &&
          InPolygon(lasso->polygon, u, v)) {
        target.push_back({p.frame, p.id});
      }
    }, &frames));
  } else {
    const Brush& brush = std::get<Brush>(req.shape);
    HVDB_RETURN_IF_ERROR(CheckCamera(brush.camera));
    if (!(brush.pixel_radius > 0) || !(brush.radius > 0) || !std::isfinite(brush.u) ||
        !std::isfinite(brush.v)) {
      return Status::InvalidArgument("brush: radii must be > 0 and (u, v) finite");
    }
    // The front surface under the brush: depths of the points projecting into its footprint
    // (a z-buffer read, 9.3.1), then the nearest or the median of them.
    std::vector<Point> seen;
    std::vector<double> depths;
    HVDB_RETURN_IF_ERROR(ForEach(ds, req.region, 0, [&](const Point& p) {
      seen.push_back(p);
      double u, v, depth;
      if (ProjectToPixel(brush.camera, p.x, p.y, p.z, &u, &v, &depth) &&
          std::hypot(u - brush.u, v - brush.v) <= brush.pixel_radius) {
        depths.push_back(depth);
      }
    }, &frames));
    if (depths.empty()) {
      return Status::NotFound("brush: no surface under pixel (" + std::to_string(brush.u) + ", " +
                              std::to_string(brush.v) + ")");
    }
    double z;
    if (brush.depth == Brush::Depth::kNearest) {
      z = *std::min_element(depths.begin(), depths.end());
    } else {
      auto mid = depths.begin() + static_cast<std::ptrdiff_t>(depths.size() / 2);
      std::nth_element(depths.begin(), mid, depths.end());
      z = *mid;
    }
    // Back-project (u, v, z) to world coordinates.
    const auto& M = brush.camera.world_from_camera;
    const double c[3] = {(brush.u - brush.camera.cx) / brush.camera.fx * z,
                         (brush.v - brush.camera.cy) / brush.camera.fy * z, z};
    std::array<double, 3> centre{};
    for (int i = 0; i < 3; ++i) {
      centre[static_cast<size_t>(i)] = M[static_cast<size_t>(4 * i)] * c[0] +
                                       M[static_cast<size_t>(4 * i + 1)] * c[1] +
                                       M[static_cast<size_t>(4 * i + 2)] * c[2] + M[static_cast<size_t>(4 * i + 3)];
    }
    res.brush_center = centre;
    for (const Point& p : seen) {
      double dx = p.x - centre[0], dy = p.y - centre[1], dz = p.z - centre[2];
      if (dx * dx + dy * dy + dz * dz <= brush.radius * brush.radius) target.push_back({p.frame, p.id});
    }
  }
  // Sorted and distinct: points sharing an id in a frame (inserts may give one twice) are one
  // key, relabelled together.
  auto sort_unique = [](std::vector<Key>* keys) {
    std::sort(keys->begin(), keys->end());
    keys->erase(std::unique(keys->begin(), keys->end()), keys->end());
  };
  sort_unique(&target);
  res.matched = target.size();

  // Points carrying the bit now, for replace / intersect and the final count. Sorted vectors
  // and set operations: a marquee over a frame is tens of thousands of keys.
  std::vector<Key> current;
  HVDB_RETURN_IF_ERROR(ForEach(ds, Everything(), mask, [&](const Point& p) {
    current.push_back({p.frame, p.id});
  }));
  sort_unique(&current);
  std::vector<Key> to_set, to_clear;
  auto minus = [](const std::vector<Key>& a, const std::vector<Key>& b, std::vector<Key>* out) {
    std::set_difference(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(*out));
  };
  switch (req.mode) {
    case SelectMode::kReplace:
      minus(target, current, &to_set);
      minus(current, target, &to_clear);
      break;
    case SelectMode::kAdd:
      minus(target, current, &to_set);
      break;
    case SelectMode::kSubtract:
      std::set_intersection(target.begin(), target.end(), current.begin(), current.end(),
                            std::back_inserter(to_clear));
      break;
    case SelectMode::kIntersect:
      minus(current, target, &to_clear);
      break;
  }
  res.selected = current.size() + to_set.size() - to_clear.size();
  if (to_set.empty() && to_clear.empty()) return res;
  Transaction t;
  if (!to_clear.empty()) t.SetLabel(Explicit(to_clear), mask, false);
  if (!to_set.empty()) t.SetLabel(Explicit(to_set), mask, true);
  HVDB_ASSIGN_OR_RETURN(CommitInfo info, ds.Commit(t));
  res.lsn = info.lsn;
  if (req.return_flips) {
    std::sort(frames.begin(), frames.end());
    for (const auto* keys : {&to_clear, &to_set}) {
      for (const Key& k : *keys) {
        if (!std::binary_search(frames.begin(), frames.end(), k.first)) continue;
        if (res.flips.empty() || res.flips.back().frame != k.first ||
            res.flips.back().set != (keys == &to_set)) {
          res.flips.push_back({k.first, keys == &to_set, {}});
        }
        res.flips.back().ids.push_back(k.second);
      }
    }
  }
  return res;
}

namespace {

uint64_t Mix(uint64_t x) {  // splitmix64's finaliser
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

template <typename T>
uint64_t Bits(T v) {
  uint64_t b = 0;
  std::memcpy(&b, &v, sizeof(T));
  return b;
}

// Of everything the graph depends on: each point's id, frame, position, colour and normal (not
// its label: strokes and selections change labels), in any order, and the parameters. Two
// independent sums of per-point hashes, so that a collision needs both to collide.
std::array<uint64_t, 2> Fingerprint(const std::vector<Point>& pts, const GraphCutParams& g) {
  std::array<uint64_t, 2> f{Mix(pts.size()), Mix(pts.size() + 1)};
  for (const Point& p : pts) {
    uint64_t h = Mix(p.id);
    h = Mix(h ^ (uint64_t{p.frame} << 32 | Bits(p.x)));
    h = Mix(h ^ (Bits(p.y) << 32 | Bits(p.z)));
    h = Mix(h ^ (uint64_t{p.r} << 40 | uint64_t{p.g} << 32 | uint64_t{p.b} << 24 |
                 (p.flags & kFlagHasNormal)));
    h = Mix(h ^ Bits(p.normal_oct));
    f[0] += h;
    f[1] += Mix(h ^ 0x5851f42d4c957f2dULL);
  }
  for (double v : {double(g.k), g.intra_radius, g.inter_radius, g.max_color_diff,
                   g.max_normal_diff, double(g.gmm_components), g.beta_c, g.beta_n, g.lambda_d,
                   g.lambda_i, g.lambda_t, double(g.use_normals)}) {
    f[0] = Mix(f[0] ^ Bits(v));
    f[1] = Mix(f[1] + Bits(v));
  }
  return f;
}

}  // namespace

Result<GraphCutReply> GraphCutSelect(Dataset& ds, const GraphCutRequest& req,
                                     GraphCutCache* cache) {
  HVDB_RETURN_IF_ERROR(CheckBit(req.foreground_bit, "graph cut foreground"));
  HVDB_RETURN_IF_ERROR(CheckBit(req.background_bit, "graph cut background"));
  HVDB_RETURN_IF_ERROR(CheckBit(req.out_bit, "graph cut output"));
  if (req.foreground_bit == req.background_bit) {
    return Status::InvalidArgument("graph cut: foreground and background strokes need different bits");
  }
  // Before any point is read: a re-cut (with a cache) and a first cut refuse the same way.
  HVDB_RETURN_IF_ERROR(ValidateParams(req.params));
  using Clock = std::chrono::steady_clock;
  auto t0 = Clock::now();
  GraphCutReply reply;
  std::vector<Point> pts;
  std::vector<Seed> seeds;
  const uint32_t fmask = 1u << req.foreground_bit, bmask = 1u << req.background_bit;
  // Reserved for all the frames' points at once (up to 4 Mi points: the bound counts whole
  // frames, however small the region): growing a million-point vector by doubling copied and
  // first-touched twice its size.
  HVDB_RETURN_IF_ERROR(ForEach(ds, req.roi, 0, [&](const Point& p) {
    pts.push_back(p);
    seeds.push_back((p.label & fmask) ? Seed::kForeground
                    : (p.label & bmask) ? Seed::kBackground
                                        : Seed::kUnknown);
  }, nullptr, [&](uint64_t bound) {
    const auto n = static_cast<size_t>(std::min<uint64_t>(bound, uint64_t{4} << 20));
    pts.reserve(n);
    seeds.reserve(n);
  }));
  reply.roi_points = pts.size();
  reply.load_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  GraphCutResult cut;
  if (cache == nullptr) {
    HVDB_ASSIGN_OR_RETURN(cut, RunGraphCut(pts, seeds, req.params));
  } else {
    std::lock_guard<std::mutex> l(cache->mu_);
    const auto fp = Fingerprint(pts, req.params);
    // Node i of the cached graph is the point of id nodes_[..].first; the query's order
    // differs from the last one's (a relabelled point moves within its frame's trees).
    std::vector<uint32_t> node(pts.size());
    bool hit = cache->graph_ && fp == cache->fingerprint_ && cache->graph_->size() == pts.size();
    const std::vector<uint32_t>& dense = cache->dense_;
    for (size_t i = 0; i < pts.size() && hit; ++i) {
      const uint64_t off = pts[i].id - cache->dense_base_;
      if (!dense.empty()) {
        hit = pts[i].id >= cache->dense_base_ && off < dense.size() && dense[off] != UINT32_MAX;
        if (hit) node[i] = dense[off];
        continue;
      }
      auto it = std::lower_bound(cache->nodes_.begin(), cache->nodes_.end(),
                                 std::make_pair(pts[i].id, uint32_t{0}));
      hit = it != cache->nodes_.end() && it->first == pts[i].id;
      if (hit) node[i] = it->second;
    }
    if (!hit) {
      cache->graph_.reset();
      cache->nodes_.clear();
      cache->dense_.clear();
      if (pts.size() <= cache->max_points_) {
        HVDB_ASSIGN_OR_RETURN(cache->graph_, GraphCut::Build(pts, req.params));
        cache->fingerprint_ = fp;
        cache->nodes_.reserve(pts.size());
        for (size_t i = 0; i < pts.size(); ++i) {
          cache->nodes_.emplace_back(pts[i].id, static_cast<uint32_t>(i));
          node[i] = static_cast<uint32_t>(i);
        }
        std::sort(cache->nodes_.begin(), cache->nodes_.end());
        if (!pts.empty()) {
          const uint64_t lo = cache->nodes_.front().first, hi = cache->nodes_.back().first;
          if (hi - lo < 4 * uint64_t{pts.size()}) {
            cache->dense_base_ = lo;
            cache->dense_.assign(hi - lo + 1, UINT32_MAX);
            for (const auto& [id, n] : cache->nodes_) cache->dense_[id - lo] = n;
          }
        }
      }
    }
    if (cache->graph_) {
      std::vector<Seed> by_node(pts.size());
      for (size_t i = 0; i < pts.size(); ++i) by_node[node[i]] = seeds[i];
      HVDB_ASSIGN_OR_RETURN(cut, cache->graph_->Cut(by_node));
      std::vector<uint8_t> sel(pts.size());
      for (size_t i = 0; i < pts.size(); ++i) sel[i] = cut.selected[node[i]];
      cut.selected = std::move(sel);
    } else {
      HVDB_ASSIGN_OR_RETURN(cut, RunGraphCut(pts, seeds, req.params));  // too large to keep
    }
  }
  t0 = Clock::now();
  const uint32_t omask = 1u << req.out_bit;
  std::vector<Key> to_set, to_clear;  // a query's points are distinct: no set needed
  for (size_t i = 0; i < pts.size(); ++i) {
    bool has = pts[i].label & omask;
    if (cut.selected[i] && !has) to_set.push_back({pts[i].frame, pts[i].id});
    if (!cut.selected[i] && has) to_clear.push_back({pts[i].frame, pts[i].id});
    reply.selected += cut.selected[i];
  }
  if (!to_set.empty() || !to_clear.empty()) {
    Transaction t;
    if (!to_clear.empty()) t.SetLabel(Explicit(to_clear), omask, false);
    if (!to_set.empty()) t.SetLabel(Explicit(to_set), omask, true);
    HVDB_ASSIGN_OR_RETURN(CommitInfo info, ds.Commit(t));
    reply.lsn = info.lsn;
  }
  reply.commit_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  cut.selected.clear();
  reply.cut = std::move(cut);
  return reply;
}

// ---- Clipboards ----

namespace {
constexpr char kClipMagic[8] = {'H', 'V', 'D', 'B', 'C', 'L', 'P', '\0'};
constexpr uint32_t kClipVersion = 1;
}  // namespace

Status ClipboardStore::Put(const std::string& name, const std::vector<Point>& points) {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));  // same rules: a safe file name
  HVDB_RETURN_IF_ERROR(env_->CreateDirs(dir_));
  Writer w;
  w.PutBytes(kClipMagic, 8);
  w.Put<uint32_t>(kClipVersion);
  w.Put<uint64_t>(points.size());
  std::string recs(points.size() * kPointRecordSize, '\0');
  EncodePoints(points, reinterpret_cast<uint8_t*>(recs.data()));
  w.PutBytes(recs.data(), recs.size());
  w.Put<uint32_t>(crc32c::Mask(crc32c::Value(w.data().data(), w.data().size())));
  return WriteFileAtomic(env_, dir_ + "/" + name + ".hvc", w.data());
}

Result<std::vector<Point>> ClipboardStore::Get(const std::string& name) const {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));
  const std::string path = dir_ + "/" + name + ".hvc";
  if (!env_->Exists(path)) return Status::NotFound("no clipboard '" + name + "'");
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, path));
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (data.size() < 24 || std::memcmp(p, kClipMagic, 8) != 0 ||
      crc32c::Unmask(DecodeLE<uint32_t>(p + data.size() - 4)) != crc32c::Value(p, data.size() - 4)) {
    return Status::Corruption(path + ": not a clipboard file, or its checksum does not match");
  }
  uint64_t n = DecodeLE<uint64_t>(p + 12);
  if (DecodeLE<uint32_t>(p + 8) != kClipVersion || data.size() != 24 + n * kPointRecordSize) {
    return Status::Corruption(path + ": bad version or size");
  }
  std::vector<Point> pts(n);
  DecodePoints(p + 20, n, pts.data());
  return pts;
}

std::vector<std::string> ClipboardStore::List() const {
  std::vector<std::string> out;
  auto names = env_->ListDir(dir_);
  if (!names.ok()) return out;
  for (const std::string& n : *names) {
    if (n.ends_with(".hvc")) out.push_back(n.substr(0, n.size() - 4));
  }
  std::sort(out.begin(), out.end());
  return out;
}

Result<CopyResult> Copy(Dataset& ds, int bit, const std::optional<Region>& region,
                        ClipboardStore& store, const std::string& clipboard, bool cut) {
  HVDB_RETURN_IF_ERROR(CheckBit(bit, "copy"));
  const uint32_t mask = 1u << bit;
  const Region r = region ? *region : Region(Everything());
  std::vector<Point> pts;
  HVDB_RETURN_IF_ERROR(ForEach(ds, r, mask, [&](const Point& p) { pts.push_back(p); }));
  // A slice returns projected positions; the clipboard keeps points as stored.
  if (std::holds_alternative<Slice>(r)) {
    std::set<Key> keys;
    for (const Point& p : pts) keys.insert({p.frame, p.id});
    pts.clear();
    HVDB_RETURN_IF_ERROR(ForEach(ds, Everything(), mask, [&](const Point& p) {
      if (keys.count({p.frame, p.id})) pts.push_back(p);
    }));
  }
  CopyResult res;
  res.points = pts.size();
  HVDB_RETURN_IF_ERROR(store.Put(clipboard, pts));
  if (cut && !pts.empty()) {
    std::set<Key> keys;
    for (const Point& p : pts) keys.insert({p.frame, p.id});
    Transaction t;
    t.DeleteSelection(Explicit(keys));
    HVDB_ASSIGN_OR_RETURN(CommitInfo info, ds.Commit(t));
    res.lsn = info.lsn;
  }
  return res;
}

Result<CommitInfo> Paste(Dataset& ds, const std::vector<Point>& clip, const Affine4& map) {
  if (clip.empty()) return Status::InvalidArgument("paste: the clipboard is empty");
  HVDB_ASSIGN_OR_RETURN(AffineMap m, AffineMap::Make(map, ds.Info().fps));
  std::vector<Point> pts;
  pts.reserve(clip.size());
  for (const Point& p : clip) {
    HVDB_ASSIGN_OR_RETURN(Point q, m.Apply(p));
    q.id = 0;  // a pasted point is a new point
    pts.push_back(q);
  }
  Transaction t;
  t.Insert(std::move(pts));
  return ds.Commit(t);
}

Result<CommitInfo> Composite(Dataset& ds, const std::vector<Point>& object, uint32_t first,
                             uint32_t count, const std::vector<std::array<double, 3>>& trajectory) {
  if (object.empty()) return Status::InvalidArgument("composite: the object has no points");
  if (count == 0) return Status::InvalidArgument("composite: the frame count must be > 0");
  if (!trajectory.empty() && trajectory.size() != count) {
    return Status::InvalidArgument("composite: the trajectory needs one offset per frame (" +
                                   std::to_string(count) + "), got " +
                                   std::to_string(trajectory.size()));
  }
  std::vector<Point> pts;
  pts.reserve(object.size() * count);
  for (uint32_t i = 0; i < count; ++i) {
    const std::array<double, 3> d = trajectory.empty() ? std::array<double, 3>{} : trajectory[i];
    for (Point p : object) {
      p.id = 0;
      p.frame = first + i;
      p.x = static_cast<float>(p.x + d[0]);
      p.y = static_cast<float>(p.y + d[1]);
      p.z = static_cast<float>(p.z + d[2]);
      pts.push_back(p);
    }
  }
  Transaction t;
  t.Insert(std::move(pts));
  return ds.Commit(t);
}

}  // namespace hvdb::edit
