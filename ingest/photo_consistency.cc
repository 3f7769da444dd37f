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
#include "render/splat.h"

namespace hvdb::ingest {

namespace {

using render::internal::ParallelFor;
using render::internal::Splat;

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
// its image in YUV.
struct PreparedView {
  bool ok = false;
  render::internal::View view;
  std::vector<Splat> splats;
  std::vector<uint32_t> index;
  std::vector<Yuv> yuv;  // row-major, view.width * view.height
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

  pv.yuv.resize(size_t{w} * h);
  ParallelFor(h, threads, [&](size_t y) {
    const cv::Vec3b* row = cv.image.ptr<cv::Vec3b>(static_cast<int>(y));
    Yuv* out = &pv.yuv[y * w];
    for (unsigned x = 0; x < w; ++x) out[x] = ToYuv(row[x][2], row[x][1], row[x][0]);
  });
  pv.ok = true;
  return pv;
}

// Calls fn(pixel index, q, fragment depth) for every pixel of splat s that passes the cutoff
// (the CPU renderer's rasterisation of one splat).
template <typename Fn>
void ForEachFragment(const Splat& s, const render::internal::View& view, const Fn& fn) {
  for (int y = s.y0; y <= s.y1; ++y) {
    const float dy = static_cast<float>(y) - s.v;
    const size_t rowbase = static_cast<size_t>(y) * view.width;
    // The row's span of the cutoff ellipse, widened by a pixel against rounding; the per-pixel
    // test decides.
    const float b = s.cb * dy, c = s.cc * dy * dy - view.cutoff2;
    const float disc = b * b - s.ca * c;
    if (!(disc >= 0)) continue;
    const float root = std::sqrt(disc);
    const int xa = std::max<int>(s.x0, static_cast<int>(std::floor(s.u + (-b - root) / s.ca)) - 1);
    const int xb = std::min<int>(s.x1, static_cast<int>(std::ceil(s.u + (-b + root) / s.ca)) + 1);
    for (int x = xa; x <= xb; ++x) {
      const float dx = static_cast<float>(x) - s.u;
      const float q = render::internal::KernelQ(s, dx, dy);
      if (q > view.cutoff2) continue;
      fn(rowbase + static_cast<size_t>(x), q, render::internal::FragmentDepth(s, dx, dy));
    }
  }
}

// Fig. 5.4 for one view: updates keep and the counters.
void TestView(std::span<const Point> points, const PreparedView& pv,
              const PhotoConsistencyOptions& o, std::vector<uint8_t>* keep, size_t* tested,
              size_t* removed, size_t* skipped) {
  const auto& view = pv.view;
  std::vector<float> zbuf(size_t{view.width} * view.height,
                          std::numeric_limits<float>::infinity());
  const float dz = view.depth_threshold;
  const float umax = static_cast<float>(view.width) - 0.5f;
  const float vmax = static_cast<float>(view.height) - 0.5f;
  struct Fragment {
    size_t px;
    float z;
  };
  std::vector<Fragment> frags;  // the current splat's, for the z-buffer write
  for (size_t k = 0; k < pv.splats.size(); ++k) {
    const uint32_t i = pv.index[k];
    if (!(*keep)[i]) continue;  // removed in an earlier view: no longer there to occlude
    const Splat& s = pv.splats[k];
    frags.clear();
    // Only splats centred on the image are tested: one centred outside shows just its tail,
    // whose colour says little about the point. Such splats still occlude (below), which can
    // only spare points behind them, the conservative side.
    const bool on_image = s.u >= -0.5f && s.u <= umax && s.v >= -0.5f && s.v <= vmax;
    const Point& p = points[i];
    const Yuv c = ToYuv(p.r, p.g, p.b);
    // Eq. 5.13 over the unoccluded fragments (xi = 1: within dz of the fuzzy z-buffer, or in
    // front of it), and the alpha they carry for the normalisation.
    double sum_a = 0, dy = 0, du = 0, dv = 0;
    ForEachFragment(s, view, [&](size_t px, float q, float z) {
      frags.push_back({px, z});
      if (!on_image || z > zbuf[px] + dz) return;  // occluded (xi = 0)
      const double a = std::exp(-0.5f * q);
      const Yuv& iv = pv.yuv[px];
      sum_a += a;
      dy += a * (iv.y - c.y);
      du += a * (iv.u - c.u);
      dv += a * (iv.v - c.v);
    });
    if (on_image) {
      if (!(sum_a > 0)) {
        ++*skipped;  // fully occluded: not tested, and behind what is drawn already
        continue;
      }
      ++*tested;
      if (std::abs(dy / sum_a) > o.max_dy || std::abs(du / sum_a) > o.max_du ||
          std::abs(dv / sum_a) > o.max_dv) {
        (*keep)[i] = 0;
        ++*removed;
        continue;
      }
    }
    // Kept: into the fuzzy z-buffer, so it occludes the splats behind it.
    for (const Fragment& f : frags) zbuf[f.px] = std::min(zbuf[f.px], f.z);
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
