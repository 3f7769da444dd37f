#include "storage/hyperslice.h"

#include <cmath>
#include <limits>
#include <string>

namespace hvdb {

static bool AllFinite(const double* v, int n) {
  for (int i = 0; i < n; ++i) {
    if (!std::isfinite(v[i])) return false;
  }
  return true;
}

Status ValidateWindow(const Window& w) {
  static const char* kAxis[4] = {"x", "y", "z", "t"};
  for (int a = 0; a < 4; ++a) {
    if (std::isnan(w.lo[a]) || std::isnan(w.hi[a])) {
      return Status::InvalidArgument(std::string("window ") + kAxis[a] + " bound is NaN");
    }
    if (w.lo[a] > w.hi[a]) {
      return Status::InvalidArgument(std::string("window ") + kAxis[a] + " range is empty: " +
                                     std::to_string(w.lo[a]) + " > " + std::to_string(w.hi[a]));
    }
  }
  return Status::OK();
}

Result<SliceGeometry> SliceGeometry::Make(const Slice& slice, double space_time_scale) {
  if (!AllFinite(slice.normal.data(), 4)) {
    return Status::InvalidArgument("slice normal has a NaN or infinite component");
  }
  double len = std::sqrt(slice.normal[0] * slice.normal[0] + slice.normal[1] * slice.normal[1] +
                         slice.normal[2] * slice.normal[2] + slice.normal[3] * slice.normal[3]);
  if (!(len > 1e-12)) return Status::InvalidArgument("slice normal must be non-zero");
  if (!std::isfinite(slice.offset)) return Status::InvalidArgument("slice offset is not finite");
  if (!std::isfinite(slice.thickness) || slice.thickness < 0) {
    return Status::InvalidArgument("slice thickness must be finite and >= 0, got " +
                                   std::to_string(slice.thickness));
  }
  if (!(space_time_scale > 0) || !std::isfinite(space_time_scale)) {
    return Status::InvalidArgument("space/time scale must be > 0");
  }
  if (slice.clip) HVDB_RETURN_IF_ERROR(ValidateWindow(*slice.clip));
  SliceGeometry g;
  for (int i = 0; i < 4; ++i) g.n_[i] = slice.normal[i] / len;
  // The offset and thickness are given for the normal as passed; rescale with it.
  g.b_ = slice.offset / len;
  g.db_ = slice.thickness / len;
  g.s_ = space_time_scale;
  // Gram-Schmidt over the axes, dropping the axis most parallel to N.
  int drop = 0;
  for (int i = 1; i < 4; ++i) {
    if (std::fabs(g.n_[i]) > std::fabs(g.n_[drop])) drop = i;
  }
  std::array<std::array<double, 4>, 4> basis{};
  basis[0] = g.n_;
  int k = 1;
  for (int axis = 0; axis < 4; ++axis) {
    if (axis == drop) continue;
    std::array<double, 4> v{};
    v[axis] = 1;
    for (int j = 0; j < k; ++j) {
      double d = 0;
      for (int c = 0; c < 4; ++c) d += v[c] * basis[j][c];
      for (int c = 0; c < 4; ++c) v[c] -= d * basis[j][c];
    }
    double vl = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3]);
    for (int c = 0; c < 4; ++c) v[c] /= vl;
    basis[k++] = v;
  }
  g.v_ = {basis[1], basis[2], basis[3]};
  return g;
}

Relation SliceGeometry::Classify(const Box3& box, double t) const {
  double lo = n_[3] * s_ * t - b_, hi = lo;
  for (int a = 0; a < 3; ++a) {
    double u = n_[a] * box.lo[a], v = n_[a] * box.hi[a];
    lo += std::min(u, v);
    hi += std::max(u, v);
  }
  if (hi < -db_ || lo > db_) return Relation::kOutside;
  // Inside only with a margin, so rounding never makes a bucket "inside" that holds a point
  // the per-point test (Selects) would reject.
  const double eps = 1e-9 * (1 + std::fabs(b_) + db_);
  if (lo >= -db_ + eps && hi <= db_ - eps) return Relation::kInside;
  return Relation::kCrosses;
}

std::pair<double, double> SliceGeometry::TimeRange(const Box3& box) const {
  double lo = -b_, hi = -b_;
  for (int a = 0; a < 3; ++a) {
    double u = n_[a] * box.lo[a], v = n_[a] * box.hi[a];
    lo += std::min(u, v);
    hi += std::max(u, v);
  }
  // Need: -db <= lo + nt s t  and  hi + nt s t >= -db ... i.e. nt s t in [-db - hi, db - lo].
  double a = -db_ - hi, b = db_ - lo;
  double k = n_[3] * s_;
  const double inf = std::numeric_limits<double>::infinity();
  if (std::fabs(k) < 1e-15) return (a <= 0 && 0 <= b) ? std::pair{-inf, inf} : std::pair{1.0, 0.0};
  double t0 = a / k, t1 = b / k;
  if (t0 > t1) std::swap(t0, t1);
  return {t0, t1};
}

void SliceGeometry::Project(Point* p, double t, double dt) const {
  const double X[4] = {p->x, p->y, p->z, s_ * t};
  double out[3];
  for (int r = 0; r < 3; ++r) {
    out[r] = v_[r][0] * X[0] + v_[r][1] * X[1] + v_[r][2] * X[2] + v_[r][3] * X[3];
  }
  // 4D covariance: the spatial block of the point, and (s dt)^2 on the time axis.
  const auto& c = p->cov;
  const double C[4][4] = {{c[0], c[1], c[2], 0},
                          {c[1], c[3], c[4], 0},
                          {c[2], c[4], c[5], 0},
                          {0, 0, 0, (s_ * dt) * (s_ * dt)}};
  double MC[3][4];
  for (int r = 0; r < 3; ++r) {
    for (int j = 0; j < 4; ++j) {
      MC[r][j] = v_[r][0] * C[0][j] + v_[r][1] * C[1][j] + v_[r][2] * C[2][j] + v_[r][3] * C[3][j];
    }
  }
  double V[3][3];
  for (int r = 0; r < 3; ++r) {
    for (int q = 0; q < 3; ++q) {
      V[r][q] = MC[r][0] * v_[q][0] + MC[r][1] * v_[q][1] + MC[r][2] * v_[q][2] +
                MC[r][3] * v_[q][3];
    }
  }
  p->x = static_cast<float>(out[0]);
  p->y = static_cast<float>(out[1]);
  p->z = static_cast<float>(out[2]);
  p->cov = {static_cast<float>(V[0][0]), static_cast<float>(V[0][1]), static_cast<float>(V[0][2]),
            static_cast<float>(V[1][1]), static_cast<float>(V[1][2]), static_cast<float>(V[2][2])};
}

Relation ClassifyWindow(const Window& w, const Box3& box) {
  bool inside = true;
  for (int a = 0; a < 3; ++a) {
    if (box.hi[a] < w.lo[a] || box.lo[a] > w.hi[a]) return Relation::kOutside;
    if (box.lo[a] < w.lo[a] || box.hi[a] > w.hi[a]) inside = false;
  }
  return inside ? Relation::kInside : Relation::kCrosses;
}

bool WindowContains(const Window& w, float x, float y, float z) {
  return x >= w.lo[0] && x <= w.hi[0] && y >= w.lo[1] && y <= w.hi[1] && z >= w.lo[2] &&
         z <= w.hi[2];
}

}  // namespace hvdb
