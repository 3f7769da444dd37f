// Spherical harmonics and rotations of Gaussian splats (storage/gaussian_sh.h).
//
// The SH rotation matrices are fitted rather than taken from closed-form Wigner-D recurrences
// (Ivanic & Ruedenberg): the basis of each degree is a set of homogeneous polynomials of that
// degree restricted to the sphere, so the turned basis functions are exact linear combinations
// of the unturned ones, and a least-squares fit over a few dozen directions recovers those
// combinations to double rounding with the very basis (constants and signs) the renderers
// evaluate (render/gaussian_raster_kernels.h, the 3DGS reference's computeColorFromSH). No
// convention of a textbook recurrence can disagree with it then.
#include "storage/gaussian_sh.h"

#include <cmath>
#include <cstring>
#include <numbers>
#include <utility>

namespace hvdb {
namespace {

// Solves the n x n system a x = b (n <= 7) in place, Gaussian elimination with partial
// pivoting; b holds k right-hand sides, row-major n x k.
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

}  // namespace

void ShBasis(int l, double x, double y, double z, double* out) {
  const double xx = x * x, yy = y * y, zz = z * z;
  switch (l) {
    case 1:
      out[0] = -kShC1 * y, out[1] = kShC1 * z, out[2] = -kShC1 * x;
      return;
    case 2:
      out[0] = kShC2[0] * x * y;
      out[1] = kShC2[1] * y * z;
      out[2] = kShC2[2] * (2 * zz - xx - yy);
      out[3] = kShC2[3] * x * z;
      out[4] = kShC2[4] * (xx - yy);
      return;
    default:
      out[0] = kShC3[0] * y * (3 * xx - yy);
      out[1] = kShC3[1] * x * y * z;
      out[2] = kShC3[2] * y * (4 * zz - xx - yy);
      out[3] = kShC3[3] * z * (2 * zz - 3 * xx - 3 * yy);
      out[4] = kShC3[4] * x * (4 * zz - xx - yy);
      out[5] = kShC3[5] * z * (xx - yy);
      out[6] = kShC3[6] * x * (xx - 3 * yy);
  }
}

std::vector<double> ShRotationMatrix(int l, const Mat3d& r) {
  const int n = 2 * l + 1;
  // Directions on a Fibonacci sphere: well spread, so A^T A is well conditioned.
  constexpr int kDirs = 48;
  std::vector<double> ata(n * n, 0.0), atb(n * n, 0.0);
  double a[7], b[7];
  for (int i = 0; i < kDirs; ++i) {
    const double z = 1 - (2 * i + 1) / static_cast<double>(kDirs);
    const double rho = std::sqrt(1 - z * z), phi = i * std::numbers::pi * (3 - std::sqrt(5.0));
    const double x = rho * std::cos(phi), y = rho * std::sin(phi);
    ShBasis(l, x, y, z, a);
    // r^T d: row k of r^T is column k of r.
    ShBasis(l, r[0] * x + r[3] * y + r[6] * z, r[1] * x + r[4] * y + r[7] * z,
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
  return atb;
}

double EvalShRest(int degree, const float* rest, const std::array<double, 3>& d) {
  double sum = 0, y[7];
  for (int l = 1, k = 0; l <= degree; ++l) {
    ShBasis(l, d[0], d[1], d[2], y);
    for (int m = 0; m < 2 * l + 1; ++m, ++k) sum += rest[k] * y[m];
  }
  return sum;
}

std::array<double, 4> QuaternionOf(const Mat3d& r) {
  // Shepperd's method: the largest of w, x, y, z is taken from the diagonal, the rest from it.
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

Mat3d RotationOf(const std::array<double, 4>& q_in) {
  double w = q_in[0], x = q_in[1], y = q_in[2], z = q_in[3];
  const double n = std::sqrt(w * w + x * x + y * y + z * z);
  if (n > 0) {
    w /= n, x /= n, y /= n, z /= n;
  } else {
    w = 1, x = y = z = 0;
  }
  return {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
          2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
          2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
}

std::array<double, 4> QuaternionProduct(const std::array<double, 4>& a,
                                        const std::array<double, 4>& b) {
  return {a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
          a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
          a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
          a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]};
}

Mat3d Mul3(const Mat3d& a, const Mat3d& b) {
  Mat3d c{};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      for (int k = 0; k < 3; ++k) c[3 * i + j] += a[3 * i + k] * b[3 * k + j];
    }
  }
  return c;
}

double Det3(const Mat3d& a) {
  return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
         a[2] * (a[3] * a[7] - a[4] * a[6]);
}

void SymmetricEigen3(const Mat3d& m, std::array<double, 3>* values, Mat3d* vectors) {
  // Cyclic Jacobi rotations: exact enough for a covariance in a few sweeps, and no dependency
  // for one matrix size.
  double a[3][3], v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) a[i][j] = m[3 * i + j];
  }
  for (int sweep = 0; sweep < 32; ++sweep) {
    const double off = a[0][1] * a[0][1] + a[0][2] * a[0][2] + a[1][2] * a[1][2];
    if (off < 1e-30) break;
    for (int p = 0; p < 2; ++p) {
      for (int q = p + 1; q < 3; ++q) {
        if (std::fabs(a[p][q]) < 1e-300) continue;
        const double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
        const double t = (theta >= 0 ? 1 : -1) / (std::fabs(theta) + std::sqrt(theta * theta + 1));
        const double c = 1 / std::sqrt(t * t + 1), s = t * c;
        for (int k = 0; k < 3; ++k) {  // A <- A J
          const double akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - s * akq;
          a[k][q] = s * akp + c * akq;
        }
        for (int k = 0; k < 3; ++k) {  // A <- J^T A
          const double apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - s * aqk;
          a[q][k] = s * apk + c * aqk;
        }
        for (int k = 0; k < 3; ++k) {
          const double vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - s * vkq;
          v[k][q] = s * vkp + c * vkq;
        }
      }
    }
  }
  for (int i = 0; i < 3; ++i) (*values)[i] = a[i][i];
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*vectors)[3 * i + j] = v[i][j];
  }
  // A proper rotation: flip the third axis if the eigenvectors form a left-handed frame.
  if (Det3(*vectors) < 0) {
    for (int k = 0; k < 3; ++k) (*vectors)[3 * k + 2] = -(*vectors)[3 * k + 2];
  }
}

}  // namespace hvdb
