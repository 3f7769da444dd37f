// `hvdb import-media` through the real binary: embedded (--data) and through hvdb-server
// (--server) the same image gives the same points, undo removes them, the plane renders closed,
// a corrupt file is an error naming its kind, and a file over the server's frame limit says so.

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "tests/run_command.h"
#include "tests/server/server_process.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

using Ran = testing::SplitRun;

class ImportMediaCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_media_cli_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  // `hvdb ARGS` run in the temporary directory.
  Ran Run(const std::string& args) {
    return testing::RunInDir(dir_, "'" HVDB_CLI_PATH "' " + args);
  }
  json Json(const std::string& args) {
    Ran r = Run(args + " --json");
    EXPECT_EQ(r.code, 0) << "hvdb " << args << "\n" << r.err;
    json j = json::parse(r.out, nullptr, false);
    EXPECT_FALSE(j.is_discarded()) << r.out;
    return j;
  }
  std::string WriteFile(const std::string& name, const std::string& bytes) {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  }
  std::string dir_;
};

std::string NoisePng(int w, int h) {
  cv::Mat m(h, w, CV_8UC3);
  std::mt19937 rng(5);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      m.at<cv::Vec3b>(y, x) = {static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()),
                               static_cast<uint8_t>(rng())};
    }
  }
  std::vector<uint8_t> buf;
  cv::imencode(".png", m, buf);
  return std::string(buf.begin(), buf.end());
}

TEST_F(ImportMediaCliTest, EmbeddedAndServedImportTheSameAndUndoRemovesIt) {
  const std::string png = WriteFile("pic.png", NoisePng(30, 20));
  ASSERT_EQ(Run("--data emb create walk --fps 30 --frames 4").code, 0);
  fs::create_directories(dir_ + "/srv");
  testing::ServerProcess server(dir_ + "/srv");
  ASSERT_TRUE(server.running());
  const std::string remote = "--server 127.0.0.1:" + std::to_string(server.port()) + " ";
  ASSERT_EQ(Run(remote + "create walk --fps 30 --frames 4").code, 0);
  const std::string args =
      "import-media walk " + png + " --frames 1 2 --at 0 1 2 --scale 3 --rotate 0 90 0 "
      "--label-bit 7";
  json e = Json("--data emb " + args), s = Json(remote + args);
  EXPECT_EQ(e["inserted"], 30 * 20 * 2);
  EXPECT_EQ(e["kind"], "image");
  EXPECT_EQ(e["first_frame"], 1);
  EXPECT_EQ(e["last_frame"], 2);
  EXPECT_EQ(s["inserted"], e["inserted"]);
  // The same points either way: same bounds (the plane faces +x after --rotate 0 90 0: x = 0,
  // 3 m along z, 2 m along y).
  json de = Json("--data emb describe walk"), ds = Json(remote + "describe walk");
  EXPECT_EQ(de["bounds_min"], ds["bounds_min"]);
  EXPECT_EQ(de["bounds_max"], ds["bounds_max"]);
  EXPECT_EQ(de["points"], 1200);
  EXPECT_NEAR(de["bounds_max"][2].get<double>() - de["bounds_min"][2].get<double>(), 2.9, 1e-3);
  EXPECT_NEAR(de["bounds_max"][0].get<double>() - de["bounds_min"][0].get<double>(), 0, 1e-5);
  // Undo takes all of it away.
  const std::string lsn = std::to_string(s["lsn"].get<uint64_t>());
  ASSERT_EQ(Run(remote + "undo walk " + lsn).code, 0);
  EXPECT_EQ(Json(remote + "describe walk")["points"], 0);
  // Default frames: every frame of the dataset (4 declared).
  EXPECT_EQ(Json("--data emb import-media walk " + png)["inserted"], 30 * 20 * 4);
}

TEST_F(ImportMediaCliTest, BadFilesAndOptionsAreErrors) {
  ASSERT_EQ(Run("--data d create walk --fps 30").code, 0);
  std::string png = NoisePng(16, 16);
  const std::string broken = WriteFile("broken.png", png.substr(0, png.size() / 3));
  Ran r = Run("--data d import-media walk " + broken);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("the image (png) could not be decoded"), std::string::npos) << r.err;
  const std::string mesh = WriteFile("bad.obj", "v 0 0 0\nf 1 2 3\n");
  r = Run("--data d import-media walk " + mesh);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("the mesh (obj)"), std::string::npos) << r.err;
  r = Run("--data d import-media walk " + dir_ + "/missing.png");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("cannot read"), std::string::npos) << r.err;
  const std::string good = WriteFile("good.png", png);
  r = Run("--data d import-media walk " + good + " --label-bit 40");
  EXPECT_EQ(r.code, 2) << r.err;
  r = Run("--data d import-media walk " + good + " --frames 3 1");
  EXPECT_EQ(r.code, 2) << r.err;
  r = Run("--data d import-media walk " + good + " --kind sound");
  EXPECT_EQ(r.code, 2) << r.err;
  r = Run("--data d import-media nope " + good);
  EXPECT_EQ(r.code, 1);
  EXPECT_EQ(Json("--data d describe walk")["points"], 0);
  r = Run("import-media --help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("--label-bit"), std::string::npos);
  EXPECT_NE(r.out.find("hvdb undo"), std::string::npos);
}

// The footprints (0.6 texel spacing) close the plane: rendered on black, far and close up
// (about 7 pixels a texel), every pixel inside it is the image's white.
TEST_F(ImportMediaCliTest, AnImportedPlaneRendersClosed) {
  cv::Mat white(100, 200, CV_8UC3, cv::Scalar(255, 255, 255));
  std::vector<uint8_t> buf;
  ASSERT_TRUE(cv::imencode(".png", white, buf));
  const std::string png = WriteFile("white.png", std::string(buf.begin(), buf.end()));
  ASSERT_EQ(Run("--data d create r --fps 30").code, 0);
  ASSERT_EQ(Run("--data d import-media r " + png).code, 0);
  const std::string render = "--data d render r --box -2 2 -2 2 -2 2 0 0 --fov 40 --size 640 480 "
                             "--renderer cpu --background 0 0 0 ";
  Ran r = Run(render + "--look-at 0 0 -1.5 0 0 0 --out far.png");
  ASSERT_EQ(r.code, 0) << r.err;
  cv::Mat far = cv::imread(dir_ + "/far.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(far.empty());
  cv::Mat lit;
  cv::findNonZero(far, lit);
  const cv::Rect box = cv::boundingRect(lit);
  EXPECT_NEAR(box.width / static_cast<double>(box.height), 2.0, 0.05);  // the image's aspect
  double lo;
  cv::minMaxLoc(far(cv::Rect(box.x + 4, box.y + 4, box.width - 8, box.height - 8)), &lo);
  EXPECT_EQ(lo, 255);
  r = Run(render + "--look-at 0.1 0.05 -0.2 0.1 0.05 0 --out close.png");
  ASSERT_EQ(r.code, 0) << r.err;
  cv::minMaxLoc(cv::imread(dir_ + "/close.png", cv::IMREAD_GRAYSCALE), &lo);
  EXPECT_EQ(lo, 255);
}

TEST_F(ImportMediaCliTest, AFileOverTheServersFrameLimitIsExplained) {
  fs::create_directories(dir_ + "/srv");
  testing::ServerProcess server(dir_ + "/srv", {"--max-frame-bytes", "65536"});
  ASSERT_TRUE(server.running());
  const std::string remote = "--server 127.0.0.1:" + std::to_string(server.port()) + " ";
  ASSERT_EQ(Run(remote + "create walk --fps 30").code, 0);
  const std::string big = WriteFile("big.png", NoisePng(300, 300));  // ~270 KB
  Ran r = Run(remote + "import-media walk " + big);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("--max-frame-bytes"), std::string::npos) << r.err;
  EXPECT_EQ(Json(remote + "describe walk")["points"], 0);
}

}  // namespace
}  // namespace hvdb
