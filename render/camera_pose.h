// A camera's pose and projection for per-pixel work (projective texturing, billboards):
// world <-> pixel with the camera's distortion. Internal to render/.
#ifndef HVDB_RENDER_CAMERA_POSE_H_
#define HVDB_RENDER_CAMERA_POSE_H_

#include <algorithm>
#include <cmath>

#include "render/renderer.h"

namespace hvdb::render::internal {

struct Vec3 {
  double x, y, z;
};

// A camera's pose and projection for per-pixel use.
struct Pose {
  const Camera* cam;
  double R[9];  // camera_from_world rotation (row-major)
  Vec3 centre;

  explicit Pose(const Camera& c) : cam(&c) {
    const auto& m = c.world_from_camera;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R[3 * i + j] = m[4 * j + i];  // transpose of the rotation
    }
    centre = {m[3], m[7], m[11]};
  }
  // World point -> pixel (with distortion) and camera z; false behind the camera.
  bool Project(const Vec3& X, double* u, double* v, double* z) const {
    const double dx = X.x - centre.x, dy = X.y - centre.y, dz = X.z - centre.z;
    const double xc = R[0] * dx + R[1] * dy + R[2] * dz;
    const double yc = R[3] * dx + R[4] * dy + R[5] * dz;
    const double zc = R[6] * dx + R[7] * dy + R[8] * dz;
    if (!(zc > 0)) return false;
    double x = xc / zc, y = yc / zc;
    const auto& d = cam->distortion;
    if (d[0] != 0 || d[1] != 0 || d[2] != 0 || d[3] != 0 || d[4] != 0) {
      const double r2 = x * x + y * y;
      const double radial = 1 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
      const double xd = x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x);
      const double yd = y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y;
      x = xd, y = yd;
    }
    *u = cam->fx * x + cam->cx;
    *v = cam->fy * y + cam->cy;
    *z = zc;
    return true;
  }
  // Pixel centre (u, v) at camera depth z -> world point (the inverse of Project; distortion
  // undone by fixed-point iteration, as OpenCV's undistortPoints does).
  Vec3 Unproject(double u, double v, double z) const {
    double x = (u - cam->cx) / cam->fx, y = (v - cam->cy) / cam->fy;
    const auto& d = cam->distortion;
    if (d[0] != 0 || d[1] != 0 || d[2] != 0 || d[3] != 0 || d[4] != 0) {
      const double x0 = x, y0 = y;
      for (int it = 0; it < 8; ++it) {
        const double r2 = x * x + y * y;
        const double radial = 1 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
        const double ex = 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x);
        const double ey = d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y;
        x = (x0 - ex) / radial;
        y = (y0 - ey) / radial;
      }
    }
    const double xc = x * z, yc = y * z;
    // world = R^T (xc, yc, z) + centre; R^T's rows are R's columns.
    return {R[0] * xc + R[3] * yc + R[6] * z + centre.x, R[1] * xc + R[4] * yc + R[7] * z + centre.y,
            R[2] * xc + R[5] * yc + R[8] * z + centre.z};
  }
};

inline double Angle(const Vec3& a, const Vec3& b) {
  const double na = std::sqrt(a.x * a.x + a.y * a.y + a.z * a.z);
  const double nb = std::sqrt(b.x * b.x + b.y * b.y + b.z * b.z);
  if (!(na > 0) || !(nb > 0)) return 0;
  return std::acos(std::clamp((a.x * b.x + a.y * b.y + a.z * b.z) / (na * nb), -1.0, 1.0));
}

}  // namespace hvdb::render::internal

#endif  // HVDB_RENDER_CAMERA_POSE_H_
