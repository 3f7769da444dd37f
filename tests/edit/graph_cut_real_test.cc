// The 4D graph cut on real data (issue 15): the Panoptic person against a floor and a wall
// that touch it, textured by real photographs, strokes in the first frame only; ground truth
// from construction (tests/edit/panoptic_scene.h). CI runs a smaller size than graphcut-bench.
#include <gtest/gtest.h>

#include <cstdio>

#include "edit/graph_cut.h"
#include "tests/edit/panoptic_scene.h"

namespace hvdb::edit {
namespace {

TEST(GraphCutRealTest, FindsThePersonInEveryFrameFromStrokesInTheFirst) {
  auto scene = testing::PanopticScene(HVDB_SHARED_DATA, 3, 0.012);
  ASSERT_TRUE(scene.ok()) << scene.status().ToString();
  size_t fg = 0, bg = 0;
  for (Seed s : scene->seeds) {
    fg += s == Seed::kForeground;
    bg += s == Seed::kBackground;
  }
  ASSERT_GT(fg, 100u);
  ASSERT_GT(bg, 100u);
  auto res = RunGraphCut(scene->points, scene->seeds);
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  auto quality = testing::PerFrameQuality(*scene, res->selected);
  for (size_t f = 0; f < quality.size(); ++f) {
    std::printf("[ real scene ] frame %zu: precision %.4f recall %.4f\n", f, quality[f][0],
                quality[f][1]);
    EXPECT_GE(quality[f][0], 0.97) << "frame " << f;
    EXPECT_GE(quality[f][1], 0.97) << "frame " << f;
  }
  // The energy of eq. 9.1 as it was (colour and normal similarities added, arcs between
  // different colours left out, lambda 1) misses much of the person here: the test can tell.
  GraphCutParams thesis;
  thesis.max_color_diff = thesis.max_normal_diff = 0.1;
  thesis.beta_c = 0.08;
  thesis.beta_n = 0.12;
  thesis.lambda_i = thesis.lambda_t = 1;
  auto old = RunGraphCut(scene->points, scene->seeds, thesis);
  ASSERT_TRUE(old.ok());
  auto before = testing::PerFrameQuality(*scene, old->selected);
  std::printf("[ real scene ] earlier energy, frame 0: precision %.4f recall %.4f\n",
              before[0][0], before[0][1]);
  EXPECT_LT(before[0][1], 0.95);
}

}  // namespace
}  // namespace hvdb::edit
