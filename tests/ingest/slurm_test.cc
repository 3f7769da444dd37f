// Ingest on a Slurm cluster (ingest/slurm.h) on the one-node cluster that the CTest fixture
// `slurm` starts (scripts/slurm-dev.sh): a generated recording ingested by two array tasks
// through a reading hvdb-server (which sends them on to the writer) equals the same recording
// ingested locally; a task killed with SIGKILL mid-ingest, then a resubmit: every frame whole,
// none twice, photos not duplicated; bad frames (a missing camera file, an image that does not
// fit the calibration): an error naming the file and nothing committed for the frame.
#include "ingest/slurm.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <thread>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "client/backend.h"
#include "ingest/generator.h"
#include "ingest/pipeline.h"
#include "storage/database.h"
#include "tests/ingest/frame_points.h"
#include "tests/ingest/test_util.h"
#include "tests/server/server_child.h"

namespace hvdb::ingest {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hvdb::testing::ServerChild;
using hvdb::testing::WaitUntil;
using std::chrono::milliseconds;
using testing::RunCommand;
using testing::TempDir;

const std::string kIngest = HVDB_INGEST_PATH;
const std::string kRunOptions = " --num-disparities 32 --workers 1";

GeneratorOptions Rig(int frames, int width, int height) {
  GeneratorOptions g;
  g.bricks = 2;
  g.frames = frames;
  g.width = width;
  g.height = height;
  g.supersample = 1;
  g.seed = 38;
  return g;
}

bool HaveCluster() {
  const char* conf = std::getenv("SLURM_CONF");
  return conf && fs::exists(conf);
}

// A frame's points as an order-independent fingerprint: count and a hash of the sorted
// records with their ids cleared (ids depend on the order frames were committed in).
struct FrameSum {
  uint64_t count = 0, hash = 0;
  bool operator==(const FrameSum&) const = default;
};

std::map<uint32_t, FrameSum> Sums(const std::string& data, int frames, double fps) {
  std::map<uint32_t, FrameSum> out;
  auto b = client::MakeEmbeddedBackend(data, 32 << 20);
  for (int f = 0; f < frames; ++f) {
    const std::vector<Point> pts = testing::FramePoints(*b, "v", static_cast<uint32_t>(f), fps);
    uint64_t h = 1469598103934665603ull;  // FNV-1a
    const auto* bytes = reinterpret_cast<const unsigned char*>(pts.data());
    for (size_t i = 0; i < pts.size() * sizeof(Point); ++i) h = (h ^ bytes[i]) * 1099511628211ull;
    out[static_cast<uint32_t>(f)] = {pts.size(), h};
  }
  return out;
}

// Per frame, per camera id: the photo's bytes.
std::map<uint32_t, std::map<uint16_t, std::string>> Photos(const std::string& data, int frames) {
  std::map<uint32_t, std::map<uint16_t, std::string>> out;
  auto db = Database::Open(data);
  EXPECT_TRUE(db.ok()) << db.status().ToString();
  if (!db.ok()) return out;
  auto ds = (*db)->GetDataset("v");
  EXPECT_TRUE(ds.ok());
  if (!ds.ok()) return out;
  for (int f = 0; f < frames; ++f) {
    auto photos = (*ds)->Photos(static_cast<uint32_t>(f));
    EXPECT_TRUE(photos.ok());
    auto& m = out[static_cast<uint32_t>(f)];
    if (photos.ok())
      for (const Photo& p : *photos) {
        EXPECT_EQ(m.count(p.camera.id), 0u) << "frame " << f << ": camera " << p.camera.id << " twice";
        m[p.camera.id] = p.image;
      }
  }
  return out;
}

class SlurmIngest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(HaveCluster()) << "run through CTest: the fixture `slurm` starts the cluster "
                                  "(scripts/slurm-dev.sh) and sets SLURM_CONF";
  }
  // The recording, and its reference: ingested locally with `run --data`.
  void Generate(int frames, int width, int height) {
    frames_ = frames;
    auto g = GenerateRecording(Rig(frames, width, height), dir_ / "rec");
    ASSERT_TRUE(g.ok()) << g.status().ToString();
    auto rec = OpenRecording(dir_ / "rec");
    ASSERT_TRUE(rec.ok());
    rec_ = *rec;
  }
  void Reference() {
    auto r = RunCommand(kIngest + " run " + dir_ / "rec" + " --data " + dir_ / "local" +
                        " --dataset v --quiet" + kRunOptions);
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  // `hvdb-ingest submit`: the job id ("" if it failed: then *out has why).
  std::string Submit(const std::string& server, const std::string& args, std::string* out = nullptr,
                     const std::string& run_options = "") {
    auto r = RunCommand(kIngest + " submit " + dir_ / "rec" + " --dataset v --server " + server +
                        " --cpus-per-task 1 " + args + " -- " + kRunOptions + run_options);
    if (out) *out = r.output;
    if (r.exit_code != 0) return "";
    // The job id is the last line (stdout); the line before it (stderr) says what was sent.
    std::string id = r.output;
    while (!id.empty() && std::isspace(static_cast<unsigned char>(id.back()))) id.pop_back();
    return id.substr(id.rfind('\n') == std::string::npos ? 0 : id.rfind('\n') + 1);
  }
  json Status(const std::string& job, int* code = nullptr) {
    auto r = RunCommand("{ " + kIngest + " status " + job + " --json 2>/dev/null; }");
    if (code) *code = r.exit_code;
    try {
      return json::parse(r.output);
    } catch (const std::exception&) {
      ADD_FAILURE() << "status " << job << ": " << r.output;
      return json::object();
    }
  }
  json WaitFinished(const std::string& job) {
    json st;
    EXPECT_TRUE(WaitUntil(milliseconds(120000), [&] {
      st = Status(job);
      return st.value("finished", false);
    })) << st.dump(2);
    return st;
  }
  std::unique_ptr<ServerChild> Server(const std::string& name) {
    auto s = std::make_unique<ServerChild>(name, std::vector<std::string>{"--data", dir_ / "data", "--follow"},
                                           dir_.path());
    EXPECT_EQ(s->Start(), "");
    return s;
  }

  TempDir dir_;
  int frames_ = 0;
  Recording rec_;
};

TEST(SlurmUnit, FramesSplitIntoTasksAndTheScriptRunsEachRange) {
  auto t = SplitFrames(7, 3);
  ASSERT_EQ(t.size(), 3u);
  EXPECT_EQ(t[2].id, 2);
  EXPECT_EQ(t[2].first, 6);
  EXPECT_EQ(t[2].count, 1);
  SubmitOptions o;
  o.recording = "/r";
  o.dataset = "v";
  o.server = "h:1";
  o.ingest_path = "/bin/hvdb-ingest";
  o.partition = "batch";
  o.run_options = {"--no-photos"};
  const std::string s = SbatchScript(o, "/j", 3, {t[0], t[2]});
  EXPECT_NE(s.find("#SBATCH --array=0,2\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --partition=batch\n"), std::string::npos) << s;
  EXPECT_NE(s.find("#SBATCH --exclusive\n"), std::string::npos) << s;
  EXPECT_NE(s.find("--first $((id * 3)) --count 3 --report '/j'/task-$id.json"), std::string::npos) << s;
  EXPECT_NE(s.find(" '--no-photos'"), std::string::npos) << s;
}

// RemoteOptions::follow_leader, which the ingest uses: a client given a reader moves to the
// writer; without it the reader's NOT_LEADER (naming the writer) is what the caller gets.
TEST(FollowLeader, AClientGivenAReaderWritesToTheWriterOnlyWhenAsked) {
  TempDir d;
  ServerChild a("a", {"--data", d / "data", "--follow"}, d.path());
  ASSERT_EQ(a.Start(), "");
  ServerChild b("b", {"--data", d / "data", "--follow"}, d.path());
  ASSERT_EQ(b.Start(), "");
  client::RemoteOptions ro;
  ro.address = b.Address();
  auto plain = client::MakeRemoteBackend(ro);
  ASSERT_TRUE(plain.ok());
  DatasetInfo info;
  info.name = "v";
  auto refused = (*plain)->CreateDataset(info);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kNotLeader);
  EXPECT_NE(refused.status().message().find(a.Address()), std::string::npos) << refused.status().ToString();
  ro.follow_leader = true;
  auto following = client::MakeRemoteBackend(ro);
  ASSERT_TRUE(following.ok());
  auto created = (*following)->CreateDataset(info);
  ASSERT_TRUE(created.ok()) << created.status().ToString();
  EXPECT_EQ((*following)->where(), a.Address());
  std::vector<Point> pts(3);
  for (size_t i = 0; i < pts.size(); ++i) pts[i].x = static_cast<float>(i);
  auto loaded = (*following)->BulkLoad("v", 0, pts);
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  EXPECT_EQ(*loaded, 3u);
  // The reader has it too once it follows the commit; the plain client still only reads there.
  EXPECT_TRUE(WaitUntil(milliseconds(10000), [&] {
    auto p = FramePresent(**plain, "v", 0, info.fps);
    return p.ok() && *p;
  }));
}

TEST_F(SlurmIngest, BadOptionsAreRefusedBeforeAnythingIsWritten) {
  Generate(2, 64, 48);
  ServerChild a("a", {"--data", dir_ / "data"}, dir_.path());
  ASSERT_EQ(a.Start(), "");
  std::string out;
  EXPECT_EQ(Submit(a.Address(), "--frames-per-task 0 --job-dir " + dir_ / "j1", &out), "");
  EXPECT_NE(out.find("--frames-per-task must be at least 1"), std::string::npos) << out;
  auto r = RunCommand(kIngest + " submit " + dir_ / "rec" + " --dataset v --server " + a.Address() +
                      " --job-dir " + dir_ / "j2" + " -- --first 3");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("run option --first: submit sets it"), std::string::npos) << r.output;
  r = RunCommand(kIngest + " submit " + dir_ / "rec" + " --dataset v --server " + a.Address() +
                 " --job-dir " + dir_ / "j3" + " -- --window 4");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("options for `hvdb-ingest run` were refused"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir_ / "j1"));
  EXPECT_FALSE(fs::exists(dir_ / "j2"));
  EXPECT_FALSE(fs::exists(dir_ / "j3"));
}

TEST_F(SlurmIngest, TwoTasksThroughAReaderEqualALocalIngest) {
  Generate(6, 128, 96);
  Reference();
  auto a = Server("writer");
  auto b = Server("reader");  // the same data: it follows the writer and refuses writes
  // Submitted to the reader: dataset, photos and points all reach the writer.
  std::string out;
  const std::string job = Submit(b->Address(), "--frames-per-task 3 --job-dir " + dir_ / "job", &out);
  ASSERT_NE(job, "") << out;
  json st = WaitFinished(job);
  EXPECT_EQ(st["frames_committed"], 6) << st.dump(2);
  ASSERT_EQ(st["tasks"].size(), 2u);
  for (const json& t : st["tasks"]) {
    EXPECT_EQ(t["state"], "COMPLETED") << st.dump(2);
    EXPECT_EQ(t["ingested"], 3) << st.dump(2);
  }
  for (const char* stage : {"load", "stereo", "photos", "commit"})
    EXPECT_GT(st["stage_median_ms"].value(stage, -1.0), 0.0) << stage << ": " << st.dump(2);
  // The text form says the same; the job directory works as well as the id.
  auto text = RunCommand(kIngest + " status " + dir_ / "job");
  EXPECT_EQ(text.exit_code, 0) << text.output;
  EXPECT_NE(text.output.find("frames: 6 of 6 committed"), std::string::npos) << text.output;
  b.reset();
  a.reset();
  EXPECT_EQ(Sums(dir_ / "data", 6, rec_.fps), Sums(dir_ / "local", 6, rec_.fps));
  EXPECT_EQ(Photos(dir_ / "data", 6), Photos(dir_ / "local", 6));
}

// `submit ... -- --gaussians`: each task fits its chunk, the chunk's first frame from its
// points and the next warm-started, exactly as local runs of the same chunks (the fit is
// deterministic whatever the cores: tasks have one, the local runs every core).
TEST_F(SlurmIngest, GaussiansOfEachTaskEqualLocalRunsOfTheSameChunks) {
  Generate(4, 96, 72);
  const std::string fit = " --gaussians --fit-iterations 40 --fit-resolution 1 --fit-sh-degree 1";
  for (int first : {0, 2}) {
    auto r = RunCommand(kIngest + " run " + dir_ / "rec" + " --data " + dir_ / "local" +
                        " --dataset v --quiet --first " + std::to_string(first) + " --count 2" +
                        kRunOptions + fit);
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  auto a = Server("writer");
  std::string out;
  const std::string job =
      Submit(a->Address(), "--frames-per-task 2 --job-dir " + dir_ / "job", &out, fit);
  ASSERT_NE(job, "") << out;
  json st = WaitFinished(job);
  EXPECT_EQ(st["frames_committed"], 4) << st.dump(2);
  EXPECT_GT(st["stage_median_ms"].value("fit", -1.0), 0.0) << st.dump(2);
  a.reset();
  auto info = client::MakeEmbeddedBackend(dir_ / "data", 16 << 20)->Describe("v");
  ASSERT_TRUE(info.ok());
  EXPECT_TRUE(info->gaussians);
  const auto got = Sums(dir_ / "data", 4, rec_.fps);
  EXPECT_EQ(got, Sums(dir_ / "local", 4, rec_.fps));
  for (const auto& [frame, sum] : got) EXPECT_GT(sum.count, 0u) << "frame " << frame;
}

TEST_F(SlurmIngest, KilledTaskThenResubmitLeavesEveryFrameWholeAndOnce) {
  Generate(8, 192, 144);
  Reference();
  auto a = Server("writer");
  std::string out;
  const std::string job = Submit(a->Address(), "--frames-per-task 8 --job-dir " + dir_ / "job1", &out);
  ASSERT_NE(job, "") << out;
  // SIGKILL once the task has committed a frame, while it works on the next.
  client::RemoteOptions ro;
  ro.address = a->Address();
  auto backend = client::MakeRemoteBackend(ro);
  ASSERT_TRUE(backend.ok());
  auto committed = [&] {
    int n = 0;
    for (int f = 0; f < frames_; ++f) {
      auto p = FramePresent(**backend, "v", static_cast<uint32_t>(f), rec_.fps);
      n += p.ok() && *p;
    }
    return n;
  };
  ASSERT_TRUE(WaitUntil(milliseconds(90000), [&] { return committed() >= 1; }));
  auto k = RunCommand("scancel --signal=KILL " + job);
  ASSERT_EQ(k.exit_code, 0) << k.output;
  json st = WaitFinished(job);
  const int before = st["frames_committed"].get<int>();
  ASSERT_LT(before, frames_) << "the task finished before it was killed: make its frames slower";
  std::printf("killed with %d of %d frames committed\n", before, frames_);
  ASSERT_EQ(st["tasks"].size(), 1u);
  EXPECT_NE(st["tasks"][0]["state"], "COMPLETED") << st.dump(2);

  // What a kill between a frame's photos and its points leaves: a photo without points. The
  // resubmit must replace it, not add a second one.
  const int last = frames_ - 1;
  const Brick& brick = rec_.calibration.bricks[0];
  Photo stale;
  stale.camera = ToCameraInfo(rec_.calibration.cameras[brick.colour], static_cast<uint16_t>(brick.colour));
  std::vector<uchar> png;
  cv::imencode(".png", cv::Mat(static_cast<int>(stale.camera.height), static_cast<int>(stale.camera.width),
                              CV_8UC3, cv::Scalar(1, 2, 3)), png);
  stale.image.assign(png.begin(), png.end());
  const hvdb::Status put = (*backend)->PutPhoto("v", static_cast<uint32_t>(last), stale);
  ASSERT_TRUE(put.ok()) << put.ToString();

  const std::string job2 = Submit(a->Address(), "--frames-per-task 4 --job-dir " + dir_ / "job2", &out);
  ASSERT_NE(job2, "") << out;
  st = WaitFinished(job2);
  EXPECT_EQ(st["frames_committed"], frames_) << st.dump(2);
  // Only the ranges with a frame missing were submitted again.
  for (const json& t : st["tasks"]) EXPECT_EQ(t["state"], "COMPLETED") << st.dump(2);
  int present = 0, ingested = 0;
  for (const json& t : st["tasks"]) {
    present += t["present"].get<int>();
    ingested += t["ingested"].get<int>();
  }
  EXPECT_EQ(ingested, frames_ - before) << st.dump(2);
  EXPECT_EQ(present + ingested, static_cast<int>(st["tasks"].size()) * 4) << st.dump(2);
  // Nothing is missing now: a third submit sends nothing.
  auto r = RunCommand(kIngest + " submit " + dir_ / "rec" + " --dataset v --server " + a->Address());
  EXPECT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("nothing to submit"), std::string::npos) << r.output;
  backend->reset();
  a.reset();
  EXPECT_EQ(Sums(dir_ / "data", frames_, rec_.fps), Sums(dir_ / "local", frames_, rec_.fps));
  EXPECT_EQ(Photos(dir_ / "data", frames_), Photos(dir_ / "local", frames_));
}

TEST_F(SlurmIngest, BadFramesNameTheirFileAndCommitNothing) {
  Generate(4, 96, 72);
  // Frame 1 lacks a camera's file; frame 2's colour image does not fit the calibration.
  const std::string missing = dir_ / "rec/frames/000001/b0_left.png";
  ASSERT_TRUE(fs::remove(missing));
  const std::string wrong = dir_ / "rec/frames/000002/b1_colour.png";
  cv::Mat im = cv::imread(wrong);
  ASSERT_FALSE(im.empty());
  cv::resize(im, im, cv::Size(im.cols / 2, im.rows / 2));
  ASSERT_TRUE(cv::imwrite(wrong, im));
  auto a = Server("writer");
  std::string out;
  // Single-frame stereo: the generated recording's spacetime window would make frame 1's
  // missing file frame 0's and 2's error too.
  const std::string job =
      Submit(a->Address(), "--frames-per-task 2 --job-dir " + dir_ / "job", &out, " --spacetime 0");
  ASSERT_NE(job, "") << out;
  json st = WaitFinished(job);
  int code = 0;
  st = Status(job, &code);
  EXPECT_EQ(code, 3) << st.dump(2);
  ASSERT_EQ(st["tasks"].size(), 2u);
  const std::string e0 = st["tasks"][0].value("error", ""), e1 = st["tasks"][1].value("error", "");
  EXPECT_EQ(st["tasks"][0]["state"], "FAILED") << st.dump(2);
  EXPECT_NE(e0.find(missing), std::string::npos) << e0;
  EXPECT_NE(e0.find("missing"), std::string::npos) << e0;
  EXPECT_NE(e1.find(wrong), std::string::npos) << e1;
  EXPECT_NE(e1.find("calibration"), std::string::npos) << e1;
  const json missing_frames = st["frames_missing"];
  EXPECT_NE(std::find(missing_frames.begin(), missing_frames.end(), 1), missing_frames.end());
  EXPECT_NE(std::find(missing_frames.begin(), missing_frames.end(), 2), missing_frames.end());
  EXPECT_EQ(std::find(missing_frames.begin(), missing_frames.end(), 0), missing_frames.end());
  a.reset();
  auto photos = Photos(dir_ / "data", 4);
  EXPECT_TRUE(photos[1].empty());
  EXPECT_TRUE(photos[2].empty());
  EXPECT_EQ(photos[0].size(), 2u);
  EXPECT_EQ(Sums(dir_ / "data", 4, rec_.fps)[1].count, 0u);
  EXPECT_EQ(Sums(dir_ / "data", 4, rec_.fps)[2].count, 0u);
}

}  // namespace
}  // namespace hvdb::ingest
