#include "ingest/photo_consistency.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <future>
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
using render::internal::Splat;

// Eight pixels at a time along a row (render/simd.h): image planes and the z-buffer have rows
// padded by this many floats, so a vector that starts at a row's last pixel stays inside.
constexpr uint32_t kLanes = 8;

// BT.601 on sRGB-encoded values in [0, 1], U and V scaled to [-0.5, 0.5] (see the header).
struct Yuv {
  float y, u, v;
};
inline Yuv ToYuv(uint8_t r8, uint8_t g8, uint8_t b8) {
  const float r = r8 * (1.0f / 255), g = g8 * (1.0f / 255), b = b8 * (1.0f / 255);
  const float y = 0.299f * r + 0.587f * g + 0.114f * b;
  return {y, (b - y) * (1.0f / 1.772f), (r - y) * (1.0f / 1.402f)};
}

// One view, ready to test: its splats sorted front to back (with the index of their point) and
// its image in YUV, one plane per component.
struct PreparedView {
  bool ok = false;
  render::internal::View view;
  std::vector<Splat> splats;
  std::vector<uint32_t> index;
  uint32_t stride = 0;                // floats per row: view.width + kLanes
  std::vector<float> y, u, v;         // row-major planes, stride * view.height
};

PreparedView Prepare(std::span<const Point> points, const ColourView& cv, size_t v,
                     const PhotoConsistencyOptions& o, unsigned threads) {
  PreparedView pv;
  const std::string where = "photo-consistency: view " + std::to_string(v);
  if (cv.camera == nullptr || cv.image.empty() || cv.image.type() != CV_8UC3) {
    render::internal::LogWarning(where + " skipped: it needs a camera and a CV_8UC3 image");
    return pv;
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
    return pv;
  }
  pv.view = view.value();
  const unsigned w = pv.view.width, h = pv.view.height;

  // Projection (the renderer's EWA set-up), chunked over threads.
  const size_t chunk = 32768;
  const size_t chunks = (points.size() + chunk - 1) / chunk;
  std::vector<std::vector<Splat>> parts(chunks);
  std::vector<std::vector<uint32_t>> part_index(chunks);
  ParallelFor(chunks, threads, [&](size_t c) {
    const size_t lo = c * chunk, hi = std::min(points.size(), lo + chunk);
    Splat s;
    for (size_t i = lo; i < hi; ++i) {
      if (render::internal::ProjectSplat(points[i], pv.view, {}, &s)) {
        parts[c].push_back(s);
        part_index[c].push_back(static_cast<uint32_t>(i));
      }
    }
  });
  size_t total = 0;
  for (const auto& p : parts) total += p.size();
  std::vector<Splat> splats;
  std::vector<uint32_t> index;
  splats.reserve(total);
  index.reserve(total);
  for (size_t c = 0; c < chunks; ++c) {
    splats.insert(splats.end(), parts[c].begin(), parts[c].end());
    index.insert(index.end(), part_index[c].begin(), part_index[c].end());
  }
  parts.clear();
  part_index.clear();

  // Front to back (fig. 5.4, lines 3-6): by the depth of the splat centre.
  std::vector<float> keys(splats.size());
  for (size_t k = 0; k < splats.size(); ++k) keys[k] = splats[k].z;
  const std::vector<uint32_t> order = render::internal::StableOrder(keys);
  pv.splats.resize(splats.size());
  pv.index.resize(splats.size());
  for (size_t k = 0; k < order.size(); ++k) {
    pv.splats[k] = splats[order[k]];
    pv.index[k] = index[order[k]];
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
  return pv;
}

// Fig. 5.4 for one view: updates keep and the counters. Each row of a splat is evaluated
// eight pixels at a time (the CPU renderer's kernel arithmetic: render/simd.h; built for
// AVX-512, AVX2 and the baseline, picked at load time), the same operations per pixel as the
// scalar renderer's, e^x to within a unit or two of the last place, the sums in float lanes.
HVDB_RENDER_CLONES
void TestView(std::span<const Point> points, const PreparedView& pv,
              const PhotoConsistencyOptions& o, std::vector<uint8_t>* keep, size_t* tested,
              size_t* removed, size_t* skipped) {
  using F = F8;
  using I = I8;
  using render::internal::Broadcast;
  using render::internal::Load;
  using render::internal::Select;
  using render::internal::Store;
  const auto& view = pv.view;
  const uint32_t S = pv.stride;
  const float inf = std::numeric_limits<float>::infinity();
  std::vector<float> zbuf(size_t{S} * view.height, inf);
  const float dz = view.depth_threshold;
  const float umax = static_cast<float>(view.width) - 0.5f;
  const float vmax = static_cast<float>(view.height) - 0.5f;
  const F iota = render::internal::VecTraits<F>::kIota;
  // The current splat's fragment depths, one vector per eight pixels of a row (+inf outside
  // its cutoff), and where each vector starts in the z-buffer: written when it is kept.
  // (Floats, not vectors: std::vector does not align its storage for them.)
  std::vector<float> frag_z;
  std::vector<size_t> frag_at;
  for (size_t k = 0; k < pv.splats.size(); ++k) {
    const uint32_t i = pv.index[k];
    if (!(*keep)[i]) continue;  // removed in an earlier view: no longer there to occlude
    const Splat& s = pv.splats[k];
    frag_z.clear();
    frag_at.clear();
    // Only splats centred on the image are tested: one centred outside shows just its tail,
    // whose colour says little about the point. Such splats still occlude (below), which can
    // only spare points behind them, the conservative side.
    const bool on_image = s.u >= -0.5f && s.u <= umax && s.v >= -0.5f && s.v <= vmax;
    const Point& p = points[i];
    const Yuv c = ToYuv(p.r, p.g, p.b);
    // Eq. 5.13 over the unoccluded fragments (xi = 1: within dz of the fuzzy z-buffer, or in
    // front of it), and the alpha they carry for the normalisation.
    // Summed in eight float lanes, added up in double per splat: a splat of a few hundred
    // pixels keeps its sums to ~1e-6 relative, far below what the thresholds can tell apart
    // (adding each row into doubles instead cost 23 % of the test's time on the SJTU frame).
    F sa{}, sy{}, su{}, sv{};
    for (int y = s.y0; y <= s.y1; ++y) {
      const float dy = static_cast<float>(y) - s.v;
      // The row's span of the cutoff ellipse, widened by a pixel against rounding; the
      // per-pixel test decides.
      const float b = s.cb * dy, cq = s.cc * dy * dy - view.cutoff2;
      const float disc = b * b - s.ca * cq;
      if (!(disc >= 0)) continue;
      const float root = std::sqrt(disc);
      const int xa = std::max<int>(s.x0, static_cast<int>(std::floor(s.u + (-b - root) / s.ca)) - 1);
      const int xb = std::min<int>(s.x1, static_cast<int>(std::ceil(s.u + (-b + root) / s.ca)) + 1);
      const size_t rowbase = static_cast<size_t>(y) * S;
      const F fdy = Broadcast<F>(dy);
      for (int x = xa; x <= xb; x += static_cast<int>(kLanes)) {
        const F fx = Broadcast<F>(static_cast<float>(x)) + iota;
        const F dx = fx - s.u;
        const F q = s.ca * dx * dx + 2.0f * s.cb * dx * fdy + s.cc * fdy * fdy;
        const I inside = (q <= view.cutoff2) & (fx <= static_cast<float>(xb));
        F z = s.z + s.dzdx * dx + s.dzdy * fdy;
        z = render::internal::Max(z, Broadcast<F>(0.f));
        const size_t at = rowbase + static_cast<size_t>(x);
        frag_z.resize(frag_z.size() + kLanes);
        Store(&frag_z[frag_z.size() - kLanes], Select(inside, z, Broadcast<F>(inf)));
        frag_at.push_back(at);
        if (!on_image) continue;
        const I seen = inside & ~(z > Load<F>(&zbuf[at]) + dz);  // not occluded (xi = 1)
        if (!render::internal::Any(seen)) continue;
        const F a = Select(seen, render::internal::Exp(q * -0.5f), Broadcast<F>(0.f));
        sa += a;
        sy += a * (Load<F>(&pv.y[at]) - c.y);
        su += a * (Load<F>(&pv.u[at]) - c.u);
        sv += a * (Load<F>(&pv.v[at]) - c.v);
      }
    }
    if (on_image) {
      double sum_a = 0, sum_y = 0, sum_u = 0, sum_v = 0;
      for (uint32_t l = 0; l < kLanes; ++l) sum_a += sa[l], sum_y += sy[l], sum_u += su[l], sum_v += sv[l];
      if (!(sum_a > 0)) {
        ++*skipped;  // fully occluded: not tested, and behind what is drawn already
        continue;
      }
      ++*tested;
      if (std::abs(sum_y / sum_a) > o.max_dy || std::abs(sum_u / sum_a) > o.max_du ||
          std::abs(sum_v / sum_a) > o.max_dv) {
        (*keep)[i] = 0;
        ++*removed;
        continue;
      }
    }
    // Kept: into the fuzzy z-buffer, so it occludes the splats behind it.
    for (size_t f = 0; f < frag_at.size(); ++f)
      Store(&zbuf[frag_at[f]], render::internal::Min(Load<F>(&zbuf[frag_at[f]]), Load<F>(&frag_z[kLanes * f])));
  }
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
    // View v+1 is projected and sorted in the background while view v is tested; the prepare
    // step does not read `keep`, so it never races with the test.
    auto prepare = [&](size_t v) { return Prepare(points, views[v], v, options, threads); };
    const auto policy = threads > 1 ? std::launch::async : std::launch::deferred;
    std::future<PreparedView> next = std::async(policy, prepare, size_t{0});
    for (size_t v = 0; v < views.size(); ++v) {
      PreparedView cur = next.get();
      if (v + 1 < views.size()) next = std::async(policy, prepare, v + 1);
      if (!cur.ok) continue;
      size_t removed = 0;
      TestView(points, cur, options, &keep, &st.tested, &removed, &st.occluded_skips);
      st.removed_per_view[v] = removed;
      st.removed += removed;
    }
  }
  st.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
  if (stats) *stats = std::move(st);
  return keep;
}

}  // namespace hvdb::ingest
