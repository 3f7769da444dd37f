#include "edit/graph_cut.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "tests/edit/scene.h"

namespace hvdb::edit {
namespace {

struct Score {
  double precision, recall;
};

Score Evaluate(const std::vector<testing::ScenePoint>& scene, const std::vector<uint8_t>& sel) {
  double tp = 0, fp = 0, fn = 0;
  for (size_t i = 0; i < scene.size(); ++i) {
    if (sel[i] && scene[i].sphere) ++tp;
    if (sel[i] && !scene[i].sphere) ++fp;
    if (!sel[i] && scene[i].sphere) ++fn;
  }
  return {tp / std::max(1.0, tp + fp), tp / std::max(1.0, tp + fn)};
}

// A few strokes in the first frame only: a dab on the sphere, two on the plane.
std::vector<Seed> Strokes(const std::vector<testing::ScenePoint>& scene) {
  std::vector<Seed> seeds(scene.size(), Seed::kUnknown);
  float top = -1;
  for (const auto& s : scene) {
    if (s.sphere && s.p.frame == 0) top = std::max(top, s.p.z);
  }
  for (size_t i = 0; i < scene.size(); ++i) {
    const Point& p = scene[i].p;
    if (p.frame != 0) continue;
    auto near = [&](double x, double y, double z) {
      return std::hypot(p.x - x, p.y - y, p.z - z) < 0.03;
    };
    if (scene[i].sphere && p.z > top - 0.015) seeds[i] = Seed::kForeground;  // a dab on top
    if (near(0.8, 0.2, 0.0) || near(0.1, 0.9, 0.0)) seeds[i] = Seed::kBackground;
  }
  return seeds;
}

TEST(GraphCutTest, SelectsTheMovingSphereFromAFewStrokes) {
  auto scene = testing::MovingSphereScene(4);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  auto seeds = Strokes(scene);
  auto with_normals = RunGraphCut(pts, seeds);
  ASSERT_TRUE(with_normals.ok()) << with_normals.status().ToString();
  Score a = Evaluate(scene, with_normals->selected);
  GraphCutParams colour_only;
  colour_only.use_normals = false;
  auto without = RunGraphCut(pts, seeds, colour_only);
  ASSERT_TRUE(without.ok());
  Score b = Evaluate(scene, without->selected);
  std::printf("[ graph cut ] %zu points, %llu intra + %llu inter arcs; colour+normals: "
              "precision %.4f recall %.4f; colour only: precision %.4f recall %.4f; "
              "neighbours %.0f ms, GMM %.0f ms, graph %.0f ms, max-flow %.0f ms\n",
              pts.size(), static_cast<unsigned long long>(with_normals->intra_edges),
              static_cast<unsigned long long>(with_normals->inter_edges), a.precision, a.recall,
              b.precision, b.recall, with_normals->neighbours_ms, with_normals->gmm_ms,
              with_normals->graph_ms, with_normals->maxflow_ms);
  ::testing::Test::RecordProperty("precision_colour_normals", std::to_string(a.precision));
  ::testing::Test::RecordProperty("recall_colour_normals", std::to_string(a.recall));
  ::testing::Test::RecordProperty("precision_colour_only", std::to_string(b.precision));
  ::testing::Test::RecordProperty("recall_colour_only", std::to_string(b.recall));
  EXPECT_GE(a.precision, 0.95);
  EXPECT_GE(a.recall, 0.95);
  EXPECT_GT(with_normals->inter_edges, 0u);
  EXPECT_GT(with_normals->energy, 0);
}

TEST(GraphCutTest, NormalsHelpWhenColoursAreAlike) {
  // Sphere and plane almost the same colour, the sphere sunk 2 cm into the plane.
  auto scene = testing::MovingSphereScene(3, 0.007, 2, {0.47, 0.44, 0.39}, 0.02);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  auto seeds = Strokes(scene);
  auto with_normals = RunGraphCut(pts, seeds);
  GraphCutParams colour_only;
  colour_only.use_normals = false;
  auto without = RunGraphCut(pts, seeds, colour_only);
  ASSERT_TRUE(with_normals.ok() && without.ok());
  Score a = Evaluate(scene, with_normals->selected), b = Evaluate(scene, without->selected);
  std::printf("[ graph cut, alike colours ] colour+normals: precision %.4f recall %.4f; "
              "colour only: precision %.4f recall %.4f\n",
              a.precision, a.recall, b.precision, b.recall);
  ::testing::Test::RecordProperty("alike_precision_colour_normals", std::to_string(a.precision));
  ::testing::Test::RecordProperty("alike_recall_colour_normals", std::to_string(a.recall));
  ::testing::Test::RecordProperty("alike_precision_colour_only", std::to_string(b.precision));
  ::testing::Test::RecordProperty("alike_recall_colour_only", std::to_string(b.recall));
  EXPECT_GE(a.precision, 0.95);
  EXPECT_GE(a.recall, 0.95);
}

TEST(GraphCutTest, StrokesAreHardConstraints) {
  auto scene = testing::MovingSphereScene(1, 0.01);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  auto seeds = Strokes(scene);
  auto r = RunGraphCut(pts, seeds);
  ASSERT_TRUE(r.ok());
  for (size_t i = 0; i < pts.size(); ++i) {
    if (seeds[i] == Seed::kForeground) {
      EXPECT_EQ(r->selected[i], 1);
    }
    if (seeds[i] == Seed::kBackground) {
      EXPECT_EQ(r->selected[i], 0);
    }
  }
}

TEST(GraphCutTest, NeedsBothKindsOfStroke) {
  auto scene = testing::MovingSphereScene(1, 0.02);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  std::vector<Seed> seeds(pts.size(), Seed::kUnknown);
  seeds[0] = Seed::kBackground;
  auto r = RunGraphCut(pts, seeds);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument());
  GraphCutParams bad;
  bad.k = 0;
  seeds[1] = Seed::kForeground;
  EXPECT_TRUE(RunGraphCut(pts, seeds, bad).status().IsInvalidArgument());
}

// A stroke of a single point on each side is enough (a one-point colour model used to throw
// inside OpenCV's EM).
TEST(GraphCutTest, OnePointStrokes) {
  auto scene = testing::MovingSphereScene(2, 0.02);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  std::vector<Seed> seeds(pts.size(), Seed::kUnknown);
  size_t fg = 0, bg = 0;
  for (size_t i = 0; i < scene.size(); ++i) {
    if (scene[i].sphere && (fg == 0 || pts[i].z > pts[fg].z)) fg = i;
    if (!scene[i].sphere) bg = i;
  }
  seeds[fg] = Seed::kForeground;
  seeds[bg] = Seed::kBackground;
  auto r = RunGraphCut(pts, seeds);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->selected[fg], 1);
  EXPECT_EQ(r->selected[bg], 0);
}

// The points' order does not matter: nodes are numbered by place, the models trained on the
// stroked colours sorted. Shuffled input, the same selection and energy.
TEST(GraphCutTest, TheInputOrderDoesNotMatter) {
  auto scene = testing::MovingSphereScene(3, 0.015);
  std::vector<Point> pts;
  for (const auto& s : scene) pts.push_back(s.p);
  auto seeds = Strokes(scene);
  std::vector<size_t> perm(pts.size());
  for (size_t i = 0; i < perm.size(); ++i) perm[i] = i;
  std::mt19937 rng(25);
  std::shuffle(perm.begin(), perm.end(), rng);
  std::vector<Point> shuffled(pts.size());
  std::vector<Seed> shuffled_seeds(pts.size());
  for (size_t i = 0; i < perm.size(); ++i) shuffled[i] = pts[perm[i]], shuffled_seeds[i] = seeds[perm[i]];
  auto a = RunGraphCut(pts, seeds);
  auto b = RunGraphCut(shuffled, shuffled_seeds);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_NEAR(a->energy, b->energy, 1e-6 * a->energy);
  size_t differ = 0;
  for (size_t i = 0; i < perm.size(); ++i) differ += a->selected[perm[i]] != b->selected[i];
  EXPECT_EQ(differ, 0u);
}

}  // namespace
}  // namespace hvdb::edit
