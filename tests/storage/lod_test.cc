#include "storage/lod.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <random>
#include <set>
#include <span>
#include <utility>

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

namespace hvdb {
namespace {

// Every node of the order splits as KdOrder promises: the left part (the largest power of two
// below n) holds the smallest records by the widest axis, ties by id.
void ExpectKdSplits(std::span<const OrderRec> recs, std::span<const Point> points) {
  const size_t n = recs.size();
  if (n <= 2) return;
  float lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = recs[0].c[a];
  for (const OrderRec& r : recs) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], r.c[a]);
      hi[a] = std::max(hi[a], r.c[a]);
    }
  }
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (hi[a] - lo[a] > hi[axis] - lo[axis]) axis = a;
  }
  auto key = [&](const OrderRec& r) { return std::make_pair(r.c[axis], points[r.idx].id); };
  const size_t left = std::bit_floor(n - 1);
  auto max_left = key(recs[0]);
  for (size_t i = 0; i < left; ++i) max_left = std::max(max_left, key(recs[i]));
  for (size_t i = left; i < n; ++i) {
    ASSERT_LT(max_left, key(recs[i])) << "a split of " << n << " records";
  }
  ExpectKdSplits(recs.subspan(0, left), points);
  ExpectKdSplits(recs.subspan(left), points);
}

TEST(LodTest, KdOrderSplitsEveryNodeAtItsMedian) {
  std::mt19937_64 rng(9);
  for (size_t n : {3u, 5u, 17u, 100u, 1023u, 2048u, 2049u, 4000u}) {
    for (int coarse = 0; coarse < 2; ++coarse) {
      // coarse: coordinates on a grid of 4 values, so most comparisons are ties (by id).
      std::vector<Point> pts(n);
      std::vector<OrderRec> recs(n);
      for (size_t i = 0; i < n; ++i) {
        pts[i].id = rng();
        for (int a = 0; a < 3; ++a) {
          recs[i].c[a] = coarse ? static_cast<float>(rng() % 4)
                                : std::uniform_real_distribution<float>(0, 1)(rng);
        }
        recs[i].idx = static_cast<uint32_t>(i);
      }
      KdOrder(recs, pts);
      std::vector<bool> seen(n);
      for (const OrderRec& r : recs) seen[r.idx] = true;
      EXPECT_EQ(std::count(seen.begin(), seen.end(), true), static_cast<long>(n));
      ExpectKdSplits(recs, pts);
      if (HasFatalFailure()) return;
    }
  }
}

}  // namespace
}  // namespace hvdb
