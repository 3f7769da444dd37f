#include "render/shadow.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "render/splat.h"

namespace hvdb::render {

namespace {

using internal::ParallelFor;
using internal::Splat;
using internal::View;

constexpr float kInf = std::numeric_limits<float>::infinity();
// A directional light's camera sits this many bounding radii away (rays parallel to 1/k).
constexpr double kDirectionalDistance = 1000;

std::string Vec(const std::array<double, 3>& v) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%g, %g, %g)", v[0], v[1], v[2]);
  return buf;
}

// The casters' bounds: each point padded by its splat's cutoff radius; and the typical (median)
// standard deviation of their splats.
struct Bounds {
  std::array<double, 3> lo{1e300, 1e300, 1e300}, hi{-1e300, -1e300, -1e300};
  double sigma = 0;
};
// Texels per splat standard deviation: enough to resolve a caster's outline at its splats'
// own scale; more only multiplies the fragments rasterised (by the square).
constexpr double kTexelsPerSigma = 1.5;

Bounds CasterBounds(std::span<const Point> casters, const RenderOptions& o) {
  Bounds b;
  const double s2 = double(o.splat_scale) * o.splat_scale;
  std::vector<double> sigmas;
  const size_t every = std::max<size_t>(1, casters.size() / 1024);
  for (size_t i = 0; i < casters.size(); ++i) {
    const Point& p = casters[i];
    double var = double(o.default_sigma) * o.default_sigma;
    if (p.flags & kFlagHasCovariance) var = std::max({double(p.cov[0]), double(p.cov[3]), double(p.cov[5])});
    const double sigma = std::sqrt(std::max(var, 0.0) * s2);
    if (i % every == 0) sigmas.push_back(sigma);
    const double pad = o.cutoff_radius * sigma;
    const double c[3] = {p.x, p.y, p.z};
    for (int k = 0; k < 3; ++k) {
      b.lo[size_t(k)] = std::min(b.lo[size_t(k)], c[k] - pad);
      b.hi[size_t(k)] = std::max(b.hi[size_t(k)], c[k] + pad);
    }
  }
  std::nth_element(sigmas.begin(), sigmas.begin() + long(sigmas.size() / 2), sigmas.end());
  b.sigma = sigmas[sigmas.size() / 2];
  return b;
}

// The light's camera, fitted to the casters' bounds.
Result<Camera> LightCamera(const ShadowOptions& s, const Bounds& b) {
  std::array<double, 3> centre{};
  double radius = 0;
  for (size_t k = 0; k < 3; ++k) {
    centre[k] = 0.5 * (b.lo[k] + b.hi[k]);
    radius += (b.hi[k] - b.lo[k]) * (b.hi[k] - b.lo[k]);
  }
  radius = std::max(0.5 * std::sqrt(radius), 1e-6);
  std::array<double, 3> eye = s.light;
  if (s.directional) {
    const double n = std::hypot(s.light[0], s.light[1], s.light[2]);
    for (size_t k = 0; k < 3; ++k) eye[k] = centre[k] + s.light[k] / n * kDirectionalDistance * radius;
  } else {
    bool inside = true;
    for (size_t k = 0; k < 3; ++k) inside = inside && s.light[k] >= b.lo[k] && s.light[k] <= b.hi[k];
    if (inside) {
      return Status::InvalidArgument(
          "render.shadow_light: the point light " + Vec(s.light) +
          " is inside the shadow casters' bounds " + Vec(b.lo) + " - " + Vec(b.hi) +
          "; put it outside them (or use a directional light)");
    }
  }
  const double d = std::hypot(eye[0] - centre[0], eye[1] - centre[1], eye[2] - centre[2]);
  // The half angle that holds the bounding sphere (at most 80 degrees when the light is within
  // the sphere but outside the box: the casters' far corners may then be cut off).
  const double half = d > radius ? std::asin(radius / d) : 80.0 * M_PI / 180;
  const double fov = std::min(2 * half * 180 / M_PI, 160.0);
  // Any up vector not along the view.
  std::array<double, 3> dir{centre[0] - eye[0], centre[1] - eye[1], centre[2] - eye[2]};
  std::array<double, 3> up{0, 1, 0};
  if (std::abs(dir[1]) > 0.9 * d) up = {1, 0, 0};
  // The map's side spans 2 d tan(fov / 2) at the casters' centre.
  const double span = 2 * d * std::tan(fov * M_PI / 360);
  const double want = std::ceil(span / std::max(b.sigma, 1e-9) * kTexelsPerSigma);
  const uint32_t size = uint32_t(std::clamp(want, 64.0, double(s.map_size)));
  return Camera::LookAt(eye, centre, up, fov, size, size);
}

// The nearest caster fragment's light-camera depth per texel (+inf where none).
std::vector<float> ShadowMap(std::span<const Point> casters, const View& view) {
  const size_t texels = size_t{view.width} * view.height;
  const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  const size_t chunks = std::min<size_t>(threads, (casters.size() + 4095) / 4096);
  std::vector<std::vector<float>> maps(std::max<size_t>(chunks, 1));
  ParallelFor(maps.size(), threads, [&](size_t c) {
    std::vector<float>& map = maps[c];
    map.assign(texels, kInf);
    const size_t n = casters.size(), lo = n * c / maps.size(), hi = n * (c + 1) / maps.size();
    Splat s;
    for (size_t i = lo; i < hi; ++i) {
      if (!internal::ProjectSplat(casters[i], view, {}, &s)) continue;
      for (int y = s.y0; y <= s.y1; ++y) {
        const float dy = float(y) - s.v;
        float* row = &map[size_t(y) * view.width];
        for (int x = s.x0; x <= s.x1; ++x) {
          const float dx = float(x) - s.u;
          if (internal::KernelQ(s, dx, dy) > view.cutoff2) continue;
          row[x] = std::min(row[x], internal::FragmentDepth(s, dx, dy));
        }
      }
    }
  });
  // Merge into the first, a band of rows per task.
  ParallelFor(view.height, threads, [&](size_t y) {
    float* out = &maps[0][y * view.width];
    for (size_t c = 1; c < maps.size(); ++c) {
      const float* in = &maps[c][y * view.width];
      for (uint32_t x = 0; x < view.width; ++x) out[x] = std::min(out[x], in[x]);
    }
  });
  return std::move(maps[0]);
}

// The normalised image coordinates of a pixel: (u - cx) / fx, (v - cy) / fy = (xd, yd), with
// the lens distortion undone (fixed-point iteration of the OpenCV model) from the guess (*x, *y):
// the previous pixel's answer shifted by the step, so that a row needs one or two iterations.
void Undistort(const Camera& c, double xd, double yd, double* x, double* y) {
  const auto& k = c.distortion;
  for (int it = 0; it < 20; ++it) {
    const double r2 = *x * *x + *y * *y;
    const double inv = 1 / (1 + r2 * (k[0] + r2 * (k[1] + r2 * k[4])));
    const double tx = 2 * k[2] * *x * *y + k[3] * (r2 + 2 * *x * *x);
    const double ty = k[2] * (r2 + 2 * *y * *y) + 2 * k[3] * *x * *y;
    const double nx = (xd - tx) * inv, ny = (yd - ty) * inv;
    const bool done = std::abs(nx - *x) + std::abs(ny - *y) < 1e-7;  // ~0.1 um at 1 m
    *x = nx;
    *y = ny;
    if (done) break;
  }
}

}  // namespace

Status CheckShadowOptions(const ShadowOptions& s) {
  for (double v : s.light) {
    if (!std::isfinite(v)) return Status::InvalidArgument("render.shadow_light: values must be finite");
  }
  if (s.directional && s.light[0] == 0 && s.light[1] == 0 && s.light[2] == 0) {
    return Status::InvalidArgument(
        "render.shadow_light: a directional light needs a non-zero direction (towards the light)");
  }
  if (s.caster_bit > 31) {
    return Status::InvalidArgument("render.shadow_casters: label bit " + std::to_string(s.caster_bit) +
                                   " is out of range; give a bit 0..31");
  }
  if (!(s.strength >= 0 && s.strength <= 1)) {
    return Status::InvalidArgument("render.shadow_strength: must be in [0, 1] (0.6 by default)");
  }
  if (s.map_size < 16 || s.map_size > kMaxImageSize) {
    return Status::InvalidArgument("shadow map size: must be in 16.." + std::to_string(kMaxImageSize));
  }
  return Status::OK();
}

Status ApplyShadows(std::span<const Point> points, const Camera& camera_in,
                    const RenderOptions& options, const ShadowOptions& shadow, Image* image,
                    ShadowStats* stats) {
  const auto t0 = std::chrono::steady_clock::now();
  HVDB_RETURN_IF_ERROR(CheckShadowOptions(shadow));
  ShadowStats local;
  ShadowStats& st = stats != nullptr ? *stats : local;
  st = ShadowStats{};
  const uint32_t bit = 1u << shadow.caster_bit;
  std::vector<Point> casters;
  for (const Point& p : points) {
    if (p.label & bit) casters.push_back(p);
  }
  st.casters = casters.size();
  if (casters.empty()) return Status::OK();
  const Camera camera = camera_in.width == image->width && camera_in.height == image->height
                            ? camera_in
                            : camera_in.Resized(image->width, image->height);
  HVDB_RETURN_IF_ERROR(camera.Validate());
  const Bounds bounds = CasterBounds(casters, options);
  HVDB_ASSIGN_OR_RETURN(const Camera light, LightCamera(shadow, bounds));
  RenderOptions lo = options;
  lo.view_dependent = false;
  lo.width = lo.height = 0;
  HVDB_ASSIGN_OR_RETURN(const View lv, internal::PrepareView(light, lo));
  const std::vector<float> map = ShadowMap(casters, lv);

  // One texel's size at the casters' distance, added to the fuzzy depth threshold: a surface
  // tilted to the light changes depth by about that much across the texel it is compared with.
  double dist = 0;
  for (size_t k = 0; k < 3; ++k) {
    const double c = 0.5 * (bounds.lo[k] + bounds.hi[k]) - light.world_from_camera[4 * k + 3];
    dist += c * c;
  }
  const float bias = options.depth_threshold + float(std::sqrt(dist) / light.fx);
  const auto& m = camera.world_from_camera;
  const bool distorted = std::any_of(camera.distortion.begin(), camera.distortion.end(),
                                     [](double v) { return v != 0; });
  const std::array<float, 4>& bg = options.background;
  const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
  std::vector<uint64_t> shadowed(image->height, 0);
  ParallelFor(image->height, threads, [&](size_t y) {
    double gx = 0, gy = 0, last_xd = 0, last_yd = 0;  // the last pixel's undistortion
    bool have_guess = false;
    for (uint32_t x = 0; x < image->width; ++x) {
      const size_t i = y * image->width + x;
      const float z = image->depth[i];
      if (!std::isfinite(z) || image->coverage[i] <= 0) continue;
      double nx = (x - camera.cx) / camera.fx, ny = (double(y) - camera.cy) / camera.fy;
      if (distorted) {
        double ux = have_guess ? gx + (nx - last_xd) : nx, uy = have_guess ? gy + (ny - last_yd) : ny;
        Undistort(camera, nx, ny, &ux, &uy);
        last_xd = nx, last_yd = ny, gx = ux, gy = uy, have_guess = true;
        nx = ux, ny = uy;
      }
      const double pc[3] = {nx * z, ny * z, z};
      float pw[3];
      for (int r = 0; r < 3; ++r) {
        pw[r] = float(m[4 * r] * pc[0] + m[4 * r + 1] * pc[1] + m[4 * r + 2] * pc[2] + m[4 * r + 3]);
      }
      float pl[3];
      for (int r = 0; r < 3; ++r) {
        pl[r] = lv.rot[3 * r] * pw[0] + lv.rot[3 * r + 1] * pw[1] + lv.rot[3 * r + 2] * pw[2] + lv.trans[r];
      }
      if (pl[2] <= lv.near_plane) continue;
      const int u = int(std::lround(lv.fx * pl[0] / pl[2] + lv.cx));
      const int v = int(std::lround(lv.fy * pl[1] / pl[2] + lv.cy));
      int taps = 0;
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const int tu = u + dx, tv = v + dy;
          if (tu < 0 || tv < 0 || tu >= int(lv.width) || tv >= int(lv.height)) continue;
          taps += pl[2] > map[size_t(tv) * lv.width + size_t(tu)] + bias;
        }
      }
      if (taps == 0) continue;
      ++shadowed[y];
      const float k = shadow.strength * float(taps) / 9.f;
      const float keep = (1.f - image->coverage[i]) * bg[3];
      float* px = &image->rgba[4 * i];
      for (int c = 0; c < 3; ++c) px[c] -= k * (px[c] - keep * bg[size_t(c)]);
    }
  });
  for (uint64_t n : shadowed) st.shadowed_pixels += n;
  st.milliseconds =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return Status::OK();
}

}  // namespace hvdb::render
