// hvdb-ingest run --gaussians (ingest/gaussian_frames.h through RunIngest): a generated
// stereo recording's frames fitted in order into a Gaussian-splat dataset, resumed, refused
// where it cannot work, and a frame with a missing photo named and not committed. (--follow
// with --gaussians: live_test.cc.)
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "ingest/generator.h"
#include "ingest/pipeline.h"
#include "tests/ingest/frame_points.h"
#include "tests/ingest/test_util.h"

namespace hvdb::ingest {
namespace {

using testing::TempDir;
namespace fs = std::filesystem;

GeneratorOptions SmallRig(int frames) {
  GeneratorOptions g;
  g.bricks = 2;
  g.frames = frames;
  g.width = 128;
  g.height = 96;
  g.supersample = 2;
  g.seed = 11;
  return g;
}

IngestOptions GaussianOptions(const std::string& dataset) {
  IngestOptions o;
  o.dataset = dataset;
  o.stereo.num_disparities = 32;
  o.gaussians = true;
  o.gaussian.fit.iterations = 150;
  o.gaussian.fit.sh_degree = 1;
  o.gaussian.fit.sh_degree_interval = 50;
  o.gaussian.fit.densify_from = 20;
  o.gaussian.fit.densify_until = 100;
  o.gaussian.fit.densify_interval = 20;
  o.gaussian.resolution_scale = 1;
  o.gaussian.max_start_splats = 20000;
  return o;
}

TEST(GaussianIngest, FitsEveryFrameInOrderIntoAGaussianDatasetAndResumes) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(SmallRig(2), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  auto backend = client::MakeEmbeddedBackend(dir / "data", 64 << 20);
  const IngestOptions o = GaussianOptions("g");
  auto rep = RunIngest(*rec, *backend, o);
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingested, 2);
  auto info = backend->Describe("g");
  ASSERT_TRUE(info.ok());
  EXPECT_TRUE(info->gaussians);
  for (const FrameReport& fr : rep->frames) {
    ASSERT_TRUE(fr.fit.has_value()) << "frame " << fr.frame;
    EXPECT_GT(fr.fit->psnr, 20.0) << "frame " << fr.frame;  // on the training views
    EXPECT_GT(fr.stage_ms.at("fit"), 0);
    // The frame stores the fitted splats, each with its Gaussian record.
    const auto points = testing::QueryFramePoints(*backend, "g", fr.dataset_frame, rec->fps);
    EXPECT_EQ(points.size(), fr.fit->splats_out);
    EXPECT_EQ(points.size(), fr.points);
    auto records = backend->ReadGaussians("g", points);
    ASSERT_TRUE(records.ok()) << records.status().ToString();
    EXPECT_EQ(records->sh_degree, 1);
  }
  EXPECT_EQ(rep->frames[0].fit->iterations, 150);  // from the points
  // Frame 1 warm-started from frame 0: a third of the steps, or none if nothing changed.
  EXPECT_LE(rep->frames[1].fit->iterations, 50);
  const nlohmann::json j = rep->ToJson();
  EXPECT_TRUE(j["frames"][0].contains("fit"));
  EXPECT_EQ(j["frames"][0]["fit"]["iterations"], 150);

  // Run again: both frames are present, nothing is fitted or added.
  auto again = RunIngest(*rec, *backend, o);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->present, 2);
  EXPECT_EQ(again->ingested, 0);

  // A points dataset is not a Gaussian one, and the other way round.
  IngestOptions plain = o;
  plain.gaussians = false;
  auto wrong = RunIngest(*rec, *backend, plain);
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("Gaussian-splat dataset"), std::string::npos)
      << wrong.status().ToString();
}

TEST(GaussianIngest, AFrameWithAMissingPhotoIsNamedAndNotCommitted) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(SmallRig(2), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  // Frame 1's colour photo of the first brick is gone.
  const std::string lost = rec->Path(rec->files[0].colour, 1);
  ASSERT_TRUE(fs::remove(lost)) << lost;
  auto backend = client::MakeEmbeddedBackend(dir / "data", 64 << 20);
  IngestOptions o = GaussianOptions("g");
  o.skip_bad_frames = true;
  o.spacetime = 0;  // each frame matched alone: frame 0 does not read frame 1's files
  auto rep = RunIngest(*rec, *backend, o);
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingested, 1);
  EXPECT_EQ(rep->skipped, 1);
  EXPECT_EQ(rep->frames[1].status, "skipped");
  EXPECT_NE(rep->frames[1].error.find(fs::path(lost).filename().string()), std::string::npos)
      << rep->frames[1].error;
  EXPECT_TRUE(testing::QueryFramePoints(*backend, "g", 1, rec->fps).empty());
  EXPECT_FALSE(testing::QueryFramePoints(*backend, "g", 0, rec->fps).empty());
}

// A point-cloud recording without colour cameras has nothing to fit to: refused, naming what
// it lacks, before a dataset is created.
TEST(GaussianIngest, ARecordingWithoutColourCamerasIsRefusedBeforeAnythingIsMade) {
  TempDir dir;
  Recording r;
  r.dir = dir / "ply";
  fs::create_directories(r.dir + "/frames");
  r.kind = RecordingKind::kPly;
  r.frames = 1;
  ASSERT_TRUE(SaveRecording(r).ok());
  std::ofstream(r.dir + "/frames/000000.ply")
      << "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
         "property float z\nend_header\n0 0 1\n";
  auto rec = OpenRecording(r.dir);
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  auto backend = client::MakeEmbeddedBackend(dir / "data", 16 << 20);
  auto rep = RunIngest(*rec, *backend, GaussianOptions("g"));
  ASSERT_FALSE(rep.ok());
  EXPECT_EQ(rep.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(rep.status().message().find("no colour cameras"), std::string::npos)
      << rep.status().ToString();
  EXPECT_TRUE(backend->Describe("g").status().IsNotFound());
}

TEST(GaussianIngest, TheCommandFitsAndReports) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(SmallRig(1), dir / "rec").ok());
  const std::string cmd = std::string(HVDB_INGEST_PATH) + " run " + (dir / "rec") +
                          " --dataset g --data " + (dir / "data") +
                          " --num-disparities 32 --gaussians --fit-iterations 60 "
                          "--fit-resolution 2 --fit-sh-degree 0 --quiet --report " +
                          (dir / "report.json");
  const auto r = testing::RunCommand(cmd);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "report.json");
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["frames"][0]["fit"]["iterations"], 60);
  EXPECT_GT(j["frames"][0]["fit"]["psnr_training_views"].get<double>(), 15.0);
}

}  // namespace
}  // namespace hvdb::ingest
