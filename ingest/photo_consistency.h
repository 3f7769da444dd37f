// Photo-consistency enforcement during scan merging (thesis 5.3, fig. 5.4, eq. 5.13).
//
// The merged point cloud is splatted into every input colour view with the EWA footprint of
// the renderer (render/splat.h: the same projection, distortion, cutoff and antialiasing filter
// as the CPU and EGL renderers). For each splat, the alpha-weighted colour deviation of its
// unoccluded pixels from the view's image is compared, per YUV component, with the thresholds;
// inconsistent points are removed, and the points they hid are tested in turn.
//
// Interpretation of the thesis where it leaves room:
//  - Eq. 5.13 sums A_S xi (C_v - c) over the splat's pixels. The sum grows with the footprint,
//    so it is divided by the summed alpha of the unoccluded pixels, sum A_S xi: the threshold is
//    then a per-pixel colour difference, a fraction of the full range of each component.
//  - YUV is BT.601 on the sRGB-encoded (gamma) values scaled to [0, 1]: Y = 0.299 R + 0.587 G +
//    0.114 B, U = (B - Y) / 1.772, V = (R - Y) / 1.402, so Y spans [0, 1] and U, V span
//    [-0.5, 0.5]: each component's full range is 1 and max_dy etc. are fractions of it. Point
//    colours (sRGB) and images (BGR, 8-bit sRGB) are compared in this same encoded space.
//  - The splats are the points' surface footprints, as fig. 5.4 renders surfels (5.1.2): a
//    point made by one of the views' cameras (ColourView::camera_id = Point::camera) is
//    splatted with the cross-section of its Gaussian through its centre along that camera's
//    ray, V - (V d)(V d)^T / (d^T V d) for the ray direction d: the pixel footprint without the
//    depth uncertainty of eq. 5.8. With it, a point seen from another camera is a streak
//    along the epipolar line (on the SJTU stage 30-40 pixels long at 1080p) that averages the
//    image over that length, which blunts the test, and costs 8x the pixels. Other points keep
//    their whole covariance.
//  - Visibility is the visibility renderer's: a pixel of a splat is unoccluded (xi = 1) when its
//    fragment depth is within depth_threshold of the nearest fragment there among the points
//    not removed (the fuzzy z-buffer). Fig. 5.4 walks the splats front to back, so that a point
//    removed there no longer hides the ones behind it; here the same holds at a fixed point:
//    all splats are tested against the z-buffer, the z-buffer is redone without the removed
//    ones, and the splats where it changed are tested again, until a round removes nothing
//    (kMaxRounds at most; almost always 2-4). The result depends neither on the order of the
//    points nor on the number of threads, and the test is done tile by tile (fast: the image
//    rows a splat touches stay in the cache) instead of in depth order across the image.
//  - Each view is tested against the points that came in, independently of the other views, and
//    a point is removed when any view rejects it: the result does not depend on the order of the
//    views (fig. 5.4's sequential order does: a point removed by one view stopped hiding others
//    in the next), and the views run in parallel.
//  - A point is not tested in the view of the camera that made it (ColourView::camera_id =
//    Point::camera): its colour is that image's pixel under its centre, so the test there can
//    only reject it for the texture within its footprint (a colour edge), never for being
//    misplaced, which is what the test is for. It still occludes there. With one camera (an
//    RGB-D recording) nothing is left to test.
//  - Points behind the camera (nearer than the renderer's near plane, 1 cm) or whose splat
//    centre falls off the image are not tested in that view: a splat centred off the image
//    shows only its tail, too little to judge the point by. Such a splat still occludes what
//    lies behind it, which can only spare points (the conservative side, as the thesis applies
//    the check).
//  - The images are the cameras' own, distorted ones: splats are projected with the lens
//    distortion (CameraModel::ToRenderCamera()).
#ifndef HVDB_INGEST_PHOTO_CONSISTENCY_H_
#define HVDB_INGEST_PHOTO_CONSISTENCY_H_

#include <cstddef>
#include <cstdint>
#include <opencv2/core.hpp>
#include <span>
#include <vector>

#include "ingest/calibration.h"
#include "storage/point.h"

namespace hvdb::ingest {

struct ColourView {
  const CameraModel* camera = nullptr;
  // CV_8UC3 BGR, the camera's own (distorted) image. When its size differs from camera->size,
  // the intrinsics are scaled to it (render::Camera::Resized).
  cv::Mat image;
  // The Point::camera of the points this camera made (-1: none). Those points are splatted
  // with their pixel footprint only (see above).
  int camera_id = -1;
};

struct PhotoConsistencyOptions {
  double max_dy = 0.40, max_du = 0.15, max_dv = 0.15;  // fractions of the full range (thesis: 40% Y, 15% U/V)
  double depth_threshold = 0.02;  // fuzzy z-buffer tolerance (m) for the occlusion test
  double cutoff_radius = 2.0;     // splat footprint cut-off in std devs
  int threads = 0;                // 0: std::thread::hardware_concurrency()
  // Rounds of removal per view (see above): a bound that is never reached in practice.
  static constexpr int kMaxRounds = 16;
};

struct PhotoConsistencyStats {
  size_t tested = 0;          // (point, view) pairs whose splat had unoccluded pixels and was tested
  size_t removed = 0;         // points removed (each counted once)
  size_t occluded_skips = 0;  // (point, view) pairs centred on the image but fully occluded
  std::vector<size_t> removed_per_view;  // removed by views[v] and by no view before it
  int rounds = 0;                        // most rounds a view took (see above)
  double ms = 0;                         // wall time
};

// Fig. 5.4 over `views`. Returns the keep mask, one entry per point: 1 = keep, 0 = removed.
// At most 2^32 - 1 points (more are all kept, with a warning). A view without a camera, with an
// image that is not CV_8UC3, or whose camera the renderer rejects is skipped (with a warning
// through render's log handler). Threads: one view per thread (each holds one view's splats,
// 48 bytes per point it sees); within a view, eight pixels of a row are evaluated at once
// (render/simd.h).
std::vector<uint8_t> PhotoConsistencyMask(std::span<const Point> points,
                                          std::span<const ColourView> views,
                                          const PhotoConsistencyOptions& options,
                                          PhotoConsistencyStats* stats = nullptr);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_PHOTO_CONSISTENCY_H_
