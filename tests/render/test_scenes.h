// Small synthetic scenes for the render tests: deterministic, a few thousand points.
#ifndef HVDB_TESTS_RENDER_TEST_SCENES_H_
#define HVDB_TESTS_RENDER_TEST_SCENES_H_

#include <cmath>
#include <random>
#include <vector>

#include "render/renderer.h"
#include "storage/point.h"

namespace hvdb::testing {

// A surfel at p with tangent axes spanned by t1, t2 (scaled by sigma) and a thin normal
// extent: the covariance of eq. 5.2 with three spanning vectors.
inline Point Surfel(float x, float y, float z, const float t1[3], const float t2[3],
                    const float n[3], float sigma, uint8_t r, uint8_t g, uint8_t b,
                    uint16_t camera = 0) {
  Point p;
  p.x = x;
  p.y = y;
  p.z = z;
  float a[3], c[3], d[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = t1[i] * sigma;
    c[i] = t2[i] * sigma;
    d[i] = n[i] * sigma * 0.1f;
  }
  p.cov = CovarianceFromSpanning(a, c, d);
  p.flags = kFlagHasCovariance;
  p.r = r;
  p.g = g;
  p.b = b;
  p.camera = camera;
  return p;
}

// A sphere of radius 1 at the origin, coloured by latitude and longitude bands, sampled on a
// Fibonacci lattice; source cameras 1..4 by octant of longitude.
inline std::vector<Point> SphereScene(size_t n = 6000) {
  std::vector<Point> pts;
  const float golden = 2.39996323f;
  float spacing = std::sqrt(4 * 3.14159265f / static_cast<float>(n));
  for (size_t i = 0; i < n; ++i) {
    float y = 1 - 2 * (static_cast<float>(i) + 0.5f) / static_cast<float>(n);
    float r = std::sqrt(1 - y * y);
    float phi = golden * static_cast<float>(i);
    float nrm[3] = {r * std::cos(phi), y, r * std::sin(phi)};
    // Tangent frame.
    float t1[3] = {-std::sin(phi), 0, std::cos(phi)};
    float t2[3] = {nrm[1] * t1[2] - nrm[2] * t1[1], nrm[2] * t1[0] - nrm[0] * t1[2],
                   nrm[0] * t1[1] - nrm[1] * t1[0]};
    int band = static_cast<int>((y + 1) * 4);
    int sector = static_cast<int>(std::fmod(phi, 6.2831853f) / 6.2831853f * 8);
    bool light = (band + sector) % 2 == 0;
    uint8_t red = light ? 230 : 40, green = static_cast<uint8_t>(30 * band),
            blue = light ? 60 : 200;
    pts.push_back(Surfel(nrm[0], nrm[1], nrm[2], t1, t2, nrm, spacing * 0.6f, red, green, blue,
                         static_cast<uint16_t>(1 + sector / 2)));
  }
  return pts;
}

// Two squares facing +z: a red one at z = 0 (2 x 2 m) and a smaller blue one at z = 0.5 in
// front of it, offset, plus random jitter in depth of `noise` metres: occlusion and the fuzzy
// depth test.
inline std::vector<Point> PlanesScene(float noise = 0.0f, float step = 0.04f) {
  std::mt19937 rng(7);
  std::normal_distribution<float> jitter(0.0f, 1.0f);
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 1, 0}, n[3] = {0, 0, 1};
  for (float y = -1; y <= 1; y += step) {
    for (float x = -1; x <= 1; x += step) {
      uint8_t g = static_cast<uint8_t>(128 + 100 * x);
      pts.push_back(Surfel(x, y, noise * jitter(rng), t1, t2, n, step * 0.6f, 220, g, 30, 1));
    }
  }
  for (float y = -0.6f; y <= 0.2f; y += step) {
    for (float x = -0.2f; x <= 0.6f; x += step) {
      pts.push_back(
          Surfel(x, y, 0.5f + noise * jitter(rng), t1, t2, n, step * 0.6f, 30, 60, 230, 2));
    }
  }
  return pts;
}

// Looks at the origin from distance `dist` along direction (dx, dy, dz).
inline render::Camera ViewFrom(double dx, double dy, double dz, double dist, uint32_t w, uint32_t h,
                               double fov = 50) {
  double n = std::sqrt(dx * dx + dy * dy + dz * dz);
  return render::Camera::LookAt({dx / n * dist, dy / n * dist, dz / n * dist}, {0, 0, 0}, {0, 1, 0},
                                fov, w, h);
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_RENDER_TEST_SCENES_H_
