// Brush strokes as a user would paint them, made from a ground-truth object mask (segmentation
// and object-billboard tests): one line across the object along its middle row, lines across
// the rest of the picture, each kept a few pixels inside its region.
#ifndef HVDB_TESTS_INGEST_STROKES_H_
#define HVDB_TESTS_INGEST_STROKES_H_

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "ingest/segmentation.h"

namespace hvdb::ingest::testing {

// truth: CV_8U, non-zero on the object. Returns CV_8U marks: kStrokeObject, kStrokeRest, 0.
inline cv::Mat BrushStrokes(const cv::Mat& truth) {
  cv::Mat inside, outside;
  cv::erode(truth != 0, inside, cv::Mat::ones(7, 7, CV_8U));
  cv::erode(truth == 0, outside, cv::Mat::ones(17, 17, CV_8U));
  const cv::Moments m = cv::moments(truth != 0, true);
  const int cy = m.m00 > 0 ? static_cast<int>(m.m01 / m.m00) : truth.rows / 2;
  cv::Mat strokes(truth.size(), CV_8U, cv::Scalar(0));
  for (int y = std::max(0, cy - 1); y <= std::min(truth.rows - 1, cy + 1); ++y)
    for (int x = 0; x < truth.cols; ++x)
      if (inside.at<uint8_t>(y, x)) strokes.at<uint8_t>(y, x) = kStrokeObject;
  for (int row : {truth.rows / 5, truth.rows / 2, 4 * truth.rows / 5})
    for (int x = 0; x < truth.cols; ++x)
      if (outside.at<uint8_t>(row, x)) strokes.at<uint8_t>(row, x) = kStrokeRest;
  for (int col : {truth.cols / 10, 9 * truth.cols / 10})
    for (int y = 0; y < truth.rows; ++y)
      if (outside.at<uint8_t>(y, col)) strokes.at<uint8_t>(y, col) = kStrokeRest;
  return strokes;
}

}  // namespace hvdb::ingest::testing

#endif  // HVDB_TESTS_INGEST_STROKES_H_
