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

// Every parameter the graph and the cut depend on.
std::array<double, 12> ParamValues(const GraphCutParams& g) {
  return {double(g.k), g.intra_radius, g.inter_radius, g.max_color_diff, g.max_normal_diff,
          double(g.gmm_components), g.beta_c, g.beta_n, g.lambda_d, g.lambda_i, g.lambda_t,
          double(g.use_normals)};
}

bool SameWindow(const Window& a, const Window& b) { return a.lo == b.lo && a.hi == b.hi; }

bool SameRegion(const Region& a, const Region& b) {
  if (a.index() != b.index()) return false;
  if (const auto* w = std::get_if<Window>(&a)) return SameWindow(*w, std::get<Window>(b));
  const Slice &x = std::get<Slice>(a), &y = std::get<Slice>(b);
  return x.normal == y.normal && x.offset == y.offset && x.thickness == y.thickness &&
         x.clip.has_value() == y.clip.has_value() && (!x.clip || SameWindow(*x.clip, *y.clip)) &&
         x.on_too_many_frames == y.on_too_many_frames && x.max_frames == y.max_frames;
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
  for (double v : ParamValues(g)) {
    f[0] = Mix(f[0] ^ Bits(v));
    f[1] = Mix(f[1] + Bits(v));
  }
  return f;
}

}  // namespace

void GraphCutCache::Watch(Dataset& ds) {
  if (watched_ == &ds && watch_ && !watch_->ended()) return;
  watch_.reset();
  watched_ = nullptr;
  {
    // A new subscription (another dataset, or this one dropped and made again at the same
    // address) makes every graph read before it stale.
    std::lock_guard<std::mutex> l(ev_mu_);
    ++seen_.content;
  }
  auto w = ds.Watch(std::nullopt, [this](const ChangeEvent& ev) {
    if (ev.kind == ChangeEvent::Kind::kLive) return;
    std::lock_guard<std::mutex> l(ev_mu_);
    seen_.lsn = std::max(seen_.lsn, ev.lsn);
    if (ev.kind == ChangeEvent::Kind::kDropped || !ev.labels_only) {
      ++seen_.content;
      return;
    }
    for (int b = 0; b < 32; ++b) seen_.bits[b] += (ev.label_bits >> b) & 1;
  });
  if (!w.ok()) return;  // not watched: every cut reads the whole region
  watch_ = std::move(w).value();
  watched_ = &ds;
  // Changes before the subscription are in what a read from now on sees; ones published after
  // it are counted (a change published late counts too, making a graph stale needlessly but
  // never wrongly).
  const uint64_t lsn = ds.Info().last_lsn;
  std::lock_guard<std::mutex> l(ev_mu_);
  seen_.lsn = std::max(seen_.lsn, lsn);
}

uint32_t GraphCutCache::Find(uint64_t id) const {
  if (!dense_.empty()) {
    const uint64_t off = id - dense_base_;
    return id >= dense_base_ && off < dense_.size() ? dense_[off] : UINT32_MAX;
  }
  auto it = std::lower_bound(nodes_.begin(), nodes_.end(), std::make_pair(id, uint32_t{0}));
  return it != nodes_.end() && it->first == id ? it->second : UINT32_MAX;
}

Status GraphCutCache::Prepare(Dataset& ds, const GraphCutRequest& req,
                              const std::vector<Point>& pts, const Seen& seen0) {
  // Node i of the cached graph is the point of id nodes_[..].first; the query's order
  // differs from the last one's (a relabelled point moves within its frame's trees).
  const auto fp = Fingerprint(pts, req.params);
  bool hit = graph_ && fp == fingerprint_ && graph_->size() == pts.size();
  for (size_t i = 0; i < pts.size() && hit; ++i) hit = Find(pts[i].id) != UINT32_MAX;
  if (!hit) {
    graph_.reset();
    nodes_.clear();
    dense_.clear();
    keys_.clear();
    has_out_.clear();
    out_count_ = content_ = kStale;
    if (pts.size() > max_points_) return Status::OK();  // too large to keep: cut without
    HVDB_ASSIGN_OR_RETURN(graph_, GraphCut::Build(pts, req.params));
    fingerprint_ = fp;
    nodes_.reserve(pts.size());
    keys_.resize(pts.size());
    for (size_t i = 0; i < pts.size(); ++i) {
      nodes_.emplace_back(pts[i].id, static_cast<uint32_t>(i));
      keys_[i] = {pts[i].frame, pts[i].id};
    }
    std::sort(nodes_.begin(), nodes_.end());
    if (!pts.empty()) {
      const uint64_t lo = nodes_.front().first, hi = nodes_.back().first;
      if (hi - lo < 4 * uint64_t{pts.size()}) {
        dense_base_ = lo;
        dense_.assign(hi - lo + 1, UINT32_MAX);
        for (const auto& [id, v] : nodes_) dense_[id - lo] = v;
      }
    }
  }
  ds_ = &ds;
  roi_ = req.roi;
  params_ = req.params;
  // The output bit is known again only once this cut commits (a cut that fails leaves it
  // unknown: other changes may have flipped it since the last successful one).
  out_count_ = kStale;
  // Valid for label-only re-cuts only if nothing but labels changed while the points were read.
  content_ = seen().content == seen0.content ? seen0.content : kStale;
  return Status::OK();
}

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
  const uint32_t fmask = 1u << req.foreground_bit, bmask = 1u << req.background_bit;
  const uint32_t omask = 1u << req.out_bit;
  auto seed_of = [&](uint32_t label) {
    return (label & fmask) ? Seed::kForeground : (label & bmask) ? Seed::kBackground : Seed::kUnknown;
  };
  // What the cut runs on, indexed alike (by node of the cached graph, or in the query's order):
  // each point's seed, whether it carries the output bit now, and (without a cached graph,
  // whose keys_ say it by node) its key.
  std::vector<Seed> seeds;
  std::vector<uint8_t> had_out;
  std::vector<Key> keys;
  GraphCutResult cut;
  std::unique_lock<std::mutex> lock;
  GraphCutCache::Seen seen0;
  bool quick = false;  // a re-cut that read labels only
  if (cache != nullptr) {
    lock = std::unique_lock<std::mutex>(cache->mu_);
    cache->Watch(ds);
    seen0 = cache->seen();
    quick = cache->graph_ && cache->ds_ == &ds && cache->content_ != GraphCutCache::kStale &&
            seen0.content == cache->content_ && SameRegion(cache->roi_, req.roi) &&
            ParamValues(cache->params_) == ParamValues(req.params) &&
            ds.Info().last_lsn == seen0.lsn;
  }
  if (quick) {
    // Only labels changed since the graph was read: the seeds come from the points carrying a
    // stroke bit, the output bit from the last cut's commit (or the points carrying it).
    const size_t n = cache->graph_->size();
    auto node_of = [&](const Point& p, uint32_t* node) {
      *node = cache->Find(p.id);
      return *node < n && cache->keys_[*node] == Key{p.frame, p.id};
    };
    seeds.assign(n, Seed::kUnknown);
    bool known = true;  // every point read is a node (else: read the region after all)
    HVDB_RETURN_IF_ERROR(ForEach(ds, req.roi, fmask | bmask, [&](const Point& p) {
      uint32_t v;
      if (!node_of(p, &v)) known = false; else seeds[v] = seed_of(p.label);
    }));
    if (req.out_bit == cache->out_bit_ && seen0.bits[req.out_bit] == cache->out_count_) {
      had_out = cache->has_out_;
    } else if (known) {
      had_out.assign(n, 0);
      HVDB_RETURN_IF_ERROR(ForEach(ds, req.roi, omask, [&](const Point& p) {
        uint32_t v;
        if (!node_of(p, &v)) known = false; else had_out[v] = 1;
      }));
    }
    if (known) {
      reply.roi_points = n;
      reply.labels_only = true;
      reply.load_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
      HVDB_ASSIGN_OR_RETURN(cut, cache->graph_->Cut(seeds));
    } else {
      quick = false;
      seeds.clear();
      had_out.clear();
      t0 = Clock::now();
    }
  }
  if (!quick) {
    std::vector<Point> pts;
    // Reserved for all the frames' points at once (up to 4 Mi points: the bound counts whole
    // frames, however small the region): growing a million-point vector by doubling copied and
    // first-touched twice its size.
    HVDB_RETURN_IF_ERROR(ForEach(ds, req.roi, 0, [&](const Point& p) {
      pts.push_back(p);
      seeds.push_back(seed_of(p.label));
    }, nullptr, [&](uint64_t bound) {
      const auto n = static_cast<size_t>(std::min<uint64_t>(bound, uint64_t{4} << 20));
      pts.reserve(n);
      seeds.reserve(n);
    }));
    reply.roi_points = pts.size();
    reply.load_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    if (cache != nullptr) HVDB_RETURN_IF_ERROR(cache->Prepare(ds, req, pts, seen0));
    const bool by_node = cache != nullptr && cache->graph_;
    const size_t n = pts.size();
    had_out.assign(n, 0);
    keys.resize(by_node ? 0 : n);
    std::vector<Seed> node_seeds(by_node ? n : 0);
    for (size_t i = 0; i < n; ++i) {
      const size_t v = by_node ? cache->Find(pts[i].id) : i;
      had_out[v] = (pts[i].label & omask) != 0;
      if (by_node) {
        node_seeds[v] = seeds[i];
      } else {
        keys[v] = {pts[i].frame, pts[i].id};
      }
    }
    if (by_node) {
      HVDB_ASSIGN_OR_RETURN(cut, cache->graph_->Cut(node_seeds));
    } else {
      HVDB_ASSIGN_OR_RETURN(cut, RunGraphCut(pts, seeds, req.params));  // no cache, or too large
    }
  }
  const std::vector<Key>& key_of = cache != nullptr && cache->graph_ ? cache->keys_ : keys;
  t0 = Clock::now();
  std::vector<Key> to_set, to_clear;  // a query's points are distinct: no set needed
  for (size_t i = 0; i < cut.selected.size(); ++i) {
    if (cut.selected[i] && !had_out[i]) to_set.push_back(key_of[i]);
    if (!cut.selected[i] && had_out[i]) to_clear.push_back(key_of[i]);
    reply.selected += cut.selected[i];
  }
  bool committed = false;
  if (!to_set.empty() || !to_clear.empty()) {
    Transaction t;
    if (!to_clear.empty()) t.SetLabel(Explicit(to_clear), omask, false);
    if (!to_set.empty()) t.SetLabel(Explicit(to_set), omask, true);
    HVDB_ASSIGN_OR_RETURN(CommitInfo info, ds.Commit(t));
    reply.lsn = info.lsn;
    committed = true;
  }
  reply.commit_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  if (cache != nullptr && cache->graph_) {
    // The output bit as this commit left it, unless some other change flipped that bit since
    // the labels were read (the commit's own event is published before Commit returns).
    cache->out_bit_ = req.out_bit;
    cache->out_count_ = cache->seen().bits[req.out_bit] == seen0.bits[req.out_bit] + committed
                            ? seen0.bits[req.out_bit] + committed
                            : GraphCutCache::kStale;
    cache->has_out_ = cut.selected;
  }
  cut.selected.clear();
  reply.cut = std::move(cut);
  return reply;
}

// ---- Clipboards ----

namespace {
constexpr char kClipMagic[8] = {'H', 'V', 'D', 'B', 'C', 'L', 'P', '\0'};
constexpr uint32_t kClipVersion = 2;  // 1 (points only) is read too
}  // namespace

Status ClipboardStore::Put(const std::string& name, const std::vector<Point>& points,
                           const GaussianColumns* gaussians) {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));  // same rules: a safe file name
  if (gaussians && gaussians->values.size() != points.size() * gaussians->stride()) {
    return Status::InvalidArgument("clipboard: " + std::to_string(points.size()) +
                                   " points but " + std::to_string(gaussians->size()) +
                                   " Gaussian records");
  }
  HVDB_RETURN_IF_ERROR(env_->CreateDirs(dir_));
  Writer w;
  w.PutBytes(kClipMagic, 8);
  w.Put<uint32_t>(kClipVersion);
  w.Put<uint64_t>(points.size());
  std::string recs(points.size() * kPointRecordSize, '\0');
  EncodePoints(points, reinterpret_cast<uint8_t*>(recs.data()));
  w.PutBytes(recs.data(), recs.size());
  w.Put<uint32_t>(gaussians ? static_cast<uint32_t>(gaussians->sh_degree) + 1 : 0);
  w.Put<uint32_t>(gaussians && gaussians->antialiased ? 1 : 0);
  // f32 little-endian, as the point records (this host's order: hvdb builds for little-endian).
  if (gaussians) w.PutBytes(gaussians->values.data(), 4 * gaussians->values.size());
  w.Put<uint32_t>(crc32c::Mask(crc32c::Value(w.data().data(), w.data().size())));
  return WriteFileAtomic(env_, dir_ + "/" + name + ".hvc", w.data());
}

Result<Clip> ClipboardStore::Get(const std::string& name) const {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));
  const std::string path = dir_ + "/" + name + ".hvc";
  if (!env_->Exists(path)) return Status::NotFound("no clipboard '" + name + "'");
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, path));
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (data.size() < 24 || std::memcmp(p, kClipMagic, 8) != 0 ||
      crc32c::Unmask(DecodeLE<uint32_t>(p + data.size() - 4)) != crc32c::Value(p, data.size() - 4)) {
    return Status::Corruption(path + ": not a clipboard file, or its checksum does not match");
  }
  const uint32_t version = DecodeLE<uint32_t>(p + 8);
  const uint64_t n = DecodeLE<uint64_t>(p + 12);
  const uint64_t points_end = 20 + n * kPointRecordSize;  // n is bounded by the size below
  bool sized = n <= data.size() / kPointRecordSize;
  Clip clip;
  if (version == 1) {
    sized = sized && data.size() == points_end + 4;
  } else if (version == 2) {
    sized = sized && data.size() >= points_end + 12;
    if (sized) {
      const uint32_t degree_plus_one = DecodeLE<uint32_t>(p + points_end);
      const uint32_t flags = DecodeLE<uint32_t>(p + points_end + 4);
      if (degree_plus_one > kMaxGaussianShDegree + 1 || flags > 1) {
        return Status::Corruption(path + ": bad Gaussian record header");
      }
      if (degree_plus_one > 0) {
        auto g = std::make_shared<GaussianColumns>();
        g->sh_degree = static_cast<int>(degree_plus_one) - 1;
        g->antialiased = flags & 1;
        const uint64_t floats = n * g->stride();
        sized = data.size() == points_end + 12 + 4 * floats;
        if (sized) {
          g->values.resize(floats);
          std::memcpy(g->values.data(), p + points_end + 8, 4 * floats);  // little-endian host
          HVDB_RETURN_IF_ERROR(ValidateGaussianColumns(*g));
          clip.gaussians = std::move(g);
        }
      } else {
        sized = data.size() == points_end + 12;
      }
    }
  } else {
    return Status::Corruption(path + ": clipboard version " + std::to_string(version) +
                              " (this build reads 1 and 2)");
  }
  if (!sized) return Status::Corruption(path + ": bad size for " + std::to_string(n) + " points");
  clip.points.resize(n);
  DecodePoints(p + 20, n, clip.points.data());
  return clip;
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
  if (ds.Info().gaussians) {
    // Splats keep their records on the clipboard (those without one get the derived Gaussian).
    HVDB_ASSIGN_OR_RETURN(GaussianColumns records, ds.ReadGaussians(pts));
    HVDB_RETURN_IF_ERROR(store.Put(clipboard, pts, &records));
  } else {
    HVDB_RETURN_IF_ERROR(store.Put(clipboard, pts));
  }
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

Result<CommitInfo> Paste(Dataset& ds, const Clip& clip, const Affine4& map) {
  if (clip.points.empty()) return Status::InvalidArgument("paste: the clipboard is empty");
  HVDB_ASSIGN_OR_RETURN(AffineMap m, AffineMap::Make(map, ds.Info().fps));
  std::vector<Point> pts;
  pts.reserve(clip.points.size());
  for (const Point& p : clip.points) {
    HVDB_ASSIGN_OR_RETURN(Point q, m.Apply(p));
    q.id = 0;  // a pasted point is a new point
    pts.push_back(q);
  }
  Transaction t;
  if (clip.gaussians && ds.Info().gaussians) {
    auto turned = std::make_shared<GaussianColumns>(*clip.gaussians);
    const GaussianRecordMap g({map.a[0], map.a[1], map.a[2], map.a[4], map.a[5], map.a[6],
                               map.a[8], map.a[9], map.a[10]});
    for (size_t i = 0; i < turned->size(); ++i) {
      if (!g.Apply(turned->sh_degree, turned->record(i))) {
        return Status::InvalidArgument("paste: the map takes splat " +
                                       std::to_string(clip.points[i].id) +
                                       "'s scale or colour beyond float");
      }
    }
    t.Insert(std::move(pts), std::move(turned));
  } else {
    t.Insert(std::move(pts));
  }
  return ds.Commit(t);
}

Result<CommitInfo> Composite(Dataset& ds, const std::vector<Point>& object, uint32_t first,
                             uint32_t count, const std::vector<std::array<double, 3>>& trajectory,
                             const GaussianColumns* gaussians) {
  if (object.empty()) return Status::InvalidArgument("composite: the object has no points");
  if (count == 0) return Status::InvalidArgument("composite: the frame count must be > 0");
  if (!trajectory.empty() && trajectory.size() != count) {
    return Status::InvalidArgument("composite: the trajectory needs one offset per frame (" +
                                   std::to_string(count) + "), got " +
                                   std::to_string(trajectory.size()));
  }
  if (gaussians && gaussians->values.size() != object.size() * gaussians->stride()) {
    return Status::InvalidArgument("composite: " + std::to_string(object.size()) +
                                   " points but " + std::to_string(gaussians->size()) +
                                   " Gaussian records");
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
  if (gaussians && ds.Info().gaussians) {
    // The object's records once per frame, in the points' order (a static splat in every frame).
    auto records = std::make_shared<GaussianColumns>();
    records->sh_degree = gaussians->sh_degree;
    records->antialiased = gaussians->antialiased;
    records->values.reserve(gaussians->values.size() * count);
    for (uint32_t i = 0; i < count; ++i) {
      records->values.insert(records->values.end(), gaussians->values.begin(),
                             gaussians->values.end());
    }
    t.Insert(std::move(pts), std::move(records));
  } else {
    t.Insert(std::move(pts));
  }
  return ds.Commit(t);
}

}  // namespace hvdb::edit
