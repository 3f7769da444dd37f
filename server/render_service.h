// The render service: a Render request (docs/PROTOCOL.md, "Rendering") run against a dataset.
//
// RenderJob validates the request once (views, dataset cameras, options), then renders its
// images one at a time, each from the points of its region, queried at the request's level of
// detail with splats grown by 2^(lod/2) (thesis 8.4). The server's sessions drive it from the
// worker pool with a renderer from the server's render::RendererPool; the embedded
// `hvdb render` (--data) can drive it directly with render::MakeRenderer().
#ifndef HVDB_SERVER_RENDER_SERVICE_H_
#define HVDB_SERVER_RENDER_SERVICE_H_

#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "protocol/wire.h"
#include "render/renderer.h"
#include "storage/database.h"

namespace hvdb::server {

struct RenderLimits {
  uint64_t max_points = 16u << 20;  // points one image may draw (they are held in memory)
  uint32_t max_images = 100000;     // images in one sequence
};

class RenderJob {
 public:
  // InvalidArgument (naming the field) for a bad request, LimitExceeded for too many images.
  static Result<std::unique_ptr<RenderJob>> Create(std::shared_ptr<Dataset> dataset,
                                                   const wire::Render& request,
                                                   const RenderLimits& limits = {});
  // Images the request asks for: path size for a sequence, else 1.
  size_t size() const { return views_.size(); }
  render::RendererKind renderer_kind() const { return kind_; }
  wire::ImageFormat format() const { return format_; }

  // Renders image i (0 <= i < size()) with `renderer`. The points of the previous image are
  // reused when its region is the same. `cancelled`, when given, is checked between batches.
  Result<render::Image> RenderImage(size_t i, render::Renderer& renderer,
                                    const std::atomic<bool>* cancelled = nullptr);
  // The same, encoded as the request's format into a reply (index, last, timings filled in).
  Result<wire::RenderReply> Render(size_t i, render::Renderer& renderer,
                                   const std::atomic<bool>* cancelled = nullptr);

 private:
  RenderJob() = default;
  Status Load(size_t region_index, const std::atomic<bool>* cancelled);

  std::shared_ptr<Dataset> dataset_;
  RenderLimits limits_;
  render::RendererKind kind_ = render::RendererKind::kAuto;
  wire::ImageFormat format_ = wire::IMAGE_PNG;
  render::RenderOptions options_;
  QueryOptions query_;
  std::vector<render::Camera> views_;
  std::vector<Region> regions_;  // one, or one per image
  std::vector<Point> points_;
  size_t loaded_ = SIZE_MAX;  // which region points_ holds
};

// A camera of the dataset (storage's CameraInfo) as a render camera: the same fields.
render::Camera CameraFromInfo(const CameraInfo& info);

// A view of a Render request as a render camera. dataset_camera ids are looked up in `info`.
Result<render::Camera> ViewFromWire(const wire::View& view, const DatasetInfo& info,
                                    const std::string& field);

// Parses a camera path for a sequence (the `hvdb render --path` file), JSON:
//   {"cameras": [ VIEW, ... ]}  where each VIEW is one of
//     {"look_at": {"eye": [x,y,z], "target": [x,y,z], "up": [x,y,z], "fov_y_deg": 50,
//                  "width": 1024, "height": 768}}
//     {"camera": {"width": W, "height": H, "fx": .., "fy": .., "cx": .., "cy": ..,
//                 "distortion": [k1,k2,p1,p2,k3], "world_from_camera": [16 values, row-major]}}
//     {"dataset_camera": ID}
//   and may carry "frame": F (then every entry must): image i shows frame F.
// Fills request->path (and request->frames); InvalidArgument names the entry at fault.
Status ParseCameraPath(const std::string& json_text, wire::Render* request);

}  // namespace hvdb::server

#endif  // HVDB_SERVER_RENDER_SERVICE_H_
