// The scene and requests the render job tests share (job_test.cc, video_test.cc): three frames
// of the sphere, each in its own colour, in a dataset at 10 fps with four cameras.
#ifndef HVDB_TESTS_RENDER_JOB_HELPERS_H_
#define HVDB_TESTS_RENDER_JOB_HELPERS_H_

#include <cmath>
#include <string>
#include <vector>

#include "protocol/render_convert.h"
#include "protocol/wire.h"
#include "render/job.h"
#include "render/renderer.h"
#include "storage/database.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render_test {

constexpr double kFps = 10;

// The sphere, recoloured per frame so that images of different frames differ.
inline std::vector<Point> FramePoints(uint32_t frame) {
  auto pts = testing::SphereScene(3000);
  for (Point& p : pts) {
    p.r = static_cast<uint8_t>(frame == 0 ? 250 : 10);
    p.g = static_cast<uint8_t>(frame == 1 ? 250 : 10);
    p.b = static_cast<uint8_t>(frame == 2 ? 250 : 10);
    p.frame = frame;
  }
  return pts;
}

inline DatasetInfo Info(const std::string& name, bool cameras) {
  DatasetInfo info;
  info.name = name;
  info.fps = kFps;
  if (cameras) {
    for (uint16_t i = 1; i <= 4; ++i) {
      CameraInfo c;
      c.id = i;
      c.name = "cam" + std::to_string(i);
      render::Camera v =
          testing::ViewFrom(std::cos(i * 1.5708), 0.3, std::sin(i * 1.5708), 3, 160, 120);
      c.width = v.width;
      c.height = v.height;
      c.fx = v.fx;
      c.fy = v.fy;
      c.cx = v.cx;
      c.cy = v.cy;
      c.world_from_camera = v.world_from_camera;
      info.cameras.push_back(c);
    }
  }
  return info;
}

inline wire::Region FrameRegion(uint32_t f) {
  Window w;
  w.lo = {-1e9, -1e9, -1e9, f / kFps};
  w.hi = {1e9, 1e9, 1e9, f / kFps};
  wire::Region r;
  wire::ToWire(Region(w), &r);
  return r;
}

inline void SetLookAt(wire::View* v, uint32_t w = 160, uint32_t h = 120) {
  auto* l = v->mutable_look_at();
  for (double x : {1.05, 1.4, 3.5}) l->add_eye(x);
  for (double x : {0, 0, 0}) l->add_target(x);
  l->set_fov_y_deg(50);
  l->set_width(w);
  l->set_height(h);
}

inline render::Camera TheLookAt(uint32_t w = 160, uint32_t h = 120) {
  return render::Camera::LookAt({1.05, 1.4, 3.5}, {0, 0, 0}, {0, 1, 0}, 50, w, h);
}

// A render job made from a wire request, as hvdb-server's sessions make it: the message
// decoded (its shape checked) into a render::RenderRequest, then the job.
inline Result<std::unique_ptr<render::RenderJob>> CreateJob(std::shared_ptr<Dataset> dataset,
                                                            const wire::Render& request,
                                                            const render::RenderLimits& limits = {}) {
  HVDB_ASSIGN_OR_RETURN(render::RenderRequest r, wire::FromWire(request));
  return render::RenderJob::Create(std::move(dataset), r, limits);
}

}  // namespace hvdb::render_test

#endif  // HVDB_TESTS_RENDER_JOB_HELPERS_H_
