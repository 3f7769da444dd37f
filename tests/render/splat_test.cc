// The EWA set-up: cameras, projection, footprints, LOD growth, blending weights.
#include "render/splat.h"

#include <gtest/gtest.h>

#include <cmath>

#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

using internal::Splat;
using internal::View;

Point IsotropicPoint(float x, float y, float z, float sigma) {
  Point p;
  p.x = x;
  p.y = y;
  p.z = z;
  p.cov = {sigma * sigma, 0, 0, sigma * sigma, 0, sigma * sigma};
  p.flags = kFlagHasCovariance;
  p.r = p.g = p.b = 200;
  return p;
}

// A camera at the origin looking along +z (world = camera frame).
Camera Pinhole(uint32_t w = 640, uint32_t h = 480, double f = 500) {
  Camera c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = f;
  c.cx = (w - 1) / 2.0;
  c.cy = (h - 1) / 2.0;
  return c;
}

Splat Project(const Point& p, const Camera& c, RenderOptions o = {}) {
  auto view = internal::PrepareView(c, o);
  EXPECT_TRUE(view.ok()) << view.status().ToString();
  Splat s{};
  EXPECT_TRUE(internal::ProjectSplat(p, *view, {}, &s));
  return s;
}

// Screen standard deviation along x of a splat (from its conic: Sigma'_xx = cc / det).
double SigmaX(const Splat& s) {
  double det = double(s.ca) * s.cc - double(s.cb) * s.cb;
  return std::sqrt(s.cc / det);
}

TEST(CameraTest, LookAtUsesOpenCvAxes) {
  Camera c = Camera::LookAt({0, 0, -3}, {0, 0, 0}, {0, 1, 0}, 60, 200, 100);
  ASSERT_TRUE(c.Validate().ok());
  EXPECT_DOUBLE_EQ(c.cx, 99.5);
  EXPECT_DOUBLE_EQ(c.cy, 49.5);
  EXPECT_NEAR(c.fy, 50 / std::tan(M_PI / 6), 1e-9);
  Splat centre = Project(IsotropicPoint(0, 0, 0, 0.01f), c);
  EXPECT_NEAR(centre.u, 99.5, 1e-3);
  EXPECT_NEAR(centre.v, 49.5, 1e-3);
  EXPECT_NEAR(centre.z, 3.0, 1e-5);
  // World up appears towards the top of the image (smaller v).
  EXPECT_LT(Project(IsotropicPoint(0, 0.5f, 0, 0.01f), c).v, 49.5);
  // Looking along +z with y up, world +x is on the left.
  EXPECT_LT(Project(IsotropicPoint(0.5f, 0, 0, 0.01f), c).u, 99.5);
}

TEST(CameraTest, ResizedScalesIntrinsicsAboutPixelEdges) {
  Camera c = Pinhole(640, 480, 500);
  Camera half = c.Resized(320, 240);
  EXPECT_DOUBLE_EQ(half.fx, 250);
  EXPECT_DOUBLE_EQ(half.cx, (c.cx + 0.5) / 2 - 0.5);
  // The same 3D point lands on the same relative image position.
  Point p = IsotropicPoint(0.3f, -0.2f, 2, 0.01f);
  Splat a = Project(p, c), b = Project(p, half);
  EXPECT_NEAR((a.u + 0.5) / 2 - 0.5, b.u, 1e-3);
  EXPECT_NEAR((a.v + 0.5) / 2 - 0.5, b.v, 1e-3);
}

TEST(CameraTest, ValidateNamesTheProblem) {
  Camera c = Pinhole();
  c.width = 0;
  EXPECT_TRUE(c.Validate().IsInvalidArgument());
  c.width = 4097;
  EXPECT_NE(c.Validate().message().find("4096"), std::string::npos);
  c = Pinhole();
  c.fx = -1;
  EXPECT_TRUE(c.Validate().IsInvalidArgument());
  c = Pinhole();
  c.world_from_camera[0] = 2;  // not a rotation
  EXPECT_NE(c.Validate().message().find("orthonormal"), std::string::npos);
  c = Pinhole();
  c.world_from_camera[0] = -1;  // a reflection
  EXPECT_NE(c.Validate().message().find("reflection"), std::string::npos);
  EXPECT_FALSE(Camera::LookAt({0, 0, 0}, {0, 0, 0}, {0, 1, 0}, 50, 10, 10).Validate().ok());
  EXPECT_FALSE(Camera::LookAt({0, 0, 0}, {0, 1, 0}, {0, 1, 0}, 50, 10, 10).Validate().ok());
  RenderOptions o;
  o.cutoff_radius = 0;
  EXPECT_TRUE(CheckRenderArguments(Pinhole(), o).IsInvalidArgument());
  o = {};
  o.width = 100;  // without height
  EXPECT_TRUE(CheckRenderArguments(Pinhole(), o).IsInvalidArgument());
  EXPECT_TRUE(CheckRenderArguments(Pinhole(), {}).ok());
}

TEST(SplatTest, FootprintIsTheProjectedGaussian) {
  // An isotropic Gaussian of sigma 1 cm at 2 m through f = 500: 2.5 px, plus the filter.
  RenderOptions o;
  o.filter_variance = 0;
  Splat s = Project(IsotropicPoint(0, 0, 2, 0.01f), Pinhole(), o);
  EXPECT_NEAR(SigmaX(s), 2.5, 1e-3);
  o.filter_variance = 1;
  s = Project(IsotropicPoint(0, 0, 2, 0.01f), Pinhole(), o);
  EXPECT_NEAR(SigmaX(s), std::sqrt(2.5 * 2.5 + 1), 1e-3);
  // The bounding box is the cutoff ellipse's: r_C sigma either side of the centre.
  double ex = o.cutoff_radius * SigmaX(s);
  EXPECT_EQ(s.x0, static_cast<int>(std::ceil(s.u - ex)));
  EXPECT_EQ(s.x1, static_cast<int>(std::floor(s.u + ex)));
}

TEST(SplatTest, LevelOfDetailGrowsSplatsBy2PowHalfLevel) {
  // Thesis 8.4: at level i the renderer grows points by 2^(i/2).
  Point p = IsotropicPoint(0.1f, 0, 3, 0.01f);
  RenderOptions o;
  o.filter_variance = 0;
  double base = SigmaX(Project(p, Pinhole(), o));
  for (int level = 1; level <= 5; ++level) {
    o.splat_scale = static_cast<float>(std::pow(2.0, level / 2.0));
    EXPECT_NEAR(SigmaX(Project(p, Pinhole(), o)) / base, std::pow(2.0, level / 2.0), 1e-4)
        << "level " << level;
  }
}

TEST(SplatTest, PointsWithoutCovarianceUseTheDefaultSigma) {
  Point p = IsotropicPoint(0, 0, 2, 0.01f);
  p.flags = 0;
  p.cov = {};
  RenderOptions o;
  o.filter_variance = 0;
  o.default_sigma = 0.02f;
  EXPECT_NEAR(SigmaX(Project(p, Pinhole(), o)), 5.0, 1e-3);
}

TEST(SplatTest, CullsBehindNearPlaneAndOffImage) {
  auto view = internal::PrepareView(Pinhole(), {});
  ASSERT_TRUE(view.ok());
  Splat s;
  EXPECT_FALSE(internal::ProjectSplat(IsotropicPoint(0, 0, -1, 0.01f), *view, {}, &s));
  EXPECT_FALSE(internal::ProjectSplat(IsotropicPoint(0, 0, 0.001f, 0.01f), *view, {}, &s));
  EXPECT_FALSE(internal::ProjectSplat(IsotropicPoint(50, 0, 1, 0.01f), *view, {}, &s));
  Point nan = IsotropicPoint(NAN, 0, 1, 0.01f);
  EXPECT_FALSE(internal::ProjectSplat(nan, *view, {}, &s));
  // Partly visible at the image border: kept, its box clipped.
  ASSERT_TRUE(internal::ProjectSplat(IsotropicPoint(-1.28f, 0, 2, 0.05f), *view, {}, &s));
  EXPECT_EQ(s.x0, 0);
}

TEST(SplatTest, DistortionJacobianMatchesFiniteDifferences) {
  // The screen covariance is J V J^T with J the Jacobian of the distorted projection: compare
  // with J estimated from how the projected centre moves.
  Camera c = Pinhole(1920, 1080, 1050);
  c.distortion = {0.05, -0.06, 0.0007, -0.0005, 0.017};
  RenderOptions o;
  o.filter_variance = 0;
  auto view = internal::PrepareView(c, o);
  ASSERT_TRUE(view.ok());
  const double V[3][3] = {{4e-6, 1e-6, 0}, {1e-6, 9e-6, -2e-6}, {0, -2e-6, 1e-6}};
  for (float x : {-0.8f, 0.0f, 0.6f}) {
    for (float y : {-0.4f, 0.3f}) {
      Point p = IsotropicPoint(x, y, 2, 0.01f);
      double J[2][3];
      for (int k = 0; k < 3; ++k) {
        Point pa = p, pb = p;
        (&pa.x)[k] -= 1e-3f;
        (&pb.x)[k] += 1e-3f;
        Splat a, b;
        ASSERT_TRUE(internal::ProjectSplat(pa, *view, {}, &a));
        ASSERT_TRUE(internal::ProjectSplat(pb, *view, {}, &b));
        J[0][k] = (double(b.u) - a.u) / 2e-3;
        J[1][k] = (double(b.v) - a.v) / 2e-3;
      }
      double want[2][2] = {};
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) {
          for (int k = 0; k < 3; ++k) {
            for (int l = 0; l < 3; ++l) want[i][j] += J[i][k] * V[k][l] * J[j][l];
          }
        }
      }
      p.cov = {4e-6f, 1e-6f, 0, 9e-6f, -2e-6f, 1e-6f};
      Splat s;
      ASSERT_TRUE(internal::ProjectSplat(p, *view, {}, &s));
      double det = double(s.ca) * s.cc - double(s.cb) * s.cb;
      double got[2][2] = {{s.cc / det, -s.cb / det}, {-s.cb / det, s.ca / det}};
      for (int i = 0; i < 2; ++i) {
        for (int j = 0; j < 2; ++j) {
          EXPECT_NEAR(got[i][j], want[i][j], 0.01 * std::abs(want[0][0] + want[1][1]))
              << "at " << x << " " << y << " entry " << i << j;
        }
      }
    }
  }
}

TEST(SplatTest, DepthSlopeFollowsATiltedSurfel) {
  // A surfel in the plane z = 2 + 0.5 x: the mean depth along the ray through a pixel offset
  // follows the plane.
  float t1[3] = {1 / std::sqrt(1.25f), 0, 0.5f / std::sqrt(1.25f)}, t2[3] = {0, 1, 0};
  float n[3] = {-0.5f / std::sqrt(1.25f), 0, 1 / std::sqrt(1.25f)};
  Point p = testing::Surfel(0, 0, 2, t1, t2, n, 0.02f, 255, 255, 255);
  RenderOptions o;
  o.filter_variance = 0;
  Splat s = Project(p, Pinhole(), o);
  // Pixel offset dx corresponds to world x ~ dx * z / f (first order): depth slope 0.5 z / f.
  EXPECT_NEAR(s.dzdx, 0.5 * 2 / 500.0, 2e-4);
  EXPECT_NEAR(s.dzdy, 0, 1e-5);
}

TEST(BlendingWeightsTest, Equations515To517) {
  Camera virt = testing::ViewFrom(0, 0, 1, 3, 10, 10);
  std::vector<SourceCamera> src;
  auto add = [&](uint16_t id, double angle_deg) {
    double a = angle_deg * M_PI / 180;
    src.push_back(
        {id, testing::ViewFrom(std::sin(a), 0, std::cos(a), 3, 10, 10).world_from_camera});
  };
  add(1, 10);
  add(2, 20);
  add(3, 40);
  std::vector<double> w = internal::BlendingWeights(virt, src);
  ASSERT_EQ(w.size(), 3u);
  // w' = (1 - a / a_max) / a (eq. 5.16), normalised (5.17).
  double a1 = 10 * M_PI / 180, a2 = 20 * M_PI / 180, a3 = 40 * M_PI / 180;
  double p1 = (1 - a1 / a3) / a1, p2 = (1 - a2 / a3) / a2, sum = p1 + p2;
  EXPECT_NEAR(w[0], p1 / sum, 1e-9);
  EXPECT_NEAR(w[1], p2 / sum, 1e-9);
  EXPECT_NEAR(w[2], 0, 1e-12);  // the farthest camera gets no weight
  // A source camera on the virtual view dominates (clamped, not infinite).
  add(4, 0);
  w = internal::BlendingWeights(virt, src);
  EXPECT_GT(w[3], 0.99);
  EXPECT_TRUE(std::isfinite(w[3]));
  // The table is relative to the best camera and clamped below.
  RenderOptions o;
  o.view_dependent = true;
  o.source_cameras = src;
  o.min_view_weight = 0.05f;
  std::vector<float> table = internal::ViewWeightTable(virt, o);
  ASSERT_EQ(table.size(), 5u);
  EXPECT_FLOAT_EQ(table[0], 1.0f);  // id 0 is not a source camera
  EXPECT_FLOAT_EQ(table[4], 1.0f);
  EXPECT_FLOAT_EQ(table[3], 0.05f);
  EXPECT_GE(table[1], 0.05f);
  EXPECT_TRUE(internal::ViewWeightTable(virt, {}).empty());
}

TEST(StableOrderTest, SortsAndKeepsTies) {
  std::vector<float> keys = {3, 1, 2, 1, 0.5f, 3, 1e6f, 2};
  std::vector<uint32_t> order = internal::StableOrder(keys);
  std::vector<uint32_t> want = {4, 1, 3, 2, 7, 0, 5, 6};
  EXPECT_EQ(order, want);
}

}  // namespace
}  // namespace hvdb::render
