// Pictures (an image, a video's frames) as a plane of surfels, and the placement's rotation.
#include <cmath>

#include "media/media.h"
#include "media/surfel.h"

namespace hvdb::media {

std::array<double, 9> RotationMatrix(const std::array<double, 3>& deg) {
  const double k = M_PI / 180;
  const double cx = std::cos(deg[0] * k), sx = std::sin(deg[0] * k);
  const double cy = std::cos(deg[1] * k), sy = std::sin(deg[1] * k);
  const double cz = std::cos(deg[2] * k), sz = std::sin(deg[2] * k);
  // Rz * Ry * Rx: X is applied first.
  return {cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx,
          sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx,
          -sy,     cy * sx,                cy * cx};
}

void Tangents(const Vec3& n, Vec3* t1, Vec3* t2) {
  // Cross with the axis least aligned with n.
  const Vec3 a = std::fabs(n[0]) < 0.9 ? Vec3{1, 0, 0} : Vec3{0, 1, 0};
  Vec3 u{n[1] * a[2] - n[2] * a[1], n[2] * a[0] - n[0] * a[2], n[0] * a[1] - n[1] * a[0]};
  const double l = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  for (double& c : u) c /= l;
  *t1 = u;
  *t2 = {n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]};
}

void SetSurfel(Point& p, const Vec3& n, const Vec3& t1, const Vec3& t2, double sigma) {
  float a[3], b[3], c[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = static_cast<float>(t1[i] * sigma);
    b[i] = static_cast<float>(t2[i] * sigma);
    c[i] = static_cast<float>(n[i] * sigma * 0.02);
  }
  p.cov = CovarianceFromSpanning(a, b, c);
  p.normal_oct = EncodeNormal(static_cast<float>(n[0]), static_cast<float>(n[1]),
                              static_cast<float>(n[2]));
  p.flags = kFlagHasNormal | kFlagHasCovariance;
}

std::vector<Point> PlaneSurfels(const Picture& pic, const Placement& place, uint32_t frame,
                                uint32_t label) {
  const std::array<double, 9> R = RotationMatrix(place.rotate_deg);
  const double w = place.width * place.scale;
  const double s = w / pic.width;  // texel spacing, metres
  const double h = s * pic.height;
  const Vec3 ex{R[0], R[3], R[6]}, ey{R[1], R[4], R[7]}, n{R[2], R[5], R[8]};
  Point proto;
  proto.frame = frame;
  proto.label = label;
  SetSurfel(proto, n, ex, ey, kSigmaPerSpacing * s);
  std::vector<Point> out;
  out.reserve(static_cast<size_t>(pic.width) * pic.height);
  for (int j = 0; j < pic.height; ++j) {
    const uint8_t* row = pic.rgba.data() + static_cast<size_t>(j) * pic.width * 4;
    const double y = h / 2 - (j + 0.5) * s;  // row 0 is the top
    for (int i = 0; i < pic.width; ++i) {
      const uint8_t* px = row + 4 * i;
      if (px[3] < 128) continue;  // transparent: no surfel, so cut-outs keep their shape
      const double x = (i + 0.5) * s - w / 2;
      Point p = proto;
      p.x = static_cast<float>(place.at[0] + x * ex[0] + y * ey[0]);
      p.y = static_cast<float>(place.at[1] + x * ex[1] + y * ey[1]);
      p.z = static_cast<float>(place.at[2] + x * ex[2] + y * ey[2]);
      p.r = px[0];
      p.g = px[1];
      p.b = px[2];
      out.push_back(p);
    }
  }
  return out;
}

}  // namespace hvdb::media
