// Billboards (thesis 6.1) and their bilateral filter (6.2) against an exact scene: cameras at
// y = 0 looking along +z at a tilted wall (z = 4 + 0.3 X) with a box face in front (z = 2.5,
// |X| < 0.4, |Y| < 0.3). Disparity noise is seeded; ground truth is the analytic depth.
#include "ingest/billboard.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

namespace hvdb::ingest {
namespace {

constexpr double kBaseline = 0.2;

CameraModel Cam(double x) {
  CameraModel c;
  c.name = "cam";
  c.K = {200, 0, 79.5, 0, 200, 59.5, 0, 0, 1};
  c.T = {-x, 0, 0};  // centre at (x, 0, 0), looking along +z
  c.size = {160, 120};
  return c;
}
double Scale(const CameraModel& c) { return c.K(0, 0) * kBaseline; }

// True depth along pixel (u, v) of c: the nearest of the box face and the wall.
double TrueDepth(const CameraModel& c, double u, double v, bool box = true) {
  const double rx = (u - c.K(0, 2)) / c.K(0, 0), ry = (v - c.K(1, 2)) / c.K(1, 1);
  const double ox = c.Centre()[0];
  if (box) {
    const double bx = ox + rx * 2.5, by = ry * 2.5;
    if (std::abs(bx) < 0.4 && std::abs(by) < 0.3) return 2.5;
  }
  // z = 4 + 0.3 (ox + rx z)  =>  z = (4 + 0.3 ox) / (1 - 0.3 rx)
  return (4 + 0.3 * ox) / (1 - 0.3 * rx);
}

// Depth from the true disparity plus Gaussian noise (sigma px) and a bias (px).
cv::Mat NoisyDepth(const CameraModel& c, uint64_t seed, double sigma, double bias = 0,
                   bool box = true) {
  cv::RNG rng(seed);
  cv::Mat d(c.size.height, c.size.width, CV_32F);
  for (int v = 0; v < d.rows; ++v)
    for (int u = 0; u < d.cols; ++u) {
      const double disp = Scale(c) / TrueDepth(c, u, v, box) + bias + rng.gaussian(sigma);
      d.at<float>(v, u) = static_cast<float>(Scale(c) / disp);
    }
  return d;
}

// RMS of (filtered disparity - true disparity) over pixels at least `margin` pixels from the
// box's edge (edge = true disparity changes within the margin), or only those within it.
double DisparityRms(const Billboard& bb, const cv::Mat& displacement, int margin, bool near_edge) {
  const cv::Mat d = BillboardDisparity(bb, displacement);
  double s = 0;
  size_t n = 0;
  for (int v = margin; v < d.rows - margin; ++v)
    for (int u = margin; u < d.cols - margin; ++u) {
      const double t = Scale(bb.camera) / TrueDepth(bb.camera, u, v);
      bool edge = false;
      for (int k = -margin; k <= margin && !edge; ++k)
        edge = std::abs(Scale(bb.camera) / TrueDepth(bb.camera, u + k, v) - t) > 1 ||
               std::abs(Scale(bb.camera) / TrueDepth(bb.camera, u, v + k) - t) > 1;
      if (edge != near_edge || !std::isfinite(d.at<float>(v, u))) continue;
      s += (d.at<float>(v, u) - t) * (d.at<float>(v, u) - t);
      ++n;
    }
  EXPECT_GT(n, 100u);
  return std::sqrt(s / static_cast<double>(n));
}

// Eq. 6.5's cost of a plane for a depth map.
double WorldCost(const cv::Mat& depth, const cv::Matx33d& K, double s, const cv::Vec3d& p) {
  double e2 = 0;
  for (int v = 0; v < depth.rows; ++v)
    for (int u = 0; u < depth.cols; ++u) {
      const double ray = cv::norm(K.inv() * cv::Vec3d(u, v, 1));
      const double e = ray * (s / (p[0] * u + p[1] * v + p[2]) - depth.at<float>(v, u));
      e2 += e * e;
    }
  return e2;
}

TEST(BillboardTest, APlaneInDisparitySpaceIsRecoveredExactly) {
  const CameraModel c = Cam(0);
  const cv::Mat depth = NoisyDepth(c, 1, 0, 0, /*box=*/false);
  auto bb = MakeBillboard(c, depth, {}, {}, Scale(c));
  ASSERT_TRUE(bb.ok()) << bb.status().ToString();
  double worst = 0;
  for (int v = 0; v < depth.rows; ++v)
    for (int u = 0; u < depth.cols; ++u)
      worst = std::max(worst, std::abs(double(bb->displacement.at<float>(v, u))));
  EXPECT_LT(worst, 1e-4);  // disparity pixels
  const cv::Mat back = BillboardDepth(*bb);
  EXPECT_LT(cv::norm(back, depth, cv::NORM_INF), 1e-5);
}

TEST(BillboardTest, ThePlaneMinimisesWorldDisplacementsNotDisparityOnes) {
  const CameraModel c = Cam(0.1);
  const cv::Mat depth = NoisyDepth(c, 2, 0.3);
  auto fit = FitBillboardPlane(depth, {}, c.K, Scale(c));
  ASSERT_TRUE(fit.ok()) << fit.status().ToString();
  const double best = WorldCost(depth, c.K, Scale(c), *fit);
  // A local minimum of eq. 6.5: every small step along a parameter costs more.
  const double step[3] = {1e-4, 1e-4, 1e-2};
  for (int k = 0; k < 3; ++k)
    for (double sign : {-1.0, 1.0}) {
      cv::Vec3d p = *fit;
      p[k] += sign * step[k];
      EXPECT_GT(WorldCost(depth, c.K, Scale(c), p), best) << "parameter " << k;
    }
  // The least-squares plane in disparity space (eq. 6.4) is worse in world units.
  cv::Matx33d A = cv::Matx33d::zeros();
  cv::Vec3d b(0, 0, 0);
  for (int v = 0; v < depth.rows; ++v)
    for (int u = 0; u < depth.cols; ++u) {
      const cv::Vec3d g(u, v, 1);
      A += g * g.t();
      b += (Scale(c) / depth.at<float>(v, u)) * g;
    }
  const cv::Vec3d ls = A.inv() * b;
  EXPECT_LT(best, 0.97 * WorldCost(depth, c.K, Scale(c), ls));
}

TEST(BillboardTest, TheIntraViewFilterRemovesNoiseAndKeepsEdges) {
  const CameraModel c = Cam(0);
  auto bb = MakeBillboard(c, NoisyDepth(c, 3, 0.3), {}, {}, Scale(c));
  ASSERT_TRUE(bb.ok());
  BillboardFilterOptions o;
  o.radius = 5;
  o.temporal_radius = 0;
  o.inter_view = false;
  auto f = FilterBillboards({{&*bb}}, 0, o);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  const double before = DisparityRms(*bb, {}, 3, false), after = DisparityRms(*bb, (*f)[0], 3, false);
  EXPECT_LT(after, before / 3) << before << " -> " << after;
  // At the box's silhouette (a 5-8 px disparity step) the range kernel keeps both sides apart.
  const double edge = DisparityRms(*bb, (*f)[0], 3, true);
  EXPECT_LT(edge, 0.35);
  // Without it (a range threshold wider than the step) the edge is smeared.
  o.delta_d = 100;
  auto smeared = FilterBillboards({{&*bb}}, 0, o);
  ASSERT_TRUE(smeared.ok());
  EXPECT_GT(DisparityRms(*bb, (*smeared)[0], 3, true), 3 * edge);
}

TEST(BillboardTest, TheTemporalKernelReducesFlicker) {
  const CameraModel c = Cam(0);
  std::vector<Billboard> frames;
  for (uint64_t t = 0; t < 7; ++t) {
    auto bb = MakeBillboard(c, NoisyDepth(c, 10 + t, 0.4), {}, {}, Scale(c));
    ASSERT_TRUE(bb.ok());
    frames.push_back(*bb);
  }
  std::vector<std::vector<const Billboard*>> window;
  for (const Billboard& b : frames) window.push_back({&b});
  // Frame-to-frame change of the filtered disparity of a static scene: the flicker.
  auto flicker = [&](int temporal_radius) {
    BillboardFilterOptions o;
    o.radius = 3;
    o.temporal_radius = temporal_radius;
    o.inter_view = false;
    std::vector<cv::Mat> d;
    for (size_t t = 2; t <= 4; ++t) {
      auto f = FilterBillboards(window, t, o);
      EXPECT_TRUE(f.ok());
      d.push_back(BillboardDisparity(frames[t], (*f)[0]));
    }
    double s = 0;
    size_t n = 0;
    for (size_t k = 1; k < d.size(); ++k)
      for (int v = 0; v < d[k].rows; ++v)
        for (int u = 0; u < d[k].cols; ++u) {
          const double e = d[k].at<float>(v, u) - d[k - 1].at<float>(v, u);
          if (!std::isfinite(e)) continue;
          s += e * e;
          ++n;
        }
    return std::sqrt(s / static_cast<double>(n));
  };
  const double spatial = flicker(0), spacetime = flicker(2);
  EXPECT_LT(spacetime, spatial / 1.3) << spatial << " -> " << spacetime;
  // A window that lacks a frame still filters (a recording's first and last frames).
  window[1] = {nullptr};
  BillboardFilterOptions o;
  o.radius = 3;
  EXPECT_TRUE(FilterBillboards(window, 2, o).ok());
}

// A hand-held depth camera: the frames around were taken from elsewhere, so their samples are
// reprojected (like another view's), not laid on the same pixels. They still smooth the noise,
// and the box's edge stays where it is.
TEST(BillboardTest, TheTemporalKernelFollowsAMovingCamera) {
  std::vector<Billboard> frames;
  for (int t = 0; t < 5; ++t) {
    const CameraModel c = Cam(-0.1 + 0.05 * t);
    auto bb = MakeBillboard(c, NoisyDepth(c, 40 + static_cast<uint64_t>(t), 0.4), {}, {}, Scale(c));
    ASSERT_TRUE(bb.ok());
    frames.push_back(*bb);
  }
  std::vector<std::vector<const Billboard*>> window;
  for (const Billboard& b : frames) window.push_back({&b});
  BillboardFilterOptions o;
  o.radius = 3;
  o.inter_view = false;
  o.temporal_radius = 0;
  auto alone = FilterBillboards(window, 2, o);
  o.temporal_radius = 2;
  auto moving = FilterBillboards(window, 2, o);
  ASSERT_TRUE(alone.ok() && moving.ok());
  const double e_alone = DisparityRms(frames[2], (*alone)[0], 4, false);
  const double e_moving = DisparityRms(frames[2], (*moving)[0], 4, false);
  EXPECT_LT(e_moving, e_alone / 1.3) << e_alone << " -> " << e_moving;
  EXPECT_LT(DisparityRms(frames[2], (*moving)[0], 4, true), 0.6);  // the edge kept its place
}

TEST(BillboardTest, TheInterViewFilterReconcilesViewsWithACalibrationError) {
  const CameraModel a = Cam(-0.15), b = Cam(0.15);
  auto ba = MakeBillboard(a, NoisyDepth(a, 20, 0.2), {}, {}, Scale(a));
  // View b measures disparities 0.5 px too large (e.g. a slightly wrong baseline or rotation).
  auto bbv = MakeBillboard(b, NoisyDepth(b, 21, 0.2, 0.5), {}, {}, Scale(b));
  ASSERT_TRUE(ba.ok() && bbv.ok());
  // Mean disparity disagreement: a's samples reprojected into b against b's disparity there.
  auto disagreement = [&](const cv::Mat& da, const cv::Mat& db) {
    const cv::Mat za = BillboardDepth(*ba, da), dispb = BillboardDisparity(*bbv, db);
    double s = 0;
    size_t n = 0;
    for (int v = 0; v < za.rows; ++v)
      for (int u = 0; u < za.cols; ++u) {
        const float z = za.at<float>(v, u);
        if (!(z > 0)) continue;
        const cv::Vec3d X = a.Centre() + a.R.t() * (a.K.inv() * cv::Vec3d(u, v, 1) * z);
        const cv::Vec3d p = b.K * (b.R * X + b.T);
        const int x = static_cast<int>(std::lround(p[0] / p[2])), y = static_cast<int>(std::lround(p[1] / p[2]));
        if (x < 0 || y < 0 || x >= dispb.cols || y >= dispb.rows) continue;
        const double e = dispb.at<float>(y, x) - Scale(b) / p[2];
        if (!std::isfinite(e) || std::abs(e) > 1.5) continue;  // occlusion, not disagreement
        s += e;
        ++n;
      }
    EXPECT_GT(n, 1000u);
    return s / static_cast<double>(n);
  };
  BillboardFilterOptions o;
  o.radius = 4;
  o.temporal_radius = 0;
  o.inter_view = false;
  auto intra = FilterBillboards({{&*ba, &*bbv}}, 0, o);
  o.inter_view = true;
  auto inter = FilterBillboards({{&*ba, &*bbv}}, 0, o);
  ASSERT_TRUE(intra.ok() && inter.ok());
  const double before = disagreement((*intra)[0], (*intra)[1]);
  const double after = disagreement((*inter)[0], (*inter)[1]);
  EXPECT_NEAR(before, 0.5, 0.1);
  EXPECT_LT(std::abs(after), 0.5 * std::abs(before)) << before << " -> " << after;
}

TEST(BillboardTest, BadInputIsAClearError) {
  const CameraModel c = Cam(0);
  EXPECT_FALSE(MakeBillboard(c, cv::Mat(10, 10, CV_32F, cv::Scalar(1)), {}, {}, Scale(c)).ok());
  EXPECT_FALSE(MakeBillboard(c, NoisyDepth(c, 1, 0), {}, {}, 0).ok());
  const cv::Mat none(c.size.height, c.size.width, CV_32F, cv::Scalar(0));
  EXPECT_FALSE(MakeBillboard(c, none, {}, {}, Scale(c)).ok());  // no samples
  auto bb = MakeBillboard(c, NoisyDepth(c, 1, 0.1), {}, {}, Scale(c));
  ASSERT_TRUE(bb.ok());
  BillboardFilterOptions o;
  o.radius = 0;
  EXPECT_FALSE(FilterBillboards({{&*bb}}, 0, o).ok());
  o = {};
  o.delta_d = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(FilterBillboards({{&*bb}}, 0, o).ok());
  o = {};
  EXPECT_FALSE(FilterBillboards({{&*bb}}, 1, o).ok());             // no centre frame
  EXPECT_FALSE(FilterBillboards({{&*bb}, {&*bb, &*bb}}, 0, o).ok()); // views differ per frame
}

}  // namespace
}  // namespace hvdb::ingest
