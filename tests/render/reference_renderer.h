// The CPU renderer as it was before the tile rasteriser (render/cpu_renderer.cc): one thread
// per band of 16 rows, scalar, std::exp per fragment. Kept, unchanged, as the brute-force
// reference the tiled renderer is compared against (tests/render/tile_raster_test.cc and
// render-bench's "reference" agreement figure): the same images within 45 dB.
#ifndef HVDB_TESTS_RENDER_REFERENCE_RENDERER_H_
#define HVDB_TESTS_RENDER_REFERENCE_RENDERER_H_

#include <algorithm>
#include <cmath>
#include <limits>
#include <span>
#include <vector>

#include "render/renderer.h"
#include "render/splat.h"

namespace hvdb::testing {

class ReferenceRenderer {
 public:
  explicit ReferenceRenderer(unsigned threads = 2) : threads_(threads) {}

  Result<render::Image> Render(std::span<const Point> points, const render::Camera& camera,
                               const render::RenderOptions& options) const {
    using namespace render;
    HVDB_ASSIGN_OR_RETURN(View view, internal::PrepareView(camera, options));
    Camera cam = options.width != 0 ? camera.Resized(options.width, options.height) : camera;
    std::vector<float> weights = internal::ViewWeightTable(cam, options);
    std::vector<Splat> splats = Project(points, view, weights);
    if (options.mode == Mode::kProbabilistic) {
      std::vector<float> keys(splats.size());
      for (size_t i = 0; i < splats.size(); ++i) keys[i] = splats[i].z;
      std::vector<uint32_t> order = internal::StableOrder(keys);
      std::vector<Splat> sorted(splats.size());
      for (size_t i = 0; i < order.size(); ++i) sorted[i] = splats[order[i]];
      splats.swap(sorted);
    }
    Image img;
    img.width = view.width;
    img.height = view.height;
    img.rgba.resize(img.pixels() * 4);
    img.coverage.resize(img.pixels());
    img.depth.resize(img.pixels());
    Rasterise(splats, view, options, &img);
    return img;
  }

 private:
  using View = render::internal::View;
  using Splat = render::internal::Splat;
  using RenderOptions = render::RenderOptions;
  using Image = render::Image;
  using Mode = render::Mode;
  static constexpr uint32_t kBandRows = 16;
  template <typename Fn>
  static void ParallelFor(size_t tasks, unsigned threads, const Fn& fn) {
    render::internal::ParallelFor(tasks, threads, fn);
  }

  std::vector<Splat> Project(std::span<const Point> points, const View& view,
                             const std::vector<float>& weights) const {
    const size_t chunk = 65536;
    size_t chunks = (points.size() + chunk - 1) / chunk;
    std::vector<std::vector<Splat>> parts(chunks);
    ParallelFor(chunks, threads_, [&](size_t c) {
      size_t lo = c * chunk, hi = std::min(points.size(), lo + chunk);
      auto& out = parts[c];
      out.reserve(hi - lo);
      Splat s;
      for (size_t i = lo; i < hi; ++i) {
        if (render::internal::ProjectSplat(points[i], view, weights, &s)) out.push_back(s);
      }
    });
    size_t total = 0;
    for (const auto& p : parts) total += p.size();
    std::vector<Splat> all;
    all.reserve(total);
    for (const auto& p : parts) all.insert(all.end(), p.begin(), p.end());
    return all;
  }

  void Rasterise(const std::vector<Splat>& splats, const View& view, const RenderOptions& o,
                 Image* img) const {
    const uint32_t w = view.width, h = view.height;
    const size_t bands = (h + kBandRows - 1) / kBandRows;
    // Bin splat indices by band, keeping splat order within a band (a counting sort).
    std::vector<size_t> start(bands + 1, 0);
    for (const Splat& s : splats) {
      for (size_t b = s.y0 / kBandRows; b <= s.y1 / kBandRows; ++b) ++start[b + 1];
    }
    for (size_t b = 0; b < bands; ++b) start[b + 1] += start[b];
    std::vector<uint32_t> bin(start[bands]);
    {
      std::vector<size_t> at(start.begin(), start.end() - 1);
      for (size_t i = 0; i < splats.size(); ++i) {
        const Splat& s = splats[i];
        for (size_t b = s.y0 / kBandRows; b <= s.y1 / kBandRows; ++b) {
          bin[at[b]++] = static_cast<uint32_t>(i);
        }
      }
    }
    const bool probabilistic = o.mode == Mode::kProbabilistic;
    ParallelFor(bands, threads_, [&](size_t band) {
      const int row0 = static_cast<int>(band * kBandRows);
      const int row1 = std::min<int>(row0 + kBandRows, static_cast<int>(h)) - 1;
      const size_t n = size_t{w} * static_cast<size_t>(row1 - row0 + 1);
      std::span<const uint32_t> list(bin.data() + start[band], start[band + 1] - start[band]);
      if (probabilistic) {
        RasteriseProbabilistic(splats, list, view, o, row0, row1, n, img);
      } else {
        RasteriseVisibility(splats, list, view, o, row0, row1, n, img);
      }
    });
  }

  // Calls fn(pixel index within the band, q, fragment depth) for every pixel of splat s in rows
  // row0..row1 that passes the cutoff.
  template <typename Fn>
  static void ForEachFragment(const Splat& s, const View& view, int row0, int row1, uint32_t width,
                              const Fn& fn) {
    int y0 = std::max<int>(s.y0, row0), y1 = std::min<int>(s.y1, row1);
    for (int y = y0; y <= y1; ++y) {
      float dy = static_cast<float>(y) - s.v;
      size_t rowbase = static_cast<size_t>(y - row0) * width;
      // The row's span of the cutoff ellipse, ca dx^2 + 2 cb dy dx + cc dy^2 = r_C^2, widened
      // by a pixel against rounding: the per-pixel test below still decides, as the shader's.
      float b = s.cb * dy, c = s.cc * dy * dy - view.cutoff2;
      float disc = b * b - s.ca * c;
      if (!(disc >= 0)) continue;
      float root = std::sqrt(disc);
      int xa = std::max<int>(s.x0, static_cast<int>(std::floor(s.u + (-b - root) / s.ca)) - 1);
      int xb = std::min<int>(s.x1, static_cast<int>(std::ceil(s.u + (-b + root) / s.ca)) + 1);
      for (int x = xa; x <= xb; ++x) {
        float dx = static_cast<float>(x) - s.u;
        float q = render::internal::KernelQ(s, dx, dy);
        if (q > view.cutoff2) continue;
        fn(rowbase + static_cast<size_t>(x), q, render::internal::FragmentDepth(s, dx, dy));
      }
    }
  }

  // Fig. 5.2 as the two-pass GPU method: pass 1 finds the nearest depth at each pixel, pass 2
  // blends every fragment within dz of it (the fuzzy depth test) additively; normalisation
  // divides the colour by the accumulated weight. Unlike fig. 5.2, which sets alpha to one,
  // coverage is the sum of all kernels at the pixel (occluded ones too), clamped to one: the
  // silhouette against the background stays antialiased, and an occluding edge does not let
  // the background through.
  static void RasteriseVisibility(const std::vector<Splat>& splats, std::span<const uint32_t> list,
                                  const View& view, const RenderOptions& o, int row0, int row1,
                                  size_t n, Image* img) {
    const uint32_t w = view.width;
    std::vector<float> zmin(n, std::numeric_limits<float>::infinity());
    for (uint32_t i : list) {
      ForEachFragment(splats[i], view, row0, row1, w,
                      [&](size_t p, float, float z) { zmin[p] = std::min(zmin[p], z); });
    }
    // Sum of w*a*c (rgb) and of w*a over the fragments that pass; sum of a over all.
    std::vector<float> acc(n * 5, 0.0f);
    for (uint32_t i : list) {
      const Splat& s = splats[i];
      ForEachFragment(s, view, row0, row1, w, [&](size_t p, float q, float z) {
        float a = std::exp(-0.5f * q);
        float* c = &acc[p * 5];
        c[4] += a;
        if (!(z - view.depth_threshold <= zmin[p])) return;  // the fuzzy depth test
        float wa = s.w * a;
        c[0] += s.r * wa;
        c[1] += s.g * wa;
        c[2] += s.b * wa;
        c[3] += wa;
      });
    }
    const size_t base = static_cast<size_t>(row0) * w;
    for (size_t p = 0; p < n; ++p) {
      const float* c = &acc[p * 5];
      // The nearest fragment always passes, so c[3] > 0 wherever c[4] > 0.
      render::internal::Resolved r = c[4] > 0 ? render::internal::Composite(c[0] / c[3], c[1] / c[3], c[2] / c[3],
                                                            std::min(1.0f, c[4]), o.background)
                                      : render::internal::Composite(0, 0, 0, 0, o.background);
      Store(r, zmin[p], base + p, img);
    }
  }

  // 5.4.1: front to back, each fragment adds min(a, 1 - A) of its colour (GL_SRC_ALPHA_SATURATE)
  // until the accumulated alpha A reaches one.
  static void RasteriseProbabilistic(const std::vector<Splat>& splats,
                                     std::span<const uint32_t> list, const View& view,
                                     const RenderOptions& o, int row0, int row1, size_t n,
                                     Image* img) {
    const uint32_t w = view.width;
    std::vector<float> acc(n * 4, 0.0f);  // C (rgb), A
    std::vector<float> zmin(n, std::numeric_limits<float>::infinity());
    for (uint32_t i : list) {
      const Splat& s = splats[i];
      ForEachFragment(s, view, row0, row1, w, [&](size_t p, float q, float z) {
        zmin[p] = std::min(zmin[p], z);
        float* c = &acc[p * 4];
        if (c[3] >= 1.0f) return;  // saturated: this ray has stopped
        float a = std::min(1.0f, s.w * std::exp(-0.5f * q));
        float f = std::min(a, 1.0f - c[3]);
        c[0] += s.r * f;
        c[1] += s.g * f;
        c[2] += s.b * f;
        c[3] = std::min(1.0f, c[3] + a);
      });
    }
    const size_t base = static_cast<size_t>(row0) * w;
    for (size_t p = 0; p < n; ++p) {
      const float* c = &acc[p * 4];
      render::internal::Resolved r =
          c[3] > 0 ? render::internal::Composite(c[0] / c[3], c[1] / c[3], c[2] / c[3], c[3], o.background)
                   : render::internal::Composite(0, 0, 0, 0, o.background);
      Store(r, zmin[p], base + p, img);
    }
  }

  static void Store(const render::internal::Resolved& r, float depth, size_t at, Image* img) {
    for (int k = 0; k < 4; ++k) img->rgba[at * 4 + k] = r.rgba[k];
    img->coverage[at] = r.coverage;
    img->depth[at] = depth;
  }

  unsigned threads_;
};

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_RENDER_REFERENCE_RENDERER_H_
