// The EWA splat set-up shared by the CPU and EGL renderers (internal to render/).
//
// The GLSL shaders in egl_renderer.cc repeat ProjectSplat() and the per-pixel kernel
// operation for operation, in float, so that both renderers give the same image; keep them
// in step (tests/render/egl_renderer_test.cc checks it).
#ifndef HVDB_RENDER_SPLAT_H_
#define HVDB_RENDER_SPLAT_H_

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <span>
#include <thread>
#include <vector>

#include "render/renderer.h"

namespace hvdb::render::internal {

// A camera and the options, reduced to what projecting a splat needs (all float).
struct View {
  uint32_t width = 0, height = 0;
  float rot[9] = {};  // camera-from-world rotation, row-major
  float trans[3] = {};
  float fx = 0, fy = 0, cx = 0, cy = 0;
  float k[5] = {};  // k1 k2 p1 p2 k3
  bool distorted = false;
  // Beyond this squared radius (normalised image coordinates) the distortion polynomial is
  // not trusted (it folds back); such points are culled.
  float max_r2 = 0;
  float near_plane = 0.01f;
  float cutoff2 = 0;      // r_C^2
  float filter = 1;       // antialiasing filter variance (pixels^2)
  float scale2 = 1;       // splat_scale^2: covariance growth at level of detail i
  float default_var = 0;  // default_sigma^2
  float depth_threshold = 0;
};

// Checks the camera and options and reduces them to a View (the camera resized first when
// options ask for another size).
Result<View> PrepareView(const Camera& camera, const RenderOptions& options);

// The blending weights of eqs. 5.15-5.17 for the source cameras, in the order given: the
// angular penalty w'' = acos(r . r_v) between viewing directions (5.15), w' = (1 - w'' /
// max w'') / w'' clamped to kMaxPenaltyWeight (5.16), normalised to sum 1 (5.17).
inline constexpr double kMaxPenaltyWeight = 1e4;
std::vector<double> BlendingWeights(const Camera& virtual_camera,
                                    std::span<const SourceCamera> sources);

// Per camera id, the factor a splat's kernel is multiplied by: the weights of BlendingWeights()
// divided by the largest one (the normalisation of eq. 5.17 only fixes a scale, which blending
// divides out; relative to the best camera, its splats stay opaque in the probabilistic mode)
// and clamped to [min_view_weight, 1]. Ids that are not listed get 1. Empty without
// options.view_dependent: every splat has weight 1.
std::vector<float> ViewWeightTable(const Camera& virtual_camera, const RenderOptions& options);

// sRGB 8-bit to linear, the table both renderers use.
const std::array<float, 256>& SrgbTable();

// One projected splat: the screen Gaussian's centre and inverse covariance (the conic), its
// pixel bounding box at the cutoff, depth, linear colour and view weight.
struct Splat {
  float u, v;        // centre (pixels)
  float ca, cb, cc;  // conic: q = ca dx^2 + 2 cb dx dy + cc dy^2
  float z;           // camera-space depth (m) of the centre
  // Depth slope over the screen: the mean depth of the 3D Gaussian along the ray through
  // pixel offset d is z + dz . d (its conditional mean given the screen position), so that
  // splats of one tilted surface agree on depth at every pixel (the fuzzy depth test).
  float dzdx, dzdy;
  float r, g, b;           // linear colour
  float w;                 // view-dependent weight
  int16_t x0, x1, y0, y1;  // inclusive pixel range that can pass the cutoff, clipped to the image
};

inline float CameraDepth(const View& view, const Point& p) {
  return view.rot[6] * p.x + view.rot[7] * p.y + view.rot[8] * p.z + view.trans[2];
}

// Projects one point (EWA: Sigma' = J W V W^T J^T s^2 + filter I, J the Jacobian of the
// projection, lens distortion included, at the point). False when it is culled: behind the
// near plane, outside the trusted distortion radius, degenerate, or off the image.
bool ProjectSplat(const Point& p, const View& view, std::span<const float> weights, Splat* out);

// The kernel at offset (dx, dy) from the centre: q = d^T Sigma'^-1 d (written as the shader
// writes it).
inline float KernelQ(const Splat& s, float dx, float dy) {
  return s.ca * dx * dx + 2.0f * s.cb * dx * dy + s.cc * dy * dy;
}

// Depth of the splat's fragment at offset (dx, dy), clamped at the camera plane.
inline float FragmentDepth(const Splat& s, float dx, float dy) {
  return std::max(s.z + s.dzdx * dx + s.dzdy * dy, 0.0f);
}

// Final pixel from the accumulated buffers (both renderers' last step).
struct Resolved {
  float rgba[4];
  float coverage;
};
inline Resolved Composite(float r, float g, float b, float coverage,
                          const std::array<float, 4>& bg) {
  Resolved o;
  float keep = (1.0f - coverage) * bg[3];
  o.rgba[0] = coverage * r + keep * bg[0];
  o.rgba[1] = coverage * g + keep * bg[1];
  o.rgba[2] = coverage * b + keep * bg[2];
  o.rgba[3] = coverage + keep;
  o.coverage = coverage;
  return o;
}

// Runs fn(i) for i in [0, tasks) on up to `threads` threads (the caller's included). Used by
// the CPU renderer and by ingest's photo-consistency test.
template <typename Fn>
void ParallelFor(size_t tasks, unsigned threads, const Fn& fn) {
  const size_t n = std::min<size_t>(threads, tasks);
  if (n <= 1) {
    for (size_t i = 0; i < tasks; ++i) fn(i);
    return;
  }
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i = next++; i < tasks; i = next++) fn(i);
  };
  std::vector<std::thread> pool;
  pool.reserve(n - 1);
  for (size_t t = 1; t < n; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

// A stable order of `keys` (ascending), by LSD radix sort.
std::vector<uint32_t> StableOrder(std::span<const float> keys);

// Warnings to the handler set by SetLogHandler; notes too, prefixed "note: ".
void LogWarning(const std::string& message);
void LogNote(const std::string& message);

}  // namespace hvdb::render::internal

#endif  // HVDB_RENDER_SPLAT_H_
