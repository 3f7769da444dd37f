// Similarity transforms of Gaussian-splat clouds (formats/gaussian_transform.h); the SH
// rotation itself is storage/gaussian_sh.h's, which edits of Gaussian datasets use too.
#include "formats/gaussian_transform.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace hvdb::formats {
namespace {

using Mat3 = Mat3d;

bool Finite3(const float* v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

Similarity Similarity::FromEulerDegrees(double x, double y, double z) {
  auto about = [](int axis, double degrees) {
    const double a = degrees * std::numbers::pi / 180, c = std::cos(a), s = std::sin(a);
    Mat3 m{1, 0, 0, 0, 1, 0, 0, 0, 1};
    const int i = (axis + 1) % 3, j = (axis + 2) % 3;
    m[3 * i + i] = c, m[3 * i + j] = -s, m[3 * j + i] = s, m[3 * j + j] = c;
    return m;
  };
  Similarity m;
  m.rotation = Mul3(about(2, z), Mul3(about(1, y), about(0, x)));
  return m;
}

bool Similarity::IsIdentity() const {
  return rotation == Mat3{1, 0, 0, 0, 1, 0, 0, 0, 1} && scale == 1 &&
         translation == std::array<double, 3>{0, 0, 0};
}

Status TransformCloud(GaussianCloud* c, const Similarity& m, const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(*c, name));
  if (!(m.scale > 0) || !std::isfinite(m.scale)) {
    return Status::InvalidArgument(name + ": scale " + std::to_string(m.scale) +
                                   " (a finite positive factor)");
  }
  const Mat3& r = m.rotation;
  Mat3 rrt{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      for (int k = 0; k < 3; ++k) rrt[3 * i + j] += r[3 * i + k] * r[3 * j + k];
    }
  }
  double off = 0;
  for (int i = 0; i < 9; ++i) off = std::max(off, std::fabs(rrt[i] - (i % 4 == 0 ? 1 : 0)));
  const double det = Det3(r);
  if (!(off <= 1e-6) || !(det > 0)) {
    return Status::InvalidArgument(
        name + ": the transform's 3x3 part is not a rotation times a uniform scale" +
        (det < 0 ? std::string(" (it mirrors, which a splat's quaternion cannot hold)")
                 : std::string(" (a shear or an unequal scale would deform the SH)")));
  }
  const bool rotates = r != Mat3{1, 0, 0, 0, 1, 0, 0, 0, 1};
  const size_t n = c->size();
  const double ls = std::log(m.scale);
  // New positions and scales first: a failure leaves the cloud as it was.
  std::vector<float> position(c->position), scale(c->scale);
  for (size_t i = 0; i < n; ++i) {
    float* p = &position[3 * i];
    const double x = p[0], y = p[1], z = p[2];
    for (int k = 0; k < 3; ++k) {
      p[k] = static_cast<float>(m.scale * (r[3 * k] * x + r[3 * k + 1] * y + r[3 * k + 2] * z) +
                                m.translation[k]);
    }
    if (m.scale != 1) {
      for (int k = 0; k < 3; ++k) scale[3 * i + k] = static_cast<float>(scale[3 * i + k] + ls);
    }
    if (!Finite3(p) || !Finite3(&scale[3 * i])) {
      return Status::InvalidArgument(name + ": splat " + std::to_string(i) +
                                     ": the transform takes its position or scale beyond float");
    }
  }
  c->position.swap(position);
  c->scale.swap(scale);
  if (!rotates) return Status::OK();
  // Rotations: q' = q_R q (Hamilton product, w x y z), keeping the stored quaternion's length.
  const std::array<double, 4> a = QuaternionOf(r);
  for (size_t i = 0; i < n; ++i) {
    float* q = &c->rotation[4 * i];
    const std::array<double, 4> p = QuaternionProduct(a, {q[0], q[1], q[2], q[3]});
    for (int k = 0; k < 4; ++k) q[k] = static_cast<float>(p[k]);
  }
  const int per_channel = ShRestPerChannel(c->sh_degree);
  for (int l = 1, first = 0; l <= c->sh_degree; first += 2 * l + 1, ++l) {
    const int dim = 2 * l + 1;
    const std::vector<double> mt = ShRotationMatrix(l, r);
    double in[7];
    for (size_t i = 0; i < 3 * n; ++i) {  // every channel of every splat
      float* v = &c->sh_rest[i * per_channel + first];
      for (int k = 0; k < dim; ++k) in[k] = v[k];
      for (int j = 0; j < dim; ++j) {
        double s = 0;
        for (int k = 0; k < dim; ++k) s += mt[j * dim + k] * in[k];
        v[j] = static_cast<float>(s);
      }
    }
  }
  return Status::OK();
}

}  // namespace hvdb::formats
