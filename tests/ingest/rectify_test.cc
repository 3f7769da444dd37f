#include "ingest/rectify.h"

#include <gtest/gtest.h>

#include <cmath>

#include "ingest/generator.h"

namespace hvdb::ingest {
namespace {

// The generator's rig has distortion and slightly rotated grey pairs: a real rectification.
Calibration Rig() {
  GeneratorOptions g;
  g.bricks = 2;
  return GeneratorCalibration(g);
}

// The rectified right camera: same K and orientation as the rectified left, at the right centre.
CameraModel RectifiedRight(const Rectification& r, const CameraModel& right) {
  CameraModel c = r.left;
  c.T = -(c.R * right.Centre());
  return c;
}

TEST(Rectify, CorrespondingPointsShareARowAndGiveTheirDepth) {
  const Calibration cal = Rig();
  for (const Brick& b : cal.bricks) {
    const CameraModel &L = cal.cameras[b.left], &R = cal.cameras[b.right];
    auto rect = PrepareRectification(L, R);
    ASSERT_TRUE(rect.ok()) << rect.status().ToString();
    EXPECT_NEAR(rect->baseline, cv::norm(L.Centre() - R.Centre()), 1e-9);
    EXPECT_DOUBLE_EQ(rect->doffs, 0);
    const CameraModel rr = RectifiedRight(*rect, R);
    cv::RNG rng(7);
    for (int i = 0; i < 200; ++i) {
      const cv::Vec3d X(rng.uniform(-0.8, 0.8), rng.uniform(-0.8, 0.5), rng.uniform(-0.8, 0.8));
      double zl = 0;
      const cv::Point2d pl = rect->left.Project(X, &zl), pr = rr.Project(X);
      EXPECT_NEAR(pl.y, pr.y, 1e-6);  // epipolar lines are rows
      const double d = pl.x - pr.x;   // x_left - x_right > 0
      ASSERT_GT(d, 0);
      EXPECT_NEAR(rect->baseline * rect->left.K(0, 0) / d, zl, 1e-6 * zl);  // eq. 3.24
      // The remap table sends the rectified pixel to where X is in the distorted image.
      const int u = static_cast<int>(std::lround(pl.x)), v = static_cast<int>(std::lround(pl.y));
      if (u < 1 || v < 1 || u >= L.size.width - 1 || v >= L.size.height - 1) continue;
      const cv::Point2d orig = L.Project(X);
      const double mx = rect->map_lx.at<float>(v, u) + (pl.x - u) * (rect->map_lx.at<float>(v, u + 1) - rect->map_lx.at<float>(v, u - 1)) / 2;
      const double my = rect->map_ly.at<float>(v, u) + (pl.y - v) * (rect->map_ly.at<float>(v + 1, u) - rect->map_ly.at<float>(v - 1, u)) / 2;
      EXPECT_NEAR(mx, orig.x, 0.05);
      EXPECT_NEAR(my, orig.y, 0.05);
    }
  }
}

TEST(Rectify, SwappedOrVerticalPairsAreErrors) {
  const Calibration cal = Rig();
  const Brick& b = cal.bricks[0];
  auto swapped = PrepareRectification(cal.cameras[b.right], cal.cameras[b.left]);
  EXPECT_TRUE(swapped.status().IsInvalidArgument());
  EXPECT_NE(swapped.status().message().find("swapped"), std::string::npos);
  auto same = PrepareRectification(cal.cameras[b.left], cal.cameras[b.left]);
  EXPECT_NE(same.status().message().find("same centre"), std::string::npos);
  CameraModel below = cal.cameras[b.left];
  below.T -= cv::Vec3d(0, 0.2, 0);  // the centre 0.2 m down the image (camera y)
  auto vertical = PrepareRectification(cal.cameras[b.left], below);
  EXPECT_NE(vertical.status().message().find("above each other"), std::string::npos)
      << vertical.status().ToString();
  CameraModel other = cal.cameras[b.right];
  other.size.width += 4;
  EXPECT_FALSE(PrepareRectification(cal.cameras[b.left], other).ok());
}

TEST(Rectify, DepthFromDisparity) {
  cv::Mat d = (cv::Mat_<float>(1, 4) << 10.f, 0.f, std::numeric_limits<float>::infinity(), 20.f);
  cv::Mat z = DepthFromDisparity(d, 0.1, 500);
  EXPECT_FLOAT_EQ(z.at<float>(0, 0), 5.f);
  EXPECT_EQ(z.at<float>(0, 1), 0.f);
  EXPECT_EQ(z.at<float>(0, 2), 0.f);
  EXPECT_FLOAT_EQ(z.at<float>(0, 3), 2.5f);
  EXPECT_FLOAT_EQ(DepthFromDisparity(d, 0.1, 500, 10).at<float>(0, 0), 2.5f);
}

// A tilted plane seen by camera A warps exactly (plane-based) into camera B.
TEST(Rectify, WarpDepthIsExactOnPlanes) {
  const Calibration cal = Rig();
  const CameraModel A = Pinhole(cal.cameras[cal.bricks[0].left]);
  const CameraModel B = Pinhole(cal.cameras[cal.bricks[0].colour]);
  const cv::Vec3d n = cv::normalize(cv::Vec3d(0.2, 0.3, 1.0));
  const double off = n.dot(cv::Vec3d(0, 0, -0.2));  // plane n.X = off through (0,0,-0.2)
  auto plane_depth = [&](const CameraModel& c) {
    cv::Mat z(c.size, CV_32F, cv::Scalar(0));
    const cv::Matx33d Kinv = c.K.inv();
    for (int v = 0; v < c.size.height; ++v)
      for (int u = 0; u < c.size.width; ++u) {
        const cv::Vec3d dir_cam = Kinv * cv::Vec3d(u, v, 1);  // z = 1
        const cv::Vec3d dir = c.R.t() * dir_cam, o = c.Centre();
        const double t = (off - n.dot(o)) / n.dot(dir);
        if (t > 0) z.at<float>(v, u) = static_cast<float>(t);
      }
    return z;
  };
  const cv::Mat za = plane_depth(A), zb = plane_depth(B);
  const cv::Mat carried(A.size, CV_32F, cv::Scalar(0.5));
  WarpedDepth w = WarpDepth(A, za, carried, B);
  int compared = 0;
  for (int v = 5; v < B.size.height - 5; ++v)
    for (int u = 5; u < B.size.width - 5; ++u) {
      const float got = w.depth.at<float>(v, u);
      if (got == 0) continue;
      ++compared;
      ASSERT_NEAR(got, zb.at<float>(v, u), 1e-4 * zb.at<float>(v, u)) << u << "," << v;
      ASSERT_EQ(w.carried.at<float>(v, u), 0.5f);
    }
  EXPECT_GT(compared, B.size.area() / 2);
}

TEST(Rectify, UndistortLeavesPinholeImagesAlone) {
  CameraModel c = Rig().cameras[0];
  cv::Mat img(c.size, CV_8UC1, cv::Scalar(9));
  c.dist.assign(5, 0.0);
  EXPECT_EQ(Undistort(c, img).data, img.data);
  c = Rig().cameras[0];
  cv::Mat u = Undistort(c, img);
  EXPECT_NE(u.data, img.data);
  EXPECT_EQ(u.size(), img.size());
}

}  // namespace
}  // namespace hvdb::ingest
