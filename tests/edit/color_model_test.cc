// edit/color_model.h: the mixture fit recovers known clusters, handles strokes of one colour or
// one point, and depends only on its samples. Seeded, deterministic.
#include "edit/color_model.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

namespace hvdb::edit {
namespace {

std::vector<Rgb> Clusters(std::mt19937& rng, const std::vector<std::pair<Rgb, size_t>>& spec,
                          double sigma) {
  std::normal_distribution<double> noise(0, sigma);
  std::vector<Rgb> out;
  for (const auto& [centre, count] : spec) {
    for (size_t i = 0; i < count; ++i) {
      out.push_back({centre[0] + noise(rng), centre[1] + noise(rng), centre[2] + noise(rng)});
    }
  }
  std::shuffle(out.begin(), out.end(), rng);
  return out;
}

TEST(ColorModelTest, RecoversSeparatedClustersAndTheirWeights) {
  std::mt19937 rng(15);
  const Rgb red{0.8, 0.1, 0.1}, blue{0.1, 0.2, 0.9};
  auto samples = Clusters(rng, {{red, 600}, {blue, 200}}, 0.02);
  ColorModel m;
  ASSERT_TRUE(m.Train(samples, 2).ok());
  ASSERT_EQ(m.components(), 2u);
  // Each true cluster has a component within 0.01 of its centre, weighted as sampled.
  for (const auto& [centre, w] : {std::pair{red, 0.75}, std::pair{blue, 0.25}}) {
    size_t best = 0;
    double bd = 1e9;
    for (size_t j = 0; j < m.components(); ++j) {
      double d = std::hypot(m.mean(j)[0] - centre[0], m.mean(j)[1] - centre[1], m.mean(j)[2] - centre[2]);
      if (d < bd) bd = d, best = j;
    }
    EXPECT_LT(bd, 0.01);
    EXPECT_NEAR(m.weight(best), w, 0.02);
  }
  // The density is higher at a centre than between the clusters, and the log-density of a
  // 3-D Gaussian with sigma 0.02 at its mean is about log(w) + 3 * 2.99.
  EXPECT_GT(m.LogLikelihood(red), m.LogLikelihood({0.45, 0.15, 0.5}) + 20);
  EXPECT_NEAR(m.LogLikelihood(red), std::log(0.75) - 1.5 * std::log(2 * M_PI * 0.0004), 0.5);
}

TEST(ColorModelTest, OneColourOrOnePointStillGivesAModel) {
  ColorModel m;
  ASSERT_TRUE(m.Train({{0.5, 0.5, 0.5}}, 5).ok());  // one stroked point
  EXPECT_EQ(m.components(), 1u);
  EXPECT_TRUE(std::isfinite(m.LogLikelihood({0.5, 0.5, 0.5})));
  EXPECT_GT(m.LogLikelihood({0.5, 0.5, 0.5}), m.LogLikelihood({0.6, 0.5, 0.5}));
  ColorModel same;
  ASSERT_TRUE(same.Train(std::vector<Rgb>(300, Rgb{0.2, 0.7, 0.1}), 5).ok());  // one colour
  EXPECT_EQ(same.components(), 1u);
  EXPECT_TRUE(std::isfinite(same.LogLikelihood({1, 1, 1})));
  ColorModel none;
  EXPECT_FALSE(none.Train({}, 5).ok());
  EXPECT_FALSE(none.Train({{0, 0, 0}}, 0).ok());
}

TEST(ColorModelTest, DependsOnlyOnTheSamples) {
  std::mt19937 rng(3);
  auto samples = Clusters(rng, {{{0.3, 0.3, 0.3}, 400}, {{0.7, 0.6, 0.2}, 400}, {{0.1, 0.9, 0.5}, 400}}, 0.05);
  ColorModel a, b;
  ASSERT_TRUE(a.Train(samples, 5).ok());
  std::mt19937 other(99);  // whatever else ran in between
  (void)other();
  ASSERT_TRUE(b.Train(samples, 5).ok());
  ASSERT_EQ(a.components(), b.components());
  for (double x = 0; x <= 1; x += 0.125) {
    EXPECT_EQ(a.LogLikelihood({x, 1 - x, 0.5}), b.LogLikelihood({x, 1 - x, 0.5}));
  }
}

}  // namespace
}  // namespace hvdb::edit
