// Photo-consistency enforcement during scan merging (thesis 5.3, fig. 5.4, eq. 5.13).
//
// The merged point cloud is splatted into every input colour view in turn, front to back, with
// the EWA footprint of the renderer (render/splat.h: the same projection, distortion, cutoff and
// antialiasing filter as the CPU and EGL renderers). For each splat, the alpha-weighted colour
// deviation of its unoccluded pixels from the view's image is compared, per YUV component, with
// the thresholds; inconsistent points are removed, consistent ones written into the fuzzy
// z-buffer so that they occlude the points behind them. Splats that are fully occluded are not
// tested (occluded surfaces generally disagree with the image).
//
// Interpretation of the thesis where it leaves room:
//  - Eq. 5.13 sums A_S xi (C_v - c) over the splat's pixels. The sum grows with the footprint,
//    so it is divided by the summed alpha of the unoccluded pixels, sum A_S xi: the threshold is
//    then a per-pixel colour difference, a fraction of the full range of each component.
//  - YUV is BT.601 on the sRGB-encoded (gamma) values scaled to [0, 1]: Y = 0.299 R + 0.587 G +
//    0.114 B, U = (B - Y) / 1.772, V = (R - Y) / 1.402, so Y spans [0, 1] and U, V span
//    [-0.5, 0.5]: each component's full range is 1 and max_dy etc. are fractions of it. Point
//    colours (sRGB) and images (BGR, 8-bit sRGB) are compared in this same encoded space.
//  - A point removed in view v no longer exists: it occludes nothing in later views.
//  - Points behind the camera (nearer than the renderer's near plane, 1 cm) or whose splat
//    centre falls off the image are not tested in that view: a splat centred off the image
//    shows only its tail, too little to judge the point by. Such a splat still occludes what
//    lies behind it, which can only spare points (the conservative side, as the thesis applies
//    the check). Views are processed in the order given.
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
};

struct PhotoConsistencyOptions {
  double max_dy = 0.40, max_du = 0.15, max_dv = 0.15;  // fractions of the full range (thesis: 40% Y, 15% U/V)
  double depth_threshold = 0.02;  // fuzzy z-buffer tolerance (m) for the occlusion test
  double cutoff_radius = 2.0;     // splat footprint cut-off in std devs
  int threads = 0;                // 0: std::thread::hardware_concurrency()
};

struct PhotoConsistencyStats {
  size_t tested = 0;          // (point, view) pairs whose splat had unoccluded pixels and was tested
  size_t removed = 0;         // points removed (each counted once)
  size_t occluded_skips = 0;  // (point, view) pairs centred on the image but fully occluded
  std::vector<size_t> removed_per_view;  // removed in views[v]
  double ms = 0;                         // wall time
};

// Fig. 5.4 over `views` in order. Returns the keep mask, one entry per point: 1 = keep,
// 0 = removed. At most 2^32 - 1 points (more are all kept, with a warning). A view without a camera, with an image that is not CV_8UC3, or whose camera the
// renderer rejects is skipped (with a warning through render's log handler).
//
// Threads: the test within a view is inherently sequential (each splat's visibility depends on
// the splats in front of it, and a removal changes what the next view sees), so threads are
// spent on what is independent: projecting the points and converting the image to YUV, chunked
// over threads, and projecting + depth-sorting view v+1 in the background while view v is
// tested (removals from view v are applied when view v+1 is tested, so this is exact). Within
// a splat, eight pixels of a row are evaluated at once (render/simd.h).
std::vector<uint8_t> PhotoConsistencyMask(std::span<const Point> points,
                                          std::span<const ColourView> views,
                                          const PhotoConsistencyOptions& options,
                                          PhotoConsistencyStats* stats = nullptr);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_PHOTO_CONSISTENCY_H_
