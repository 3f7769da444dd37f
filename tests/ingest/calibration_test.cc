#include "ingest/calibration.h"

#include <gtest/gtest.h>

#include <fstream>

#include <opencv2/calib3d.hpp>

#include "ingest/generator.h"
#include "tests/ingest/test_util.h"

namespace hvdb::ingest {
namespace {

using testing::TempDir;

const std::string kBoards = std::string(HVDB_SHARED_DATA) + "/opencv-stereo-chessboard/";

std::vector<std::string> Boards(const char* side) {
  std::vector<std::string> v;
  for (int i : {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14}) {
    char name[32];
    std::snprintf(name, sizeof name, "%s%02d.jpg", side, i);
    v.push_back(kBoards + name);
  }
  return v;
}

TEST(Calibration, YamlRoundTripKeepsEveryCamera) {
  GeneratorOptions g;
  g.bricks = 2;
  const Calibration cal = GeneratorCalibration(g);
  TempDir dir;
  ASSERT_TRUE(SaveCalibration(cal, dir / "c.yml").ok());
  auto back = LoadCalibration(dir / "c.yml");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->cameras.size(), cal.cameras.size());
  ASSERT_EQ(back->bricks.size(), 2u);
  for (size_t i = 0; i < cal.cameras.size(); ++i) {
    const auto &a = cal.cameras[i], &b = back->cameras[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.size, b.size);
    EXPECT_LT(cv::norm(cv::Mat(a.K), cv::Mat(b.K)), 1e-9);
    EXPECT_LT(cv::norm(cv::Mat(a.R), cv::Mat(b.R)), 1e-9);
    EXPECT_LT(cv::norm(a.T - b.T), 1e-12);
    EXPECT_EQ(a.dist, b.dist);
    EXPECT_DOUBLE_EQ(a.reprojection_error, b.reprojection_error);
  }
  EXPECT_EQ(back->bricks[1].left, cal.bricks[1].left);
  EXPECT_EQ(back->bricks[1].colour, cal.bricks[1].colour);
  EXPECT_NEAR(back->SigmaC(), kGeneratorReprojectionError, 1e-12);
}

TEST(Calibration, ProjectAgreesWithOpenCv) {
  GeneratorOptions g;
  const CameraModel c = GeneratorCalibration(g).cameras[0];
  ASSERT_FALSE(c.dist.empty());
  const cv::Vec3d X(0.3, -0.2, 0.1);
  std::vector<cv::Point3d> obj{cv::Point3d(X[0], X[1], X[2])};
  std::vector<cv::Point2d> img;
  cv::Mat rvec;
  cv::Rodrigues(cv::Mat(c.R), rvec);
  cv::projectPoints(obj, rvec, cv::Mat(c.T), cv::Mat(c.K), cv::Mat(c.dist), img);
  const cv::Point2d p = c.Project(X);
  EXPECT_NEAR(p.x, img[0].x, 1e-9);
  EXPECT_NEAR(p.y, img[0].y, 1e-9);
}

TEST(Calibration, BadFilesAreClearErrors) {
  TempDir dir;
  auto missing = LoadCalibration(dir / "none.yml");
  EXPECT_TRUE(missing.status().IsNotFound());
  EXPECT_NE(missing.status().message().find("none.yml"), std::string::npos);
  {
    std::ofstream(dir / "junk.yml") << "this is not yaml: [";
  }
  EXPECT_FALSE(LoadCalibration(dir / "junk.yml").ok());
  // A camera whose R is not a rotation.
  GeneratorOptions g;
  g.bricks = 1;
  Calibration cal = GeneratorCalibration(g);
  cal.cameras[1].R(0, 0) = 2;
  Status st = SaveCalibration(cal, dir / "bad.yml");
  EXPECT_TRUE(st.IsInvalidArgument());
  EXPECT_NE(st.message().find("not a rotation"), std::string::npos) << st.ToString();
  cal = GeneratorCalibration(g);
  cal.cameras[2].K(0, 0) = -1;
  EXPECT_NE(cal.Validate().message().find("fx"), std::string::npos);
  cal = GeneratorCalibration(g);
  cal.cameras[1].name = cal.cameras[0].name;
  EXPECT_FALSE(cal.Validate().ok());
  cal = GeneratorCalibration(g);
  cal.cameras[1].size.width += 2;  // the grey pair differs in size
  EXPECT_NE(cal.Validate().message().find("different image sizes"), std::string::npos);
}

// The OpenCV sample boards (9x6 inner corners, nominal 25 mm squares): the figures its README
// checked (RMS ~0.41 px, fx ~536, baseline ~83.6 mm with the right camera to the right).
TEST(Calibration, CheckerboardStereoOnRealImages) {
  CheckerboardOptions o;
  auto r = CalibrateCheckerboard(Boards("left"), Boards("right"), o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->used.size(), 13u);
  EXPECT_LT(r->left_rms, 0.5);
  EXPECT_LT(r->right_rms, 0.5);
  EXPECT_LT(r->stereo_rms, 0.6);
  const auto& l = r->calibration.cameras[0];
  const auto& rc = r->calibration.cameras[1];
  EXPECT_NEAR(l.K(0, 0), 536, 4);
  EXPECT_NEAR(l.K(0, 2), 342, 4);
  EXPECT_NEAR(cv::norm(rc.T), 0.0836, 0.002);
  EXPECT_GT(rc.Centre()[0], 0.07);  // right of the left camera
  EXPECT_GT(r->calibration.SigmaC(), 0.2);
}

TEST(Calibration, CheckerboardNeedsTheBoard) {
  CheckerboardOptions o;
  o.pattern = {7, 7};  // not this board
  auto r = CalibrateCheckerboard(Boards("left"), {}, o);
  EXPECT_TRUE(r.status().IsInvalidArgument());
  EXPECT_NE(r.status().message().find("found in only"), std::string::npos);
  auto m = CalibrateCheckerboard({kBoards + "nope.jpg"}, {}, CheckerboardOptions{});
  EXPECT_TRUE(m.status().IsNotFound());
  EXPECT_FALSE(CalibrateCheckerboard(Boards("left"), {kBoards + "right01.jpg"}, {}).ok());
}

TEST(Calibration, CalibrateCommandWritesTheYaml) {
  TempDir dir;
  std::string cmd = std::string(HVDB_INGEST_PATH) + " calibrate --out " + (dir / "cal.yml") + " --left";
  for (const auto& f : Boards("left")) cmd += " " + f;
  cmd += " --right";
  for (const auto& f : Boards("right")) cmd += " " + f;
  auto r = testing::RunCommand(cmd);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("reprojection error"), std::string::npos);
  auto cal = LoadCalibration(dir / "cal.yml");
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  EXPECT_EQ(cal->cameras.size(), 2u);
}

}  // namespace
}  // namespace hvdb::ingest
