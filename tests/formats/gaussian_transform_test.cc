// formats/gaussian_transform.h: a similarity moves each splat's mean, covariance and
// view-dependent colour together. The SH rotation is checked three ways: the colour seen along
// R d afterwards equals the one along d before (at random directions), the coefficients equal a
// brute-force resampling (the rotated colour function projected back onto the basis by
// quadrature over the sphere), and a half turn about z flips exactly the signs glTF's axis
// conversion flips. Deterministic: fixed seeds.
#include "formats/gaussian_transform.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <numbers>
#include <random>

namespace hvdb::formats {
namespace {

GaussianCloud RandomCloud(uint64_t seed, int degree, size_t n) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(-1, 1);
  GaussianCloud c;
  c.sh_degree = degree;
  c.Resize(n);
  for (float& v : c.position) v = 10 * u(rng);
  for (float& v : c.scale) v = -3 + u(rng);
  for (float& v : c.rotation) v = 2 * u(rng);
  for (float& v : c.opacity) v = 4 * u(rng);
  for (float& v : c.sh_dc) v = u(rng);
  for (float& v : c.sh_rest) v = 0.5f * u(rng);
  return c;
}

std::array<double, 3> RandomDirection(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  std::array<double, 3> d{g(rng), g(rng), g(rng)};
  const double n = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  for (double& v : d) v /= n;
  return d;
}

std::array<double, 3> Apply(const std::array<double, 9>& r, const std::array<double, 3>& d) {
  return {r[0] * d[0] + r[1] * d[1] + r[2] * d[2], r[3] * d[0] + r[4] * d[1] + r[5] * d[2],
          r[6] * d[0] + r[7] * d[1] + r[8] * d[2]};
}

TEST(GaussianTransform, ColourAlongTheRotatedDirectionIsKept) {
  for (int degree = 1; degree <= 3; ++degree) {
    SCOPED_TRACE(degree);
    const GaussianCloud before = RandomCloud(degree, degree, 200);
    GaussianCloud after = before;
    const Similarity m = Similarity::FromEulerDegrees(31, -47, 122);
    ASSERT_TRUE(TransformCloud(&after, m, "x").ok());
    const size_t k = static_cast<size_t>(ShRestPerChannel(degree));
    std::mt19937_64 rng(7);
    for (size_t i = 0; i < 3 * before.size(); ++i) {  // every channel of every splat
      for (int t = 0; t < 5; ++t) {
        const auto d = RandomDirection(rng);
        EXPECT_NEAR(EvalShRest(degree, &after.sh_rest[i * k], Apply(m.rotation, d)),
                    EvalShRest(degree, &before.sh_rest[i * k], d), 2e-6);
      }
    }
  }
}

// c'_k = integral over the sphere of f(R^T d) Y_k(d), over that of Y_k^2 (the basis is
// orthogonal): a Fibonacci lattice of 200 000 directions, accurate to ~1e-6 for these degrees.
TEST(GaussianTransform, ShMatchesBruteForceResampling) {
  const Similarity m = Similarity::FromEulerDegrees(-65, 12, 203);
  for (int l = 1; l <= 3; ++l) {
    SCOPED_TRACE(l);
    const int n = 2 * l + 1;
    std::mt19937_64 rng(l);
    std::uniform_real_distribution<float> u(-1, 1);
    float coef[15] = {};
    const int first = l * l - 1;  // the degree's first coefficient among 1..3
    for (int k = 0; k < n; ++k) coef[first + k] = u(rng);
    const std::vector<double> mt = ShRotationMatrix(l, m.rotation);
    constexpr int kN = 200000;
    std::vector<double> num(n, 0.0), den(n, 0.0);
    for (int i = 0; i < kN; ++i) {
      const double z = 1 - (2 * i + 1) / static_cast<double>(kN);
      const double rho = std::sqrt(1 - z * z), phi = i * std::numbers::pi * (3 - std::sqrt(5.0));
      const std::array<double, 3> d{rho * std::cos(phi), rho * std::sin(phi), z};
      // f(R^T d): R^T d is R's transpose applied.
      const auto& r = m.rotation;
      const std::array<double, 3> rd{r[0] * d[0] + r[3] * d[1] + r[6] * d[2],
                                     r[1] * d[0] + r[4] * d[1] + r[7] * d[2],
                                     r[2] * d[0] + r[5] * d[1] + r[8] * d[2]};
      const double f = EvalShRest(3, coef, rd);
      for (int k = 0; k < n; ++k) {
        float unit[15] = {};
        unit[first + k] = 1;
        const double y = EvalShRest(3, unit, d);
        num[k] += f * y;
        den[k] += y * y;
      }
    }
    for (int j = 0; j < n; ++j) {
      double fitted = 0;
      for (int k = 0; k < n; ++k) fitted += mt[j * n + k] * coef[first + k];
      EXPECT_NEAR(fitted, num[j] / den[j], 1e-4) << "coefficient " << j;
    }
  }
}

TEST(GaussianTransform, CovarianceFollowsRotationAndScale) {
  const GaussianCloud before = RandomCloud(11, 2, 100);
  GaussianCloud after = before;
  Similarity m = Similarity::FromEulerDegrees(10, 20, 30);
  m.scale = 2.5;
  m.translation = {1, -2, 3};
  ASSERT_TRUE(TransformCloud(&after, m, "x").ok());
  const auto& r = m.rotation;
  for (size_t i = 0; i < before.size(); ++i) {
    const auto c = before.Covariance(i);
    const double s[9] = {c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]};
    double rs[9] = {}, want[9] = {};
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        for (int k = 0; k < 3; ++k) rs[3 * a + b] += r[3 * a + k] * s[3 * k + b];
      }
    }
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        for (int k = 0; k < 3; ++k) want[3 * a + b] += rs[3 * a + k] * r[3 * b + k];
      }
    }
    const auto got = after.Covariance(i);
    const int idx[6] = {0, 1, 2, 4, 5, 8};
    const double norm = std::fabs(want[0]) + std::fabs(want[4]) + std::fabs(want[8]);
    for (int k = 0; k < 6; ++k) {
      EXPECT_NEAR(got[k], 6.25 * want[idx[k]], 1e-5 * 6.25 * norm) << i << " " << k;
    }
    const auto p = Apply(r, {before.position[3 * i], before.position[3 * i + 1],
                             before.position[3 * i + 2]});
    for (int k = 0; k < 3; ++k) {
      EXPECT_NEAR(after.position[3 * i + k], 2.5 * p[k] + m.translation[k], 1e-4);
      EXPECT_NEAR(after.scale[3 * i + k], before.scale[3 * i + k] + std::log(2.5), 1e-6);
    }
  }
}

// 180 degrees about z is glTF's axis change from the PLY's (formats/gaussian_glb.cc): odd orders
// m flip, the quaternion becomes (-z, -y, x, w).
TEST(GaussianTransform, HalfTurnAboutZIsTheGlbConvention) {
  const GaussianCloud before = RandomCloud(12, 3, 50);
  GaussianCloud after = before;
  ASSERT_TRUE(TransformCloud(&after, Similarity::FromEulerDegrees(0, 0, 180), "x").ok());
  const float flip[15] = {-1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1, 1, -1};
  for (size_t i = 0; i < before.sh_rest.size(); ++i) {
    EXPECT_NEAR(after.sh_rest[i], flip[i % 15] * before.sh_rest[i], 1e-6) << i;
  }
  for (size_t i = 0; i < before.size(); ++i) {
    const float* q = &before.rotation[4 * i];
    const float* g = &after.rotation[4 * i];
    EXPECT_NEAR(g[0], -q[3], 1e-6);
    EXPECT_NEAR(g[1], -q[2], 1e-6);
    EXPECT_NEAR(g[2], q[1], 1e-6);
    EXPECT_NEAR(g[3], q[0], 1e-6);
  }
}

TEST(GaussianTransform, IdentityTranslationAndInverse) {
  const GaussianCloud before = RandomCloud(13, 3, 64);
  GaussianCloud same = before;
  ASSERT_TRUE(TransformCloud(&same, Similarity{}, "x").ok());
  EXPECT_EQ(0, std::memcmp(same.sh_rest.data(), before.sh_rest.data(), 4 * before.sh_rest.size()));
  EXPECT_EQ(same.position, before.position);
  EXPECT_EQ(same.rotation, before.rotation);
  Similarity shift;
  shift.translation = {5, 0, -1};
  ASSERT_TRUE(TransformCloud(&same, shift, "x").ok());
  EXPECT_EQ(same.rotation, before.rotation);  // bit for bit: nothing rotates
  EXPECT_EQ(same.sh_rest, before.sh_rest);
  EXPECT_EQ(same.scale, before.scale);
  // R then R^T: back within float rounding.
  GaussianCloud back = before;
  Similarity m = Similarity::FromEulerDegrees(70, -20, 15), inv = m;
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) inv.rotation[3 * a + b] = m.rotation[3 * b + a];
  }
  ASSERT_TRUE(TransformCloud(&back, m, "x").ok());
  ASSERT_TRUE(TransformCloud(&back, inv, "x").ok());
  for (size_t i = 0; i < before.sh_rest.size(); ++i) {
    EXPECT_NEAR(back.sh_rest[i], before.sh_rest[i], 1e-5);
  }
  for (size_t i = 0; i < before.rotation.size(); ++i) {
    EXPECT_NEAR(back.rotation[i], before.rotation[i], 1e-5);
  }
}

TEST(GaussianTransform, RefusesWhatASplatCannotFollow) {
  GaussianCloud c = RandomCloud(14, 1, 4);
  Similarity mirror;
  mirror.rotation = {-1, 0, 0, 0, 1, 0, 0, 0, 1};
  Status s = TransformCloud(&c, mirror, "a.ply");
  EXPECT_TRUE(s.IsInvalidArgument());
  EXPECT_NE(s.message().find("a.ply: "), std::string::npos);
  EXPECT_NE(s.message().find("mirrors"), std::string::npos) << s.message();
  Similarity shear;
  shear.rotation = {1, 0.5, 0, 0, 1, 0, 0, 0, 1};
  s = TransformCloud(&c, shear, "a.ply");
  EXPECT_NE(s.message().find("shear"), std::string::npos) << s.message();
  Similarity zero;
  zero.scale = 0;
  EXPECT_TRUE(TransformCloud(&c, zero, "a.ply").IsInvalidArgument());
  Similarity far;
  far.scale = 1e38;
  s = TransformCloud(&c, far, "a.ply");
  EXPECT_NE(s.message().find("beyond float"), std::string::npos) << s.message();
}

}  // namespace
}  // namespace hvdb::formats
