// GeometricConsistencyMask (cross-view depth agreement) and RemoveDepthEdges (mixed pixels):
// two cameras looking at a wall with a box in front; a floating sample between them (a mixed
// pixel) is removed, the wall and the box stay, a sample no other view can judge stays.
#include "ingest/geometric_consistency.h"

#include <gtest/gtest.h>

#include "ingest/points.h"

namespace hvdb::ingest {
namespace {

CameraModel Cam(double x) {
  CameraModel c;
  c.name = "cam";
  c.K = {100, 0, 49.5, 0, 100, 39.5, 0, 0, 1};
  c.T = {-x, 0, 0};  // centre at (x, 0, 0), looking along +z
  c.size = {100, 80};
  return c;
}

// The depth camera c sees: a wall at z = 4, a box face at z = 2 for |X| < 0.3, |Y| < 0.3.
cv::Mat Depth(const CameraModel& c) {
  cv::Mat d(c.size.height, c.size.width, CV_32F);
  const double ox = c.Centre()[0];
  for (int v = 0; v < d.rows; ++v) {
    for (int u = 0; u < d.cols; ++u) {
      const double rx = (u - 49.5) / 100, ry = (v - 39.5) / 100;
      const double bx = ox + rx * 2, by = ry * 2;
      d.at<float>(v, u) = std::abs(bx) < 0.3 && std::abs(by) < 0.3 ? 2.0f : 4.0f;
    }
  }
  return d;
}

Point At(double x, double y, double z, uint16_t camera) {
  Point p;
  p.x = static_cast<float>(x), p.y = static_cast<float>(y), p.z = static_cast<float>(z);
  p.camera = camera;
  return p;
}

TEST(GeometricConsistencyTest, RemovesWhatOtherViewsSeeThrough) {
  const CameraModel a = Cam(-0.2), b = Cam(0.2);
  const cv::Mat da = Depth(a), db = Depth(b);
  std::vector<DepthMapView> views = {{&a, da, 0}, {&b, db, 1}};
  std::vector<Point> pts = {
      At(0.0, 0.0, 4.0, 0),    // the wall where b sees the box in front of it: no evidence
      At(-1.0, 0.0, 4.0, 0),   // the wall, seen by both
      At(0.0, 0.1, 2.0, 1),    // the box face, seen by both
      At(0.6, 0.0, 3.0, 0),    // floating between box and wall: b sees the wall behind it
      At(40.0, 0.0, 4.0, 0),   // outside b's image: nobody can judge it
  };
  GeometricConsistencyStats st;
  auto keep = GeometricConsistencyMask(pts, views, {}, &st);
  EXPECT_EQ(keep, (std::vector<uint8_t>{1, 1, 1, 0, 1}));
  EXPECT_EQ(st.removed, 1u);
  EXPECT_EQ(st.unjudged, 2u);  // the hidden wall point (occluded in b) and the far one
  GeometricConsistencyOptions strict;
  strict.min_support = 1;  // unjudged points go too
  keep = GeometricConsistencyMask(pts, views, strict);
  EXPECT_EQ(keep, (std::vector<uint8_t>{0, 1, 1, 0, 0}));
}

TEST(GeometricConsistencyTest, MixedPixelsAtDepthEdgesAreDropped) {
  const CameraModel a = Cam(0);
  cv::Mat d = Depth(a);
  d.at<float>(0, 0) = 0;  // a hole: no jump against it
  const cv::Mat cleaned = RemoveDepthEdges(d, 0.05, 2);
  int dropped = 0;
  for (int v = 0; v < d.rows; ++v) {
    for (int u = 0; u < d.cols; ++u) {
      // Distance (in pixels) to the nearest pixel of the other depth, along rows or columns.
      int near = 99;
      for (int k = -3; k <= 3; ++k) {
        for (int j = -3; j <= 3; ++j) {
          const int uu = u + k, vv = v + j;
          if (uu < 0 || vv < 0 || uu >= d.cols || vv >= d.rows || d.at<float>(vv, uu) <= 0) continue;
          if (d.at<float>(vv, uu) != d.at<float>(v, u)) near = std::min(near, std::max(std::abs(k), std::abs(j)));
        }
      }
      const bool gone = cleaned.at<float>(v, u) == 0 && d.at<float>(v, u) > 0;
      dropped += gone;
      // Within one pixel of the edge: always dropped; three or more away: never.
      if (near <= 1 && d.at<float>(v, u) > 0) {
        EXPECT_TRUE(gone) << u << "," << v;
      }
      if (near >= 3) {
        EXPECT_FALSE(gone) << u << "," << v;
      }
    }
  }
  EXPECT_GT(dropped, 0);
  EXPECT_EQ(cv::countNonZero(RemoveDepthEdges(d, 0.05, 0) != d), 0);  // radius 0: unchanged
}

}  // namespace
}  // namespace hvdb::ingest
