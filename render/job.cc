#include "render/job.h"

#include "formats/image_codec.h"
#include "render/projective_texture.h"
#include "render/job/internal.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <thread>
#include <variant>
#include <nlohmann/json.hpp>

namespace hvdb::render {

namespace {

Status Invalid(const std::string& field, const std::string& why) {
  return Status::InvalidArgument(field + ": " + why);
}

// What an image holds per pixel while a job draws it (float RGBA + depth: 20 bytes; the
// renderer's accumulators about as much again; the encoded image), for the job's budget.
constexpr uint64_t kImageBytesPerPixel = 64;

// Replies must fit the client's frame limit (256 MiB) with room to spare.
constexpr size_t kMaxEncodedImage = 200u << 20;

Status CheckReplySize(const std::string& bytes) {
  if (bytes.size() <= kMaxEncodedImage) return Status::OK();
  return Status::LimitExceeded("render: the encoded image has " +
                               std::to_string(bytes.size() >> 20) +
                               " MiB, more than a reply may carry; ask for PNG or a smaller size");
}

}  // namespace

namespace internal {

Status InField(const std::string& field, const Status& st) {
  if (st.ok()) return st;
  return Status(st.code(), field + ": " + st.message());
}

Result<std::vector<uint8_t>> DecodeRgb8(const std::string& bytes, uint32_t width, uint32_t height,
                                        const std::string& what) {
  auto decoded = formats::DecodeImage(bytes, what, formats::ImageMode::kColour);
  // Stored photos were checked when they were ingested: one that does not decode now is damage.
  if (!decoded.ok()) return Status::Corruption(decoded.status().message());
  const cv::Mat& bgr = *decoded;
  if (static_cast<uint32_t>(bgr.cols) != width || static_cast<uint32_t>(bgr.rows) != height) {
    return Status::Corruption(what + ": the image is " + std::to_string(bgr.cols) + "x" +
                              std::to_string(bgr.rows) + ", its camera " + std::to_string(width) +
                              "x" + std::to_string(height));
  }
  std::vector<uint8_t> rgb(size_t{width} * height * 3);
  for (int y = 0; y < bgr.rows; ++y) {
    const cv::Vec3b* row = bgr.ptr<cv::Vec3b>(y);
    uint8_t* out = &rgb[size_t(y) * width * 3];
    for (int x = 0; x < bgr.cols; ++x) {
      out[3 * x] = row[x][2], out[3 * x + 1] = row[x][1], out[3 * x + 2] = row[x][0];
    }
  }
  return rgb;
}

}  // namespace internal

using internal::DecodeRgb8;
using internal::InField;

Status CheckPhoto(const Photo& photo) {
  const std::string what = "photo of camera " + std::to_string(photo.camera.id);
  HVDB_RETURN_IF_ERROR(InField(what, CameraFromInfo(photo.camera).Validate()));
  HVDB_RETURN_IF_ERROR(ValidatePhoto(photo));  // storage's checks (the billboard's among them)
  auto rgb = DecodeRgb8(photo.image, photo.camera.width, photo.camera.height, what);
  if (!rgb.ok()) return Status::InvalidArgument(rgb.status().message());
  if (photo.billboard.scale != 0) {
    auto board = DecodeBillboard(photo, *rgb, what);
    if (!board.ok()) return board.status();
  }
  return Status::OK();
}

Camera CameraFromInfo(const CameraInfo& info) {
  Camera c;
  c.width = info.width;
  c.height = info.height;
  c.fx = info.fx;
  c.fy = info.fy;
  c.cx = info.cx;
  c.cy = info.cy;
  c.distortion = info.distortion;
  c.world_from_camera = info.world_from_camera;
  return c;
}

Result<Camera> ViewCamera(const View& view, const DatasetInfo& info, const std::string& field) {
  if (const auto* c = std::get_if<CameraInfo>(&view)) return CameraFromInfo(*c);
  if (const auto* d = std::get_if<DatasetCameraView>(&view)) {
    for (const CameraInfo& c : info.cameras) {
      if (c.id == d->id) return CameraFromInfo(c);
    }
    return Invalid(field + ".dataset_camera",
                   "dataset '" + info.name + "' has no camera " + std::to_string(d->id));
  }
  const LookAtView& l = std::get<LookAtView>(view);
  if (!(l.fov_y_deg > 0 && l.fov_y_deg < 180)) {
    return Invalid(field + ".look_at.fov_y_deg", "must be in (0, 180) degrees");
  }
  const std::array<double, 3>& eye = l.eye;
  const std::array<double, 3>& target = l.target;
  const std::array<double, 3> up = l.up.value_or(std::array<double, 3>{0, 1, 0});
  // Said here in the request's words: LookAt leaves such a camera without a pose, which
  // Validate would report as a bad pose matrix.
  const double dx = target[0] - eye[0], dy = target[1] - eye[1], dz = target[2] - eye[2];
  if (dx == 0 && dy == 0 && dz == 0) {
    return Invalid(field + ".look_at", "eye and target are the same point: the camera "
                                       "looks nowhere");
  }
  const double cx = dy * up[2] - dz * up[1], cy = dz * up[0] - dx * up[2],
               cz = dx * up[1] - dy * up[0];
  if (cx == 0 && cy == 0 && cz == 0) {
    return Invalid(field + ".look_at.up", "is parallel to the view direction (or zero): "
                                          "give an up that is not");
  }
  return Camera::LookAt(eye, target, up, l.fov_y_deg, l.width, l.height);
}

Result<std::unique_ptr<RenderJob>> RenderJob::Create(std::shared_ptr<Dataset> dataset,
                                                     const RenderRequest& r,
                                                     const RenderLimits& limits) {
  std::unique_ptr<RenderJob> job(new RenderJob());
  const DatasetInfo info = dataset->Info();
  job->dataset_ = std::move(dataset);
  job->limits_ = limits;
  // The shape (known renderer, format and mode values; counts of background, highlight_color,
  // shadow_light and of a look-at's vectors) is the request's type's: the protocol's
  // render_convert.h checks it where a wire message is decoded.
  job->kind_ = r.renderer;
  job->format_ = r.format;
  const bool video = r.format == ImageFormat::kMp4 || r.format == ImageFormat::kWebm;
  if (video && r.path.empty()) {
    return Invalid("render.path", "a video (format MP4 or WebM) needs a camera path with at "
                                  "least one view; it has none");
  }
  RenderOptions& o = job->options_;
  // Unset means kVisibility for the points (and the depth under a texture).
  o.mode = r.mode.value_or(Mode::kVisibility);
  // Storage's rule, the one every query follows: 0 .. the dataset's coarsest level.
  HVDB_RETURN_IF_ERROR(job->dataset_->CheckLod(r.lod));
  job->query_.lod = static_cast<int>(r.lod);
  job->query_.temporal_lod = !r.no_temporal_lod;
  job->query_.label_mask = r.label_mask;
  job->highlight_mask_ = r.highlight_mask;
  if (r.highlight_color) {
    for (size_t i = 0; i < 4; ++i) {
      const float v = (*r.highlight_color)[i];
      if (!(v >= 0.f && v <= 1.f)) {
        return Invalid("render.highlight_color", "values must be in [0, 1], got " + std::to_string(v));
      }
      job->highlight_[i] = v;
    }
  }
  if (r.background) o.background = *r.background;
  if (r.depth_threshold != 0) o.depth_threshold = r.depth_threshold;
  if (r.cutoff_radius != 0) o.cutoff_radius = r.cutoff_radius;
  if ((r.width == 0) != (r.height == 0)) {
    return Invalid("render.width", "give width and height together, or neither");
  }
  o.width = r.width;
  o.height = r.height;
  if (r.view_dependent) {
    if (info.cameras.empty()) {
      return Invalid("render.view_dependent", "dataset '" + info.name + "' declares no cameras");
    }
    o.view_dependent = true;
    for (const CameraInfo& c : info.cameras)
      o.source_cameras.push_back({c.id, c.world_from_camera});
  }
  if (r.shadow_light) {
    job->shadow_ = true;
    job->shadow_opts_.light = *r.shadow_light;
    job->shadow_opts_.directional = r.shadow_directional;
    job->shadow_opts_.caster_bit = r.shadow_casters;
    if (r.shadow_strength != 0) job->shadow_opts_.strength = r.shadow_strength;
    if (r.shadow_map_size != 0) job->shadow_opts_.map_size = r.shadow_map_size;
    HVDB_RETURN_IF_ERROR(CheckShadowOptions(job->shadow_opts_));
  } else if (r.shadow_directional || r.shadow_casters != 0 || r.shadow_strength != 0 ||
             r.shadow_map_size != 0) {
    return Invalid("render.shadow_light", "shadow options were given without a light: give "
                                          "shadow_light (3 values)");
  }
  const bool texture = r.texture.value_or(false), billboards = r.billboards.value_or(false);
  if (texture && !r.path.empty()) {
    return Invalid("render.texture", "textures a single view of one frame, not a sequence");
  }
  if (billboards && !r.path.empty()) {
    return Invalid("render.billboards", "draws a single view of one frame, not a sequence");
  }
  // Billboards take precedence over texture; any of the three given and neither true: the
  // points; none given: auto (per image, ResolveColour).
  if (billboards) {
    job->colour_ = Colour::kBillboards;
  } else if (texture) {
    job->colour_ = Colour::kTexture;
  } else if (r.mode || r.texture || r.billboards) {
    job->colour_ = Colour::kPoints;
  }
  if (r.mode == Mode::kGaussian) {
    if (texture || billboards) {
      return Invalid("render.mode", "gaussian draws the splats' own colours; texture and "
                                    "billboards draw the photos: give one of them");
    }
    job->colour_ = Colour::kGaussian;
  }
  // A Gaussian-splat dataset is drawn as 3DGS draws it unless the request says otherwise.
  job->gaussian_ = job->colour_ == Colour::kGaussian ||
                   (job->colour_ == Colour::kAuto && info.gaussians);
  if (job->gaussian_ && job->shadow_) {
    return Invalid("render.shadow_light", "shadows darken the point modes' images by their "
                                          "depth; gaussian mode has none (give mode "
                                          "visibility or probabilistic)");
  }
  job->sequence_ = !r.path.empty();
  // Views.
  if (!r.path.empty()) {
    if (r.view) return Invalid("render.view", "give a view or a path, not both");
    if (static_cast<uint64_t>(r.path.size()) > limits.max_images) {
      return Status::LimitExceeded("render.path: " + std::to_string(r.path.size()) +
                                   " images; at most " + std::to_string(limits.max_images) +
                                   " per request");
    }
    for (size_t i = 0; i < r.path.size(); ++i) {
      std::string field = "render.path[" + std::to_string(i) + "]";
      HVDB_ASSIGN_OR_RETURN(Camera c, ViewCamera(r.path[i], info, field));
      job->views_.push_back(c);
    }
  } else {
    if (!r.view) return Invalid("render.view", "required (or a path for a sequence)");
    HVDB_ASSIGN_OR_RETURN(Camera c, ViewCamera(*r.view, info, "render.view"));
    job->views_.push_back(c);
  }
  for (size_t i = 0; i < job->views_.size(); ++i) {
    std::string field =
        !r.path.empty() ? "render.path[" + std::to_string(i) + "]" : std::string("render.view");
    HVDB_RETURN_IF_ERROR(InField(field, CheckRenderArguments(job->views_[i], o)));
  }
  if (video) {
    if (r.video_fps != 0) job->video_fps_ = r.video_fps;
    if (!(job->video_fps_ > 0 && job->video_fps_ <= 1000)) {
      return Invalid("render.video_fps", "must be in (0, 1000] frames a second (0: 30)");
    }
    // One size for the whole video, even on both sides (YUV 4:2:0).
    const uint32_t w0 = o.width != 0 ? o.width : job->views_[0].width;
    const uint32_t h0 = o.height != 0 ? o.height : job->views_[0].height;
    for (size_t i = 0; i < job->views_.size(); ++i) {
      const uint32_t w = o.width != 0 ? o.width : job->views_[i].width;
      const uint32_t h = o.height != 0 ? o.height : job->views_[i].height;
      const std::string field = "render.path[" + std::to_string(i) + "]";
      if (w != w0 || h != h0) {
        return Invalid(field, "is " + std::to_string(w) + "x" + std::to_string(h) +
                                  ", the video's first view " + std::to_string(w0) + "x" +
                                  std::to_string(h0) + ": give every view one size (or width "
                                  "and height)");
      }
      if (w % 2 != 0 || h % 2 != 0) {
        return Invalid(field, "a video needs an even width and height (YUV 4:2:0), got " +
                                  std::to_string(w) + "x" + std::to_string(h));
      }
    }
  } else if (r.video_fps != 0) {
    return Invalid("render.video_fps", "is for videos: set format to IMAGE_MP4 or IMAGE_WEBM");
  }
  // Regions.
  if (!r.frames.empty()) {
    if (r.frames.size() != r.path.size()) {
      return Invalid("render.frames", "needs one frame per view of the path (" +
                                          std::to_string(r.path.size()) + "), got " +
                                          std::to_string(r.frames.size()));
    }
    Window space;
    space.lo = {-1e30, -1e30, -1e30, 0};
    space.hi = {1e30, 1e30, 1e30, 0};
    if (r.region) {
      if (!std::holds_alternative<Window>(*r.region)) {
        return Invalid("render.frames",
                       "frames go with a window region (its x y z bounds), "
                       "not a slice");
      }
      space = std::get<Window>(*r.region);
    }
    for (size_t i = 0; i < r.frames.size(); ++i) {
      const uint32_t f = r.frames[i];
      // A frame past the dataset's end would render an empty image without a word.
      if (f >= info.frame_count) {
        return Invalid("render.frames[" + std::to_string(i) + "]",
                       "frame " + std::to_string(f) + " is past the dataset's frames (" +
                           std::to_string(info.frame_count) + ": 0 to " +
                           std::to_string(info.frame_count == 0 ? 0 : info.frame_count - 1) + ")");
      }
      Window w = space;
      w.lo[3] = w.hi[3] = f / info.fps;  // frame f is at t = f / fps
      job->regions_.push_back(w);
    }
  } else {
    if (!r.region) return Invalid("render.region", "required (or frames for a sequence)");
    job->regions_.push_back(*r.region);
  }
  // Replies.
  if (r.progressive) {
    if (!r.path.empty()) {
      return Invalid("render.progressive", "is for a single view, not a sequence (path)");
    }
    // About 1/16 of the points: levels hold 2^-i of the samples (thesis 8.4).
    int preview = std::min(job->query_.lod + 4, job->dataset_->lod_levels());
    if (preview > job->query_.lod) job->steps_.push_back({0, 0, preview, true});
  }
  for (size_t i = 0; i < job->views_.size(); ++i) {
    job->steps_.push_back({i, job->regions_.size() == 1 ? 0 : i, job->query_.lod, false});
  }
  // The images' buffers, reserved before any is made: the largest view's pixels at
  // kImageBytesPerPixel (the float image and depth, the renderer's accumulators, the encoded
  // copy; a textured render's sources are reserved as they are decoded).
  uint64_t pixels = 0;
  for (const Camera& v : job->views_) {
    const uint64_t w = job->options_.width != 0 ? job->options_.width : v.width;
    const uint64_t h = job->options_.height != 0 ? job->options_.height : v.height;
    pixels = std::max(pixels, w * h);
  }
  job->image_lease_ = limits.job.Lease();
  HVDB_RETURN_IF_ERROR(job->image_lease_.Reserve(
      pixels * kImageBytesPerPixel, "render: an image of " + std::to_string(pixels) + " pixels"));
  return job;
}

RenderJob::~RenderJob() {
  stop_ = true;  // a query in flight stops at its next batch
  if (prefetch_.valid()) prefetch_.wait();
  EglGaussianRasterizer::Recycle(std::move(egl_));  // its context serves the next job
}

Status RenderJob::Query(const Step& step, const std::atomic<bool>* cancelled,
                        Points* out) const {
  out->points.clear();
  out->region = SIZE_MAX;
  if (out->lease.held() == 0) out->lease = limits_.job.Lease();
  QueryOptions q = query_;
  q.lod = step.lod;
  HVDB_ASSIGN_OR_RETURN(auto cursor, dataset_->Query(regions_[step.region], q));
  // The cursor writes straight into the points' buffer (render/point_buffer.h says why), a
  // read of up to kRead points at a time: at least a bucket level, which a read never splits
  // (2 * block / 64 points; blocks are at most 1 MiB).
  constexpr size_t kRead = size_t{1} << 15;  // 2 MiB
  static_assert(kRead >= 2 * (size_t{1} << 20) / sizeof(Point));
  Batch info;
  for (;;) {
    if ((cancelled != nullptr && *cancelled) || stop_) {
      return Status::Cancelled("render cancelled");
    }
    HVDB_RETURN_IF_ERROR(limits_.job.CheckTime("render"));
    PointBuffer& pts = out->points;
    // The mapping grows ahead by doubling (untouched pages cost nothing); what the points
    // take is reserved from the job's budget as they arrive, a read at a time.
    if (pts.capacity() - pts.size() < kRead) {
      pts.Reserve(std::max(pts.size() + kRead, 2 * pts.capacity()));
    }
    Point* at = pts.Append(kRead);
    size_t n = 0;
    Result<bool> more = cursor->NextInto(at, kRead, &n, &info);
    pts.Shrink(kRead - n);
    if (!more.ok()) return more.status();
    if (pts.size() > limits_.max_points) {
      pts.clear();
      return Status::LimitExceeded("render: the region holds more than " +
                                   std::to_string(limits_.max_points) +
                                   " points, the limit per image; use a coarser lod "
                                   "or a smaller region");
    }
    if (const uint64_t need = pts.size() * sizeof(Point); need > out->lease.held()) {
      Status st = out->lease.Reserve(need - out->lease.held(), "render: the region's points");
      if (!st.ok()) {
        pts.clear();
        return st;
      }
    }
    if (highlight_mask_ != 0 && !gaussian_) {
      // The overlay: selected points' colours blended toward the highlight colour (gaussian
      // mode blends the splats' records instead: MakeCloud).
      const float a = highlight_[3];
      for (Point* p = at; p != at + n; ++p) {
        if ((p->label & highlight_mask_) == 0) continue;
        uint8_t* c[3] = {&p->r, &p->g, &p->b};
        for (int k = 0; k < 3; ++k) {
          *c[k] = static_cast<uint8_t>(std::lround((1 - a) * *c[k] + a * 255.f * highlight_[static_cast<size_t>(k)]));
        }
      }
    }
    if (!more.value()) break;
  }
  if (gaussian_) HVDB_RETURN_IF_ERROR(MakeCloud(out));
  out->region = step.region;
  out->lod = step.lod;
  return Status::OK();
}

Status RenderJob::Load(size_t i, const std::atomic<bool>* cancelled) {
  const Step& step = steps_[i];
  if (!current_.Holds(step) && prefetch_.valid()) {
    Status st = prefetch_.get();
    if (next_.Holds(step) || !st.ok()) {
      HVDB_RETURN_IF_ERROR(st);
      std::swap(current_, next_);
    }
  }
  if (!current_.Holds(step)) HVDB_RETURN_IF_ERROR(Query(step, cancelled, &current_));
  // The pipeline: the next image's points are queried while this one is drawn and encoded.
  if (i + 1 < steps_.size() && !current_.Holds(steps_[i + 1]) && !prefetch_.valid()) {
    const Step next = steps_[i + 1];
    prefetch_ = std::async(std::launch::async,
                           [this, next, cancelled] { return Query(next, cancelled, &next_); });
  }
  return Status::OK();
}

Result<Image> RenderJob::RenderImage(size_t i, Renderer& renderer,
                                     const std::atomic<bool>* cancelled) {
  HVDB_RETURN_IF_ERROR(Draw(i, renderer, cancelled));
  return image_;
}

Status RenderJob::Draw(size_t i, Renderer& renderer, const std::atomic<bool>* cancelled) {
  if (i >= steps_.size()) return Status::InvalidArgument("render: no image " + std::to_string(i));
  HVDB_RETURN_IF_ERROR(Load(i, cancelled));
  if (cancelled != nullptr && *cancelled) return Status::Cancelled("render cancelled");
  RenderOptions o = options_;
  // At level i the sampling density falls by 2^i, so splats grow by 2^(i/2) (thesis 8.4).
  o.splat_scale = static_cast<float>(std::pow(2.0, steps_[i].lod / 2.0));
  const Camera& view = views_[steps_[i].view];
  if (steps_[i].preview) {
    // At half the size: a level 4 finer grows splats 4x, so at full size the preview would
    // cost as many fragments as the final image; the client scales it up meanwhile.
    uint32_t w = o.width != 0 ? o.width : view.width, h = o.height != 0 ? o.height : view.height;
    o.width = std::max(1u, w / 2);
    o.height = std::max(1u, h / 2);
  }
  // The billboards replace the points, which are then not drawn (their frame is all they are
  // needed for).
  HVDB_ASSIGN_OR_RETURN(const Colour colour, ResolveColour(i));
  gaussian_ms_ = -1;
  if (colour == Colour::kGaussian) {
    billboards_ms_ = -1;
    return DrawGaussians(view, o, renderer);
  }
  if (colour == Colour::kBillboards) {
    const auto t0 = std::chrono::steady_clock::now();
    HVDB_RETURN_IF_ERROR(Billboards(view, o));
    billboards_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  } else {
    billboards_ms_ = -1;
    HVDB_RETURN_IF_ERROR(renderer.RenderInto(current_.points, view, o, &image_));
    if (colour == Colour::kTexture) HVDB_RETURN_IF_ERROR(Texture(view, o, renderer));
  }
  // One pass over whichever renderer's image and depth (render/shadow.h).
  if (shadow_) HVDB_RETURN_IF_ERROR(ApplyShadows(current_.points, view, o, shadow_opts_, &image_));
  return Status::OK();
}

Result<uint32_t> RenderJob::SingleFrame(const std::string& field) const {
  const uint32_t frame = current_.points.front().frame;
  for (const Point& p : current_.points) {
    if (p.frame != frame) {
      return Invalid(field, "draws one frame; the region holds frames " + std::to_string(frame) +
                                " and " + std::to_string(p.frame));
    }
  }
  return frame;
}

Result<const std::vector<Photo>*> RenderJob::FramePhotos(uint32_t frame) {
  if (frame != photos_frame_) {
    photos_.clear();
    photos_frame_ = UINT32_MAX;
    HVDB_ASSIGN_OR_RETURN(photos_, dataset_->Photos(frame));
    photos_frame_ = frame;
  }
  return &photos_;
}

Result<RenderJob::Colour> RenderJob::ResolveColour(size_t i) {
  const char* points_mode = options_.mode == Mode::kProbabilistic ? "probabilistic" : "visibility";
  auto use = [&](Colour c, std::string why) {
    mode_used_ = c == Colour::kTexture      ? "textured"
                 : c == Colour::kBillboards ? "billboards"
                 : c == Colour::kGaussian   ? "gaussian"
                                            : points_mode;
    mode_choice_ = std::move(why);
    return c;
  };
  if (gaussian_) {
    return use(Colour::kGaussian, colour_ == Colour::kGaussian
                                      ? "asked for"
                                      : "auto: a Gaussian-splat dataset draws its splats as "
                                        "3DGS does");
  }
  // The progressive preview stays a plain point rendering: a quick look.
  if (steps_[i].preview) return use(Colour::kPoints, "a progressive preview draws the points");
  if (colour_ != Colour::kAuto) return use(colour_, "asked for");
  // Auto: the best picture the frame has (bench/README.md, "Novel views": textured beats the
  // points by ~3 dB on the SJTU stage, billboards texturing by ~6 dB where stored), when the
  // image is a single view of one frame, as texture and billboards need.
  if (sequence_) {
    return use(Colour::kPoints, "auto: a sequence draws the points (texture and billboards "
                                "draw a single view)");
  }
  if (highlight_mask_ != 0) {
    return use(Colour::kPoints, "auto: the selection overlay (highlight_mask) shows on the "
                                "points' colours");
  }
  if (current_.points.empty()) return use(Colour::kPoints, "auto: the region holds no points");
  const uint32_t frame = current_.points.front().frame;
  for (const Point& p : current_.points) {
    if (p.frame != frame) {
      return use(Colour::kPoints, "auto: the region holds several frames (texture and "
                                  "billboards draw one)");
    }
  }
  HVDB_ASSIGN_OR_RETURN(const std::vector<Photo>* photos, FramePhotos(frame));
  size_t boards = 0;
  for (const Photo& p : *photos) boards += p.billboard.scale > 0;
  const std::string of = " of frame " + std::to_string(frame);
  if (boards > 0) {
    return use(Colour::kBillboards, "auto: " + std::to_string(boards) + " billboards" + of);
  }
  if (!photos->empty()) {
    return use(Colour::kTexture, "auto: " + std::to_string(photos->size()) + " photos" + of);
  }
  return use(Colour::kPoints, "auto: no photos" + of);
}

Status RenderJob::Billboards(const Camera& view, const RenderOptions& o) {
  if (current_.points.empty()) return Status::OK();  // no frame in the region: nothing to draw
  HVDB_ASSIGN_OR_RETURN(const uint32_t frame, SingleFrame("render.billboards"));
  if (frame != boards_frame_) {
    boards_.clear();
    boards_frame_ = UINT32_MAX;
    HVDB_ASSIGN_OR_RETURN(const std::vector<Photo>* photos, FramePhotos(frame));
    for (const Photo& photo : *photos) {
      if (!(photo.billboard.scale > 0)) continue;
      const std::string what = "render.billboards: the billboard of camera " +
                               std::to_string(photo.camera.id) + " of frame " + std::to_string(frame);
      HVDB_RETURN_IF_ERROR(InField(what, CameraFromInfo(photo.camera).Validate()));
      HVDB_ASSIGN_OR_RETURN(std::vector<uint8_t> rgb,
                            DecodeRgb8(photo.image, photo.camera.width, photo.camera.height, what));
      auto board = DecodeBillboard(photo, rgb, what);
      if (!board.ok()) return Status::Corruption(board.status().message());
      boards_.push_back(std::move(board).value());
    }
    if (boards_.empty()) {
      return Status::NotFound("render.billboards: dataset '" + dataset_->Info().name +
                              "' has no billboards of frame " + std::to_string(frame) +
                              " (hvdb-ingest run --filter billboard stores them; render without "
                              "billboards to see the points)");
    }
    boards_frame_ = frame;
  }
  // The view at the size asked for (RenderOptions width/height, else its own).
  const uint32_t w = o.width != 0 ? o.width : view.width, h = o.height != 0 ? o.height : view.height;
  const Camera drawn = w == view.width && h == view.height ? view : view.Resized(w, h);
  BillboardDrawOptions bo;
  bo.background = o.background;
  HVDB_RETURN_IF_ERROR(DrawBillboardDepth(drawn, boards_, bo, &image_));
  std::vector<TextureView> tv;
  for (const BillboardSource& b : boards_) tv.push_back({b.camera, b.rgb, b.depth, 0, 0});
  TextureOptions to;
  to.background = o.background;
  return ProjectiveTexture(drawn, tv, to, &image_);
}

Result<RenderReply> RenderJob::Render(size_t i, Renderer& renderer,
                                      const std::atomic<bool>* cancelled) {
  HVDB_RETURN_IF_ERROR(limits_.job.CheckTime("render: image " + std::to_string(i + 1) + " of " +
                                             std::to_string(steps_.size())));
  HVDB_RETURN_IF_ERROR(Draw(i, renderer, cancelled));
  const Image& img = image_;
  RenderReply reply;
  if (format_ == ImageFormat::kMp4 || format_ == ImageFormat::kWebm) {
    HVDB_RETURN_IF_ERROR(EncodeVideoFrame(i, &reply));
  } else if (format_ == ImageFormat::kExr) {
    HVDB_ASSIGN_OR_RETURN(std::string bytes, EncodeExr(img));
    HVDB_RETURN_IF_ERROR(CheckReplySize(bytes));
    reply.exr = std::move(bytes);
  } else {
    HVDB_ASSIGN_OR_RETURN(std::string bytes, EncodePng(img));
    HVDB_RETURN_IF_ERROR(CheckReplySize(bytes));
    reply.png = std::move(bytes);
  }
  reply.images = static_cast<uint32_t>(steps_.size());
  reply.width = img.width;
  reply.height = img.height;
  reply.renderer_used = renderer.name();
  reply.points = current_.points.size();
  reply.render_ms = billboards_ms_ >= 0 ? billboards_ms_ : renderer.last_stats().milliseconds;
  if (gaussian_ms_ >= 0) {
    reply.renderer_used = gaussian_used_;
    reply.renderer_choice = gaussian_choice_;
    reply.render_ms = gaussian_ms_;
  }
  reply.index = static_cast<uint32_t>(steps_[i].view);
  reply.preview = steps_[i].preview;
  reply.lod = static_cast<uint32_t>(steps_[i].lod);
  reply.last = i + 1 == steps_.size();
  reply.mode_used = mode_used_;
  reply.mode_choice = mode_choice_;
  return reply;
}

Status RenderJob::EncodeVideoFrame(size_t i, RenderReply* reply) {
  if (video_ == nullptr) {
    const VideoContainer c =
        format_ == ImageFormat::kMp4 ? VideoContainer::kMp4 : VideoContainer::kWebm;
    HVDB_ASSIGN_OR_RETURN(video_, VideoEncoder::Create(c, image_.width, image_.height, video_fps_));
  }
  if (video_->frames() != i) {
    return Status::InvalidArgument("render: a video's images go in order; image " +
                                   std::to_string(i) + " came after " +
                                   std::to_string(video_->frames()));
  }
  HVDB_RETURN_IF_ERROR(video_->Add(image_));
  reply->video_codec = video_->codec();
  if (i + 1 < steps_.size()) return Status::OK();
  HVDB_ASSIGN_OR_RETURN(std::string bytes, video_->Finish());
  video_.reset();
  if (bytes.size() > kMaxEncodedImage) {
    return Status::LimitExceeded("render: the video has " + std::to_string(bytes.size() >> 20) +
                                 " MiB, more than a reply may carry; render fewer or smaller "
                                 "images");
  }
  reply->video = std::move(bytes);
  return Status::OK();
}

Status ParseCameraPath(const std::string& json_text, RenderRequest* request) {
  using nlohmann::json;
  json doc = json::parse(json_text, nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded()) return Invalid("camera path", "not valid JSON");
  if (!doc.is_object() || !doc.contains("cameras") || !doc["cameras"].is_array()) {
    return Invalid("camera path", "expected {\"cameras\": [...]}");
  }
  request->path.clear();
  request->frames.clear();
  const json& cams = doc["cameras"];
  size_t with_frame = 0;
  auto numbers = [](const json& j, size_t n, std::vector<double>* out) {
    if (!j.is_array() || j.size() != n) return false;
    out->clear();
    for (const json& v : j) {
      if (!v.is_number()) return false;
      out->push_back(v.get<double>());
    }
    return true;
  };
  auto three = [](const std::vector<double>& a) { return std::array<double, 3>{a[0], a[1], a[2]}; };
  for (size_t i = 0; i < cams.size(); ++i) {
    const json& e = cams[i];
    std::string where = "camera path entry " + std::to_string(i);
    if (!e.is_object()) return Invalid(where, "must be an object");
    std::vector<double> a;
    try {
      if (e.contains("look_at")) {
        const json& l = e["look_at"];
        LookAtView o;
        if (!numbers(l.value("eye", json()), 3, &a))
          return Invalid(where, "look_at.eye: 3 numbers");
        o.eye = three(a);
        if (!numbers(l.value("target", json()), 3, &a)) {
          return Invalid(where, "look_at.target: 3 numbers");
        }
        o.target = three(a);
        if (l.contains("up")) {
          if (!numbers(l["up"], 3, &a)) return Invalid(where, "look_at.up: 3 numbers");
          o.up = three(a);
        }
        o.fov_y_deg = l.value("fov_y_deg", 50.0);
        o.width = l.value("width", 1024u);
        o.height = l.value("height", 768u);
        request->path.push_back(o);
      } else if (e.contains("camera")) {
        const json& c = e["camera"];
        CameraInfo o;
        o.width = c.at("width").get<uint32_t>();
        o.height = c.at("height").get<uint32_t>();
        o.fx = c.at("fx").get<double>();
        o.fy = c.at("fy").get<double>();
        o.cx = c.at("cx").get<double>();
        o.cy = c.at("cy").get<double>();
        if (c.contains("distortion")) {
          if (!numbers(c["distortion"], 5, &a))
            return Invalid(where, "camera.distortion: 5 numbers");
          std::copy(a.begin(), a.end(), o.distortion.begin());
        }
        if (!numbers(c.value("world_from_camera", json()), 16, &a)) {
          return Invalid(where, "camera.world_from_camera: 16 numbers, row-major");
        }
        std::copy(a.begin(), a.end(), o.world_from_camera.begin());
        request->path.push_back(o);
      } else if (e.contains("dataset_camera")) {
        request->path.push_back(DatasetCameraView{e["dataset_camera"].get<uint32_t>()});
      } else {
        return Invalid(where, "needs look_at, camera or dataset_camera");
      }
      if (e.contains("frame")) {
        // get<uint32_t> would wrap -1 and cut 10^12 to another frame: checked as a number.
        const json& f = e["frame"];
        if (!f.is_number_integer() || (f.is_number_integer() && !f.is_number_unsigned() &&
                                       f.get<int64_t>() < 0) ||
            (f.is_number_unsigned() && f.get<uint64_t>() > UINT32_MAX)) {
          return Invalid(where, "frame: a frame number, 0 to 4294967295 (got " + f.dump() + ")");
        }
        request->frames.push_back(f.get<uint32_t>());
        ++with_frame;
      }
    } catch (const json::exception& ex) {
      return Invalid(where, ex.what());
    }
  }
  if (with_frame != 0 && with_frame != cams.size()) {
    return Invalid("camera path", "either every entry has a frame or none does");
  }
  return Status::OK();
}

}  // namespace hvdb::render
