#include "codec/metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <vector>

#include <nanoflann.hpp>

#include "codec/internal.h"

namespace hvdb::codec {
namespace {

struct Cloud {
  std::span<const Point> pts;
  size_t kdtree_get_point_count() const { return pts.size(); }
  float kdtree_get_pt(uint32_t i, size_t d) const {
    return d == 0 ? pts[i].x : d == 1 ? pts[i].y : pts[i].z;
  }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const { return false; }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>,
                                                   Cloud, 3, uint32_t>;

struct Sums {
  double pos = 0, y = 0, u = 0, v = 0, ang = 0;
  size_t n = 0, normals = 0;
};

void Yuv(const Point& p, double out[3]) {
  out[0] = 0.299 * p.r + 0.587 * p.g + 0.114 * p.b;
  out[1] = -0.168736 * p.r - 0.331264 * p.g + 0.5 * p.b + 128;
  out[2] = 0.5 * p.r - 0.418688 * p.g - 0.081312 * p.b + 128;
}

// Mean squared errors of `from` against its nearest neighbours in `to`.
Sums OneWay(std::span<const Point> from, std::span<const Point> to, const KdTree& tree) {
  std::vector<Sums> parts(4);
  size_t per = (from.size() + parts.size() - 1) / parts.size();
  ParallelRange(parts.size(), [&](size_t pb, size_t pe) {
    for (size_t part = pb; part < pe; ++part) {
      Sums& s = parts[part];
      for (size_t i = part * per; i < std::min(from.size(), (part + 1) * per); ++i) {
        const Point& p = from[i];
        float q[3] = {p.x, p.y, p.z};
        uint32_t idx;
        float d2;
        nanoflann::KNNResultSet<float, uint32_t> rs(1);
        rs.init(&idx, &d2);
        tree.findNeighbors(rs, q, nanoflann::SearchParams());
        const Point& o = to[idx];
        double dx = double{p.x} - o.x, dy = double{p.y} - o.y, dz = double{p.z} - o.z;
        s.pos += dx * dx + dy * dy + dz * dz;
        double a[3], b[3];
        Yuv(p, a);
        Yuv(o, b);
        s.y += (a[0] - b[0]) * (a[0] - b[0]);
        s.u += (a[1] - b[1]) * (a[1] - b[1]);
        s.v += (a[2] - b[2]) * (a[2] - b[2]);
        if ((p.flags & kFlagHasNormal) && (o.flags & kFlagHasNormal)) {
          auto na = DecodeNormal(p.normal_oct), nb = DecodeNormal(o.normal_oct);
          double dot = na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2];
          double deg = std::acos(std::clamp(dot, -1.0, 1.0)) * 180.0 / M_PI;
          s.ang += deg * deg;
          ++s.normals;
        }
        ++s.n;
      }
    }
  });
  Sums t;
  for (const Sums& s : parts) {
    t.pos += s.pos, t.y += s.y, t.u += s.u, t.v += s.v, t.ang += s.ang;
    t.n += s.n, t.normals += s.normals;
  }
  return t;
}

double Psnr(double peak, double mse) {
  if (mse <= 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(peak * peak / mse);
}

}  // namespace

Quality Compare(std::span<const Point> original, std::span<const Point> decoded) {
  Quality q;
  if (original.empty() || decoded.empty()) return q;
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  for (const Point& p : original) {
    const double v[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
  }
  double diag = std::sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                          (hi[2] - lo[2]) * (hi[2] - lo[2]));
  Cloud ca{original}, cb{decoded};
  KdTree ta(3, ca, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  KdTree tb(3, cb, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  Sums ab = OneWay(original, decoded, tb), ba = OneWay(decoded, original, ta);
  auto worse = [](double s1, size_t n1, double s2, size_t n2) {
    return std::max(n1 ? s1 / n1 : 0.0, n2 ? s2 / n2 : 0.0);
  };
  double mse = worse(ab.pos, ab.n, ba.pos, ba.n);
  q.position_psnr = Psnr(diag, mse);
  q.position_rmse = std::sqrt(mse);
  q.y_psnr = Psnr(255, worse(ab.y, ab.n, ba.y, ba.n));
  q.u_psnr = Psnr(255, worse(ab.u, ab.n, ba.u, ba.n));
  q.v_psnr = Psnr(255, worse(ab.v, ab.n, ba.v, ba.n));
  double amse = worse(ab.ang, ab.normals, ba.ang, ba.normals);
  q.normal_psnr = Psnr(180, amse);
  q.normal_rmse_degrees = std::sqrt(amse);
  return q;
}

}  // namespace hvdb::codec
