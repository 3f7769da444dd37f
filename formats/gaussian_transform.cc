// Similarity transforms of Gaussian-splat clouds (formats/gaussian_transform.h).
//
// The SH rotation matrices are fitted rather than taken from closed-form Wigner-D recurrences
// (Ivanic & Ruedenberg): the basis of each degree is a set of homogeneous polynomials of that
// degree restricted to the sphere, so the rotated basis functions are exact linear combinations
// of the unrotated ones, and a least-squares fit over a few dozen directions recovers those
// combinations to double rounding with the very basis (constants and signs) the renderer
// evaluates (render/gaussian_raster_kernels.h, the 3DGS reference's computeColorFromSH). No
// convention of a textbook recurrence can disagree with it then.
#include "formats/gaussian_transform.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace hvdb::formats {
namespace {

using Mat3 = std::array<double, 9>;

// The 3DGS basis (SH_C1, SH_C2, SH_C3 of the reference, signs included) of degree l at d.
void Basis(int l, double x, double y, double z, double* out) {
  constexpr double kC1 = kShC1;
  constexpr const double* kC2 = kShC2;
  constexpr const double* kC3 = kShC3;
  const double xx = x * x, yy = y * y, zz = z * z;
  switch (l) {
    case 1:
      out[0] = -kC1 * y, out[1] = kC1 * z, out[2] = -kC1 * x;
      return;
    case 2:
      out[0] = kC2[0] * x * y;
      out[1] = kC2[1] * y * z;
      out[2] = kC2[2] * (2 * zz - xx - yy);
      out[3] = kC2[3] * x * z;
      out[4] = kC2[4] * (xx - yy);
      return;
    default:
      out[0] = kC3[0] * y * (3 * xx - yy);
      out[1] = kC3[1] * x * y * z;
      out[2] = kC3[2] * y * (4 * zz - xx - yy);
      out[3] = kC3[3] * z * (2 * zz - 3 * xx - 3 * yy);
      out[4] = kC3[4] * x * (4 * zz - xx - yy);
      out[5] = kC3[5] * z * (xx - yy);
      out[6] = kC3[6] * x * (xx - 3 * yy);
  }
}

// Solves the n x n system a x = b (n <= 7, a symmetric positive definite) in place, Gaussian
// elimination with partial pivoting; b holds k right-hand sides, row-major n x k.
void Solve(int n, int k, double* a, double* b) {
  for (int c = 0; c < n; ++c) {
    int p = c;
    for (int r = c + 1; r < n; ++r) {
      if (std::fabs(a[r * n + c]) > std::fabs(a[p * n + c])) p = r;
    }
    for (int j = 0; j < n; ++j) std::swap(a[c * n + j], a[p * n + j]);
    for (int j = 0; j < k; ++j) std::swap(b[c * k + j], b[p * k + j]);
    for (int r = 0; r < n; ++r) {
      if (r == c) continue;
      const double f = a[r * n + c] / a[c * n + c];
      for (int j = 0; j < n; ++j) a[r * n + j] -= f * a[c * n + j];
      for (int j = 0; j < k; ++j) b[r * k + j] -= f * b[c * k + j];
    }
  }
  for (int r = 0; r < n; ++r) {
    for (int j = 0; j < k; ++j) b[r * k + j] /= a[r * n + r];
  }
}

Mat3 Mul(const Mat3& a, const Mat3& b) {
  Mat3 c{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      for (int k = 0; k < 3; ++k) c[3 * i + j] += a[3 * i + k] * b[3 * k + j];
    }
  }
  return c;
}

// The unit quaternion (w x y z) of a rotation matrix, in 3DGS's convention (build_rotation).
std::array<double, 4> QuaternionOf(const Mat3& r) {
  const double trace = r[0] + r[4] + r[8];
  std::array<double, 4> q;
  if (trace > 0) {
    const double s = 2 * std::sqrt(trace + 1);
    q = {s / 4, (r[7] - r[5]) / s, (r[2] - r[6]) / s, (r[3] - r[1]) / s};
  } else if (r[0] > r[4] && r[0] > r[8]) {
    const double s = 2 * std::sqrt(1 + r[0] - r[4] - r[8]);
    q = {(r[7] - r[5]) / s, s / 4, (r[1] + r[3]) / s, (r[2] + r[6]) / s};
  } else if (r[4] > r[8]) {
    const double s = 2 * std::sqrt(1 + r[4] - r[0] - r[8]);
    q = {(r[2] - r[6]) / s, (r[1] + r[3]) / s, s / 4, (r[5] + r[7]) / s};
  } else {
    const double s = 2 * std::sqrt(1 + r[8] - r[0] - r[4]);
    q = {(r[3] - r[1]) / s, (r[2] + r[6]) / s, (r[5] + r[7]) / s, s / 4};
  }
  return q;
}

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
  m.rotation = Mul(about(2, z), Mul(about(1, y), about(0, x)));
  return m;
}

bool Similarity::IsIdentity() const {
  return rotation == Mat3{1, 0, 0, 0, 1, 0, 0, 0, 1} && scale == 1 &&
         translation == std::array<double, 3>{0, 0, 0};
}

std::vector<double> ShRotationMatrix(int l, const Mat3& r) {
  const int n = 2 * l + 1;
  // Directions on a Fibonacci sphere: well spread, so A^T A is well conditioned.
  constexpr int kDirs = 48;
  std::vector<double> ata(n * n, 0.0), atb(n * n, 0.0);
  double a[7], b[7];
  for (int i = 0; i < kDirs; ++i) {
    const double z = 1 - (2 * i + 1) / static_cast<double>(kDirs);
    const double rho = std::sqrt(1 - z * z), phi = i * std::numbers::pi * (3 - std::sqrt(5.0));
    const double x = rho * std::cos(phi), y = rho * std::sin(phi);
    Basis(l, x, y, z, a);
    // R^T d: row k of R^T is column k of R.
    Basis(l, r[0] * x + r[3] * y + r[6] * z, r[1] * x + r[4] * y + r[7] * z,
          r[2] * x + r[5] * y + r[8] * z, b);
    for (int j = 0; j < n; ++j) {
      for (int k = 0; k < n; ++k) {
        ata[j * n + k] += a[j] * a[k];
        atb[j * n + k] += a[j] * b[k];
      }
    }
  }
  // A M^T = B in the least-squares sense: M^T = (A^T A)^-1 A^T B; c' = M^T c.
  Solve(n, n, ata.data(), atb.data());
  std::vector<double> mt(n * n);
  for (int j = 0; j < n; ++j) {
    for (int k = 0; k < n; ++k) mt[j * n + k] = atb[j * n + k];
  }
  return mt;
}

double EvalShRest(int degree, const float* rest, const std::array<double, 3>& d) {
  double sum = 0, y[7];
  for (int l = 1, k = 0; l <= degree; ++l) {
    Basis(l, d[0], d[1], d[2], y);
    for (int m = 0; m < 2 * l + 1; ++m, ++k) sum += rest[k] * y[m];
  }
  return sum;
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
  const double det = r[0] * (r[4] * r[8] - r[5] * r[7]) - r[1] * (r[3] * r[8] - r[5] * r[6]) +
                     r[2] * (r[3] * r[7] - r[4] * r[6]);
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
    const double bw = q[0], bx = q[1], by = q[2], bz = q[3];
    q[0] = static_cast<float>(a[0] * bw - a[1] * bx - a[2] * by - a[3] * bz);
    q[1] = static_cast<float>(a[0] * bx + a[1] * bw + a[2] * bz - a[3] * by);
    q[2] = static_cast<float>(a[0] * by - a[1] * bz + a[2] * bw + a[3] * bx);
    q[3] = static_cast<float>(a[0] * bz + a[1] * by - a[2] * bx + a[3] * bw);
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
