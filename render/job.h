// Render jobs: a render request (render/request.h; docs/PROTOCOL.md, "Rendering") run against
// a dataset.
//
// RenderJob validates the request once (views, dataset cameras, options), then renders its
// images one at a time, each from the points of its region, queried at the request's level of
// detail with splats grown by 2^(lod/2) (thesis 8.4). It is a pipeline: while image i is drawn
// and encoded, the points of image i + 1 are queried on a thread of their own. A progressive
// request gets a preview from a coarser level first. Two callers drive it: hvdb-server's
// sessions, from the worker pool with a renderer from the server's RendererPool, and the
// embedded `hvdb render` (client/backend.cc, --data DIR) with MakeRenderer(). Both therefore
// give the same images and the same errors for the same request.
//
// Unlike the rest of render/ (which needs only storage's Point record), this part of it reads
// a Dataset: it is its own library, hvdb_render_job (render/CMakeLists.txt), so that the
// renderers do not depend on it. It takes and gives plain values (render/request.h); the wire
// protocol's Render messages are converted to and from them by the protocol's render_convert.h.
#ifndef HVDB_RENDER_JOB_H_
#define HVDB_RENDER_JOB_H_

#include <array>
#include <atomic>
#include <future>
#include <memory>
#include <string>
#include <vector>

#include "render/billboard_render.h"
#include "render/egl_gaussian.h"
#include "render/gaussian_raster.h"
#include "render/point_buffer.h"
#include "render/renderer.h"
#include "render/request.h"
#include "render/shadow.h"
#include "render/video_encoder.h"
#include "storage/database.h"
#include "storage/job_limits.h"

namespace hvdb::render {

struct RenderLimits {
  // Points one image may draw (they are held in memory; a sequence holds the next image's
  // too while it draws one); hvdb-server: --max-render-points.
  uint64_t max_points = 16u << 20;
  uint32_t max_images = 100000;  // images in one sequence
  // The memory the job's points and images may take from the process's budget, and its
  // deadline (service::Service sets these; default: none).
  JobLimits job;
};

class RenderJob {
 public:
  // InvalidArgument (naming the field) for a bad request, LimitExceeded for too many images.
  // The level of detail follows storage's rule (Dataset::CheckLod).
  static Result<std::unique_ptr<RenderJob>> Create(std::shared_ptr<Dataset> dataset,
                                                   const RenderRequest& request,
                                                   const RenderLimits& limits = {});
  // Stops and waits for a query in flight.
  ~RenderJob();
  // Replies the request asks for: path size for a sequence, 2 for a progressive single view
  // (preview, then the image), else 1.
  size_t size() const { return steps_.size(); }
  // What colours an image: the points (in options' mode), the photos over the points' depth,
  // or the billboards. kAuto, the request's default, picks per image the best the frame has.
  // kGaussian: the splats as 3DGS draws them (render/gaussian_raster.h), with the dataset's
  // Gaussian records (DatasetInfo::gaussians; derived ones for points without).
  enum class Colour : uint8_t { kAuto, kPoints, kTexture, kBillboards, kGaussian };
  RendererKind renderer_kind() const { return kind_; }
  // Gaussian mode (the request's, or auto's on a Gaussian-splat dataset): every image is drawn
  // by the CPU 3DGS rasteriser, so the point Renderer that Render takes draws nothing (a caller
  // that makes one for the job can make the cheap CPU one).
  bool gaussian() const { return gaussian_; }
  ImageFormat format() const { return format_; }

  // Renders image i (0 <= i < size()) with `renderer`. The points of the previous image are
  // reused when its region and level are the same; those of image i + 1 are queried while
  // image i is drawn. `cancelled`, when given, is checked between batches; it must outlive
  // the job (the next image's query may still read it).
  Result<Image> RenderImage(size_t i, Renderer& renderer,
                            const std::atomic<bool>* cancelled = nullptr);
  // The same, encoded as the request's format into a reply (index, last, preview, lod,
  // timings filled in; fallback and renderer_choice are the caller's, who made the renderer).
  // A video (kMp4 / kWebm) must be rendered in order: each image is fed to the encoder and
  // its reply carries none; the last one carries the file.
  Result<RenderReply> Render(size_t i, Renderer& renderer,
                             const std::atomic<bool>* cancelled = nullptr);

 private:
  // One reply: which view, which region, at which level.
  struct Step {
    size_t view = 0, region = 0;
    int lod = 0;
    bool preview = false;
  };
  // The points of one (region, level).
  struct Points {
    size_t region = SIZE_MAX;
    int lod = -1;
    PointBuffer points;
    // Gaussian mode: the points as a 3DGS cloud with their records (made once per region and
    // level, shared by the images that show them).
    formats::GaussianCloud cloud;
    JobLease lease;        // the points' capacity, reserved from RenderLimits::job
    JobLease cloud_lease;  // the cloud's and its records' (while they are read), likewise
    bool Holds(const Step& s) const { return region == s.region && lod == s.lod; }
  };

  RenderJob() = default;
  // Makes current_ hold step i's points: kept, taken from the prefetch, or queried now.
  Status Load(size_t i, const std::atomic<bool>* cancelled);
  // Queries step i's points into `out` (run on the prefetch thread or the caller's).
  Status Query(const Step& step, const std::atomic<bool>* cancelled, Points* out) const;
  // Draws image i into image_.
  Status Draw(size_t i, Renderer& renderer, const std::atomic<bool>* cancelled);
  // Feeds image_ (image i of a video) to video_; the last one's reply gets the file.
  Status EncodeVideoFrame(size_t i, RenderReply* reply);
  // What draws step i (colour_, or kAuto's choice for its frame), and why, into mode_used_
  // and mode_choice_. Needs step i's points loaded.
  Result<Colour> ResolveColour(size_t i);
  // The photos stored for `frame`, read once per frame for auto, texture and billboards.
  Result<const std::vector<Photo>*> FramePhotos(uint32_t frame);
  // RenderRequest::texture: recolours image_ from the photos of the frame current_ shows.
  Status Texture(const Camera& view, const RenderOptions& o, Renderer& renderer);
  // RenderRequest::billboards: redraws image_ from the billboards of the frame current_ shows.
  Status Billboards(const Camera& view, const RenderOptions& o);
  // The one frame current_'s points belong to; InvalidArgument naming `field` otherwise.
  Result<uint32_t> SingleFrame(const std::string& field) const;

  std::shared_ptr<Dataset> dataset_;
  RenderLimits limits_;
  RendererKind kind_ = RendererKind::kAuto;
  ImageFormat format_ = ImageFormat::kPng;
  RenderOptions options_;
  QueryOptions query_;
  Colour colour_ = Colour::kAuto;  // RenderRequest::mode / texture / billboards
  bool sequence_ = false;          // RenderRequest::path given (even of one view)
  // What drew the last image ("visibility", "textured", ...) and why: RenderReply::mode_used,
  // mode_choice.
  std::string mode_used_, mode_choice_;
  std::vector<Photo> photos_;  // the photos of photos_frame_ (FramePhotos)
  uint32_t photos_frame_ = UINT32_MAX;
  // The photos of textured_frame_ (RGB) and what each sees (its render's depth at
  // textured_lod_), kept for the next image of the same frame and level.
  struct Source {
    Camera camera;
    std::vector<uint8_t> rgb;
    Image seen;
  };
  std::vector<Source> sources_;
  uint32_t textured_frame_ = UINT32_MAX;
  int textured_lod_ = -1;
  std::vector<BillboardSource> boards_;          // the billboards of boards_frame_
  uint32_t boards_frame_ = UINT32_MAX;
  double billboards_ms_ = -1;                    // the last image's billboard draw (-1: none)
  // Gaussian mode: whether the points' clouds are made (the request's mode, or auto on a
  // Gaussian-splat dataset), and the last image's rasteriser run (-1 ms: none).
  bool gaussian_ = false;
  GaussianRenderStats gaussian_stats_;
  int gaussian_threads_ = 0;
  double gaussian_ms_ = -1;
  GaussianRasterizer rasteriser_;  // its working memory kept from image to image
  GaussianImage gimg_;             // its output, reused
  // The GPU's 3DGS rasteriser, made at the first gaussian image when the job's point renderer
  // is the EGL one (asked for, or auto's choice on a GPU); what drew the last image, and why.
  std::unique_ptr<EglGaussianRasterizer> egl_;
  bool egl_tried_ = false;
  std::string egl_error_;  // why it could not be made
  std::string gaussian_used_, gaussian_choice_;
  // Draws image_ with a 3DGS rasteriser from current_.cloud: the GPU's where `renderer` is the
  // EGL renderer, else (or where the GPU's refuses the cloud) the CPU's.
  Status DrawGaussians(const Camera& view, const RenderOptions& o, const Renderer& renderer);
  // Gaussian mode: out's points' records (highlighted when asked) as out->cloud.
  Status MakeCloud(Points* out) const;
  // kMp4 / kWebm: the path's images go into video_ (made at the first image).
  std::unique_ptr<VideoEncoder> video_;
  double video_fps_ = 30;
  bool shadow_ = false;                          // RenderRequest::shadow_light given
  ShadowOptions shadow_opts_;
  uint32_t highlight_mask_ = 0;                  // the selection overlay (RenderRequest::highlight_*)
  std::array<float, 4> highlight_{1.f, 0.45f, 0.f, 0.5f};
  std::vector<Camera> views_;
  std::vector<Region> regions_;  // one, or one per image
  std::vector<Step> steps_;
  Points current_;
  Image image_;  // the last image drawn; its buffers are reused by the next
  // The next step's points, filled by prefetch_'s thread; read only after prefetch_.get().
  // With current_, a job may hold two images' points: up to 2x RenderLimits::max_points.
  Points next_;
  JobLease image_lease_;  // image_'s and the renderer's buffers (an estimate per pixel)
  std::future<Status> prefetch_;
  std::atomic<bool> stop_{false};  // set by the destructor: the prefetch gives up
};

// A camera of the dataset (storage's CameraInfo) as a render camera: the same fields.
Camera CameraFromInfo(const CameraInfo& info);

// Checks a photo before it is stored (hvdb-server's PutPhoto, the embedded backend's): its
// camera is valid and its image decodes (PNG or JPEG) to the camera's size. InvalidArgument
// saying what is wrong otherwise, so that a bad photo is refused, not stored to fail renders.
Status CheckPhoto(const Photo& photo);

// A view of a render request as a render camera. Dataset camera ids are looked up in `info`;
// InvalidArgument naming `field` (e.g. "render.view") for a view that cannot be one.
Result<Camera> ViewCamera(const View& view, const DatasetInfo& info, const std::string& field);

// Parses a camera path for a sequence (the `hvdb render --path` file), JSON:
//   {"cameras": [ VIEW, ... ]}  where each VIEW is one of
//     {"look_at": {"eye": [x,y,z], "target": [x,y,z], "up": [x,y,z], "fov_y_deg": 50,
//                  "width": 1024, "height": 768}}
//     {"camera": {"width": W, "height": H, "fx": .., "fy": .., "cx": .., "cy": ..,
//                 "distortion": [k1,k2,p1,p2,k3], "world_from_camera": [16 values, row-major]}}
//     {"dataset_camera": ID}
//   and may carry "frame": F (then every entry must): image i shows frame F.
// Fills request->path (and request->frames); InvalidArgument names the entry at fault.
Status ParseCameraPath(const std::string& json_text, RenderRequest* request);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_JOB_H_
