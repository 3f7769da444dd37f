// The differentiable 3DGS rasteriser (render/gaussian_grad.h): its forward pass against the
// render mode's rasteriser, and its gradient against central finite differences of the forward
// pass for every kind of stored value (position, log scale, quaternion, logit opacity, SH DC and
// every SH degree), on seeded random scenes.
#include "render/gaussian_grad.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "render/gaussian_raster.h"

namespace hvdb::render {
namespace {

using formats::GaussianCloud;

// n splats in a 1 m cube about the origin, seen from 3 m by a small camera.
GaussianCloud RandomScene(size_t n, int sh_degree, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  GaussianCloud g;
  g.sh_degree = sh_degree;
  g.Resize(n);
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) g.position[3 * i + k] = 0.5f * u(rng);
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = std::log(0.12f) + 0.5f * u(rng);
    for (int k = 0; k < 4; ++k) g.rotation[4 * i + k] = u(rng);
    g.opacity[i] = 1.0f + 1.5f * u(rng);
    for (int k = 0; k < 3; ++k) g.sh_dc[3 * i + k] = 1.2f * u(rng);
  }
  for (float& v : g.sh_rest) v = 0.3f * u(rng);
  return g;
}

Camera TestCamera(double angle) {
  return Camera::LookAt({3 * std::sin(angle), -0.4, -3 * std::cos(angle)}, {0, 0, 0}, {0, -1, 0},
                        45, 64, 48);
}

TEST(GaussianGradTest, ForwardIsTheRenderModesImage) {
  for (int degree = 0; degree <= 3; ++degree) {
    const GaussianCloud g = RandomScene(400, degree, 7 + degree);
    const Camera cam = TestCamera(0.3 * degree);
    GaussianImage want;
    ASSERT_TRUE(RenderGaussians(g, cam, {}, &want).ok());
    GaussianGradRasterizer r;
    std::vector<float> got;
    ASSERT_TRUE(r.Forward(g, cam, {0, 0, 0}, 2, &got).ok());
    ASSERT_EQ(got.size(), want.rgb.size());
    size_t close = 0;
    double worst = 0;
    for (size_t i = 0; i < got.size(); ++i) {
      const double d = std::fabs(got[i] - want.rgb[i]);
      worst = std::max(worst, d);
      close += d < 1e-4;
    }
    // Float rounding differs (the render mode's exp and operation order); a pixel whose
    // transmittance lands at the stopping threshold may stop one splat apart.
    EXPECT_GE(close, got.size() * 999 / 1000) << "degree " << degree << ", worst " << worst;
    EXPECT_GT(r.visible(), 100u);
  }
}

// L = sum w . rgb for fixed random weights w, in double.
double Loss(const GaussianCloud& g, const Camera& cam, const std::vector<float>& w,
            const std::array<float, 3>& bg) {
  GaussianGradRasterizer r;
  std::vector<float> rgb;
  EXPECT_TRUE(r.Forward(g, cam, bg, 1, &rgb).ok());
  double sum = 0;
  for (size_t i = 0; i < rgb.size(); ++i) sum += static_cast<double>(w[i]) * rgb[i];
  return sum;
}

// The render is discontinuous where a splat's alpha crosses 1/255 (the reference skips it
// there): moving a splat moves that edge across pixels, each a jump that no difference step
// resolves. So each check weighs only the pixels well inside the splat checked (where it adds
// at least 0.03 to some channel), which its edge does not reach in a step; there the render
// is smooth in that splat's values, and other splats' edges do not move.
void ExpectGradientsAgree(const GaussianCloud& g0, const Camera& cam) {
  const std::array<float, 3> bg{0.2f, 0.5f, 0.1f};
  const size_t values = 3u * cam.width * cam.height;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> u(-1, 1);
  std::vector<float> w(values);
  for (float& v : w) v = u(rng);
  std::vector<float> all;
  {
    GaussianGradRasterizer r;
    ASSERT_TRUE(r.Forward(g0, cam, bg, 1, &all).ok());
  }
  // Splat i's pixels: where removing it changes the render by more than 0.03.
  auto inside = [&](size_t i) {
    GaussianCloud without = g0;
    without.opacity[i] = -100.0f;
    GaussianGradRasterizer r;
    std::vector<float> rgb;
    EXPECT_TRUE(r.Forward(without, cam, bg, 1, &rgb).ok());
    std::vector<float> mask(values, 0.0f);
    size_t count = 0;
    for (size_t p = 0; p < values / 3; ++p) {
      bool in = false;
      for (int c = 0; c < 3; ++c) in = in || std::fabs(rgb[3 * p + c] - all[3 * p + c]) > 0.03f;
      if (in) mask[3 * p] = mask[3 * p + 1] = mask[3 * p + 2] = 1.0f, ++count;
    }
    return std::pair(mask, count);
  };

  struct Kind {
    const char* name;
    std::vector<float> GaussianCloud::*array;
    size_t width;
  };
  const Kind kinds[] = {
      {"position", &GaussianCloud::position, 3}, {"scale", &GaussianCloud::scale, 3},
      {"rotation", &GaussianCloud::rotation, 4}, {"opacity", &GaussianCloud::opacity, 1},
      {"sh_dc", &GaussianCloud::sh_dc, 3},       {"sh_rest", &GaussianCloud::sh_rest, 45}};
  // The splats checked: those covering at least 12 pixels.
  std::vector<std::pair<size_t, std::vector<float>>> splats;
  for (size_t i = 0; i < g0.size() && splats.size() < 12; ++i) {
    auto [mask, count] = inside(i);
    if (count >= 12) splats.emplace_back(i, std::move(mask));
  }
  ASSERT_GE(splats.size(), 8u);
  const float eps = 1e-3f;
  for (const Kind& kind : kinds) {
    int agree = 0, checks = 0;
    double largest = 0;
    std::string misses;
    for (const auto& [i, mask] : splats) {
      std::vector<float> wi(values);
      for (size_t k = 0; k < values; ++k) wi[k] = w[k] * mask[k];
      GaussianGradRasterizer r;
      std::vector<float> rgb;
      ASSERT_TRUE(r.Forward(g0, cam, bg, 2, &rgb).ok());
      GaussianGradient grad;
      r.Backward(wi, &grad);
      for (int c = 0; c < 3; ++c) {
        const size_t k = i * kind.width + rng() % kind.width;
        GaussianCloud plus = g0, minus = g0;
        (plus.*kind.array)[k] += eps;
        (minus.*kind.array)[k] -= eps;
        const double fd = (Loss(plus, cam, wi, bg) - Loss(minus, cam, wi, bg)) / (2 * eps);
        const double a = (grad.*kind.array)[k];
        largest = std::max(largest, std::fabs(a));
        ++checks;
        if (std::fabs(fd - a) <= 0.02 * std::fabs(a) + 2e-3) {
          ++agree;
        } else {
          misses += " [splat " + std::to_string(i) + " value " + std::to_string(k) + ": " +
                    std::to_string(a) + " vs " + std::to_string(fd) + "]";
        }
      }
    }
    EXPECT_EQ(agree, checks) << kind.name << ": analytic vs finite difference:" << misses;
    EXPECT_GT(largest, 0.05) << kind.name << ": the checks saw no gradient";
  }
}

TEST(GaussianGradTest, GradientsAgreeWithFiniteDifferences) {
  ExpectGradientsAgree(RandomScene(60, 3, 11), TestCamera(0.4));
}

// Where the reference's backward pass departs from its forward function: splats whose alpha is
// clamped at 0.99 (opacity logit 6) and splats beyond 1.3 times the field of view, whose EWA
// Jacobian is taken at the clamped x/z (large, so that they still reach into the image).
TEST(GaussianGradTest, GradientsAgreeAtTheClampsToo) {
  GaussianCloud g = RandomScene(60, 2, 17);
  for (size_t i = 0; i < g.size(); ++i) {
    if (i % 3 == 0) g.opacity[i] = 6.0f;
    if (i % 3 == 1) {
      g.position[3 * i] = (i % 2 ? 1.0f : -1.0f) * 2.2f;  // x/z ~ 0.75 from 3 m; the limit 0.54
      for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = std::log(0.5f);
    }
  }
  ExpectGradientsAgree(g, Camera::LookAt({0, 0, -3}, {0, 0, 0}, {0, -1, 0}, 45, 64, 48));
}

TEST(GaussianGradTest, BackwardIsTheSameOnAnyNumberOfThreads) {
  const GaussianCloud g = RandomScene(3000, 2, 3);
  const Camera cam = TestCamera(1.0);
  std::vector<float> w(3u * cam.width * cam.height);
  std::mt19937_64 rng(1);
  for (float& v : w) v = static_cast<float>(rng() % 1000) / 1000.0f - 0.5f;
  GaussianGradient one, four;
  for (int threads : {1, 4}) {
    GaussianGradRasterizer r;
    std::vector<float> rgb;
    ASSERT_TRUE(r.Forward(g, cam, {0, 0, 0}, threads, &rgb).ok());
    r.Backward(w, threads == 1 ? &one : &four);
  }
  EXPECT_EQ(one.position, four.position);
  EXPECT_EQ(one.scale, four.scale);
  EXPECT_EQ(one.rotation, four.rotation);
  EXPECT_EQ(one.opacity, four.opacity);
  EXPECT_EQ(one.sh_dc, four.sh_dc);
  EXPECT_EQ(one.sh_rest, four.sh_rest);
}

TEST(GaussianGradTest, RefusesWhatItCannotDifferentiate) {
  GaussianCloud g = RandomScene(10, 0, 1);
  g.antialiased = true;
  GaussianGradRasterizer r;
  std::vector<float> rgb;
  EXPECT_EQ(r.Forward(g, TestCamera(0), {0, 0, 0}, 1, &rgb).code(), StatusCode::kInvalidArgument);
  g.antialiased = false;
  Camera distorted = TestCamera(0);
  distorted.distortion[0] = 0.1;
  EXPECT_EQ(r.Forward(g, distorted, {0, 0, 0}, 1, &rgb).code(), StatusCode::kInvalidArgument);
  g.opacity.pop_back();
  EXPECT_EQ(r.Forward(g, TestCamera(0), {0, 0, 0}, 1, &rgb).code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace hvdb::render
