#include "ingest/photo_consistency.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>

#include "render/renderer.h"
// simd.h's helpers pass 32-byte vectors by value; they are always inlined, so the ABI note
// GCC gives for them in the non-AVX clone does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"
#include "render/simd.h"
#include "render/splat.h"

namespace hvdb::ingest {

namespace {

using render::internal::F8;
using render::internal::I8;
using render::internal::ParallelFor;

// Eight pixels at a time along a row (render/simd.h): image planes and the z-buffer have rows
// padded by this many floats, so a vector that starts at a row's last pixel stays inside.
constexpr uint32_t kLanes = 8;
// Splats are kept in the points' order. Points made from depth maps come row by row of their
// camera, so the splats tested one after another touch the same few rows of the image and
// z-buffer in any view, which stay in the cache (in depth order, as fig. 5.4 walks them, they
// jumped across the whole image: that cost 4x). Other orders give the same result, slower.
// Later rounds redo the z-buffer and the tests only where a removal changed something, in
// blocks of 8x8 pixels.
constexpr int kBlock = 8;

// BT.601 on sRGB-encoded values in [0, 1], U and V scaled to [-0.5, 0.5] (see the header).
struct Yuv {
  float y, u, v;
};
inline Yuv ToYuv(uint8_t r8, uint8_t g8, uint8_t b8) {
  const float r = r8 * (1.0f / 255), g = g8 * (1.0f / 255), b = b8 * (1.0f / 255);
  const float y = 0.299f * r + 0.587f * g + 0.114f * b;
  return {y, (b - y) * (1.0f / 1.772f), (r - y) * (1.0f / 1.402f)};
}

// What the test needs of a projected splat (render::internal::Splat without the renderer's
// colour and weight), with its point's index and sRGB colour.
struct TestSplat {
  float u, v, ca, cb, cc, z, dzdx, dzdy;
  int16_t x0, x1, y0, y1;
  uint32_t point;
  uint8_t r, g, b;
  bool on_image;  // centred on the image: tested (else it only occludes)
};

// A splat's state in its view.
enum : uint8_t { kUntested = 0, kSeen = 1, kOccluded = 2, kRemoved = 3 };

// One view: its splats, the image in YUV (one plane per component), and per run of splats
// (those of a chunk of points) the blocks they reach.
struct PreparedView {
  bool ok = false;
  render::internal::View view;
  std::vector<TestSplat> splats;
  uint32_t stride = 0;         // floats per row: view.width + kLanes
  std::vector<float> y, u, v;  // row-major planes, stride * view.height
  int blocks_x = 0, blocks_y = 0;
  struct Run {
    uint32_t begin, end;         // splats[begin, end)
    int16_t bx0, bx1, by0, by1;  // blocks touched by them
  };
  std::vector<Run> runs;
  size_t testable = 0;  // splats with on_image set
};

// The cross-section of the point's Gaussian through its centre along the ray from `source`
// (the camera that made it): its covariance conditioned on the position along the ray.
std::array<float, 6> SurfaceFootprint(const Point& p, const cv::Vec3d& source) {
  const double d[3] = {p.x - source[0], p.y - source[1], p.z - source[2]};
  const auto& c = p.cov;  // xx xy xz yy yz zz
  const double vd[3] = {c[0] * d[0] + c[1] * d[1] + c[2] * d[2], c[1] * d[0] + c[3] * d[1] + c[4] * d[2],
                        c[2] * d[0] + c[4] * d[1] + c[5] * d[2]};
  const double s = d[0] * vd[0] + d[1] * vd[1] + d[2] * vd[2];
  if (!(s > 0)) return c;
  const int ij[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
  std::array<float, 6> out;
  for (int k = 0; k < 6; ++k)
    out[static_cast<size_t>(k)] = static_cast<float>(c[static_cast<size_t>(k)] - vd[ij[k][0]] * vd[ij[k][1]] / s);
  return out;
}

// Prepares view v into *out, reusing its buffers (a thread tests view after view: fresh
// buffers per view cost as much in page faults as the projection). `covs`: the covariance
// each point is splatted with (its surface footprint), or empty for the points' own.
void Prepare(std::span<const Point> points, std::span<const std::array<float, 6>> covs,
             const ColourView& cv, size_t v, const PhotoConsistencyOptions& o, unsigned threads,
             PreparedView* out) {
  PreparedView& pv = *out;
  pv.ok = false;
  pv.runs.clear();
  pv.testable = 0;
  const std::string where = "photo-consistency: view " + std::to_string(v);
  if (cv.camera == nullptr || cv.image.empty() || cv.image.type() != CV_8UC3) {
    render::internal::LogWarning(where + " skipped: it needs a camera and a CV_8UC3 image");
    return;
  }
  render::Camera cam = cv.camera->ToRenderCamera();
  render::RenderOptions ro;
  ro.cutoff_radius = static_cast<float>(o.cutoff_radius);
  ro.depth_threshold = static_cast<float>(o.depth_threshold);
  const auto iw = static_cast<uint32_t>(cv.image.cols), ih = static_cast<uint32_t>(cv.image.rows);
  if (cam.width == 0 || cam.height == 0) {
    cam.width = iw;  // no size in the calibration: the image's
    cam.height = ih;
  } else if (cam.width != iw || cam.height != ih) {
    ro.width = iw;  // PrepareView scales the intrinsics to the image
    ro.height = ih;
  }
  auto view = render::internal::PrepareView(cam, ro);
  if (!view.ok()) {
    render::internal::LogWarning(where + " (camera '" + cv.camera->name +
                                 "') skipped: " + view.status().ToString());
    return;
  }
  pv.view = view.value();
  const unsigned w = pv.view.width, h = pv.view.height;
  pv.blocks_x = static_cast<int>((w + kBlock - 1) / kBlock);
  pv.blocks_y = static_cast<int>((h + kBlock - 1) / kBlock);
  const float umax = static_cast<float>(w) - 0.5f, vmax = static_cast<float>(h) - 0.5f;

  // Projection (the renderer's EWA set-up), chunked over threads, in the points' order. Each
  // chunk of points writes its splats from its own start on: the runs skip the gaps.
  const size_t chunk = 16384;
  const size_t chunks = (points.size() + chunk - 1) / chunk;
  if (pv.splats.size() < points.size()) pv.splats.resize(points.size());
  std::vector<uint32_t> made(chunks, 0);
  ParallelFor(chunks, threads, [&](size_t c) {
    const size_t lo = c * chunk, hi = std::min(points.size(), lo + chunk);
    render::internal::Splat s;
    TestSplat* at = pv.splats.data() + lo;
    for (size_t i = lo; i < hi; ++i) {
      Point p = points[i];
      if (!covs.empty()) p.cov = covs[i];
      if (!render::internal::ProjectSplat(p, pv.view, {}, &s)) continue;
      // Only splats centred on the image are tested: one centred outside shows just its tail,
      // whose colour says little about the point; nor a point in its own camera's view (see
      // the header). Such splats still occlude.
      const bool on = s.u >= -0.5f && s.u <= umax && s.v >= -0.5f && s.v <= vmax &&
                      !(cv.camera_id >= 0 && p.camera == cv.camera_id);
      *at++ = {s.u, s.v, s.ca, s.cb, s.cc, s.z, s.dzdx, s.dzdy, s.x0, s.x1, s.y0, s.y1,
               static_cast<uint32_t>(i), p.r, p.g, p.b, on};
    }
    made[c] = static_cast<uint32_t>(at - (pv.splats.data() + lo));
  });
  // Runs of at most 256 splats: small enough that a later round passes over most of them
  // by their box alone (SplatsReaching).
  constexpr uint32_t kRun = 256;
  for (size_t c = 0; c < chunks; ++c) {
    const auto lo = static_cast<uint32_t>(c * chunk);
    for (uint32_t b = lo; b < lo + made[c]; b += kRun) {
      PreparedView::Run run{b, std::min(lo + made[c], b + kRun), INT16_MAX, INT16_MIN, INT16_MAX, INT16_MIN};
      for (uint32_t j = run.begin; j < run.end; ++j) {
        const TestSplat& s = pv.splats[j];
        pv.testable += s.on_image;
        run.bx0 = std::min<int16_t>(run.bx0, static_cast<int16_t>(s.x0 / kBlock));
        run.bx1 = std::max<int16_t>(run.bx1, static_cast<int16_t>(s.x1 / kBlock));
        run.by0 = std::min<int16_t>(run.by0, static_cast<int16_t>(s.y0 / kBlock));
        run.by1 = std::max<int16_t>(run.by1, static_cast<int16_t>(s.y1 / kBlock));
      }
      pv.runs.push_back(run);
    }
  }

  pv.stride = w + kLanes;
  pv.y.assign(size_t{pv.stride} * h, 0.f);
  pv.u.assign(size_t{pv.stride} * h, 0.f);
  pv.v.assign(size_t{pv.stride} * h, 0.f);
  ParallelFor(h, threads, [&](size_t y) {
    const cv::Vec3b* row = cv.image.ptr<cv::Vec3b>(static_cast<int>(y));
    const size_t base = y * pv.stride;
    for (unsigned x = 0; x < w; ++x) {
      const Yuv c = ToYuv(row[x][2], row[x][1], row[x][0]);
      pv.y[base + x] = c.y, pv.u[base + x] = c.u, pv.v[base + x] = c.v;
    }
  });
  pv.ok = true;
}

// The columns of row y (dy = y - v) that can be inside the splat's cutoff ellipse, widened by
// a pixel against rounding (the per-pixel test decides). False: the row misses it. A splat at
// most two vectors wide takes its whole box: the square root and divisions cost more than the
// vector they might save.
HVDB_SIMD_INLINE bool RowSpan(const TestSplat& s, float dy, float cutoff2, int* xa, int* xb) {
  if (s.x1 - s.x0 < static_cast<int>(2 * kLanes)) {
    *xa = s.x0, *xb = s.x1;
    return true;
  }
  const float b = s.cb * dy, cq = s.cc * dy * dy - cutoff2;
  const float disc = b * b - s.ca * cq;
  if (!(disc >= 0)) return false;
  const float root = std::sqrt(disc);
  *xa = std::max<int>(s.x0, static_cast<int>(std::floor(s.u + (-b - root) / s.ca)) - 1);
  *xb = std::min<int>(s.x1, static_cast<int>(std::ceil(s.u + (-b + root) / s.ca)) + 1);
  return true;
}

// The fragments of splat s at columns x .. x + 7 of row y (dy = y - v; the row's span ends at
// xb): q = ca dx^2 + 2 cb dx dy + cc dy^2, which lanes are inside the cutoff, and their depths
// z + dzdx dx + dzdy dy clamped at the camera plane (the dy terms once per row, in `row`).
struct FragmentRow {
  float qb, qc, zr;
  int xb;
};
HVDB_SIMD_INLINE FragmentRow RowTerms(const TestSplat& s, float dy, int xb) {
  return {2.0f * s.cb * dy, s.cc * dy * dy, s.z + s.dzdy * dy, xb};
}
HVDB_SIMD_INLINE void Fragments(const TestSplat& s, const FragmentRow& row, int x, float cutoff2,
                                F8* q, I8* inside, F8* z) {
  using render::internal::Broadcast;
  const F8 fx = Broadcast<F8>(static_cast<float>(x)) + render::internal::VecTraits<F8>::kIota;
  const F8 dx = fx - s.u;
  *q = dx * (s.ca * dx + row.qb) + row.qc;
  *inside = (*q <= cutoff2) & (fx <= static_cast<float>(row.xb));
  *z = render::internal::Max(row.zr + s.dzdx * dx, Broadcast<F8>(0.f));
}

// The fuzzy z-buffer: the nearest fragment depth of the listed splats (splats [first,
// first + n) when `list` is null) that are not removed, min-ed into zbuf. Order does not matter (a min).
HVDB_RENDER_CLONES
void RasterDepth(const PreparedView& pv, const uint32_t* list, size_t n, uint32_t first,
                 const uint8_t* state, float* zbuf) {
  using F = F8;
  using render::internal::Broadcast;
  const auto& view = pv.view;
  const uint32_t S = pv.stride;
  const F inf = Broadcast<F>(std::numeric_limits<float>::infinity());
  for (size_t k = 0; k < n; ++k) {
    const uint32_t j = list ? list[k] : first + static_cast<uint32_t>(k);
    if (state[j] == kRemoved) continue;
    const TestSplat& s = pv.splats[j];
    for (int y = s.y0; y <= s.y1; ++y) {
      const float dy = static_cast<float>(y) - s.v;
      int xa, xb;
      if (!RowSpan(s, dy, view.cutoff2, &xa, &xb)) continue;
      const FragmentRow terms = RowTerms(s, dy, xb);
      float* row = zbuf + static_cast<size_t>(y) * S;
      for (int x = xa; x <= xb; x += static_cast<int>(kLanes)) {
        F q, z;
        I8 inside;
        Fragments(s, terms, x, view.cutoff2, &q, &inside, &z);
        const F old = render::internal::Load<F>(row + x);
        render::internal::Store(row + x, render::internal::Min(old, render::internal::Select(inside, z, inf)));
      }
    }
  }
}

// Eq. 5.13 for the listed splats that are centred on the image and not removed, against the
// z-buffer: sets their state (seen and kept, fully occluded, or removed) and appends the
// removed ones to `removed`. Each row of a splat is evaluated eight pixels at a time (the CPU
// renderer's kernel arithmetic: render/simd.h; built for AVX-512, AVX2 and the baseline,
// picked at load time), the same operations per pixel as the scalar renderer's, e^x to within
// a unit or two of the last place, the sums in float lanes.
HVDB_RENDER_CLONES
void TestSplats(const PreparedView& pv, const uint32_t* list, size_t n, uint32_t first,
                const float* zbuf, const PhotoConsistencyOptions& o, uint8_t* state,
                std::vector<uint32_t>* removed) {
  using F = F8;
  using render::internal::Broadcast;
  using render::internal::Load;
  using render::internal::Select;
  const auto& view = pv.view;
  const uint32_t S = pv.stride;
  const float dz = view.depth_threshold;
  for (size_t k = 0; k < n; ++k) {
    const uint32_t j = list ? list[k] : first + static_cast<uint32_t>(k);
    const TestSplat& s = pv.splats[j];
    if (!s.on_image || state[j] == kRemoved) continue;
    const Yuv c = ToYuv(s.r, s.g, s.b);
    // Eq. 5.13 over the unoccluded fragments (xi = 1: within dz of the fuzzy z-buffer), and the
    // alpha they carry for the normalisation. Summed in eight float lanes, added up in double
    // per splat: a splat of a few hundred pixels keeps its sums to ~1e-6 relative, far below
    // what the thresholds can tell apart.
    F sa{}, sy{}, su{}, sv{};
    for (int y = s.y0; y <= s.y1; ++y) {
      const float dy = static_cast<float>(y) - s.v;
      int xa, xb;
      if (!RowSpan(s, dy, view.cutoff2, &xa, &xb)) continue;
      const size_t rowbase = static_cast<size_t>(y) * S;
      const FragmentRow terms = RowTerms(s, dy, xb);
      for (int x = xa; x <= xb; x += static_cast<int>(kLanes)) {
        F q, z;
        I8 inside;
        Fragments(s, terms, x, view.cutoff2, &q, &inside, &z);
        const size_t at = rowbase + static_cast<size_t>(x);
        const I8 seen = inside & ~(z > Load<F>(&zbuf[at]) + dz);  // not occluded (xi = 1)
        if (!render::internal::Any(seen)) continue;
        const F a = Select(seen, render::internal::Exp(q * -0.5f), Broadcast<F>(0.f));
        sa += a;
        sy += a * (Load<F>(&pv.y[at]) - c.y);
        su += a * (Load<F>(&pv.u[at]) - c.u);
        sv += a * (Load<F>(&pv.v[at]) - c.v);
      }
    }
    double sum_a = 0, sum_y = 0, sum_u = 0, sum_v = 0;
    for (uint32_t l = 0; l < kLanes; ++l) sum_a += sa[l], sum_y += sy[l], sum_u += su[l], sum_v += sv[l];
    if (!(sum_a > 0)) {
      state[j] = kOccluded;  // fully occluded: not tested
    } else if (std::abs(sum_y / sum_a) > o.max_dy || std::abs(sum_u / sum_a) > o.max_du ||
               std::abs(sum_v / sum_a) > o.max_dv) {
      state[j] = kRemoved;
      removed->push_back(j);
    } else {
      state[j] = kSeen;
    }
  }
}

// Which of a grid's cells are flagged, with a summed-area table for "any flagged in this
// rectangle" in O(1).
class BlockSet {
 public:
  BlockSet(int w, int h) : w_(w), h_(h), flag_(static_cast<size_t>(w) * h, 0) {}
  void Mark(int x0, int x1, int y0, int y1) {
    for (int y = std::max(0, y0); y <= std::min(h_ - 1, y1); ++y)
      for (int x = std::max(0, x0); x <= std::min(w_ - 1, x1); ++x) flag_[Index(x, y)] = 1;
  }
  bool At(int x, int y) const { return flag_[Index(x, y)] != 0; }
  void Clear(int x, int y) { flag_[Index(x, y)] = 0; }
  void Finish() {
    sat_.assign(static_cast<size_t>(w_ + 1) * (h_ + 1), 0);
    for (int y = 0; y < h_; ++y)
      for (int x = 0; x < w_; ++x)
        sat_[Sat(x + 1, y + 1)] = flag_[Index(x, y)] + sat_[Sat(x, y + 1)] + sat_[Sat(x + 1, y)] - sat_[Sat(x, y)];
  }
  bool Any(int x0, int x1, int y0, int y1) const {
    x0 = std::max(0, x0), y0 = std::max(0, y0), x1 = std::min(w_ - 1, x1), y1 = std::min(h_ - 1, y1);
    if (x0 > x1 || y0 > y1) return false;
    return sat_[Sat(x1 + 1, y1 + 1)] - sat_[Sat(x0, y1 + 1)] - sat_[Sat(x1 + 1, y0)] + sat_[Sat(x0, y0)] > 0;
  }
  int width() const { return w_; }
  int height() const { return h_; }

 private:
  size_t Index(int x, int y) const { return static_cast<size_t>(y) * w_ + x; }
  size_t Sat(int x, int y) const { return static_cast<size_t>(y) * (w_ + 1) + x; }
  int w_, h_;
  std::vector<uint8_t> flag_;
  std::vector<int32_t> sat_;
};

// The splats that are not removed and reach a flagged block (flags finished).
std::vector<uint32_t> SplatsReaching(const PreparedView& pv, const BlockSet& blocks,
                                     const std::vector<uint8_t>& state) {
  std::vector<uint32_t> out;
  for (const PreparedView::Run& r : pv.runs) {
    if (!blocks.Any(r.bx0, r.bx1, r.by0, r.by1)) continue;
    for (uint32_t j = r.begin; j < r.end; ++j) {
      const TestSplat& s = pv.splats[j];
      if (state[j] != kRemoved &&
          blocks.Any(s.x0 / kBlock, s.x1 / kBlock, s.y0 / kBlock, s.y1 / kBlock))
        out.push_back(j);
    }
  }
  return out;
}

struct ViewResult {
  std::vector<uint32_t> removed_points;  // ascending
  size_t tested = 0, occluded = 0;
  int rounds = 0;
};

// Fig. 5.4 in one view, to a fixed point: the z-buffer of the splats not removed, every splat
// centred on the image tested against it, and again where removals uncovered something, until
// a round removes nothing (at most kMaxRounds).
ViewResult RunView(const PreparedView& pv, const PhotoConsistencyOptions& o) {
  ViewResult res;
  const size_t n = pv.splats.size();
  const uint32_t S = pv.stride, w = pv.view.width, h = pv.view.height;
  if (pv.testable == 0) return res;  // nothing to test here (e.g. one camera's own points)
  std::vector<uint8_t> state(n, kUntested);
  std::vector<float> zbuf(size_t{S} * h, std::numeric_limits<float>::infinity());
  for (const PreparedView::Run& r : pv.runs) RasterDepth(pv, nullptr, r.end - r.begin, r.begin, state.data(), zbuf.data());
  std::vector<uint32_t> removed;
  for (const PreparedView::Run& r : pv.runs)
    TestSplats(pv, nullptr, r.end - r.begin, r.begin, zbuf.data(), o, state.data(), &removed);
  std::vector<uint32_t> all_removed = removed;
  res.rounds = 1;
  std::vector<float> old;
  while (!removed.empty() && res.rounds < PhotoConsistencyOptions::kMaxRounds) {
    // The blocks the removed splats covered: their depths are redone from the splats left.
    BlockSet dirty(pv.blocks_x, pv.blocks_y);
    for (uint32_t j : removed) {
      const TestSplat& s = pv.splats[j];
      dirty.Mark(s.x0 / kBlock, s.x1 / kBlock, s.y0 / kBlock, s.y1 / kBlock);
    }
    dirty.Finish();
    old = zbuf;
    for (int by = 0; by < dirty.height(); ++by)
      for (int bx = 0; bx < dirty.width(); ++bx) {
        if (!dirty.At(bx, by)) continue;
        for (uint32_t y = by * kBlock; y < std::min<uint32_t>(h, (by + 1) * kBlock); ++y)
          std::fill_n(&zbuf[y * S + bx * kBlock], std::min<uint32_t>(kBlock, w - bx * kBlock),
                      std::numeric_limits<float>::infinity());
      }
    // (A splat's depth written outside the dirty blocks is no news there: min is idempotent.)
    std::vector<uint32_t> list = SplatsReaching(pv, dirty, state);
    RasterDepth(pv, list.data(), list.size(), 0, state.data(), zbuf.data());
    // Where the nearest depth changed, the splats there see something new: test them again.
    BlockSet changed(pv.blocks_x, pv.blocks_y);
    bool any = false;
    for (int by = 0; by < dirty.height(); ++by)
      for (int bx = 0; bx < dirty.width(); ++bx) {
        if (!dirty.At(bx, by)) continue;
        bool diff = false;
        for (uint32_t y = by * kBlock; y < std::min<uint32_t>(h, (by + 1) * kBlock) && !diff; ++y)
          for (uint32_t x = bx * kBlock; x < std::min<uint32_t>(w, (bx + 1) * kBlock); ++x)
            if (zbuf[y * S + x] != old[y * S + x]) diff = true;
        if (diff) changed.Mark(bx, bx, by, by), any = true;
      }
    ++res.rounds;
    removed.clear();
    if (!any) break;
    changed.Finish();
    list = SplatsReaching(pv, changed, state);
    TestSplats(pv, list.data(), list.size(), 0, zbuf.data(), o, state.data(), &removed);
    all_removed.insert(all_removed.end(), removed.begin(), removed.end());
  }
  for (const PreparedView::Run& r : pv.runs) {
    for (uint32_t j = r.begin; j < r.end; ++j) {
      res.tested += state[j] == kSeen || state[j] == kRemoved;
      res.occluded += state[j] == kOccluded;
    }
  }
  for (uint32_t j : all_removed) res.removed_points.push_back(pv.splats[j].point);
  std::sort(res.removed_points.begin(), res.removed_points.end());
  return res;
}

}  // namespace

std::vector<uint8_t> PhotoConsistencyMask(std::span<const Point> points,
                                          std::span<const ColourView> views,
                                          const PhotoConsistencyOptions& options,
                                          PhotoConsistencyStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  PhotoConsistencyStats st;
  st.removed_per_view.assign(views.size(), 0);
  std::vector<uint8_t> keep(points.size(), 1);
  const unsigned threads =
      options.threads > 0 ? static_cast<unsigned>(options.threads)
                          : std::max(1u, std::thread::hardware_concurrency());
  const bool too_many = points.size() > std::numeric_limits<uint32_t>::max();  // splat indices
  if (too_many) {
    render::internal::LogWarning("photo-consistency: more than 2^32 - 1 points; nothing tested");
  }
  if (!too_many && !points.empty() && !views.empty()) {
    // The views are independent: one per thread at a time (memory: one view's splats per
    // thread); a view's projection gets the threads no view needs.
    // A view in which every point is its own camera's has nothing to test: not even projected.
    std::vector<std::pair<int, size_t>> made_by;  // Point::camera -> points
    for (const Point& p : points) {
      auto it = std::find_if(made_by.begin(), made_by.end(), [&](const auto& m) { return m.first == p.camera; });
      if (it == made_by.end()) {
        made_by.emplace_back(p.camera, 1);
      } else {
        ++it->second;
      }
    }
    auto own = [&](const ColourView& cv) -> size_t {
      for (const auto& [id, n] : made_by)
        if (cv.camera_id >= 0 && id == cv.camera_id) return n;
      return 0;
    };
    std::vector<size_t> to_test;  // the views with points of other cameras
    for (size_t v = 0; v < views.size(); ++v)
      if (own(views[v]) < points.size()) to_test.push_back(v);
    const unsigned outer = std::max(1u, std::min<unsigned>(threads, static_cast<unsigned>(to_test.size())));
    const unsigned inner = std::max(1u, threads / outer);
    // Each point's surface footprint (see the header), once for all views.
    std::vector<std::pair<int, cv::Vec3d>> sources;
    for (const ColourView& cv : views)
      if (cv.camera != nullptr && cv.camera_id >= 0) sources.emplace_back(cv.camera_id, cv.camera->Centre());
    std::vector<std::array<float, 6>> covs;
    if (!sources.empty() && !to_test.empty()) {
      covs.resize(points.size());
      const size_t chunk = 65536;
      ParallelFor((points.size() + chunk - 1) / chunk, threads, [&](size_t c) {
        for (size_t i = c * chunk; i < std::min(points.size(), (c + 1) * chunk); ++i) {
          const Point& p = points[i];
          covs[i] = p.cov;
          if (!(p.flags & kFlagHasCovariance)) continue;
          for (const auto& [id, centre] : sources)
            if (id == p.camera) covs[i] = SurfaceFootprint(p, centre);
        }
      });
    }
    std::vector<ViewResult> results(views.size());
    std::atomic<size_t> next{0};
    auto work = [&] {
      PreparedView pv;  // this thread's buffers, view after view
      for (size_t k = next++; k < to_test.size(); k = next++) {
        const size_t v = to_test[k];
        Prepare(points, covs, views[v], v, options, inner, &pv);
        if (pv.ok) results[v] = RunView(pv, options);
      }
    };
    std::vector<std::thread> pool;
    for (unsigned t = 1; t < outer; ++t) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
    // A point is removed when any view rejects it; counted for the first view (in the order
    // given) that does.
    for (size_t v = 0; v < views.size(); ++v) {
      for (uint32_t i : results[v].removed_points) {
        if (!keep[i]) continue;
        keep[i] = 0;
        ++st.removed_per_view[v];
        ++st.removed;
      }
      st.tested += results[v].tested;
      st.occluded_skips += results[v].occluded;
      st.rounds = std::max(st.rounds, results[v].rounds);
    }
  }
  st.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
  if (stats) *stats = std::move(st);
  return keep;
}

}  // namespace hvdb::ingest
