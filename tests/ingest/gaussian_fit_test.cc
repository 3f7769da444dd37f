// Fitting Gaussians to photos (ingest/gaussian_fit.h, gaussian_loss.h): the loss's gradient
// against finite differences, the starting cloud from points, and fits of synthetic scenes with
// known Gaussians, judged on views the fit never saw; warm starts of a static and of a moving
// scene. Seeded, so every run fits the same.
#include "ingest/gaussian_fit.h"
#include "ingest/gaussian_frames.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "ingest/gaussian_loss.h"
#include "render/gaussian_raster.h"

namespace hvdb::ingest {
namespace {

using formats::GaussianCloud;

TEST(GaussianLossTest, GradientAgreesWithFiniteDifferences) {
  const int w = 24, h = 20;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<float> render(3 * w * h), target(3 * w * h);
  for (size_t i = 0; i < render.size(); ++i) {
    target[i] = u(rng);
    render[i] = 0.5f * target[i] + 0.5f * u(rng);  // correlated, as a render and its photo
  }
  std::vector<float> grad;
  const PhotoLoss at = L1DssimLoss(render, target, w, h, 0.2f, 2, &grad);
  EXPECT_GT(at.ssim, 0.2);
  EXPECT_LT(at.ssim, 1.0);
  for (int c = 0; c < 40; ++c) {
    const size_t k = rng() % render.size();
    if (std::fabs(render[k] - target[k]) < 3e-3f) continue;  // L1's kink
    const float eps = 1e-3f;
    auto plus = render, minus = render;
    plus[k] += eps;
    minus[k] -= eps;
    const double fd = (L1DssimLoss(plus, target, w, h, 0.2f, 1, nullptr).loss -
                       L1DssimLoss(minus, target, w, h, 0.2f, 1, nullptr).loss) /
                      (2 * eps);
    EXPECT_NEAR(grad[k], fd, 0.02 * std::fabs(fd) + 2e-7) << "value " << k;
  }
  // Equal images: SSIM 1, loss 0.
  EXPECT_NEAR(L1DssimLoss(target, target, w, h, 0.2f, 1, nullptr).loss, 0.0, 1e-6);
}

TEST(GaussianFitTest, CloudFromPointsKeepsEachPointsCovarianceAndColour) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<float> u(-1, 1);
  // Points 1 mm apart, narrower than their covariances: these are kept exactly.
  std::vector<Point> points(50);
  for (size_t i = 0; i < points.size(); ++i) {
    Point& p = points[i];
    p.x = 0.001f * static_cast<float>(i), p.y = 0.0005f * static_cast<float>(i % 7), p.z = 1;
    float a[9];
    for (float& v : a) v = 0.05f * u(rng);
    // A A^T + a little: symmetric positive definite.
    for (int r = 0, k = 0; r < 3; ++r) {
      for (int c = r; c < 3; ++c, ++k) {
        p.cov[k] = a[3 * r] * a[3 * c] + a[3 * r + 1] * a[3 * c + 1] + a[3 * r + 2] * a[3 * c + 2] +
                   (r == c ? 1e-5f : 0.0f);
      }
    }
    p.r = static_cast<uint8_t>(rng() % 256), p.g = 40, p.b = 250;
  }
  const GaussianCloud c = CloudFromPoints(points, 2);
  ASSERT_TRUE(formats::ValidateGaussianCloud(c, "fit start").ok());
  ASSERT_EQ(c.size(), points.size());
  EXPECT_EQ(c.sh_degree, 2);
  for (size_t i = 0; i < points.size(); ++i) {
    const auto cov = c.Covariance(i);
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(cov[k], points[i].cov[k], 2e-6) << i << " " << k;
    EXPECT_NEAR(0.5 + formats::kShC0 * c.sh_dc[3 * i], points[i].r / 255.0, 1e-6);
    EXPECT_NEAR(formats::Sigmoid(c.opacity[i]), 0.1, 1e-6);
  }
  // Points 1 m apart with 1 cm deviations grow to their neighbours' distance, shape kept.
  std::vector<Point> sparse(8);
  for (size_t i = 0; i < sparse.size(); ++i) {
    sparse[i].x = static_cast<float>(i % 2), sparse[i].y = static_cast<float>(i / 2 % 2);
    sparse[i].z = static_cast<float>(i / 4);
    sparse[i].cov = {1e-4f, 0, 0, 0.25e-4f, 0, 0.25e-4f};  // 1 cm along x, 0.5 cm across
  }
  const GaussianCloud s = CloudFromPoints(sparse, 0);
  for (size_t i = 0; i < sparse.size(); ++i) {
    const auto cov = s.Covariance(i);
    EXPECT_NEAR(cov[0], 1.0, 1e-4);  // the 3 nearest are 1 m away
    EXPECT_NEAR(cov[3], 0.25, 1e-4);
    EXPECT_NEAR(cov[5], 0.25, 1e-4);
  }
  // A subsample: every 5th of 50.
  EXPECT_EQ(CloudFromPoints(points, 0, 10).size(), 10u);
}

// A scene of known Gaussians: n splats of a 1 m cube, SH degree 1, fairly opaque.
GaussianCloud KnownScene(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  GaussianCloud g;
  g.sh_degree = 1;
  g.Resize(n);
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) g.position[3 * i + k] = 0.5f * u(rng);
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = std::log(0.08f) + 0.4f * u(rng);
    for (int k = 0; k < 4; ++k) g.rotation[4 * i + k] = u(rng);
    g.opacity[i] = 2.0f + u(rng);
    for (int k = 0; k < 3; ++k) g.sh_dc[3 * i + k] = 1.2f * u(rng);
  }
  for (float& v : g.sh_rest) v = 0.2f * u(rng);
  return g;
}

// `count` cameras on a ring of radius 3 about the origin, from angle `phase`, alternately
// above and below.
std::vector<render::Camera> Ring(int count, double phase) {
  std::vector<render::Camera> cams;
  for (int k = 0; k < count; ++k) {
    const double a = phase + 2 * M_PI * k / count;
    const double h = (k % 2 == 0 ? 0.8 : -0.8);
    cams.push_back(render::Camera::LookAt({3 * std::sin(a), h, 3 * std::cos(a)}, {0, 0, 0},
                                          {0, -1, 0}, 45, 64, 48));
  }
  return cams;
}

std::vector<FitView> Photograph(const GaussianCloud& g, const std::vector<render::Camera>& cams) {
  std::vector<FitView> views;
  for (const auto& cam : cams) {
    render::GaussianImage img;
    EXPECT_TRUE(render::RenderGaussians(g, cam, {}, &img).ok());
    views.push_back({cam, img.rgb, {}, {}});
  }
  return views;
}

double MeanPsnr(const GaussianCloud& g, const std::vector<FitView>& views) {
  double sum = 0;
  for (const FitView& v : views) {
    render::GaussianImage img;
    EXPECT_TRUE(render::RenderGaussians(g, v.camera, {}, &img).ok());
    sum += Psnr(img.rgb, v.rgb);
  }
  return sum / views.size();
}

// The known scene disturbed: centres moved by ~2 cm, sizes, opacities and colours off, no
// view-dependent colour.
GaussianCloud Disturbed(const GaussianCloud& truth, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> n(0, 1);
  GaussianCloud g = truth;
  for (float& v : g.position) v += 0.02f * n(rng);
  for (float& v : g.scale) v += 0.2f * n(rng);
  for (float& v : g.opacity) v = formats::Logit(0.3f);
  for (float& v : g.sh_dc) v += 0.3f * n(rng);
  for (float& v : g.sh_rest) v = 0;
  return g;
}

TEST(GaussianFitTest, RecoversKnownGaussiansOnViewsItWasNotFittedTo) {
  const GaussianCloud truth = KnownScene(120, 21);
  const auto train = Photograph(truth, Ring(24, 0.0));
  const auto held_out = Photograph(truth, Ring(5, 0.37));
  GaussianCloud fit = Disturbed(truth, 4);
  const double before = MeanPsnr(fit, held_out);
  FitOptions o;
  o.iterations = 3000;
  o.sh_degree = 1;
  o.sh_degree_interval = 300;
  o.densify = false;
  o.threads = 2;
  FitReport report;
  ASSERT_TRUE(FitGaussians(train, o, &fit, &report).ok());
  const double after = MeanPsnr(fit, held_out);
  EXPECT_GE(after, 40.0) << "held-out PSNR " << before << " -> " << after << " dB; training "
                         << report.psnr << " dB";
  EXPECT_EQ(report.iterations, 3000);
  EXPECT_EQ(fit.size(), truth.size());
}

TEST(GaussianFitTest, DensifiesFromPointsAndGetsClose) {
  // From the known splats' centres as small round points of the wrong colour: densification
  // and pruning must reshape the cloud.
  const GaussianCloud truth = KnownScene(120, 5);
  std::vector<Point> points(truth.size());
  for (size_t i = 0; i < points.size(); ++i) {
    points[i].x = truth.position[3 * i], points[i].y = truth.position[3 * i + 1];
    points[i].z = truth.position[3 * i + 2];
    points[i].cov = {4e-4f, 0, 0, 4e-4f, 0, 4e-4f};
    points[i].r = points[i].g = points[i].b = 128;
  }
  GaussianCloud fit = CloudFromPoints(points, 0);
  FitOptions o;
  o.iterations = 1500;
  o.sh_degree = 1;
  o.densify_from = 100, o.densify_until = 1000, o.densify_interval = 100;
  o.max_splats = 600;
  o.threads = 2;
  FitReport report;
  ASSERT_TRUE(FitGaussians(Photograph(truth, Ring(24, 0.0)), o, &fit, &report).ok());
  EXPECT_NE(fit.size(), truth.size());  // densified and pruned
  EXPECT_LE(fit.size(), 600u);
  EXPECT_GE(MeanPsnr(fit, Photograph(truth, Ring(5, 0.37))), 30.0);
}

TEST(GaussianFitTest, AWarmStartOfAStaticSceneChangesNothing) {
  const GaussianCloud truth = KnownScene(80, 8);
  const auto cams = Ring(12, 0.0);
  auto frame1 = Photograph(truth, cams);
  GaussianCloud fit = Disturbed(truth, 2);
  FitOptions o;
  o.iterations = 300;
  o.densify = false;
  o.threads = 2;
  ASSERT_TRUE(FitGaussians(frame1, o, &fit, nullptr).ok());
  const GaussianCloud after1 = fit;
  auto frame2 = Photograph(truth, cams);  // nothing moved
  for (size_t k = 0; k < cams.size(); ++k) {
    frame2[k].mask = ChangedPixels(frame1[k].rgb, frame2[k].rgb, 64, 48);
  }
  FitReport report;
  ASSERT_TRUE(FitGaussians(frame2, o, &fit, &report).ok());
  EXPECT_EQ(report.iterations, 0);
  EXPECT_EQ(fit.position, after1.position);
  EXPECT_EQ(fit.scale, after1.scale);
  EXPECT_EQ(fit.opacity, after1.opacity);
  EXPECT_EQ(fit.sh_dc, after1.sh_dc);
  EXPECT_EQ(fit.sh_rest, after1.sh_rest);
}

// Points where the known splats are, with their covariances and base colours: what ingest's
// geometry stage would hand the fit.
std::vector<Point> PointsOf(const GaussianCloud& g) {
  std::vector<Point> points(g.size());
  for (size_t i = 0; i < g.size(); ++i) {
    Point& p = points[i];
    p.x = g.position[3 * i], p.y = g.position[3 * i + 1], p.z = g.position[3 * i + 2];
    p.cov = g.Covariance(i);
    auto to8 = [&](int c) {
      const double v = 0.5 + formats::kShC0 * g.sh_dc[3 * i + c];
      return static_cast<uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255));
    };
    p.r = to8(0), p.g = to8(1), p.b = to8(2);
  }
  return points;
}

TEST(GaussianFitTest, AMovingObjectsGaussiansFollowItAndTheRestStaysTheSame) {
  // A wall of 150 splats 1.2 m behind an object of 20 splats that moves 4 cm to the right.
  std::mt19937_64 rng(13);
  std::uniform_real_distribution<float> u(-1, 1);
  GaussianCloud truth = KnownScene(170, 13);
  const size_t object = 20;  // splats [0, 20)
  for (size_t i = 0; i < truth.size(); ++i) {
    float* p = &truth.position[3 * i];
    if (i < object) {  // small splats: the object's footprint stays small
      for (int k = 0; k < 3; ++k) p[k] = 0.07f * u(rng);
      for (int k = 0; k < 3; ++k) truth.scale[3 * i + k] = std::log(0.03f) + 0.3f * u(rng);
    } else {
      p[0] = 1.6f * u(rng), p[1] = 1.1f * u(rng), p[2] = 1.2f + 0.05f * u(rng);
    }
  }
  std::vector<render::Camera> cams;
  for (int k = 0; k < 12; ++k) {  // in front of the scene
    const double a = -0.3 + 0.6 * k / 11;
    cams.push_back(render::Camera::LookAt({3 * std::sin(a), (k % 2 ? 0.3 : -0.3), -3 * std::cos(a)},
                                          {0, 0, 0.5}, {0, -1, 0}, 50, 96, 72));
  }
  GaussianFrameOptions fo;
  fo.fit.iterations = 1500;
  fo.fit.densify = false;
  fo.fit.sh_degree = 1;
  fo.fit.threads = 2;
  fo.warm_iterations = 600;
  GaussianVideoFitter fitter(fo);
  const auto points = PointsOf(truth);
  auto frame0 = fitter.Fit(0, Photograph(truth, cams), points, nullptr);
  ASSERT_TRUE(frame0.ok()) << frame0.status().ToString();
  GaussianCloud moved = truth;
  for (size_t i = 0; i < object; ++i) moved.position[3 * i] += 0.04f;
  const auto views1 = Photograph(moved, cams);
  const double before = MeanPsnr(*frame0, views1);
  FitReport report;
  auto frame1 = fitter.Fit(1, views1, PointsOf(moved), &report);
  ASSERT_TRUE(frame1.ok()) << frame1.status().ToString();
  EXPECT_EQ(report.iterations, 600);  // warm-started
  const double after = MeanPsnr(*frame1, views1);
  EXPECT_GT(after, before + 1) << before << " -> " << after << " dB";
  double dx = 0;
  for (size_t i = 0; i < object; ++i)
    dx += (frame1->position[3 * i] - frame0->position[3 * i]) / object;
  EXPECT_NEAR(dx, 0.04, 0.015);
  // The wall away from the object keeps its values bit for bit: the splats whose centre (where
  // the first fit put it) is over 14 pixels from the object's centre in every view, beyond its
  // footprint and the changed pixels grown by 6.
  auto pixel = [](const render::Camera& c, const float* p) {
    const auto& m = c.world_from_camera;
    double v[3] = {0, 0, 0};
    for (int r = 0; r < 3; ++r) {
      for (int k = 0; k < 3; ++k) v[r] += m[4 * k + r] * (p[k] - m[4 * k + 3]);
    }
    return std::array<double, 2>{c.fx * v[0] / v[2] + c.cx, c.fy * v[1] / v[2] + c.cy};
  };
  size_t far = 0, same = 0;
  const float origin[3] = {0, 0, 0};
  for (size_t i = object; i < truth.size(); ++i) {
    const float* p = &frame0->position[3 * i];
    bool near = false;
    for (const auto& cam : cams) {
      const auto a = pixel(cam, p), b = pixel(cam, origin);
      near = near || std::hypot(a[0] - b[0], a[1] - b[1]) < 14;
    }
    if (near) continue;
    ++far;
    bool equal = true;
    for (int k = 0; k < 3; ++k)
      equal = equal && frame1->position[3 * i + k] == frame0->position[3 * i + k];
    for (int k = 0; k < 3; ++k)
      equal = equal && frame1->sh_dc[3 * i + k] == frame0->sh_dc[3 * i + k];
    equal = equal && frame1->opacity[i] == frame0->opacity[i];
    same += equal;
  }
  EXPECT_EQ(same, far);
  EXPECT_GE(far, 40u);
}

TEST(GaussianFitTest, ACancelledFitStopsAtTheNextIteration) {
  GaussianCloud g = KnownScene(20, 3);
  const auto views = Photograph(g, Ring(4, 0));
  FitOptions o;
  o.iterations = 1000;
  o.threads = 1;
  int asked = 0;
  o.cancelled = [&asked] { return ++asked > 5; };
  const Status st = FitGaussians(views, o, &g);
  EXPECT_EQ(st.code(), StatusCode::kCancelled) << st.ToString();
  EXPECT_EQ(asked, 6);
}

TEST(GaussianFitTest, RefusesViewsThatDoNotMatchTheirCameras) {
  GaussianCloud g = KnownScene(10, 1);
  auto views = Photograph(g, Ring(2, 0));
  views[1].rgb.pop_back();
  EXPECT_EQ(FitGaussians(views, {}, &g).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(FitGaussians({}, {}, &g).code(), StatusCode::kInvalidArgument);
  GaussianCloud empty;
  EXPECT_EQ(FitGaussians(Photograph(g, Ring(2, 0)), {}, &empty).code(),
            StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace hvdb::ingest
