// Geometry between cameras of a brick: undistortion and rectification of the grey pair (thesis
// 3.2.4; OpenCV's stereoRectify, a variant of Fusiello's method of eqs. 3.13-3.21), depth from
// disparity (3.24), and the warp of a depth map into another camera (4.x: depth is delivered in
// the brick's colour camera).
#ifndef HVDB_INGEST_RECTIFY_H_
#define HVDB_INGEST_RECTIFY_H_

#include <opencv2/core.hpp>

#include "ingest/calibration.h"
#include "storage/status.h"

namespace hvdb::ingest {

struct Rectification {
  cv::Size size;
  cv::Mat map_lx, map_ly, map_rx, map_ry;  // remap tables (CV_32F) original -> rectified
  CameraModel left;    // the rectified left camera in the world: K = P1, R = R1 R_left, no distortion
  double baseline = 0; // metres, > 0 (the right camera is to the right of the left one)
  double doffs = 0;    // cx_right - cx_left of the rectified pair (0 here: CALIB_ZERO_DISPARITY)
};

// Errors: cameras of different sizes, coincident centres, or a "right" camera that is really
// to the left (swapped names in the calibration).
Result<Rectification> PrepareRectification(const CameraModel& left, const CameraModel& right);
void Rectify(const Rectification& rect, const cv::Mat& left, const cv::Mat& right,
             cv::Mat* left_out, cv::Mat* right_out);

// z = baseline * fx / (d + doffs) for d finite and > -doffs; 0 (no depth) elsewhere.
cv::Mat DepthFromDisparity(const cv::Mat& disparity, double baseline, double fx, double doffs = 0);

// The undistorted pinhole version of a camera (same K, R, T, no distortion) and the image
// resampled to it.
CameraModel Pinhole(const CameraModel& camera);
cv::Mat Undistort(const CameraModel& camera, const cv::Mat& image, bool nearest = false);

// Warps a depth map of pinhole camera `src` (z in metres, 0 = none) and a per-pixel value
// carried along (sigma_z; may be empty) into pinhole camera `dst`. Every source pixel is
// splatted to the destination pixels around its projection with a z-buffer; the depth written
// is where the destination pixel's ray meets the source pixel's local plane (from its
// neighbours), so planar surfaces warp exactly. Source pixels at depth discontinuities
// (relative jump > max_relative_jump) fall back to their own depth and to the nearest pixel.
struct WarpedDepth {
  cv::Mat depth;    // CV_32F, dst size, 0 = none
  cv::Mat carried;  // CV_32F (empty if none given)
};
WarpedDepth WarpDepth(const CameraModel& src, const cv::Mat& depth, const cv::Mat& carried,
                      const CameraModel& dst, double max_relative_jump = 0.05);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_RECTIFY_H_
