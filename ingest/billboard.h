// 3D video billboards (thesis ch. 6): a camera's depth map as a proxy plane in that camera's
// disparity space plus a displacement map, and the spatio-temporal bilateral filter that
// smooths the displacements within a view (6.2.1) and across views (6.2.2).
//
// Disparity space (6.1.1): pixel (x, y) with d = s / z, where s = fx * baseline of the stereo
// pair that measured the depth (pixels * metres), so d is the pair's disparity in pixels and
// its error (quantisation, matching noise) is about the same everywhere; planes in disparity
// space are planes in camera space. The billboard (eqs. 6.2, 6.3):
//     Pi(x, y) = pi_x x + pi_y y + pi_0          the proxy plane, disparity pixels
//     D(x, y)  = d(x, y) - Pi(x, y)              the displacement map
// The plane is the one that minimises the displacements in world units (eq. 6.5), not in
// disparity (6.4), so a filter's or a coder's small change of D stays small on the surface.
//
// The filter (eqs. 6.9, 6.12, fig. 6.5) replaces each displacement by the alpha-weighted mean
// of the displacements around it, under a cubic B-spline over pixels (and frames), counting
// only those within delta_d of it (the range kernel: depth edges and occlusions survive).
// Within a view the samples lie on the pixel grid of the frames around; from the other views
// each sample is reprojected into the view (by its own unfiltered depth) and splatted.
//
// Where the billboards go from here: ToDepth turns a filtered billboard back into depth, which
// becomes points like any depth map (6.7: "backprojecting all pixels of their texture maps").
#ifndef HVDB_INGEST_BILLBOARD_H_
#define HVDB_INGEST_BILLBOARD_H_

#include <opencv2/core.hpp>
#include <vector>

#include "ingest/calibration.h"
#include "storage/database.h"
#include "storage/status.h"

namespace hvdb::ingest {

struct Billboard {
  CameraModel camera;       // undistorted pinhole camera the maps are in (K, R, T, size)
  double scale = 0;         // s: d = s / z, pixels * metres
  cv::Vec3d plane{0, 0, 0}; // (pi_x, pi_y, pi_0) of eq. 6.2
  cv::Mat displacement;     // CV_32F, D = d - Pi; NaN where there is no sample
  cv::Mat alpha;            // CV_32F in [0, 1]: how much each pixel belongs to the billboard
  cv::Mat colour;           // CV_8UC3 BGR (may be empty)

  double Plane(double x, double y) const { return plane[0] * x + plane[1] * y + plane[2]; }
};

// The plane of eq. 6.5 for the depth samples (z > 0, finite) weighted by alpha (empty: 1):
// Levenberg-Marquardt from the least-squares plane in disparity space (eq. 6.4), stopping at a
// relative change below 1e-6 or after 20 iterations. Fails with fewer than 3 samples or when
// they lie on one line.
Result<cv::Vec3d> FitBillboardPlane(const cv::Mat& depth, const cv::Mat& alpha,
                                    const cv::Matx33d& K, double scale);

// A billboard of a depth map (CV_32F metres; <= 0, NaN, inf: none) in pinhole camera `camera`.
// alpha: CV_32F of the depth's size, or empty for 1 wherever there is depth (one billboard for
// the whole view). colour: CV_8UC3 of the same size or empty. scale > 0.
Result<Billboard> MakeBillboard(const CameraModel& camera, const cv::Mat& depth,
                                const cv::Mat& alpha, const cv::Mat& colour, double scale);

// z = s / (Pi + D) for every pixel with a displacement, alpha >= min_alpha and Pi + D > 0;
// 0 elsewhere. `displacement` replaces the billboard's own (e.g. a filtered one) if not empty.
cv::Mat BillboardDepth(const Billboard& billboard, const cv::Mat& displacement = {},
                       float min_alpha = 0.5f);

// Disparity Pi + D (CV_32F, +inf where BillboardDepth has none): the input of eq. 5.8's
// uncertainty (DepthSigmaFromDisparity with baseline = s / fx).
cv::Mat BillboardDisparity(const Billboard& billboard, const cv::Mat& displacement = {},
                           float min_alpha = 0.5f);

// Eq. 5.8's depth uncertainty of the billboard's samples (CV_32F metres, +inf where there is no
// sample): its disparity space is a stereo pair's with baseline s / fx, and the slope along x
// of the (filtered) disparity widens it, as the LM's gradient does for plain stereo.
cv::Mat BillboardDepthSigma(const Billboard& billboard, const cv::Mat& displacement, double sigma_c);

// The billboard as the dataset keeps it with its photo (docs/FORMAT.md "Photo", version 2):
// scale, plane, the displacement map as a 16-bit grey PNG of (D + 128) * 256 (0: no sample),
// alpha as an 8-bit grey PNG. `displacement` replaces the billboard's own if not empty. A
// displacement outside [-128, 128) pixels is stored as no sample.
Result<PhotoBillboard> EncodeBillboard(const Billboard& billboard, const cv::Mat& displacement = {});

struct BillboardFilterOptions {
  // Spatial support of the B-spline: (2 radius + 1)^2 pixels (the thesis: 21 x 21).
  int radius = 10;
  // Frames on either side of the filtered one in the intra-view filter (the thesis: 5 frames
  // in all). Frames missing from the window are simply not there.
  int temporal_radius = 2;
  double delta_d = 1.0;     // the range kernel's threshold, disparity pixels (eq. 6.8)
  bool inter_view = true;   // 6.2.2: the other views of the same frame, reprojected
  int iterations = 1;       // inter-view passes, each projecting with the last pass's result
  int threads = 0;          // 0: hardware threads
  Status Validate() const;
};

// Filters the displacement maps of the billboards of frame `centre`. window[t][v]: view v's
// billboard at frame t of the window (views in the same order in every frame; a missing one
// has an empty displacement map); window[centre] are the billboards filtered. A view whose
// camera moved between frames has its other frames' samples reprojected like another view's. Returns one
// CV_32F displacement map per view of window[centre] (NaN where there was none: the filter
// smooths, it does not fill holes).
Result<std::vector<cv::Mat>> FilterBillboards(
    const std::vector<std::vector<const Billboard*>>& window, size_t centre,
    const BillboardFilterOptions& options);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_BILLBOARD_H_
