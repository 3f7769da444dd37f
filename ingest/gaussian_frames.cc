// Frames of Gaussian video fitted in order (gaussian_frames.h).
#include "ingest/gaussian_frames.h"

#include <algorithm>
#include <string>

#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::ingest {

namespace {

// One colour photo as a training view.
Result<FitView> MakeView(const CameraModel& model, const cv::Mat& bgr, const std::string& path,
                         int scale) {
  if (bgr.empty()) {
    return Status::InvalidArgument("camera " + model.name + ": no colour photo (" + path +
                                   "); --gaussians fits to every colour camera's photo");
  }
  if (bgr.cols != model.size.width || bgr.rows != model.size.height || bgr.type() != CV_8UC3) {
    return Status::InvalidArgument(path + ": the photo is " + std::to_string(bgr.cols) + "x" +
                                   std::to_string(bgr.rows) + ", camera " + model.name +
                                   " is calibrated for " + std::to_string(model.size.width) + "x" +
                                   std::to_string(model.size.height));
  }
  bool distorted = false;
  for (double d : model.dist) distorted = distorted || d != 0;
  cv::Mat pinhole;
  if (distorted) {
    cv::undistort(bgr, pinhole, cv::Mat(model.K), model.dist);
  } else {
    pinhole = bgr;
  }
  const int w = std::max(1, bgr.cols / scale), h = std::max(1, bgr.rows / scale);
  cv::Mat small = pinhole;
  if (w != bgr.cols || h != bgr.rows)
    cv::resize(pinhole, small, cv::Size(w, h), 0, 0, cv::INTER_AREA);
  FitView v;
  v.camera = model.ToRenderCamera();
  v.camera.distortion = {};
  v.camera = v.camera.Resized(static_cast<uint32_t>(w), static_cast<uint32_t>(h));
  v.rgb.resize(3u * static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y) {
    const auto* row = small.ptr<cv::Vec3b>(y);
    for (int x = 0; x < w; ++x) {
      float* to = &v.rgb[3 * (static_cast<size_t>(y) * w + x)];
      to[0] = row[x][2] / 255.0f, to[1] = row[x][1] / 255.0f, to[2] = row[x][0] / 255.0f;
    }
  }
  return v;
}

// The pixels of `view` within `radius` pixels of a projected point: where the frame's geometry
// is (a point cloud clipped to a person leaves the studio around it out of the fit).
std::vector<uint8_t> Coverage(const FitView& view, const std::vector<Point>& points, int radius) {
  const auto& cam = view.camera;
  const int w = static_cast<int>(cam.width), h = static_cast<int>(cam.height);
  std::vector<uint8_t> hit(static_cast<size_t>(w) * h, 0);
  for (const Point& p : points) {
    const long at = PixelOf(cam, p.x, p.y, p.z);
    if (at >= 0) hit[static_cast<size_t>(at)] = 1;
  }
  cv::Mat in(h, w, CV_8U, hit.data()), out;
  cv::dilate(in, out,
             cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius + 1, 2 * radius + 1)));
  return std::vector<uint8_t>(out.data, out.data + hit.size());
}

}  // namespace

Result<std::vector<FitView>> FrameFitViews(const Recording& rec, const FrameInput& frame,
                                           int resolution_scale) {
  if (resolution_scale < 1) {
    return Status::InvalidArgument("--fit-resolution " + std::to_string(resolution_scale) +
                                   ": photos are fitted at 1/N of their size, N >= 1");
  }
  std::vector<FitView> views;
  for (const StereoView& s : frame.stereo) {
    const int idx = rec.calibration.bricks[static_cast<size_t>(s.brick)].colour;
    if (idx < 0) continue;  // a brick without a colour camera
    HVDB_ASSIGN_OR_RETURN(FitView v, MakeView(rec.calibration.cameras[static_cast<size_t>(idx)],
                                              s.colour, s.colour_path, resolution_scale));
    views.push_back(std::move(v));
  }
  for (const DepthFrameView& d : frame.depth) {
    HVDB_ASSIGN_OR_RETURN(FitView v, MakeView(d.model, d.colour, d.colour_path, resolution_scale));
    views.push_back(std::move(v));
  }
  if (views.empty()) return CheckFitCameras(Recording{});
  return views;
}

Status CheckFitCameras(const Recording& rec) {
  bool colour = !rec.files.empty() && rec.kind != RecordingKind::kStereo;
  for (const Brick& b : rec.calibration.bricks) colour = colour || b.colour >= 0;
  if (colour) return Status::OK();
  return Status::InvalidArgument(
      "--gaussians fits Gaussians to each frame's colour photos; this recording has no colour "
      "cameras (a ply recording lists them under `cameras` with a calibration.yml: "
      "docs/RECORDING.md)");
}

Result<formats::GaussianCloud> GaussianVideoFitter::Fit(int index, std::vector<FitView> views,
                                                        const std::vector<Point>& points,
                                                        FitReport* report) {
  bool warm = previous_.has_value() && previous_->index == index - 1 &&
              previous_->views.size() == views.size();
  for (size_t k = 0; warm && k < views.size(); ++k) {
    const render::Camera &a = previous_->views[k].camera, &b = views[k].camera;
    warm = a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy &&
           a.cx == b.cx && a.cy == b.cy && a.world_from_camera == b.world_from_camera;
  }
  FitOptions o = options_.fit;
  formats::GaussianCloud cloud;
  if (warm) {
    cloud = previous_->cloud;
    for (size_t k = 0; k < views.size(); ++k) {
      views[k].mask = ChangedPixels(
          previous_->views[k].rgb, views[k].rgb, static_cast<int>(views[k].camera.width),
          static_cast<int>(views[k].camera.height), options_.change_threshold);
    }
    // The same schedule, shortened: densification over its first two thirds.
    o.iterations = options_.warm_iterations > 0 ? options_.warm_iterations
                                                : std::max(1, options_.fit.iterations / 3);
    const double k = static_cast<double>(o.iterations) / std::max(1, options_.fit.iterations);
    o.densify_from = static_cast<int>(options_.fit.densify_from * k);
    o.densify_until = static_cast<int>(options_.fit.densify_until * k);
    o.densify_interval = std::max(1, static_cast<int>(options_.fit.densify_interval * k));
    o.sh_degree_interval = std::max(1, static_cast<int>(options_.fit.sh_degree_interval * k));
    // Positions start from where they were and must be free to follow what moved: a warm
    // start's position learning rate starts higher and decays less (to half the first
    // frame's initial rate, not to its hundredth).
    o.lr_position_final = o.lr_position / 2;
    o.lr_position *= options_.warm_position_lr;
  } else {
    if (points.empty()) {
      return Status::InvalidArgument("frame " + std::to_string(index) +
                                     " has no points to start its Gaussians from");
    }
    cloud = CloudFromPoints(points, 0, options_.max_start_splats);
  }
  for (FitView& v : views) v.valid = Coverage(v, points, options_.coverage_radius);
  previous_.reset();
  HVDB_RETURN_IF_ERROR(FitGaussians(views, o, &cloud, report));
  for (FitView& v : views) v.mask.clear();
  previous_ = Previous{index, cloud, std::move(views)};
  return cloud;
}

}  // namespace hvdb::ingest
