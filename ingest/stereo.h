// The stereo matcher of thesis 3.3-3.5: a local, window-based matcher in five stages
//   S1 Birchfield-Tomasi pixel cost (symmetric, sampling-insensitive),
//   S2 box-filter aggregation of every disparity layer (eq. 3.27),
//   S3 multi-window minimum filter of every layer (eq. 3.32),
//   S4 winner-takes-all, with a left-right cross-check from the same cost volume (3.5.1),
//   S5 subpixel refinement of (d, dx, dy[, dt]) by Levenberg-Marquardt (eqs. 3.28-3.31),
//      masking window pixels across depth discontinuities; or only the parabola through the
//      three costs around the winner (S4), at a twentieth of the time.
// Disparities are d = x_left - x_right (positive for points in front of the cameras), the
// Middlebury convention.
#ifndef HVDB_INGEST_STEREO_H_
#define HVDB_INGEST_STEREO_H_

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "storage/status.h"

namespace hvdb::ingest {

// What makes disparities subpixel.
enum class Subpixel {
  kNone,      // integer disparities (the winners of S4)
  kParabola,  // the parabola through the aggregated costs at d-1, d, d+1 (as SGBM does)
  // S5: Levenberg-Marquardt on (d, dx, dy[, dt]) over the window, with gradients: the
  // thesis's refinement for structured-light stripes. On Middlebury's natural scenes it
  // scores as the parabola does (bench/README.md, stereo-bench --subpixel lm) at 8x the time.
  kLevenbergMarquardt,
};

// "none", "parabola" or "lm" (command-line spelling); false for anything else.
bool ParseSubpixel(const std::string& name, Subpixel* out);

struct StereoParams {
  int min_disparity = 0;        // disparities searched: [min_disparity, min_disparity + num_disparities)
  int num_disparities = 64;     // d = x_left - x_right (positive), pixels
  int window = 9;               // odd side of the square aggregation window (S2)
  bool multi_window = true;     // S3: minimum filter of eq. 3.32 with the same window
  bool cross_check = true;      // left-right check; mismatch > cross_check_tolerance => invalid
  int cross_check_tolerance = 1;
  Subpixel subpixel = Subpixel::kLevenbergMarquardt;
  double discontinuity_threshold = 2.0;  // px: window pixels whose coarse d differs more are masked in S5
  int threads = 0;              // 0 = all hardware threads
  Status Validate(const cv::Size& image_size) const;   // clear errors for out-of-range params
};

// Wall-clock milliseconds per stage of one MatchStereo / MatchSpacetime call; the stages add
// up to total_ms. prepare: grey conversion and the prefilter; S1-S4 and the cross-check run
// interleaved on all threads (band by band), so their wall time is split among them in
// proportion to the threads' time in each.
struct StereoTiming {
  double prepare_ms = 0, cost_ms = 0, aggregate_ms = 0, min_filter_ms = 0, wta_ms = 0,
         cross_check_ms = 0, subpixel_ms = 0, total_ms = 0;
};

struct DisparityMap {
  cv::Mat d;            // CV_32F, left view, pixels, x_left - x_right; +inf = invalid (occluded/unmatched)
  cv::Mat dx, dy, dt;   // CV_32F disparity gradients from S5 (zeros without LM; dt empty unless spacetime)
  StereoTiming timing;
};

// left, right: rectified 8-bit grey (CV_8UC1) or BGR (converted to grey), same size.
Result<DisparityMap> MatchStereo(const cv::Mat& left, const cv::Mat& right,
                                 const StereoParams& params);

// Spacetime stereo (eqs. 3.30-3.31): pairs of consecutive frames, refinement of
// (d, dx, dy, dt) at frame `centre` with a window spanning all given frames. The coarse
// stages S1-S4 run on the pixel cost averaged over all frames (a spacetime window of constant
// disparity).
Result<DisparityMap> MatchSpacetime(const std::vector<cv::Mat>& lefts,
                                    const std::vector<cv::Mat>& rights, size_t centre,
                                    const StereoParams& params);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_STEREO_H_
