// FrameProcessor's parts for billboards of one object (thesis 6.4): the strokes and the
// segmentation models fitted to them, and single-frame depth in a brick's colour camera.
#include <opencv2/imgcodecs.hpp>

#include "ingest/pipeline.h"
#include "ingest/rectify.h"

namespace hvdb::ingest {

Status FrameProcessor::FitObjectModels() {
  const Recording& rec = *rec_;
  if (opt_.filter != IngestOptions::Filter::kBillboard)
    return Status::InvalidArgument("--object-strokes makes object billboards: it needs --filter billboard");
  if (rec.kind != RecordingKind::kStereo)
    return Status::InvalidArgument("--object-strokes: object billboards are made from stereo recordings");
  HVDB_RETURN_IF_ERROR(opt_.segmentation.Validate());
  HVDB_RETURN_IF_ERROR(opt_.matting.Validate());
  if (opt_.strokes_frame < 0 || opt_.strokes_frame >= rec.frames)
    return Status::InvalidArgument("--strokes-frame " + std::to_string(opt_.strokes_frame) +
                                   " is outside the recording's frames 0.." + std::to_string(rec.frames - 1));
  HVDB_ASSIGN_OR_RETURN(FrameInput in, LoadFrame(rec, opt_.strokes_frame));
  models_.assign(rec.calibration.bricks.size(), nullptr);
  strokes_.assign(rec.calibration.bricks.size(), cv::Mat());
  for (size_t j = 0; j < in.stereo.size(); ++j) {
    const int brick = in.stereo[j].brick;
    const CameraModel& cam = rec.calibration.cameras[static_cast<size_t>(rec.calibration.bricks[static_cast<size_t>(brick)].colour)];
    const std::string path = rec.Path(opt_.object_strokes, opt_.strokes_frame, cam.name);
    const cv::Mat painted = cv::imread(path, cv::IMREAD_COLOR);
    if (painted.empty())
      return Status::NotFound(path + ": no stroke image for camera " + cam.name +
                              " (--object-strokes: red strokes on the object, blue on the rest)");
    if (painted.size() != cam.size)
      return Status::InvalidArgument(path + ": the stroke image is " + std::to_string(painted.cols) + "x" +
                                     std::to_string(painted.rows) + ", camera " + cam.name + "'s images " +
                                     std::to_string(cam.size.width) + "x" + std::to_string(cam.size.height));
    cv::Mat marks(painted.size(), CV_8U, cv::Scalar(0));
    for (int y = 0; y < painted.rows; ++y)
      for (int x = 0; x < painted.cols; ++x) {
        const cv::Vec3b c = painted.at<cv::Vec3b>(y, x);  // BGR
        if (c[2] > 200 && c[1] < 60 && c[0] < 60) marks.at<uint8_t>(y, x) = kStrokeObject;
        if (c[0] > 200 && c[1] < 60 && c[2] < 60) marks.at<uint8_t>(y, x) = kStrokeRest;
      }
    strokes_[static_cast<size_t>(brick)] = Undistort(cam, marks, /*nearest=*/true);
    HVDB_ASSIGN_OR_RETURN(cv::Mat depth, ColourDepth(in, j));
    auto model = SegmentationModel::Fit(Undistort(cam, in.stereo[j].colour), depth,
                                        strokes_[static_cast<size_t>(brick)], opt_.segmentation);
    if (!model.ok()) return Status::InvalidArgument(path + ": " + model.status().message());
    models_[static_cast<size_t>(brick)] = std::make_shared<const SegmentationModel>(std::move(model).value());
  }
  return Status::OK();
}

Result<cv::Mat> FrameProcessor::ColourDepth(const FrameInput& in, size_t j) const {
  const StereoView& v = in.stereo[j];
  const Calibration& cal = rec_->calibration;
  const Brick& b = cal.bricks[static_cast<size_t>(v.brick)];
  const Rectification& r = *rect_[static_cast<size_t>(v.brick)];
  cv::Mat l, rr;
  Rectify(r, v.left, v.right, &l, &rr);
  HVDB_ASSIGN_OR_RETURN(DisparityMap d, MatchStereo(l, rr, opt_.stereo));
  const CameraModel colour = Pinhole(cal.cameras[static_cast<size_t>(b.colour)]);
  cv::Mat depth = WarpDepth(r.left, DepthFromDisparity(d.d, r.baseline, r.left.K(0, 0), r.doffs), {}, colour).depth;
  if (opt_.edge_radius > 0) depth = RemoveDepthEdges(depth, opt_.edge_jump, opt_.edge_radius);
  return depth;
}

}  // namespace hvdb::ingest
