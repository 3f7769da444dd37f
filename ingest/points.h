// Probabilistic point samples from depth maps (thesis 5.1.1, 5.2).
//
// Every valid depth pixel (x, y, z) becomes one hvdb Point: a 3D Gaussian centred at the
// back-projection of the pixel (eq. 5.12)
//     X = R^-1 P^-1 (x, y, 1)^T z + O,
// with covariance V = R^-1 P^-1 V_R P^-T R^-T (eq. 5.11), V_R = Sigma_R Sigma_R^T (5.9) and
//     Sigma_R = [ sigma_x z   0           sigma_z x ]
//               [ 0           sigma_y z   sigma_z y ]      (5.10)
//               [ 0           0           sigma_z   ]
// i.e. the pixel's footprint (sigma_x = sigma_y = 1 + sigma_C pixels, 5.2) back-projected to
// depth z, extruded along the viewing ray by the depth uncertainty sigma_z. Here P is the
// intrinsic matrix K (pixel centres at integer coordinates, OpenCV convention) and R, O the
// camera's world->camera rotation and centre (CameraModel: X_cam = R X + T, O = -R^T T).
//
// Optionally each point also gets a surfel normal: the cross product of the spanning vectors
// T1, T2 of eqs. 5.5-5.6, oriented toward the camera.
#ifndef HVDB_INGEST_POINTS_H_
#define HVDB_INGEST_POINTS_H_

#include <cstddef>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "ingest/calibration.h"
#include "storage/point.h"

namespace hvdb::ingest {

struct DepthView {
  // The depth/colour image is in this camera's UNDISTORTED pinhole frame (only K, R, T are
  // used; the distortion coefficients are ignored).
  const CameraModel* camera = nullptr;
  cv::Mat depth;    // CV_32F camera-space z in metres; <= 0, NaN or inf = no sample
  cv::Mat colour;   // CV_8UC3 BGR, same size (required)
  // Optional CV_32F per-pixel depth std dev (m), e.g. from eq. 5.8 for stereo (see
  // DepthSigmaFromDisparity); a NaN, inf or negative value marks the pixel invalid. Empty:
  // derived from the depth-sensor model of PointOptions::default_relative_sigma_z.
  cv::Mat sigma_z;
  uint16_t camera_id = 0;
};

struct PointOptions {
  double sigma_c = 0.0;  // calibration reprojection error (px); sigma_x = sigma_y = 1 + sigma_c (5.2)
  // When DepthView::sigma_z is empty: sigma_z = default_relative_sigma_z * z^2 / (1 m), the
  // usual quadratic growth of depth noise with distance of triangulating depth sensors (and
  // of eq. 5.8 itself, since d ~ 1/z). 0.002 = 2 mm at 1 m, 8 mm at 2 m.
  double default_relative_sigma_z = 0.002;
  uint32_t frame = 0;
  bool normals = true;  // surfel normals from depth differences (5.5-5.6), flagged kFlagHasNormal
  // Neighbour depths differing more than this fraction of z are depth discontinuities: no
  // difference is taken across them; a pixel without a usable neighbour in x or in y gets no
  // normal.
  double max_relative_jump = 0.05;
  int stride = 1;  // take every stride-th pixel in x and y (subsampling for big depth images)
};

struct PointStats {
  size_t pixels = 0;       // pixels visited (after stride)
  size_t valid = 0;        // of those, with a valid depth (and sigma_z)
  size_t points = 0;       // points made (== valid)
  size_t with_normal = 0;  // of those, with kFlagHasNormal
};

// Probabilistic 3D Gaussians (eqs. 5.9-5.12): one point per valid pixel, in row-major pixel
// order; position by back-projection (5.12), covariance (5.10-5.11) flagged
// kFlagHasCovariance, colour from `colour`, camera id and frame from the arguments, id 0.
// Returns no points when the view is malformed (no camera, depth not CV_32F, colour not
// CV_8UC3 of the same size, sigma_z neither empty nor CV_32F of the same size, stride < 1).
// Multi-threaded over bands of rows.
std::vector<Point> PointsFromDepth(const DepthView& view, const PointOptions& options,
                                   PointStats* stats = nullptr);

// Eq. 5.8: sigma_z = baseline * fx / d^2 * (|d_x| + sigma_c), per pixel, from a disparity map
// (CV_32F, d > 0 px valid; <= 0, NaN or inf invalid) and its x-gradient (CV_32F, same size;
// a non-finite gradient counts as 0). Invalid pixels get +inf, which PointsFromDepth treats as
// no sample. Returns CV_32F of the disparity's size (empty when the inputs do not match).
// Mixed pixels at depth edges: a copy of `depth` (CV_32F, <= 0 / NaN / inf = none) with every
// pixel within `radius` pixels of a jump between neighbours of more than `max_relative_jump`
// of the nearer depth set to 0. At a silhouette the samples on both sides blend foreground
// and background (a sensor's footprint, a matcher's window) and land between the two.
cv::Mat RemoveDepthEdges(const cv::Mat& depth, double max_relative_jump, int radius);

cv::Mat DepthSigmaFromDisparity(const cv::Mat& disparity, const cv::Mat& disparity_dx,
                                double baseline, double fx, double sigma_c);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_POINTS_H_
