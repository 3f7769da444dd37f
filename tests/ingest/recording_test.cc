#include "ingest/recording.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "client/backend.h"
#include "ingest/generator.h"
#include "tests/ingest/test_util.h"

namespace hvdb::ingest {
namespace {

using testing::TempDir;
namespace fs = std::filesystem;

GeneratorOptions Small() {
  GeneratorOptions g;
  g.bricks = 2;
  g.frames = 2;
  g.width = 96;
  g.height = 72;
  g.supersample = 1;
  return g;
}

TEST(Recording, GeneratedStereoRecordingLoads) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Small(), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  EXPECT_EQ(rec->kind, RecordingKind::kStereo);
  EXPECT_EQ(rec->frames, 2);
  ASSERT_EQ(rec->files.size(), 2u);
  EXPECT_EQ(rec->Path(rec->files[1].left, 1), (dir / "rec") + "/frames/000001/b1_left.png");
  auto f = LoadFrame(*rec, 1);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  ASSERT_EQ(f->stereo.size(), 2u);
  EXPECT_EQ(f->stereo[0].left.type(), CV_8UC1);
  EXPECT_EQ(f->stereo[0].colour.type(), CV_8UC3);
  EXPECT_EQ(f->stereo[0].left.size(), cv::Size(96, 72));
  EXPECT_GT(f->bytes_read, 0u);
  EXPECT_FALSE(LoadFrame(*rec, 2).ok());
  // Its stripes change every frame: it declares a spacetime window, which survives a save.
  EXPECT_EQ(rec->spacetime, 1);
  ASSERT_TRUE(SaveRecording(*rec).ok());
  auto again = OpenRecording(dir / "rec");
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->spacetime, 1);
  again->spacetime = 20;
  ASSERT_TRUE(SaveRecording(*again).ok());
  auto bad = OpenRecording(dir / "rec");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("spacetime must be 0..8"), std::string::npos)
      << bad.status().ToString();
  // Under structured light by default (the generator's stripes); natural texture survives a
  // save, and anything but 0 or 1 is a clear error.
  EXPECT_TRUE(rec->structured_light);
  again->spacetime = 1;
  again->structured_light = false;
  ASSERT_TRUE(SaveRecording(*again).ok());
  auto natural = OpenRecording(dir / "rec");
  ASSERT_TRUE(natural.ok()) << natural.status().ToString();
  EXPECT_FALSE(natural->structured_light);
  {
    std::ifstream in(dir / "rec/recording.yml");
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const auto at = text.find("structured_light: 0");
    ASSERT_NE(at, std::string::npos) << text;
    text.replace(at, 19, "structured_light: 2");
    std::ofstream(dir / "rec/recording.yml") << text;
  }
  auto wrong = OpenRecording(dir / "rec");
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("structured_light must be 0 or 1"), std::string::npos)
      << wrong.status().ToString();
}

// A PLY frame with NaN or infinite coordinates is a bad frame that names the file and
// --skip-invalid; with --skip-invalid its other points go in and the report counts the rest.
TEST(Recording, PlyNonFiniteIsAnErrorUnlessSkipInvalid) {
  TempDir dir;
  Recording r;
  r.dir = dir / "ply";
  fs::create_directories(r.dir + "/frames");
  r.kind = RecordingKind::kPly;
  r.frames = 2;
  ASSERT_TRUE(SaveRecording(r).ok());
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n";
  std::ofstream(r.dir + "/frames/000000.ply") << header << "0 0 1\n1 0 1\n0 1 1\n1 1 1\n";
  std::ofstream(r.dir + "/frames/000001.ply") << header << "0 0 1\n-inf 0 1\n0 nan 1\n1 1 1\n";

  auto f = LoadFrame(*OpenRecording(r.dir), 1);
  ASSERT_FALSE(f.ok());
  EXPECT_TRUE(f.status().IsInvalidArgument());
  EXPECT_NE(f.status().message().find("000001.ply: 2 of 4 vertices have a NaN or infinite "
                                      "coordinate (the first: vertex 1, x = -inf)"),
            std::string::npos)
      << f.status().ToString();
  f = LoadFrame(*OpenRecording(r.dir), 1, /*skip_invalid=*/true);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  EXPECT_EQ(f->points.size(), 2u);
  EXPECT_EQ(f->skipped_invalid, 2u);

  const std::string base =
      std::string(HVDB_INGEST_PATH) + " run " + r.dir + " --quiet --data " + (dir / "data");
  auto stop = testing::RunCommand(base + " --dataset p");
  EXPECT_EQ(stop.exit_code, 2) << stop.output;
  EXPECT_NE(stop.output.find("000001.ply: 2 of 4 vertices"), std::string::npos) << stop.output;
  EXPECT_NE(stop.output.find("--skip-invalid"), std::string::npos) << stop.output;
  // Another dataset: frame 0 of p may or may not have gone in before frame 1 failed.
  auto skip =
      testing::RunCommand(base + " --dataset q --skip-invalid --report " + (dir / "r.json"));
  EXPECT_EQ(skip.exit_code, 0) << skip.output;
  EXPECT_NE(skip.output.find("skipped 2 points with a NaN or infinite coordinate in 1 frame"),
            std::string::npos)
      << skip.output;
  std::ifstream in(dir / "r.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_EQ(j["skipped_invalid"], 2);
  EXPECT_EQ(j["points"], 6);
  EXPECT_EQ(j["frames"][1]["skipped_invalid"], 2);
  auto backend = client::MakeEmbeddedBackend(dir / "data", 16 << 20);
  auto info = backend->Describe("q");
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->point_count, 6u);
}

TEST(Recording, MissingAndMismatchedFilesNameTheFile) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Small(), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  const std::string gone = dir / "rec/frames/000001/b1_right.png";
  fs::remove(gone);
  auto f = LoadFrame(*rec, 1);
  EXPECT_TRUE(f.status().IsNotFound());
  EXPECT_NE(f.status().message().find(gone), std::string::npos) << f.status().ToString();
  // An image of the wrong size: the error says the calibration disagrees.
  const std::string small = dir / "rec/frames/000000/b0_left.png";
  cv::imwrite(small, cv::Mat(10, 10, CV_8UC1, cv::Scalar(1)));
  auto g = LoadFrame(*rec, 0);
  EXPECT_TRUE(g.status().IsInvalidArgument());
  EXPECT_NE(g.status().message().find("calibration"), std::string::npos) << g.status().ToString();
  // An unreadable image.
  std::ofstream(dir / "rec/frames/000000/b0_left.png") << "garbage";
  EXPECT_TRUE(LoadFrame(*rec, 0).status().IsCorruption());
  // recording.yml problems.
  EXPECT_TRUE(OpenRecording(dir.path()).status().IsNotFound());
  std::ofstream(dir / "rec/recording.yml") << "%YAML:1.0\nformat: \"hvdb-recording\"\nversion: 1\nkind: \"video\"\nframes: 2\n";
  EXPECT_NE(OpenRecording(dir / "rec").status().message().find("kind must be"), std::string::npos);
}

// A depth recording written by hand: png16 depth with an invalid code, EXR with NaN, poses.
TEST(Recording, DepthEncodingsPosesAndNaN) {
  TempDir dir;
  GeneratorOptions g = Small();
  Calibration cal;
  cal.cameras.push_back(GeneratorCalibration(g).cameras[2]);
  cal.cameras[0].name = "cam";
  cal.cameras[0].dist.clear();
  fs::create_directories(dir / "frames/000003");
  ASSERT_TRUE(SaveCalibration(cal, dir / "calibration.yml").ok());
  Recording r;
  r.dir = dir.path();
  r.kind = RecordingKind::kDepth;
  r.frames = 1;
  r.first_frame = 3;
  r.depth_encoding = DepthEncoding::kPng16;
  r.depth_scale = 0.001;
  r.depth_invalid = {0, 65535};
  CameraFiles cf;
  cf.camera = "cam";
  cf.pose = "frames/{frame:06d}/{camera}.pose.txt";
  r.files.push_back(cf);
  ASSERT_TRUE(SaveRecording(r).ok());
  cv::Mat d16(72, 96, CV_16UC1, cv::Scalar(1500));
  d16.at<uint16_t>(0, 0) = 0;
  d16.at<uint16_t>(0, 1) = 65535;
  cv::imwrite(dir / "frames/000003/cam.depth.png", d16);
  cv::imwrite(dir / "frames/000003/cam.png", cv::Mat(72, 96, CV_8UC3, cv::Scalar(1, 2, 3)));
  // Camera-to-world: 90 degrees about y, at (1, 2, 3); CRLF, tabs, 3-digit exponents.
  std::ofstream(dir / "frames/000003/cam.pose.txt")
      << "0.0e+000\t0\t1.0000000e+000\t1\t\r\n0 1 0 2\r\n-1 0 0 3e+000\r\n0 0 0 1\r\n";
  auto rec = OpenRecording(dir.path());
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  auto f = LoadFrame(*rec, 0);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  ASSERT_EQ(f->depth.size(), 1u);
  const cv::Mat& z = f->depth[0].depth;
  EXPECT_EQ(z.at<float>(0, 0), 0.f);
  EXPECT_EQ(z.at<float>(0, 1), 0.f);
  EXPECT_FLOAT_EQ(z.at<float>(5, 5), 1.5f);
  const CameraModel& m = f->depth[0].model;
  EXPECT_LT(cv::norm(m.Centre() - cv::Vec3d(1, 2, 3)), 1e-9);
  // Camera z (forward) maps to world +x... the pose's third column is (1, 0, 0).
  EXPECT_LT(cv::norm(m.R.t() * cv::Vec3d(0, 0, 1) - cv::Vec3d(1, 0, 0)), 1e-9);

  // The same as EXR with a NaN: an error that names the file and the pixel.
  r.depth_encoding = DepthEncoding::kExr;
  ASSERT_TRUE(SaveRecording(r).ok());
  cv::Mat zf(72, 96, CV_32F, cv::Scalar(2.0f));
  zf.at<float>(4, 7) = std::numeric_limits<float>::infinity();
  ASSERT_TRUE(WriteDepthExr(dir / "frames/000003/cam.depth.exr", zf).ok());
  auto ok = LoadFrame(*OpenRecording(dir.path()), 0);
  ASSERT_TRUE(ok.ok()) << ok.status().ToString();
  EXPECT_EQ(ok->depth[0].depth.at<float>(4, 7), 0.f);  // +inf = no depth
  zf.at<float>(4, 7) = std::nanf("");
  ASSERT_TRUE(WriteDepthExr(dir / "frames/000003/cam.depth.exr", zf).ok());
  auto bad = LoadFrame(*OpenRecording(dir.path()), 0);
  EXPECT_TRUE(bad.status().IsCorruption());
  EXPECT_NE(bad.status().message().find("NaN depth at pixel (7, 4)"), std::string::npos)
      << bad.status().ToString();
}

TEST(Recording, PoseFilesAreCheckedAndInverse8Decodes) {
  TempDir dir;
  std::ofstream(dir / "short.txt") << "1 0 0 0\n0 1 0 0\n";
  EXPECT_TRUE(ReadPoseFile(dir / "short.txt").status().IsCorruption());
  std::ofstream(dir / "row.txt") << "1 0 0 0 0 1 0 0 0 0 1 0 0 0 1 1";
  EXPECT_TRUE(ReadPoseFile(dir / "row.txt").status().IsCorruption());
  EXPECT_TRUE(ReadPoseFile(dir / "none.txt").status().IsNotFound());

  // inverse8: v = 255 is z_near, v = 1 close to z_far, 0 invalid.
  GeneratorOptions g = Small();
  Calibration cal;
  cal.cameras.push_back(GeneratorCalibration(g).cameras[2]);
  ASSERT_TRUE(SaveCalibration(cal, dir / "calibration.yml").ok());
  Recording r;
  r.dir = dir.path();
  r.kind = RecordingKind::kDepth;
  r.frames = 1;
  r.depth_encoding = DepthEncoding::kInverse8;
  r.z_near = 2;
  r.z_far = 10;
  ASSERT_TRUE(SaveRecording(r).ok());
  fs::create_directories(dir / "frames/000000");
  const std::string cam = cal.cameras[0].name;
  cv::Mat v(72, 96, CV_8UC1, cv::Scalar(255));
  v.at<uint8_t>(1, 1) = 0;
  cv::imwrite(dir / ("frames/000000/" + cam + ".depth.png"), v);
  cv::imwrite(dir / ("frames/000000/" + cam + ".png"), cv::Mat(72, 96, CV_8UC3, cv::Scalar(0)));
  auto f = LoadFrame(*OpenRecording(dir.path()), 0);
  ASSERT_TRUE(f.ok()) << f.status().ToString();
  EXPECT_NEAR(f->depth[0].depth.at<float>(0, 0), 2.0, 1e-5);
  EXPECT_EQ(f->depth[0].depth.at<float>(1, 1), 0.f);
}

}  // namespace
}  // namespace hvdb::ingest
