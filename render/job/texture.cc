// Render jobs in textured mode (render/job.h, Colour::kTexture; thesis 6.3): the points give
// the view its depth, the frame's photos its colour (projective_texture.h), each photo where
// its camera sees the surface, which the depth of the points drawn from that camera decides.
#include <algorithm>
#include <cmath>
#include <exception>
#include <thread>

#include "render/job.h"
#include "render/job/internal.h"
#include "render/projective_texture.h"
#include "render/splat.h"

namespace hvdb::render {

namespace internal {

// A source's depth only decides visibility, within a tolerance, over a 3x3 neighbourhood
// (projective_texture.cc), so it needs pixels no finer than the splats that make the surface.
// The depth is drawn at 1/k of the camera's size, k the largest power of two up to kMaxScale
// for which the median splat's narrower standard deviation (its geometry, without the
// antialiasing filter) still spans a depth pixel. Measured with view-bench on the SJTU stage
// (1080p, stride 2: that median is 2.5 px): k = 2 changed the six held-out cameras' PSNR by
// -0.06..+0.01 dB and took 9.9 -> 6.3 s a render; k = 4 (0.6 px) lost up to 0.11 dB. The
// generated recordings of the tests (160x120, 1.1 px) keep k = 1: there a half-size depth had
// cost 3.4 dB (26.2 instead of 29.6 dB).
constexpr uint32_t kMaxScale = 4;
constexpr float kMinSigma = 1.0f;
constexpr size_t kSample = 4096;  // points looked at (evenly spaced through the frame)

uint32_t SourceDepthScale(std::span<const Point> points, const Camera& camera,
                          const RenderOptions& options) {
  RenderOptions o = options;
  o.width = o.height = 0;  // the camera's own pixels, whatever size the view is drawn at
  auto view = PrepareView(camera, o);
  if (!view.ok() || points.empty()) return 1;
  const std::vector<float> weights;
  std::vector<float> sigma;
  const size_t step = std::max<size_t>(1, points.size() / kSample);
  for (size_t i = 0; i < points.size(); i += step) {
    Splat s;
    if (!ProjectSplat(points[i], *view, weights, &s)) continue;
    // The conic is the screen covariance's inverse: its larger eigenvalue is 1 / the narrower
    // variance, which includes the filter.
    const float mean = 0.5f * (s.ca + s.cc), d = 0.5f * (s.ca - s.cc);
    const float largest = mean + std::sqrt(d * d + s.cb * s.cb);
    if (!(largest > 0)) continue;
    sigma.push_back(std::sqrt(std::max(0.0f, 1.0f / largest - view->filter)));
  }
  if (sigma.empty()) return 1;
  const auto mid = sigma.begin() + static_cast<std::ptrdiff_t>(sigma.size() / 2);
  std::nth_element(sigma.begin(), mid, sigma.end());
  const float median = *mid;
  uint32_t k = 1;
  while (2 * k <= kMaxScale && median / static_cast<float>(2 * k) >= kMinSigma &&
         camera.width / (2 * k) >= 1 && camera.height / (2 * k) >= 1) {
    k *= 2;
  }
  return k;
}

}  // namespace internal

using internal::DecodeRgb8;
using internal::InField;

Status RenderJob::Texture(const Camera& view, const RenderOptions& o, Renderer& renderer) {
  if (current_.points.empty()) return Status::OK();  // nothing drawn, nothing to colour
  HVDB_ASSIGN_OR_RETURN(const uint32_t frame, SingleFrame("render.texture"));
  if (frame != textured_frame_ || current_.lod != textured_lod_) {
    sources_.clear();
    textured_frame_ = UINT32_MAX;  // until every source is ready: a failure is not cached
    HVDB_ASSIGN_OR_RETURN(const std::vector<Photo>* photos, FramePhotos(frame));
    if (photos->empty()) {
      return Status::NotFound("render.texture: dataset '" + dataset_->Info().name +
                              "' has no photos of frame " + std::to_string(frame) +
                              " (hvdb-ingest stores the colour cameras' images; render without "
                              "texture to see the points)");
    }
    // The photos are decoded in parallel (a 1080p PNG takes ~50 ms, a core's whole time);
    // the renders below use every core each.
    sources_.resize(photos->size());
    std::vector<Status> decoded(photos->size());
    internal::ParallelFor(photos->size(), std::max(1u, std::thread::hardware_concurrency()),
                          [&](size_t i) {
      const Photo& photo = (*photos)[i];
      Source& src = sources_[i];
      src.camera = CameraFromInfo(photo.camera);
      const std::string what = "render.texture: the photo of camera " +
                               std::to_string(photo.camera.id) + " of frame " +
                               std::to_string(frame);
      decoded[i] = InField(what, src.camera.Validate());
      if (!decoded[i].ok()) return;
      // Nothing may leave a pool thread (it would end the server): failures become statuses.
      try {
        auto rgb = DecodeRgb8(photo.image, src.camera.width, src.camera.height, what);
        if (rgb.ok()) {
          src.rgb = std::move(rgb).value();
        } else {
          decoded[i] = rgb.status();
        }
      } catch (const std::exception& e) {
        decoded[i] = Status::Internal(what + ": " + e.what());
      }
    });
    for (size_t i = 0; i < sources_.size(); ++i) {
      HVDB_RETURN_IF_ERROR(decoded[i]);
      Source& src = sources_[i];
      // What this camera sees: the depth of the same points from its pose, at a size that
      // resolves their splats (SourceDepthScale).
      RenderOptions so = o;
      so.view_dependent = false;
      so.depth_only = true;  // visibility is all the texturing takes from this render
      const uint32_t k = internal::SourceDepthScale(current_.points, src.camera, so);
      so.width = std::max(1u, src.camera.width / k);
      so.height = std::max(1u, src.camera.height / k);
      HVDB_RETURN_IF_ERROR(renderer.RenderInto(current_.points, src.camera, so, &src.seen));
    }
    textured_frame_ = frame;
    textured_lod_ = current_.lod;
  }
  std::vector<TextureView> tv;
  for (const Source& src : sources_) {
    tv.push_back({src.camera, src.rgb, src.seen.depth, src.seen.width, src.seen.height});
  }
  TextureOptions to;
  to.background = o.background;
  const Camera drawn = image_.width == view.width && image_.height == view.height
                           ? view
                           : view.Resized(image_.width, image_.height);
  return ProjectiveTexture(drawn, tv, to, &image_);
}


}  // namespace hvdb::render
