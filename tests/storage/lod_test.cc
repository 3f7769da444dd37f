#include "storage/lod.h"

#include <gtest/gtest.h>

#include <random>
#include <set>

#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

TEST(LodTest, LevelOfRankIsTrailingOnes) {
  EXPECT_EQ(LevelOfRank(0, 5), 0);
  EXPECT_EQ(LevelOfRank(2, 5), 0);
  EXPECT_EQ(LevelOfRank(1, 5), 1);
  EXPECT_EQ(LevelOfRank(5, 5), 1);
  EXPECT_EQ(LevelOfRank(3, 5), 2);
  EXPECT_EQ(LevelOfRank(7, 5), 3);
  EXPECT_EQ(LevelOfRank(63, 5), 5);  // capped at l
}

TEST(LodTest, LevelsPartitionABucketWithHalvingSizes) {
  std::mt19937_64 rng(1);
  auto pts = testing::RandomPoints(rng, 2048, 0);
  for (size_t i = 0; i < pts.size(); ++i) pts[i].id = i + 1;
  auto levels = SplitIntoLevels(pts, 5);
  ASSERT_EQ(levels.size(), 6u);
  // 2048 points: 1024, 512, 256, 128, 64 and the top level 64.
  size_t expect[6] = {1024, 512, 256, 128, 64, 64};
  std::set<uint64_t> ids;
  for (int k = 0; k < 6; ++k) {
    EXPECT_EQ(levels[k].size(), expect[k]) << k;
    for (const Point& p : levels[k]) ids.insert(p.id);
  }
  EXPECT_EQ(ids.size(), 2048u);
}

TEST(LodTest, CoarseLevelsCoverTheBucket) {
  // Every point's partner (its sibling in the kd order) is near: the coarse set spreads over
  // the whole bucket instead of clustering.
  std::mt19937_64 rng(2);
  auto pts = testing::RandomPoints(rng, 2048, 0, 1.f);
  auto levels = SplitIntoLevels(pts, 5);
  // Each octant of the unit cube holds some top-level points.
  int octants[8] = {};
  for (const Point& p : levels[5]) {
    octants[(p.x > .5f) + 2 * (p.y > .5f) + 4 * (p.z > .5f)]++;
  }
  for (int o : octants) EXPECT_GT(o, 2);
}

TEST(LodTest, LevelOfIdHasTheRightProportions) {
  int counts[6] = {};
  for (uint64_t id = 1; id <= 64000; ++id) counts[LevelOfId(id, 5)]++;
  EXPECT_NEAR(counts[0], 32000, 800);
  EXPECT_NEAR(counts[1], 16000, 600);
  EXPECT_NEAR(counts[5], 2000, 300);
}

}  // namespace
}  // namespace hvdb
