// Render jobs in gaussian mode (render/job.h, Colour::kGaussian): the region's points and their
// Gaussian records as a 3DGS cloud, drawn by the CPU rasteriser (gaussian_raster.h).
#include <algorithm>
#include <limits>
#include <thread>

#include "formats/gaussian_points.h"
#include "render/job.h"

namespace hvdb::render {

Status RenderJob::MakeCloud(Points* out) const {
  // The records and the cloud made of them, reserved at the highest degree before either is,
  // with the reader's per-point bookkeeping (ids, order: ~32 bytes a point); the previous
  // region's cloud is given back first.
  const uint64_t n = out->points.size();
  out->cloud = {};
  out->cloud_lease = limits_.job.Lease();
  HVDB_RETURN_IF_ERROR(out->cloud_lease.Reserve(
      n * (2 * sizeof(float) * GaussianRecordFloats(3) + 32), "render: the splats' Gaussian records"));
  HVDB_ASSIGN_OR_RETURN(GaussianColumns records, dataset_->ReadGaussians(out->points));
  if (highlight_mask_ != 0) {
    // The overlay on the splats: the base colour blended toward the highlight, the
    // view-dependent part faded by as much.
    const float a = highlight_[3];
    const size_t stride = records.stride();
    for (size_t i = 0; i < n; ++i) {
      if ((out->points[i].label & highlight_mask_) == 0) continue;
      float* rec = records.record(i);
      for (size_t c = 0; c < 3; ++c) {
        const double target = (highlight_[c] - 0.5) / formats::kShC0;
        rec[kGsDc + c] = static_cast<float>((1 - a) * rec[kGsDc + c] + a * target);
      }
      for (size_t k = kGsRest; k < stride; ++k) rec[k] *= 1 - a;
    }
  }
  out->cloud = formats::PointsToCloud(out->points, records);
  return Status::OK();
}

Status RenderJob::DrawGaussians(const Camera& view, const RenderOptions& o,
                                const Renderer& renderer) {
  const uint32_t w = o.width != 0 ? o.width : view.width, h = o.height != 0 ? o.height : view.height;
  const Camera drawn = w == view.width && h == view.height ? view : view.Resized(w, h);
  // The rasteriser composites in the cloud's own (display) values, as 3DGS does; the job's
  // images hold linear light, so its values are linearised here and the PNG's encoder takes
  // them back to what the rasteriser computed, clamped and rounded to 8 bits.
  const std::array<float, 4>& bg = o.background;
  GaussianRenderOptions go;
  for (size_t c = 0; c < 3; ++c) go.background[c] = LinearToSrgb(bg[c]) * bg[3];
  // The GPU's rasteriser where the job draws points with EGL; the CPU's otherwise, and where
  // the GPU's cannot take the cloud (a driver's storage-buffer bound).
  if (renderer.kind() == RendererKind::kEgl && !egl_tried_) {
    egl_tried_ = true;
    auto made = EglGaussianRasterizer::Take();
    if (made.ok()) {
      egl_ = std::move(made).value();
    } else {
      egl_error_ = made.status().message();
    }
  }
  Status by_gpu = Status::Unsupported(egl_error_);
  if (egl_ != nullptr) {
    by_gpu = egl_->Render(current_.cloud, drawn, go, &gimg_, &gaussian_stats_);
    // A bad camera or cloud is the request's error; anything the GPU could not do, the CPU
    // draws instead.
    if (by_gpu.code() == StatusCode::kInvalidArgument) return by_gpu;
  }
  if (by_gpu.ok()) {
    gaussian_used_ = egl_->name() + ": 3DGS rasteriser";
    gaussian_choice_ = "gaussian mode draws with the GPU's 3DGS rasteriser, as " +
                       renderer.name() + " draws the point modes";
  } else {
    HVDB_RETURN_IF_ERROR(rasteriser_.Render(current_.cloud, drawn, go, &gimg_, &gaussian_stats_));
    gaussian_used_ = "cpu: 3DGS rasteriser (" +
                     std::to_string(std::max(1u, std::thread::hardware_concurrency())) +
                     " threads)";
    gaussian_choice_ = renderer.kind() != RendererKind::kEgl
                           ? "gaussian mode draws with the CPU 3DGS rasteriser, as " +
                                 renderer.name() + " draws the point modes"
                           : "the CPU 3DGS rasteriser, the GPU's refusing: " + by_gpu.message();
  }
  gaussian_ms_ = gaussian_stats_.milliseconds;
  const size_t px = size_t{w} * h;
  image_.width = w;
  image_.height = h;
  image_.rgba.resize(4 * px);
  image_.coverage.resize(px);
  image_.depth.assign(px, std::numeric_limits<float>::infinity());
  for (size_t i = 0; i < px; ++i) {
    const float alpha = gimg_.alpha[i], t = 1 - alpha;
    const float a = alpha + t * bg[3];  // the background's own alpha behind what is left
    const float inv = a > 0 ? 1 / a : 0;
    for (size_t c = 0; c < 3; ++c) {
      const float straight = std::clamp(gimg_.rgb[3 * i + c] * inv, 0.f, 1.f);
      image_.rgba[4 * i + c] = SrgbToLinear(straight) * a;
    }
    image_.rgba[4 * i + 3] = a;
    image_.coverage[i] = alpha;
  }
  return Status::OK();
}

}  // namespace hvdb::render
