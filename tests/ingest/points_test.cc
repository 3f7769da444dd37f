// PointsFromDepth (thesis eqs. 5.4-5.6, 5.9-5.12) and DepthSigmaFromDisparity (eq. 5.8).
#include "ingest/points.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace hvdb::ingest {
namespace {

constexpr double kPi = 3.14159265358979323846;

cv::Matx33d RotX(double deg) {
  const double a = deg * kPi / 180, c = std::cos(a), s = std::sin(a);
  return {1, 0, 0, 0, c, -s, 0, s, c};
}
cv::Matx33d RotY(double deg) {
  const double a = deg * kPi / 180, c = std::cos(a), s = std::sin(a);
  return {c, 0, s, 0, 1, 0, -s, 0, c};
}

CameraModel MakeCamera(double fx, double fy, double cx, double cy, int w, int h,
                       cv::Matx33d R = cv::Matx33d::eye(), cv::Vec3d T = {0, 0, 0}) {
  CameraModel c;
  c.name = "cam";
  c.K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
  c.R = R;
  c.T = T;
  c.size = {w, h};
  return c;
}

// A colour image whose every pixel is distinct, so colours can be traced back to pixels.
cv::Mat PixelColours(int w, int h) {
  cv::Mat m(h, w, CV_8UC3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) m.at<cv::Vec3b>(y, x) = cv::Vec3b(x * 3 % 256, y * 5 % 256, 77);
  return m;
}

cv::Vec3d Pos(const Point& p) { return {p.x, p.y, p.z}; }

cv::Vec3d Normal(const Point& p) {
  auto n = DecodeNormal(p.normal_oct);
  return {n[0], n[1], n[2]};
}

cv::Matx33d Cov(const Point& p) {
  const auto& c = p.cov;
  return {c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]};
}

// V of eqs. 5.9-5.11 written out as matrices: R^-1 P^-1 Sigma_R Sigma_R^T P^-T R^-T.
cv::Matx33d HandCovariance(const CameraModel& cam, double x, double y, double z, double sxy,
                           double sz) {
  const cv::Matx33d sigma_r(sxy * z, 0, sz * x,  //
                            0, sxy * z, sz * y,  //
                            0, 0, sz);
  const cv::Matx33d vr = sigma_r * sigma_r.t();
  const cv::Matx33d m = cam.R.inv() * cam.K.inv();
  return m * vr * m.t();
}

void ExpectCovNear(const cv::Matx33d& got, const cv::Matx33d& want, double rel) {
  double scale = 0;
  for (int i = 0; i < 9; ++i) scale = std::max(scale, std::abs(want.val[i]));
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(got.val[i], want.val[i], rel * scale) << "element " << i;
}

TEST(PointsFromDepth, FrontoParallelPlane) {
  const CameraModel cam = MakeCamera(100, 110, 31.5, 23.5, 64, 48);
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(48, 64, CV_32F, cv::Scalar(2.0f));
  view.colour = PixelColours(64, 48);
  view.camera_id = 3;
  PointOptions opt;
  opt.sigma_c = 0.3;
  opt.frame = 7;
  PointStats st;
  const std::vector<Point> pts = PointsFromDepth(view, opt, &st);
  ASSERT_EQ(pts.size(), 64u * 48u);
  EXPECT_EQ(st.pixels, 64u * 48u);
  EXPECT_EQ(st.valid, 64u * 48u);
  EXPECT_EQ(st.points, 64u * 48u);
  EXPECT_EQ(st.with_normal, 64u * 48u);
  for (int y = 0; y < 48; ++y) {
    for (int x = 0; x < 64; ++x) {
      const Point& p = pts[static_cast<size_t>(y * 64 + x)];
      // Back-projection by hand (eq. 5.12 with R = I, O = 0).
      EXPECT_NEAR(p.x, (x - 31.5) / 100 * 2, 1e-6);
      EXPECT_NEAR(p.y, (y - 23.5) / 110 * 2, 1e-6);
      EXPECT_NEAR(p.z, 2.0, 1e-6);
      ASSERT_EQ(p.flags, kFlagHasNormal | kFlagHasCovariance);
      const cv::Vec3d n = Normal(p);  // the plane's normal, toward the camera at the origin
      EXPECT_NEAR(n[0], 0, 1e-4);
      EXPECT_NEAR(n[1], 0, 1e-4);
      EXPECT_NEAR(n[2], -1, 1e-4);
      const cv::Vec3b bgr = view.colour.at<cv::Vec3b>(y, x);
      EXPECT_EQ(p.b, bgr[0]);
      EXPECT_EQ(p.g, bgr[1]);
      EXPECT_EQ(p.r, bgr[2]);
      EXPECT_EQ(p.camera, 3);
      EXPECT_EQ(p.frame, 7u);
      EXPECT_EQ(p.id, 0u);
    }
  }
  // Covariance of pixel (10, 5), eqs. 5.10-5.11 by hand for K = [fx 0 cx; 0 fy cy; 0 0 1],
  // R = I: P^-1 Sigma_R has columns (sx z / fx, 0, 0), (0, sy z / fy, 0) and
  // sz ((x - cx) / fx, (y - cy) / fy, 1); sigma_z = 0.002 * z^2 = 0.008 m.
  const Point& p = pts[5 * 64 + 10];
  const double s = 1.3 * 2, sz = 0.008, a = (10 - 31.5) / 100, b = (5 - 23.5) / 110;
  EXPECT_NEAR(p.cov[0], s * s / (100 * 100) + sz * sz * a * a, 1e-9);  // xx
  EXPECT_NEAR(p.cov[1], sz * sz * a * b, 1e-9);                        // xy
  EXPECT_NEAR(p.cov[2], sz * sz * a, 1e-9);                            // xz
  EXPECT_NEAR(p.cov[3], s * s / (110 * 110) + sz * sz * b * b, 1e-9);  // yy
  EXPECT_NEAR(p.cov[4], sz * sz * b, 1e-9);                            // yz
  EXPECT_NEAR(p.cov[5], sz * sz, 1e-9);                                // zz
  ExpectCovNear(Cov(p), HandCovariance(cam, 10, 5, 2, 1.3, sz), 1e-5);
}

TEST(PointsFromDepth, RotatedCameraMatchesHandBackProjection) {
  const CameraModel cam =
      MakeCamera(120, 118, 40.2, 29.7, 80, 60, RotY(30) * RotX(-10), {0.1, -0.2, 0.5});
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(60, 80, CV_32F);
  for (int y = 0; y < 60; ++y)
    for (int x = 0; x < 80; ++x) view.depth.at<float>(y, x) = 1.5f + 0.01f * x + 0.004f * y;
  view.colour = PixelColours(80, 60);
  PointOptions opt;
  opt.sigma_c = 0.5;
  opt.default_relative_sigma_z = 0.003;
  const std::vector<Point> pts = PointsFromDepth(view, opt);
  ASSERT_EQ(pts.size(), 80u * 60u);
  const cv::Matx33d kinv = cam.K.inv();
  for (int y = 0; y < 60; y += 7) {
    for (int x = 0; x < 80; x += 9) {
      const Point& p = pts[static_cast<size_t>(y * 80 + x)];
      const double z = view.depth.at<float>(y, x);
      // X_cam = K^-1 (x, y, 1) z; X = R^T (X_cam - T).
      const cv::Vec3d want = cam.R.t() * (kinv * cv::Vec3d(x, y, 1) * z - cam.T);
      EXPECT_LT(cv::norm(Pos(p) - want), 1e-5) << x << "," << y;
      double zc = 0;
      const cv::Point2d back = cam.Project(Pos(p), &zc);
      EXPECT_NEAR(back.x, x, 1e-3);
      EXPECT_NEAR(back.y, y, 1e-3);
      EXPECT_NEAR(zc, z, 1e-5);
      ExpectCovNear(Cov(p), HandCovariance(cam, x, y, z, 1.5, 0.003 * z * z), 1e-5);
    }
  }
}

TEST(PointsFromDepth, TiltedPlaneNormal) {
  const CameraModel cam =
      MakeCamera(150, 150, 39.5, 29.5, 80, 60, RotY(-20) * RotX(15), {0.3, 0.1, -0.2});
  // The plane n . X_cam = n . (0, 0, 2) in camera coordinates; n faces the camera.
  const cv::Vec3d n = cv::normalize(cv::Vec3d(0.3, -0.2, -1));
  const double d = n.dot(cv::Vec3d(0, 0, 2));
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(60, 80, CV_32F);
  const cv::Matx33d kinv = cam.K.inv();
  for (int y = 0; y < 60; ++y)
    for (int x = 0; x < 80; ++x)
      view.depth.at<float>(y, x) = static_cast<float>(d / n.dot(kinv * cv::Vec3d(x, y, 1)));
  view.colour = PixelColours(80, 60);
  PointStats st;
  const std::vector<Point> pts = PointsFromDepth(view, {}, &st);
  ASSERT_EQ(pts.size(), 80u * 60u);
  EXPECT_EQ(st.with_normal, pts.size());
  const cv::Vec3d want = cam.R.t() * n;  // the plane normal in the world
  const cv::Vec3d o = cam.Centre();
  for (const Point& p : pts) {
    ASSERT_TRUE(p.flags & kFlagHasNormal);
    const cv::Vec3d got = Normal(p);
    EXPECT_LT(cv::norm(got - want), 2e-3);
    EXPECT_GT(got.dot(o - Pos(p)), 0);  // toward the camera
    // And every point lies on the plane.
    EXPECT_NEAR(n.dot(cam.R * Pos(p) + cam.T), d, 1e-5);
  }
}

TEST(PointsFromDepth, InvalidDepthsGiveNoPoints) {
  const CameraModel cam = MakeCamera(100, 100, 7.5, 5.5, 16, 12);
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(12, 16, CV_32F, cv::Scalar(1.0f));
  view.colour = PixelColours(16, 12);
  const float bad[] = {0.0f, -1.0f, std::numeric_limits<float>::quiet_NaN(),
                       std::numeric_limits<float>::infinity(),
                       -std::numeric_limits<float>::infinity()};
  for (int i = 0; i < 5; ++i) view.depth.at<float>(2 + i, 3 + 2 * i) = bad[i];
  PointStats st;
  const std::vector<Point> pts = PointsFromDepth(view, {}, &st);
  EXPECT_EQ(st.pixels, 16u * 12u);
  EXPECT_EQ(st.valid, 16u * 12u - 5);
  ASSERT_EQ(pts.size(), 16u * 12u - 5);
  for (const Point& p : pts) {
    EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y));
    EXPECT_NEAR(p.z, 1.0, 1e-6);
    // Neighbours of the holes still have a one-sided difference in each direction.
    EXPECT_TRUE(p.flags & kFlagHasNormal);
  }
  // The hole pixels are exactly the ones missing: pixel (3, 2) is gone, (4, 2) is there.
  for (const Point& p : pts) {
    const int x = static_cast<int>(std::lround(p.x * 100 / p.z + 7.5));
    const int y = static_cast<int>(std::lround(p.y * 100 / p.z + 5.5));
    for (int i = 0; i < 5; ++i) EXPECT_FALSE(x == 3 + 2 * i && y == 2 + i);
  }
}

TEST(PointsFromDepth, DiscontinuitiesGiveNoNormals) {
  const CameraModel cam = MakeCamera(100, 100, 15.5, 11.5, 32, 24);
  DepthView view;
  view.camera = &cam;
  view.colour = PixelColours(32, 24);
  PointStats st;

  // Alternating columns 1 m / 1.5 m: every x-neighbour is across a jump.
  view.depth = cv::Mat(24, 32, CV_32F);
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x) view.depth.at<float>(y, x) = x % 2 ? 1.5f : 1.0f;
  std::vector<Point> pts = PointsFromDepth(view, {}, &st);
  EXPECT_EQ(pts.size(), 32u * 24u);
  EXPECT_EQ(st.with_normal, 0u);
  for (const Point& p : pts) EXPECT_EQ(p.flags, kFlagHasCovariance);

  // Alternating rows: the same in y.
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x) view.depth.at<float>(y, x) = y % 2 ? 1.0f : 1.2f;
  pts = PointsFromDepth(view, {}, &st);
  EXPECT_EQ(st.with_normal, 0u);

  // A larger threshold makes the same 20% jumps continuous again.
  PointOptions loose;
  loose.max_relative_jump = 0.25;
  pts = PointsFromDepth(view, loose, &st);
  EXPECT_EQ(st.with_normal, 32u * 24u);

  // A step edge (two fronto-parallel planes): pixels at the edge use the difference on their
  // own side, so every pixel has the planes' normal.
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 32; ++x) view.depth.at<float>(y, x) = x < 16 ? 1.0f : 2.0f;
  pts = PointsFromDepth(view, {}, &st);
  EXPECT_EQ(st.with_normal, 32u * 24u);
  for (const Point& p : pts) EXPECT_NEAR(Normal(p)[2], -1, 1e-4);

  // An isolated valid pixel (neighbours invalid) has nothing to differentiate against.
  view.depth = cv::Mat(24, 32, CV_32F, cv::Scalar(0.0f));
  view.depth.at<float>(10, 10) = 1.0f;
  pts = PointsFromDepth(view, {}, &st);
  ASSERT_EQ(pts.size(), 1u);
  EXPECT_EQ(st.with_normal, 0u);

  // normals = false: none at all.
  view.depth = cv::Mat(24, 32, CV_32F, cv::Scalar(1.0f));
  PointOptions no_normals;
  no_normals.normals = false;
  pts = PointsFromDepth(view, no_normals, &st);
  EXPECT_EQ(pts.size(), 32u * 24u);
  EXPECT_EQ(st.with_normal, 0u);
  for (const Point& p : pts) EXPECT_EQ(p.flags, kFlagHasCovariance);
}

TEST(PointsFromDepth, Stride) {
  const CameraModel cam = MakeCamera(100, 100, 31.5, 23.5, 64, 48);
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(48, 64, CV_32F);
  for (int y = 0; y < 48; ++y)
    for (int x = 0; x < 64; ++x) view.depth.at<float>(y, x) = 1.0f + 0.01f * x;
  view.colour = PixelColours(64, 48);
  PointOptions opt;
  opt.stride = 3;
  PointStats st;
  const std::vector<Point> pts = PointsFromDepth(view, opt, &st);
  const int cols = 22, rows = 16;  // ceil(64 / 3), ceil(48 / 3)
  ASSERT_EQ(pts.size(), static_cast<size_t>(cols * rows));
  EXPECT_EQ(st.pixels, pts.size());
  EXPECT_EQ(st.with_normal, pts.size());
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const Point& p = pts[static_cast<size_t>(r * cols + c)];
      const int x = c * 3, y = r * 3;
      const double z = view.depth.at<float>(y, x);
      EXPECT_NEAR(p.x, (x - 31.5) / 100 * z, 1e-6);
      EXPECT_NEAR(p.y, (y - 23.5) / 100 * z, 1e-6);
      EXPECT_NEAR(p.z, z, 1e-6);
      const cv::Vec3b bgr = view.colour.at<cv::Vec3b>(y, x);
      EXPECT_EQ(p.b, bgr[0]);
      EXPECT_EQ(p.g, bgr[1]);
    }
  }
  opt.stride = 0;
  EXPECT_TRUE(PointsFromDepth(view, opt).empty());
}

TEST(PointsFromDepth, SigmaZMap) {
  const CameraModel cam = MakeCamera(100, 100, 8, 6, 17, 13);  // pixel (8, 6) on the axis
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(13, 17, CV_32F, cv::Scalar(3.0f));
  view.colour = PixelColours(17, 13);
  view.sigma_z = cv::Mat(13, 17, CV_32F, cv::Scalar(0.05f));
  view.sigma_z.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  view.sigma_z.at<float>(0, 1) = std::numeric_limits<float>::infinity();
  view.sigma_z.at<float>(0, 2) = -1.0f;
  PointStats st;
  const std::vector<Point> pts = PointsFromDepth(view, {}, &st);
  EXPECT_EQ(st.valid, 17u * 13u - 3);
  ASSERT_EQ(pts.size(), 17u * 13u - 3);
  // On the optical axis V = diag((z / fx)^2, (z / fy)^2, sigma_z^2).
  const Point& p = pts[6 * 17 + 8 - 3];
  EXPECT_NEAR(p.x, 0, 1e-7);
  EXPECT_NEAR(p.y, 0, 1e-7);
  EXPECT_NEAR(p.cov[0], 0.03 * 0.03, 1e-9);
  EXPECT_NEAR(p.cov[3], 0.03 * 0.03, 1e-9);
  EXPECT_NEAR(p.cov[5], 0.05 * 0.05, 1e-9);
  EXPECT_NEAR(p.cov[1], 0, 1e-12);
  EXPECT_NEAR(p.cov[2], 0, 1e-12);
  EXPECT_NEAR(p.cov[4], 0, 1e-12);
}

TEST(PointsFromDepth, MalformedViewsGiveNothing) {
  const CameraModel cam = MakeCamera(100, 100, 8, 6, 16, 12);
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(12, 16, CV_32F, cv::Scalar(1.0f));
  view.colour = PixelColours(16, 12);
  EXPECT_EQ(PointsFromDepth(view, {}).size(), 16u * 12u);
  DepthView v = view;
  v.camera = nullptr;
  EXPECT_TRUE(PointsFromDepth(v, {}).empty());
  v = view;
  v.depth.convertTo(v.depth, CV_64F);
  EXPECT_TRUE(PointsFromDepth(v, {}).empty());
  v = view;
  v.colour = PixelColours(15, 12);
  EXPECT_TRUE(PointsFromDepth(v, {}).empty());
  v = view;
  v.colour = cv::Mat();
  EXPECT_TRUE(PointsFromDepth(v, {}).empty());
  v = view;
  v.sigma_z = cv::Mat(11, 16, CV_32F, cv::Scalar(0.01f));
  EXPECT_TRUE(PointsFromDepth(v, {}).empty());
}

TEST(DepthSigmaFromDisparity, MatchesEq58) {
  cv::Mat d = (cv::Mat_<float>(2, 4) << 10, 20, 40, 0,  //
               5, -3, std::numeric_limits<float>::infinity(),
               std::numeric_limits<float>::quiet_NaN());
  cv::Mat dx = (cv::Mat_<float>(2, 4) << 0, 0.5f, -2, 1,  //
                std::numeric_limits<float>::quiet_NaN(), 0, 0, 0);
  const double baseline = 0.12, fx = 800, sc = 0.25;
  const cv::Mat s = DepthSigmaFromDisparity(d, dx, baseline, fx, sc);
  ASSERT_EQ(s.type(), CV_32F);
  ASSERT_EQ(s.size(), d.size());
  EXPECT_NEAR(s.at<float>(0, 0), 0.12 * 800 / 100 * (0 + 0.25), 1e-6);
  EXPECT_NEAR(s.at<float>(0, 1), 0.12 * 800 / 400 * (0.5 + 0.25), 1e-6);
  EXPECT_NEAR(s.at<float>(0, 2), 0.12 * 800 / 1600 * (2 + 0.25), 1e-6);  // |d_x|
  EXPECT_NEAR(s.at<float>(1, 0), 0.12 * 800 / 25 * 0.25, 1e-6);          // NaN gradient: 0
  EXPECT_TRUE(std::isinf(s.at<float>(0, 3)));                            // invalid disparities
  EXPECT_TRUE(std::isinf(s.at<float>(1, 1)));
  EXPECT_TRUE(std::isinf(s.at<float>(1, 2)));
  EXPECT_TRUE(std::isinf(s.at<float>(1, 3)));
  EXPECT_TRUE(DepthSigmaFromDisparity(d, cv::Mat(3, 4, CV_32F), baseline, fx, sc).empty());

  // Fed to PointsFromDepth, the invalid pixels make no points and the others carry the sigma.
  const CameraModel cam = MakeCamera(800, 800, 1.5, 0.5, 4, 2);
  DepthView view;
  view.camera = &cam;
  view.depth = cv::Mat(2, 4, CV_32F, cv::Scalar(1.0f));
  view.colour = PixelColours(4, 2);
  view.sigma_z = s;
  const std::vector<Point> pts = PointsFromDepth(view, {});
  ASSERT_EQ(pts.size(), 4u);
  const Point& p = pts[0];  // pixel (0, 0): ray (-1.5/800, -0.5/800, 1)
  EXPECT_NEAR(p.cov[5], std::pow(s.at<float>(0, 0), 2), 1e-7);
}

}  // namespace
}  // namespace hvdb::ingest
