// edit/neighbours.h against brute force: every point's k nearest within the radius, in the same
// order (distance, then position), within a grid and from one grid into another, on surfaces
// with sparse outliers, for radii of one to several cells. Seeded, deterministic.
#include "edit/neighbours.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

namespace hvdb::edit {
namespace {

// A wavy sheet of points with some points scattered far from it.
std::vector<float> Cloud(std::mt19937& rng, size_t n, float shift) {
  std::uniform_real_distribution<float> u(0, 1), far(-0.5f, 1.5f);
  std::vector<float> xyz;
  for (size_t i = 0; i < n; ++i) {
    if (i % 50 == 0) {
      xyz.insert(xyz.end(), {far(rng), far(rng), far(rng)});
      continue;
    }
    const float x = u(rng), y = u(rng);
    xyz.insert(xyz.end(), {x + shift, y, 0.1f * std::sin(6 * x) * std::cos(4 * y) + 0.003f * u(rng)});
  }
  return xyz;
}

std::vector<uint32_t> Brute(const PointGrid& target, const std::vector<float>& target_xyz,
                            const PointGrid& queries, const std::vector<float>& query_xyz, bool same,
                            int k, float radius) {
  // Positions from input indices: invert the grids' orders.
  std::vector<uint32_t> tpos(target.size());
  for (size_t j = 0; j < target.size(); ++j) tpos[target.input(j)] = static_cast<uint32_t>(j);
  std::vector<uint32_t> out(queries.size() * static_cast<size_t>(k), PointGrid::kNone);
  for (size_t j = 0; j < queries.size(); ++j) {
    const float* q = &query_xyz[3 * queries.input(j)];
    std::vector<std::pair<float, uint32_t>> all;
    for (size_t i = 0; i < target.size(); ++i) {
      const float* p = &target_xyz[3 * i];
      const float ex = p[0] - q[0], ey = p[1] - q[1], ez = p[2] - q[2];
      const float d2 = ex * ex + ey * ey + ez * ez;
      if (d2 <= radius * radius && !(same && tpos[i] == j)) all.push_back({d2, tpos[i]});
    }
    std::sort(all.begin(), all.end());
    for (size_t h = 0; h < all.size() && h < static_cast<size_t>(k); ++h) out[j * k + h] = all[h].second;
  }
  return out;
}

TEST(NeighboursTest, SameAsBruteForceWithinAndAcrossGrids) {
  std::mt19937 rng(151125);
  for (int round = 0; round < 6; ++round) {
    auto a = Cloud(rng, 3000, 0), b = Cloud(rng, 2500, 0.01f * static_cast<float>(round));
    const std::array<float, 3> origin = {-0.5f, -0.5f, -0.5f};
    const float cell = 0.02f + 0.01f * static_cast<float>(round % 3);
    PointGrid ga(a, origin, cell), gb(b, origin, cell);
    for (float radius : {cell * 0.7f, cell, cell * 2.5f}) {
      for (int k : {1, 4, 9}) {
        std::vector<uint32_t> got;
        ga.Nearest(ga, k, radius, &got);
        EXPECT_EQ(got, Brute(ga, a, ga, a, true, k, radius)) << "within, round " << round << " k " << k;
        gb.Nearest(ga, k, radius, &got);
        EXPECT_EQ(got, Brute(gb, b, ga, a, false, k, radius)) << "across, round " << round << " k " << k;
      }
    }
  }
}

TEST(NeighboursTest, OrderIsByCellAndCoversEveryPoint) {
  std::mt19937 rng(3);
  auto a = Cloud(rng, 2000, 0);
  PointGrid g(a, {-0.5f, -0.5f, -0.5f}, 0.05f);
  std::vector<uint32_t> seen(g.size(), 0);
  for (size_t j = 0; j < g.size(); ++j) ++seen[g.input(j)];
  EXPECT_TRUE(std::all_of(seen.begin(), seen.end(), [](uint32_t c) { return c == 1; }));
  PointGrid empty({}, {0, 0, 0}, 1.f);
  std::vector<uint32_t> out;
  g.Nearest(empty, 4, 0.1f, &out);
  EXPECT_TRUE(out.empty());
  empty.Nearest(g, 4, 0.1f, &out);
  EXPECT_TRUE(std::all_of(out.begin(), out.end(), [](uint32_t p) { return p == PointGrid::kNone; }));
}

}  // namespace
}  // namespace hvdb::edit
