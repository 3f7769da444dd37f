// `hvdb render --video`, `--shadow-*` and `--mode` end to end (the real binary on a data directory with two
// Panoptic frames): the video decodes to one frame per path entry at the size asked; bad paths
// and bad shadow options fail naming the culprit and write nothing.

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include "tests/render/video_probe.h"
#include "tests/run_command.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;

const std::string kPanoptic =
    std::string(HVDB_SHARED_DATA) + "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/";

using RunResult = testing::SplitRun;

class RenderCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_render_cli_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
    ASSERT_EQ(Run("create walk --fps 30").code, 0);
    RunResult r = Run("import walk --frame 0 --units-scale 0.01 " + kPanoptic +
                      "ptcloud_hd00000380.ply " + kPanoptic + "ptcloud_hd00000381.ply");
    ASSERT_EQ(r.code, 0) << r.err;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  // Runs `hvdb --data DIR/data ARGS` in the temporary directory.
  RunResult Run(const std::string& args) {
    return testing::RunInDir(dir_, "'" + std::string(HVDB_CLI_PATH) + "' --data data " + args);
  }
  // A path of n views of the person (frames 0, 1, 0, ...) at w x h.
  std::string WritePath(const std::string& name, int n, int w, int h) {
    std::ofstream out(dir_ + "/" + name);
    out << "{\"cameras\": [";
    for (int i = 0; i < n; ++i) {
      out << (i ? ", " : "") << "{\"look_at\": {\"eye\": [" << -0.4 + 0.1 * i
          << ", -0.9, -3], \"target\": [-0.4, -0.9, 0], \"up\": [0, -1, 0], \"fov_y_deg\": 40, "
          << "\"width\": " << w << ", \"height\": " << h << "}, \"frame\": " << i % 2 << "}";
    }
    out << "]}";
    return name;
  }
  std::string dir_;
};

TEST_F(RenderCliTest, VideoHasOneFramePerPathEntryAtTheSizeAsked) {
  for (const char* ext : {"mp4", "webm"}) {
    const std::string out = std::string("walk.") + ext;
    RunResult r = Run("render walk --path " + WritePath("p.json", 9, 320, 240) + " --video " + out +
                      " --fps 12 --renderer cpu");
    ASSERT_EQ(r.code, 0) << r.err;
    EXPECT_NE(r.out.find("rendered 9 frames into " + out), std::string::npos) << r.out;
    testing::Probe p = testing::DecodeFile(dir_ + "/" + out);
    ASSERT_TRUE(p.error.empty()) << p.error;
    EXPECT_EQ(p.frames, 9) << ext;
    EXPECT_EQ(p.width, 320);
    EXPECT_EQ(p.height, 240);
    EXPECT_NEAR(p.fps, 12, 0.01);
    EXPECT_EQ(p.codec, std::string(ext) == "mp4" ? "h264" : "vp9");
  }
}

TEST_F(RenderCliTest, BadVideosFailAndWriteNothing) {
  std::ofstream(dir_ + "/empty.json") << "{\"cameras\": []}";
  RunResult r = Run("render walk --path empty.json --video a.mp4");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("has no cameras"), std::string::npos) << r.err;
  r = Run("render walk --path " + WritePath("odd.json", 3, 321, 240) + " --video b.mp4");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("render.path[0]: a video needs an even width"), std::string::npos) << r.err;
  r = Run("render walk --path " + WritePath("mixed.json", 1, 320, 240) + " --video c.avi");
  EXPECT_EQ(r.code, 2);
  r = Run("render walk --box -10 10 -10 10 -10 10 0 0 --look-at 0 0 -3 0 0 0 --fov 40 "
          "--video d.mp4");
  EXPECT_EQ(r.code, 2);  // --video needs --path
  for (const char* f : {"a.mp4", "b.mp4", "b.mp4.partial", "c.avi", "d.mp4"}) {
    EXPECT_FALSE(fs::exists(dir_ + "/" + f)) << f;
  }
}

TEST_F(RenderCliTest, ShadowOptionsReachTheRender) {
  const std::string view =
      "render walk --box -10 10 -10 10 -10 10 0 0 --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 "
      "--up 0 -1 0 --size 320 240 --renderer cpu ";
  // Bit 3 on the upper part of the person (y down: above y = -1.3 m).
  ASSERT_EQ(Run("select walk --bit 3 --box -10 10 -10 -1.3 -10 10 0 0").code, 0);
  RunResult r = Run(view + "--shadow-light 0.2 -1 0.1 --shadow-directional --shadow-casters 3 "
                           "--shadow-strength 0.8 --out lit.png");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ + "/lit.png"));
  r = Run(view + "--shadow-light 0 -3 0 --shadow-casters 32 --out bad.png");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("render.shadow_casters"), std::string::npos) << r.err;
  r = Run(view + "--shadow-light 0 -3 0 --shadow-casters 3 --shadow-strength 2 --out bad.png");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("render.shadow_strength"), std::string::npos) << r.err;
  r = Run(view + "--shadow-light -0.4 -1.5 0 --shadow-casters 3 --out bad.png");  // in the head
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("inside the shadow casters' bounds"), std::string::npos) << r.err;
  r = Run(view + "--shadow-casters 3 --out bad.png");
  EXPECT_EQ(r.code, 2);  // casters need a light
  EXPECT_FALSE(fs::exists(dir_ + "/bad.png"));
}

// The default picks the best the frame has and the output says what drew: these frames have
// no photos, so the points; an explicit mode is taken as asked.
TEST_F(RenderCliTest, SaysWhichModeDrew) {
  const std::string view =
      "render walk --box -10 10 -10 10 -10 10 0 0 --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 "
      "--up 0 -1 0 --size 160 120 --renderer cpu ";
  RunResult r = Run(view + "--out a.png");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("; mode visibility (auto: no photos of frame 0)"), std::string::npos)
      << r.out;
  r = Run(view + "--mode probabilistic --json --out b.png");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("\"mode\":\"probabilistic\""), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("\"mode_choice\":\"asked for\""), std::string::npos) << r.out;
  r = Run(view + "--mode textured --out c.png");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("render.texture: dataset 'walk' has no photos of frame 0"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ + "/c.png"));
}

}  // namespace
}  // namespace hvdb
