// The camera as the 3DGS rasterisers hold it, in float as the reference: shared by the CPU
// kernels (gaussian_raster_kernels.h) and the GPU's (egl_gaussian.cc). Internal to render/.
#ifndef HVDB_RENDER_GAUSSIAN_VIEW_H_
#define HVDB_RENDER_GAUSSIAN_VIEW_H_

#include "render/renderer.h"

namespace hvdb::render::gaussian {

constexpr int kTile = 16;  // the reference's BLOCK_X = BLOCK_Y

struct ViewF {
  float rot[9];     // camera-from-world rotation, row-major
  float trans[3];   // camera-from-world translation
  float centre[3];  // camera centre in the world
  float fx, fy, cx, cy;
  float lim_x, lim_y;  // 1.3 tan(half fov): the EWA Jacobian's clamp of x/z and y/z
  int width, height, tiles_x, tiles_y;
};

inline ViewF MakeView(const Camera& cam) {
  const auto& m = cam.world_from_camera;  // [R | t]: camera-from-world is [R^T | -R^T t]
  ViewF v{};
  for (int i = 0; i < 3; ++i) {
    double t = 0;
    for (int j = 0; j < 3; ++j) {
      v.rot[3 * i + j] = static_cast<float>(m[4 * j + i]);
      t -= m[4 * j + i] * m[4 * j + 3];
    }
    v.trans[i] = static_cast<float>(t);
    v.centre[i] = static_cast<float>(m[4 * i + 3]);
  }
  v.fx = static_cast<float>(cam.fx);
  v.fy = static_cast<float>(cam.fy);
  v.cx = static_cast<float>(cam.cx);
  v.cy = static_cast<float>(cam.cy);
  const float tan_fovx = static_cast<float>(cam.width / (2.0 * cam.fx));
  const float tan_fovy = static_cast<float>(cam.height / (2.0 * cam.fy));
  v.lim_x = 1.3f * tan_fovx;
  v.lim_y = 1.3f * tan_fovy;
  v.width = static_cast<int>(cam.width);
  v.height = static_cast<int>(cam.height);
  v.tiles_x = (v.width + kTile - 1) / kTile;
  v.tiles_y = (v.height + kTile - 1) / kTile;
  return v;
}

}  // namespace hvdb::render::gaussian

#endif  // HVDB_RENDER_GAUSSIAN_VIEW_H_
