#include "bench/gaussian_scene.h"

#include <array>
#include <cmath>
#include <random>
#include <vector>

namespace hvdb::bench {

namespace {

using V3 = std::array<double, 3>;

V3 Cross(const V3& a, const V3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
V3 Normalised(const V3& a) {
  const double n = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  return {a[0] / n, a[1] / n, a[2] / n};
}

// The quaternion (w x y z) of the rotation whose columns are c0 c1 c2 (orthonormal, right-handed).
std::array<float, 4> Quaternion(const V3& c0, const V3& c1, const V3& c2) {
  const double m00 = c0[0], m11 = c1[1], m22 = c2[2];
  double w, x, y, z;
  const double tr = m00 + m11 + m22;
  if (tr > 0) {
    const double s = std::sqrt(tr + 1) * 2;
    w = s / 4, x = (c1[2] - c2[1]) / s, y = (c2[0] - c0[2]) / s, z = (c0[1] - c1[0]) / s;
  } else if (m00 > m11 && m00 > m22) {
    const double s = std::sqrt(1 + m00 - m11 - m22) * 2;
    w = (c1[2] - c2[1]) / s, x = s / 4, y = (c1[0] + c0[1]) / s, z = (c2[0] + c0[2]) / s;
  } else if (m11 > m22) {
    const double s = std::sqrt(1 + m11 - m00 - m22) * 2;
    w = (c2[0] - c0[2]) / s, x = (c1[0] + c0[1]) / s, y = s / 4, z = (c2[1] + c1[2]) / s;
  } else {
    const double s = std::sqrt(1 + m22 - m00 - m11) * 2;
    w = (c0[1] - c1[0]) / s, x = (c2[0] + c0[2]) / s, y = (c2[1] + c1[2]) / s, z = s / 4;
  }
  return {static_cast<float>(w), static_cast<float>(x), static_cast<float>(y),
          static_cast<float>(z)};
}

}  // namespace

formats::GaussianCloud GaussianScene(size_t n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uni(0, 1);
  auto range = [&](double lo, double hi) { return lo + (hi - lo) * uni(rng); };
  struct Sphere {
    V3 c;
    double r;
    std::array<float, 3> dc;
  };
  std::vector<Sphere> spheres;
  for (int i = 0; i < 12; ++i) {
    const double r = range(0.25, 0.8);
    spheres.push_back({{range(-3, 3), 1 - r, range(-0.5, 5)},
                       r,
                       {static_cast<float>(range(-1.5, 1.5)), static_cast<float>(range(-1.5, 1.5)),
                        static_cast<float>(range(-1.5, 1.5))}});
  }
  const double floor_area = 10.0 * 8, wall_area = 10.0 * 5;
  double sphere_area = 0;
  for (const Sphere& s : spheres) sphere_area += 4 * M_PI * s.r * s.r;
  const double total = floor_area + wall_area + sphere_area;
  const double spacing = std::sqrt(total / static_cast<double>(n));

  formats::GaussianCloud g;
  g.sh_degree = 3;
  g.Resize(n);
  const size_t K = g.sh_rest_per_splat();
  for (size_t i = 0; i < n; ++i) {
    const double pick = range(0, total);
    V3 p, normal;
    std::array<float, 3> dc;
    if (pick < floor_area) {
      p = {range(-5, 5), 1, range(-2, 6)};
      normal = {0, -1, 0};
      const bool check =
          (static_cast<int>(std::floor(p[0] * 2)) + static_cast<int>(std::floor(p[2] * 2))) % 2;
      dc = check ? std::array<float, 3>{1.2f, 1.1f, 0.9f}
                 : std::array<float, 3>{-1.0f, -0.9f, -0.8f};
    } else if (pick < floor_area + wall_area) {
      p = {range(-5, 5), range(-4, 1), 6};
      normal = {0, 0, -1};
      dc = {static_cast<float>(0.3 * std::sin(p[0] * 3)), -0.2f, 0.6f};
    } else {
      double at = pick - floor_area - wall_area;
      size_t k = 0;
      while (k + 1 < spheres.size() && at > 4 * M_PI * spheres[k].r * spheres[k].r) {
        at -= 4 * M_PI * spheres[k].r * spheres[k].r;
        ++k;
      }
      const Sphere& s = spheres[k];
      std::normal_distribution<double> nd(0, 1);
      normal = Normalised({nd(rng), nd(rng), nd(rng)});
      p = {s.c[0] + s.r * normal[0], s.c[1] + s.r * normal[1], s.c[2] + s.r * normal[2]};
      dc = s.dc;
    }
    // Tangent frame, turned by a random angle about the normal.
    const V3 helper = std::abs(normal[1]) < 0.9 ? V3{0, 1, 0} : V3{1, 0, 0};
    const V3 a = Normalised(Cross(helper, normal)), b = Cross(normal, a);
    const double phi = range(0, 2 * M_PI);
    const V3 t1 = {std::cos(phi) * a[0] + std::sin(phi) * b[0],
                   std::cos(phi) * a[1] + std::sin(phi) * b[1],
                   std::cos(phi) * a[2] + std::sin(phi) * b[2]};
    const V3 t2 = Cross(normal, t1);
    const auto q = Quaternion(t1, t2, normal);
    for (int c = 0; c < 3; ++c) g.position[3 * i + c] = static_cast<float>(p[c]);
    for (int c = 0; c < 4; ++c) g.rotation[4 * i + c] = q[c];
    g.scale[3 * i] = static_cast<float>(std::log(spacing * range(0.4, 1.0)));
    g.scale[3 * i + 1] = static_cast<float>(std::log(spacing * range(0.3, 0.8)));
    g.scale[3 * i + 2] = static_cast<float>(std::log(spacing * 0.05));
    g.opacity[i] = static_cast<float>(uni(rng) < 0.7 ? range(1, 6) : range(-4, 1));
    for (int c = 0; c < 3; ++c) g.sh_dc[3 * i + c] = dc[c] + static_cast<float>(range(-0.2, 0.2));
    for (size_t k = 0; k < K; ++k) g.sh_rest[i * K + k] = static_cast<float>(range(-0.08, 0.08));
  }
  return g;
}

render::Camera GaussianSceneCamera(uint32_t width, uint32_t height) {
  return render::Camera::LookAt({0.4, -1.1, -4.5}, {0, 0.2, 1.5}, {0, -1, 0}, 50, width, height);
}

formats::Srgb8Image ToSrgb8(const render::GaussianImage& image) {
  formats::Srgb8Image img;
  img.width = image.width, img.height = image.height, img.channels = 3;
  const std::vector<uint8_t> rgba = image.ToRgba8();
  img.data.reserve(rgba.size() / 4 * 3);
  for (size_t i = 0; i < rgba.size(); i += 4) {
    img.data.insert(img.data.end(), &rgba[i], &rgba[i + 3]);
  }
  return img;
}

}  // namespace hvdb::bench
