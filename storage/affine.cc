#include "storage/affine.h"

#include <cmath>

namespace hvdb {

static constexpr double kMaxFrameIndex = 100'000'000;  // as in dataset.cc's frame bound

Result<AffineMap> AffineMap::Make(const Affine4& map, double fps) {
  for (double v : map.a) {
    if (!std::isfinite(v)) return Status::InvalidArgument("transform matrix is not finite");
  }
  for (double v : map.c) {
    if (!std::isfinite(v)) return Status::InvalidArgument("transform offset is not finite");
  }
  AffineMap m;
  m.m_ = map;
  m.fps_ = fps;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.s_[r][c] = map.a[static_cast<size_t>(r * 4 + c)];
  }
  const auto& S = m.s_;
  m.det_ = S[0][0] * (S[1][1] * S[2][2] - S[1][2] * S[2][1]) -
           S[0][1] * (S[1][0] * S[2][2] - S[1][2] * S[2][0]) +
           S[0][2] * (S[1][0] * S[2][1] - S[1][1] * S[2][0]);
  if (std::fabs(m.det_) < 1e-12) {
    return Status::InvalidArgument("transform: the spatial 3x3 part is singular");
  }
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      int r1 = (r + 1) % 3, r2 = (r + 2) % 3, c1 = (c + 1) % 3, c2 = (c + 2) % 3;
      m.cof_[r][c] = S[r1][c1] * S[r2][c2] - S[r1][c2] * S[r2][c1];
    }
  }
  return m;
}

Result<Point> AffineMap::Apply(const Point& p) const {
  const double X[4] = {p.x, p.y, p.z, p.frame / fps_};
  double Y[4];
  for (int r = 0; r < 4; ++r) {
    Y[r] = m_.c[static_cast<size_t>(r)];
    for (int c = 0; c < 4; ++c) Y[r] += m_.a[static_cast<size_t>(r * 4 + c)] * X[c];
  }
  double nf = std::round(Y[3] * fps_);
  if (!(nf >= 0) || nf >= kMaxFrameIndex) {
    return Status::InvalidArgument("transform moves point " + std::to_string(p.id) + " to t = " +
                                   std::to_string(Y[3]) + " s, outside the video");
  }
  Point q = p;
  q.x = static_cast<float>(Y[0]);
  q.y = static_cast<float>(Y[1]);
  q.z = static_cast<float>(Y[2]);
  q.frame = static_cast<uint32_t>(nf);
  const auto& cv = p.cov;
  const double V[3][3] = {{cv[0], cv[1], cv[2]}, {cv[1], cv[3], cv[4]}, {cv[2], cv[4], cv[5]}};
  double SV[3][3] = {}, W[3][3] = {};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) SV[r][c] += s_[r][k] * V[k][c];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) W[r][c] += SV[r][k] * s_[c][k];
  q.cov = {static_cast<float>(W[0][0]), static_cast<float>(W[0][1]), static_cast<float>(W[0][2]),
           static_cast<float>(W[1][1]), static_cast<float>(W[1][2]), static_cast<float>(W[2][2])};
  if (p.flags & kFlagHasNormal) {
    auto n = DecodeNormal(p.normal_oct);
    double v[3];
    for (int r = 0; r < 3; ++r) v[r] = cof_[r][0] * n[0] + cof_[r][1] * n[1] + cof_[r][2] * n[2];
    if (det_ < 0) {  // the cofactor matrix carries det's sign; a mirror must not flip normals in
      for (double& x : v) x = -x;
    }
    q.normal_oct = EncodeNormal(static_cast<float>(v[0]), static_cast<float>(v[1]),
                                static_cast<float>(v[2]));
  }
  if (!std::isfinite(q.x) || !std::isfinite(q.y) || !std::isfinite(q.z)) {
    return Status::InvalidArgument("transform moves point " + std::to_string(p.id) +
                                   " out of the float range");
  }
  return q;
}

}  // namespace hvdb
