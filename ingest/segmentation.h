// Objects for billboards (thesis 6.4): a camera's video segmented into an object and the rest
// by a graph cut over its pixels in space and time, guided by colour and depth models fitted to
// a few brush strokes (6.4.1), and the object's boundary refined into an alpha matte by
// Bayesian matting (6.4.2, Chuang et al. 2001).
//
// Segmentation (eqs. 6.16-6.25): minimise E = lambda_D E_D + E_S over labels a_i in {0, 1}.
//   E_D: stroked pixels are fixed; any other pixel pays -log P(object | c_i, z_i) for label 1
//        and -log P(rest | c_i, z_i) for 0, where the likelihoods combine a colour GMM and a
//        depth GMM of each side, Theta = (1 - lambda_Z) Theta_C + lambda_Z Theta_Z (6.20-6.22,
//        as negative log-likelihoods; normalised to a posterior as in Rother et al. 2004: the
//        thesis's ratio Theta_F / (Theta_F + Theta_B) needs positive Thetas, which densities
//        above 1 do not give).
//   E_S: lambda_I exp(-beta |c_i - c_j|^2) for 4-neighbours within a frame with different
//        labels, lambda_T the same for a pixel and itself in the next frame (6.23-6.25);
//        beta = 1 / (2 <|c_i - c_j|^2>) over the frames (Boykov and Jolly 2001).
// Solved by edit/'s Boykov-Kolmogorov max-flow.
//
// Matting (6.26): a graymap from the segmentation (within `band` pixels of its boundary:
// unknown), then per unknown pixel, from the nearest known and already solved pixels around it,
// a Gaussian of the object's and of the background's colours, and alternately the colours F, B
// that best explain c = alpha F + (1 - alpha) B under them and the alpha that best fits those
// F, B. Pixels are solved from the known regions inwards (onion peel), as Chuang et al. do.
#ifndef HVDB_INGEST_SEGMENTATION_H_
#define HVDB_INGEST_SEGMENTATION_H_

#include <memory>
#include <opencv2/core.hpp>
#include <vector>

#include "storage/status.h"

namespace hvdb::ingest {

// Stroke images: CV_8U, 0 unknown, kStrokeObject or kStrokeRest where the user painted.
inline constexpr uint8_t kStrokeObject = 1, kStrokeRest = 2;

struct SegmentationOptions {
  int components = 5;     // Gaussians per colour and per depth model (the thesis: 5 to 10)
  double lambda_d = 1.0;  // weight of the data energy
  double lambda_z = 0.5;  // share of the depth model in each side's likelihood (0: colour only)
  double lambda_i = 4.0;  // weight of the links within a frame
  double lambda_t = 2.0;  // weight of the links between frames
  Status Validate() const;
};

// The colour and depth models of the object and of the rest (Theta_F, Theta_B), fitted to the
// stroked pixels of one frame.
class SegmentationModel {
 public:
  // colour: CV_8UC3 (BGR); depth: CV_32F metres (<= 0, NaN, inf: none; such pixels have no
  // depth term) or empty; strokes: CV_8U of the same size. Needs strokes of both kinds.
  static Result<SegmentationModel> Fit(const cv::Mat& colour, const cv::Mat& depth,
                                       const cv::Mat& strokes, const SegmentationOptions& options);
  // -log P(object | c, z) and -log P(rest | c, z); z <= 0 or not finite: colour alone.
  void Costs(const cv::Vec3b& bgr, float z, double* object, double* rest) const;

 private:
  struct Impl;
  std::shared_ptr<const Impl> impl_;
};

// Labels (CV_8U: 1 object, 0 rest) of every frame of one camera's video, cut together.
// colours: CV_8UC3, all of one size; depths: as many (each CV_32F of that size or empty), or
// none; strokes: as many (each CV_8U or empty: no strokes in that frame), or none.
Result<std::vector<cv::Mat>> SegmentFrames(const SegmentationModel& model,
                                           const std::vector<cv::Mat>& colours,
                                           const std::vector<cv::Mat>& depths,
                                           const std::vector<cv::Mat>& strokes,
                                           const SegmentationOptions& options);

struct MattingOptions {
  int band = 3;           // unknown: within this many pixels of the segmentation's boundary
  int neighbours = 24;    // known or solved pixels of each side gathered per unknown pixel
  int radius = 12;        // searched within this many pixels
  int iterations = 6;     // alternations of (F, B) and alpha per pixel
  double sigma_c = 0.02;  // camera noise of a colour channel, in [0, 1] units
  Status Validate() const;
};

// Bayesian matting of `colour` (CV_8UC3) around the boundary of `labels` (CV_8U, non-zero:
// object). Returns alpha (CV_32F in [0, 1]: 1 inside, 0 outside, solved in the band); if
// `foreground` is given it receives the object's colours (CV_8UC3; the observed colour outside
// the band).
Result<cv::Mat> BayesianMatte(const cv::Mat& colour, const cv::Mat& labels,
                              const MattingOptions& options, cv::Mat* foreground = nullptr);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_SEGMENTATION_H_
