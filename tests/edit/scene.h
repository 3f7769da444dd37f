// A generated scene with a known object for the editing tests and benchmark: a sphere rolling
// over a plane across frames, with noisy colours and exact normals.
#ifndef HVDB_TESTS_EDIT_SCENE_H_
#define HVDB_TESTS_EDIT_SCENE_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <vector>

#include "storage/point.h"

namespace hvdb::testing {

struct ScenePoint {
  Point p;
  bool sphere;
};

// `spacing` metres between samples; the sphere (radius 0.15 m) moves 3 cm in x per frame.
// `sphere_rgb` close to the plane's (0.42, 0.45, 0.40) makes colour ambiguous; `sink` lowers
// the sphere into the plane so that the two touch along a ring.
inline std::vector<ScenePoint> MovingSphereScene(int frames, double spacing = 0.007,
                                                 uint64_t seed = 1,
                                                 std::array<double, 3> sphere_rgb = {0.60, 0.38, 0.33},
                                                 double sink = -0.01) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.035);
  auto colour = [&](Point* p, double r, double g, double b) {
    auto c = [&](double v) {
      return static_cast<uint8_t>(std::lround(std::clamp(v + noise(rng), 0.0, 1.0) * 255));
    };
    p->r = c(r);
    p->g = c(g);
    p->b = c(b);
  };
  std::vector<ScenePoint> out;
  const double radius = 0.15;
  const int nsphere = static_cast<int>(4 * M_PI * radius * radius / (spacing * spacing));
  for (int f = 0; f < frames; ++f) {
    const double cx = 0.3 + 0.03 * f, cy = 0.5, cz = radius - sink;
    for (double x = 0; x < 1.0; x += spacing) {
      for (double y = 0; y < 1.0; y += spacing) {
        Point p;
        p.x = static_cast<float>(x);
        p.y = static_cast<float>(y);
        p.z = 0;
        p.frame = static_cast<uint32_t>(f);
        p.normal_oct = EncodeNormal(0, 0, 1);
        p.flags = kFlagHasNormal;
        colour(&p, 0.42, 0.45, 0.40);
        out.push_back({p, false});
      }
    }
    // Fibonacci sphere: even sampling.
    for (int i = 0; i < nsphere; ++i) {
      double zz = 1 - 2 * (i + 0.5) / nsphere, rr = std::sqrt(1 - zz * zz);
      double phi = i * M_PI * (3 - std::sqrt(5.0));
      double nx = rr * std::cos(phi), ny = rr * std::sin(phi), nz = zz;
      Point p;
      p.x = static_cast<float>(cx + radius * nx);
      p.y = static_cast<float>(cy + radius * ny);
      p.z = static_cast<float>(cz + radius * nz);
      p.frame = static_cast<uint32_t>(f);
      p.normal_oct = EncodeNormal(static_cast<float>(nx), static_cast<float>(ny),
                                  static_cast<float>(nz));
      p.flags = kFlagHasNormal;
      colour(&p, sphere_rgb[0], sphere_rgb[1], sphere_rgb[2]);
      out.push_back({p, true});
    }
  }
  return out;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_EDIT_SCENE_H_
