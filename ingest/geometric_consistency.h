// Cross-view geometric consistency of merged depth maps (the fusion test of multi-view stereo:
// Merrell et al. 2007, COLMAP's fusion), before photo-consistency (thesis 5.3).
//
// Each point, made from one camera's depth map, is projected into every other camera with a
// depth map. There it either agrees with that camera's depth (within `tolerance`, relative:
// support), lies in front of it (it would hide the surface that camera saw: a free-space
// violation), lies behind it (hidden there: no evidence) or falls outside the image or on a
// pixel without depth (no evidence). A point is kept when at least `min_support` other views
// agree with it and no more views contradict it than agree with it. Points that float in
// front of the surfaces, such as the mixed samples at a silhouette that the depth of one view
// smeared between foreground and background, are seen through by the other views and removed;
// they are what makes doubled silhouettes in novel views. A point that no other camera can
// judge (outside all of them, or on depth holes) is kept only when `min_support` is 0.
#ifndef HVDB_INGEST_GEOMETRIC_CONSISTENCY_H_
#define HVDB_INGEST_GEOMETRIC_CONSISTENCY_H_

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include <opencv2/core.hpp>

#include "ingest/calibration.h"
#include "storage/point.h"

namespace hvdb::ingest {

struct DepthMapView {
  const CameraModel* camera = nullptr;  // pinhole (K, R, T; distortion ignored)
  cv::Mat depth;                        // CV_32F camera-space z (m); <= 0, NaN, inf = none
  uint16_t camera_id = 0;               // the Point::camera of the points made from it
};

struct GeometricConsistencyOptions {
  double tolerance = 0.01;  // |z_point - z_view| / z_view within this: agreement
  int min_support = 0;      // other views that must agree
  int threads = 0;          // 0: std::thread::hardware_concurrency()
};

struct GeometricConsistencyStats {
  size_t removed = 0, unjudged = 0;  // unjudged: no other view had evidence either way
  double ms = 0;
};

// One entry per point: 1 = keep. Views with a malformed depth map are ignored.
std::vector<uint8_t> GeometricConsistencyMask(std::span<const Point> points,
                                              std::span<const DepthMapView> views,
                                              const GeometricConsistencyOptions& options,
                                              GeometricConsistencyStats* stats = nullptr);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_GEOMETRIC_CONSISTENCY_H_
