// Live ingest (ingest/live.h): the completeness test on real files, `run --follow` on
// recordings written frame by frame (renamed into place, or written in place in pieces) against
// ingesting the finished recording, a frame that never completes, SIGTERM during a follow (with
// one and with several frames in flight), frames in flight committed in order, and replay of
// the real 7-Scenes sequence.
#include "ingest/live.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include <opencv2/imgcodecs.hpp>

#include "client/backend.h"
#include "formats/ply.h"
#include "ingest/generator.h"
#include "storage/database.h"
#include "tests/ingest/frame_points.h"
#include "tests/ingest/test_util.h"
#include "tests/server/server_process.h"

namespace hvdb::ingest {
namespace {

using testing::FramePoints;

using testing::TempDir;
namespace fs = std::filesystem;
using std::chrono::milliseconds;

GeneratorOptions Rig(int frames) {
  GeneratorOptions g;
  g.bricks = 2;
  g.frames = frames;
  g.width = 128;
  g.height = 96;
  g.supersample = 1;
  g.seed = 34;
  return g;
}

IngestOptions Options(const std::string& dataset = "v") {
  IngestOptions o;
  o.dataset = dataset;  // not a literal here: GCC 12 warns falsely (-Wrestrict) on that
  o.stereo.num_disparities = 32;
  return o;
}

// The reference: the finished recording ingested by RunIngest.
std::map<uint32_t, std::vector<Point>> Reference(const Recording& rec, const std::string& data) {
  auto backend = client::MakeEmbeddedBackend(data, 32 << 20);
  auto rep = RunIngest(rec, *backend, Options());
  EXPECT_TRUE(rep.ok()) << rep.status().ToString();
  std::map<uint32_t, std::vector<Point>> out;
  for (int f = 0; f < rec.frames; ++f) out[f] = FramePoints(*backend, "v", f, rec.fps);
  return out;
}

// Dataset "v"'s photos of frame f in data directory `data`: per camera id, the image's bytes.
std::map<uint16_t, std::string> FramePhotos(const std::string& data, uint32_t f) {
  std::map<uint16_t, std::string> out;
  auto db = Database::Open(data);
  EXPECT_TRUE(db.ok()) << db.status().ToString();
  if (!db.ok()) return out;
  auto ds = (*db)->GetDataset("v");
  EXPECT_TRUE(ds.ok());
  if (!ds.ok()) return out;
  auto photos = (*ds)->Photos(f);
  EXPECT_TRUE(photos.ok());
  if (photos.ok())
    for (const Photo& p : *photos) out[p.camera.id] = p.image;
  return out;
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

void WriteAll(const std::string& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary | std::ios::trunc) << bytes;
}

TEST(Live, CompletenessOfEachFormat) {
  TempDir dir;
  FileCompleteness files(/*settle_ms=*/150);
  EXPECT_EQ(files.Check(dir / "nothing.png").why, "missing");
  // PNG and JPEG: whole, and cut short by one byte.
  cv::Mat im(20, 30, CV_8UC3, cv::Scalar(10, 200, 30));
  for (const char* ext : {".png", ".jpg"}) {
    const std::string path = dir / (std::string("im") + ext);
    ASSERT_TRUE(cv::imwrite(path, im));
    EXPECT_TRUE(files.Check(path).complete) << path;
    const std::string bytes = ReadAll(path);
    WriteAll(path, bytes.substr(0, bytes.size() - 1));
    EXPECT_FALSE(files.Check(path).complete) << path;
    EXPECT_NE(files.Check(path).why.find("incomplete"), std::string::npos);
  }
  // EXR: whole, and without its last scanlines.
  const std::string exr = dir / "d.depth.exr";
  ASSERT_TRUE(WriteDepthExr(exr, cv::Mat(40, 50, CV_32F, cv::Scalar(1.5f))).ok());
  EXPECT_TRUE(files.Check(exr).complete);
  const std::string e = ReadAll(exr);
  WriteAll(exr, e.substr(0, e.size() - 300));
  EXPECT_FALSE(files.Check(exr).complete);
  // Binary PLY: whole, and without its last vertex.
  std::vector<Point> pts(10);
  for (size_t i = 0; i < pts.size(); ++i) pts[i].x = static_cast<float>(i);
  const std::string ply = dir / "f.ply";
  ASSERT_TRUE(formats::WritePly(ply, pts).ok());
  EXPECT_TRUE(files.Check(ply).complete);
  const std::string pb = ReadAll(ply);
  WriteAll(ply, pb.substr(0, pb.size() - 5));
  EXPECT_FALSE(files.Check(ply).complete);
  // A pose: whole with its 16 numbers and final newline; cut short, it is not (a cut after
  // "0 0 0 1" may be one in the middle of "0 0 0 1.5").
  const std::string pose = dir / "p.pose.txt";
  WriteAll(pose, "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  EXPECT_TRUE(files.Check(pose).complete);
  WriteAll(pose, "1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1");
  EXPECT_FALSE(files.Check(pose).complete);
  // Any other file: complete once closed by its writer, or unchanged for settle_ms.
  const std::string yml = dir / "r.yml";
  WriteAll(yml, "%YAML:1.0\n");
  EXPECT_FALSE(files.Check(yml).complete);
  EXPECT_TRUE(files.Check(yml, /*closed=*/true).complete);
  std::this_thread::sleep_for(milliseconds(200));
  EXPECT_TRUE(files.Check(yml).complete);
  EXPECT_TRUE(files.Check(pose).complete);
}

// Writes the recording `src` into `out` frame by frame, every file in place (not renamed) in
// three pieces a few milliseconds apart: the follower must wait for each file's end.
void WriteInPieces(const std::string& src_dir, const std::string& out, int frames_written, int skip_frame,
                   const std::string& skip_file) {
  fs::create_directories(out);
  fs::copy_file(src_dir + "/calibration.yml", out + "/calibration.yml");
  fs::copy_file(src_dir + "/recording.yml", out + "/recording.yml");
  auto src = OpenRecording(src_dir);
  auto dst = OpenRecording(out);
  ASSERT_TRUE(src.ok() && dst.ok());
  for (int f = 0; f < frames_written; ++f) {
    const auto from = FrameFiles(*src, f), to = FrameFiles(*dst, f);
    for (size_t k = 0; k < from.size(); ++k) {
      if (f == skip_frame && fs::path(to[k]).filename() == skip_file) continue;
      fs::create_directories(fs::path(to[k]).parent_path());
      const std::string bytes = ReadAll(from[k]);
      std::ofstream o(to[k], std::ios::binary);
      const size_t third = bytes.size() / 3;
      for (size_t at = 0; at < bytes.size(); at += third) {
        o.write(bytes.data() + at, static_cast<std::streamsize>(std::min(third, bytes.size() - at)));
        o.flush();
        std::this_thread::sleep_for(milliseconds(3));
      }
    }
    std::this_thread::sleep_for(milliseconds(40));
  }
}

// A recording written frame by frame, in place and in pieces, followed: every frame's points
// are exactly those of ingesting the finished recording.
TEST(Live, FollowEqualsIngestingTheFinishedRecording) {
  TempDir dir;
  const int frames = 4;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  std::thread writer([&] { WriteInPieces(dir / "src", dir / "live", frames, -1, ""); });
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  auto rep = FollowRecording(dir / "live", *backend, Options(), fo);
  writer.join();
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingest.ingested, frames);
  EXPECT_EQ(rep->timed_out, 0);
  EXPECT_EQ(rep->latency_s.size(), static_cast<size_t>(frames));
  for (int f = 0; f < frames; ++f) {
    const auto got = FramePoints(*backend, "v", f, rec->fps);
    EXPECT_GT(got.size(), 100u);
    EXPECT_EQ(got.size(), reference.at(f).size()) << "frame " << f;
    EXPECT_TRUE(got == reference.at(f)) << "frame " << f;
  }
  backend.reset();
  // The same photos, too.
  for (uint32_t f = 0; f < frames; ++f) {
    const auto got = FramePhotos(dir / "data", f);
    EXPECT_EQ(got.size(), 2u);
    EXPECT_TRUE(got == FramePhotos(dir / "ref", f)) << "frame " << f;
  }
}

// --follow --gaussians: each frame fitted as it is committed, warm-started from the one before,
// gives the splats of a run over the finished recording.
TEST(Live, FollowWithGaussiansEqualsIngestingTheFinishedRecording) {
  TempDir dir;
  const int frames = 3;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  IngestOptions o = Options();
  o.gaussians = true;
  o.gaussian.fit = Scheduled(o.gaussian.fit, 45);
  o.gaussian.fit.sh_degree = 1;
  o.gaussian.resolution_scale = 2;
  std::map<uint32_t, std::vector<Point>> reference;
  {
    auto backend = client::MakeEmbeddedBackend(dir / "ref", 32 << 20);
    auto rep = RunIngest(*rec, *backend, o);
    ASSERT_TRUE(rep.ok()) << rep.status().ToString();
    for (int f = 0; f < frames; ++f) reference[f] = FramePoints(*backend, "v", f, rec->fps);
    EXPECT_LE(rep->frames[1].fit->iterations, 15);  // warm-started
  }
  std::thread writer([&] { WriteInPieces(dir / "src", dir / "live", frames, -1, ""); });
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  auto rep = FollowRecording(dir / "live", *backend, o, fo);
  writer.join();
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingest.ingested, frames);
  auto info = backend->Describe("v");
  ASSERT_TRUE(info.ok());
  EXPECT_TRUE(info->gaussians);
  for (int f = 0; f < frames; ++f) {
    ASSERT_TRUE(rep->ingest.frames[static_cast<size_t>(f)].fit.has_value()) << "frame " << f;
    const auto got = FramePoints(*backend, "v", f, rec->fps);
    EXPECT_GT(got.size(), 100u);
    EXPECT_TRUE(got == reference.at(f)) << "frame " << f;
  }
}

// Without inotify events (as on NFS) the bounded poll alone still takes every frame: a PLY
// video replayed at 20 fps, followed by polling, is the finished video's ingest.
TEST(Live, ThePollAloneTakesEveryFrame) {
  TempDir dir;
  const int frames = 6;
  fs::create_directories(dir / "ply/frames");
  for (int f = 0; f < frames; ++f) {
    std::vector<Point> pts(2000);
    for (size_t i = 0; i < pts.size(); ++i) {
      pts[i].x = static_cast<float>(i % 50) * 0.01f + f * 0.1f;
      pts[i].y = static_cast<float>(i / 50) * 0.01f;
      pts[i].z = 1;
      pts[i].r = static_cast<uint8_t>(i);
    }
    char name[64];
    std::snprintf(name, sizeof name, "/frames/%06d.ply", f);
    ASSERT_TRUE(formats::WritePly(dir / "ply" + name, pts).ok());
  }
  WriteAll(dir / "ply/recording.yml", "%YAML:1.0\n---\nformat: \"hvdb-recording\"\nversion: 1\nkind: \"ply\"\nframes: " +
                                          std::to_string(frames) + "\nfps: 20\n");
  auto rec = OpenRecording(dir / "ply");
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  const auto reference = Reference(*rec, dir / "ref");
  std::thread writer([&] {
    ReplayOptions ro;
    ro.fps = 20;
    EXPECT_TRUE(ReplayRecording(dir / "ply", dir / "live", ro).ok());
  });
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  fo.inotify = false;
  auto rep = FollowRecording(dir / "live", *backend, Options(), fo);
  writer.join();
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingest.ingested, frames);
  for (int f = 0; f < frames; ++f) {
    const auto got = FramePoints(*backend, "v", f, rec->fps);
    EXPECT_EQ(got.size(), 2000u);
    EXPECT_TRUE(got == reference.at(f)) << f;
  }
}

// A file of frame 2 never appears: frame 2 is reported by that file's name and not committed;
// the frames after it still are (frame 4 exactly as in the finished recording: its window does
// not reach frame 2).
TEST(Live, AFrameThatNeverCompletesIsReportedAndSkipped) {
  TempDir dir;
  const int frames = 5;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  std::thread writer([&] { WriteInPieces(dir / "src", dir / "live", frames, 2, "b1_right.png"); });
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  fo.frame_timeout = 1;
  auto rep = FollowRecording(dir / "live", *backend, Options(), fo);
  writer.join();
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->timed_out, 1);
  ASSERT_EQ(rep->ingest.frames.size(), static_cast<size_t>(frames));
  const FrameReport& bad = rep->ingest.frames[2];
  EXPECT_EQ(bad.status, "skipped");
  EXPECT_NE(bad.error.find("000002/b1_right.png: missing"), std::string::npos) << bad.error;
  EXPECT_EQ(rep->ingest.ingested, frames - 1);
  EXPECT_TRUE(FramePoints(*backend, "v", 2, rec->fps).empty());
  for (int f : {0, 1, 3, 4}) EXPECT_FALSE(FramePoints(*backend, "v", f, rec->fps).empty()) << f;
  for (int f : {0, 4}) EXPECT_TRUE(FramePoints(*backend, "v", f, rec->fps) == reference.at(f)) << f;
}

// `hvdb-ingest run LIVE --follow --verbose` (into DATA, plus `extra`) in a child, sent SIGTERM
// once it says "frame 1: taken"; its output and wait status.
struct SigtermRun {
  std::string output;
  bool signalled = false;
  int status = 0;
};
SigtermRun FollowUntilSigterm(const std::string& live, const std::string& data,
                              std::vector<std::string> extra) {
  std::vector<std::string> args = {HVDB_INGEST_PATH, "run", live, "--follow", "--verbose"};
  args.insert(args.end(), extra.begin(), extra.end());
  for (const char* a : {"--dataset", "v", "--data"}) args.push_back(a);
  args.push_back(data);
  for (const char* a : {"--num-disparities", "32", "--quiet"}) args.push_back(a);
  SigtermRun run;
  int out[2];
  if (::pipe(out) != 0) return run;
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(out[1], 1);
    ::close(out[0]);
    ::close(out[1]);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  ::close(out[1]);
  char buf[256];
  ssize_t n;
  while ((n = ::read(out[0], buf, sizeof buf)) > 0) {
    run.output.append(buf, static_cast<size_t>(n));
    if (!run.signalled && run.output.find("frame 1: taken ") != std::string::npos) {
      run.signalled = ::kill(pid, SIGTERM) == 0;
    }
  }
  ::close(out[0]);
  ::waitpid(pid, &run.status, 0);
  return run;
}

// hvdb-ingest run --follow gets SIGTERM while it processes frame 1: it commits frame 1 whole,
// exits 0 with its summary, and takes no frame after it.
TEST(Live, SigtermFinishesTheFrameInHand) {
  TempDir dir;
  const int frames = 5;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  // Frames 0..2 of 5 are there: frame 1 can be taken, frame 2 waits for frame 3.
  fs::copy(dir / "src", dir / "live", fs::copy_options::recursive);
  for (int f : {3, 4}) fs::remove_all(fs::path(dir / "live") / "frames" / ("00000" + std::to_string(f)));
  const SigtermRun run = FollowUntilSigterm(dir / "live", dir / "data", {});
  const std::string& output = run.output;
  ASSERT_TRUE(run.signalled) << output;
  ASSERT_TRUE(WIFEXITED(run.status)) << output;
  EXPECT_EQ(WEXITSTATUS(run.status), 0) << output;
  EXPECT_NE(output.find("frame 1: committed"), std::string::npos) << output;
  EXPECT_NE(output.find("(stopped by a signal)"), std::string::npos) << output;
  EXPECT_EQ(output.find("frame 2: taken "), std::string::npos) << output;
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  for (int f : {0, 1}) EXPECT_TRUE(FramePoints(*backend, "v", f, rec->fps) == reference.at(f)) << f;
  EXPECT_TRUE(FramePoints(*backend, "v", 2, rec->fps).empty());
}

// A recording written at once, followed with two workers: frames are prepared together
// (several in flight), committed in frame order, each exactly as a normal run commits it.
TEST(Live, FramesInFlightCommitInOrderAndEqualARun) {
  TempDir dir;
  const int frames = 6;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  fs::copy(dir / "src", dir / "live", fs::copy_options::recursive);
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  IngestOptions o = Options();
  o.workers = 2;
  auto rep = FollowRecording(dir / "live", *backend, o, fo);
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingest.ingested, frames);
  EXPECT_GE(rep->max_in_flight, 2);
  EXPECT_LE(rep->max_in_flight, 3);  // workers + 1
  ASSERT_EQ(rep->ingest.frames.size(), static_cast<size_t>(frames));
  for (int f = 0; f < frames; ++f) {
    EXPECT_EQ(rep->ingest.frames[f].frame, f);  // reported (committed) in order
    const auto got = FramePoints(*backend, "v", f, rec->fps);
    EXPECT_GT(got.size(), 100u);
    EXPECT_TRUE(got == reference.at(f)) << "frame " << f;
  }
}

// SIGTERM while several frames are in flight (--workers 2, the whole recording there): every
// frame taken is committed whole, in order, and none after; the dataset holds frames 0..k
// exactly as a normal run, nothing after k.
TEST(Live, SigtermWithFramesInFlightCommitsThemInOrder) {
  TempDir dir;
  const int frames = 10;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  fs::copy(dir / "src", dir / "live", fs::copy_options::recursive);
  const SigtermRun run = FollowUntilSigterm(dir / "live", dir / "data", {"--workers", "2"});
  const std::string& output = run.output;
  ASSERT_TRUE(run.signalled) << output;
  ASSERT_TRUE(WIFEXITED(run.status)) << output;
  EXPECT_EQ(WEXITSTATUS(run.status), 0) << output;
  EXPECT_NE(output.find("(stopped by a signal)"), std::string::npos) << output;
  // The frames taken and those committed, in the order said.
  std::vector<int> taken, committed;
  std::istringstream lines(output);
  for (std::string line; std::getline(lines, line);) {
    int f = -1;
    char what[16] = {};
    if (std::sscanf(line.c_str(), "frame %d: %15s", &f, what) != 2) continue;
    if (std::string(what) == "taken") taken.push_back(f);
    if (std::string(what) == "committed") committed.push_back(f);
  }
  ASSERT_GE(committed.size(), 2u) << output;
  EXPECT_LT(committed.size(), static_cast<size_t>(frames)) << output;
  EXPECT_EQ(committed, taken) << output;
  for (size_t k = 0; k < committed.size(); ++k) EXPECT_EQ(committed[k], static_cast<int>(k)) << output;
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  for (int f = 0; f < frames; ++f) {
    if (f < static_cast<int>(committed.size())) {
      EXPECT_TRUE(FramePoints(*backend, "v", f, rec->fps) == reference.at(f)) << f;
    } else {
      EXPECT_TRUE(FramePoints(*backend, "v", f, rec->fps).empty()) << f;
    }
  }
}

// Runs argv (argv[0] the binary) with its stdout on a pipe; returns the child and the read end.
std::pair<pid_t, int> Spawn(std::vector<std::string> argv) {
  int fds[2];
  if (::pipe(fds) != 0) return {-1, -1};
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(fds[1], 1);
    ::close(fds[0]);
    ::close(fds[1]);
    std::vector<char*> args;
    for (auto& a : argv) args.push_back(a.data());
    args.push_back(nullptr);
    ::execv(args[0], args.data());
    ::_exit(127);
  }
  ::close(fds[1]);
  return {pid, fds[0]};
}

// hvdb-ingest run --follow --server on a recording replayed at 2 fps: each frame is in the
// server, exactly as a normal run commits it, when the follower says it committed it, while
// the capture is still going on.
TEST(Live, FollowThroughTheServerCommitsEachFrameAsItCompletes) {
  TempDir dir;
  const int frames = 6;
  ASSERT_TRUE(GenerateRecording(Rig(frames), dir / "src").ok());
  auto rec = OpenRecording(dir / "src");
  ASSERT_TRUE(rec.ok());
  const auto reference = Reference(*rec, dir / "ref");
  hvdb::testing::ServerProcess server(dir / "data");
  ASSERT_TRUE(server.running());
  const std::string addr = "127.0.0.1:" + std::to_string(server.port());
  auto [follower, out] = Spawn({HVDB_INGEST_PATH, "run", dir / "live", "--follow", "--verbose", "--quiet",
                                "--dataset", "v", "--server", addr, "--num-disparities", "32"});
  ASSERT_GT(follower, 0);
  auto [replay, replay_out] = Spawn({HVDB_INGEST_PATH, "replay", dir / "src", dir / "live", "--realtime", "2",
                                     "--quiet"});
  ASSERT_GT(replay, 0);
  auto reader = client::MakeRemoteBackend({addr, ""});
  ASSERT_TRUE(reader.ok());
  std::string output, line;
  int seen = 0;
  bool replay_done_first = false;
  char c;
  while (::read(out, &c, 1) == 1) {
    if (c != '\n') {
      line += c;
      continue;
    }
    output += line + "\n";
    if (line.rfind("frame " + std::to_string(seen) + ": committed", 0) == 0) {
      // Committed means visible: a reader sees the frame whole now.
      EXPECT_TRUE(FramePoints(**reader, "v", seen, rec->fps) == reference.at(seen)) << seen;
      if (seen == 0) replay_done_first = ::waitpid(replay, nullptr, WNOHANG) == replay;
      ++seen;
    }
    line.clear();
  }
  ::close(out);
  int st = 0;
  ::waitpid(follower, &st, 0);
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0) << output;
  EXPECT_EQ(seen, frames) << output;
  EXPECT_NE(output.find("followed"), std::string::npos) << output;
  // Frame 0 was committed before the capture ended (the replay takes 2.5 s).
  EXPECT_FALSE(replay_done_first);
  if (!replay_done_first) ::waitpid(replay, &st, 0);
  ::close(replay_out);
}

// The real 7-Scenes RGB-D sequence (PNG colour, 16-bit PNG depth, text poses) replayed at
// 15 fps by `hvdb-ingest replay` while `run --follow` takes it: the same points as ingesting
// the sequence itself.
TEST(Live, ReplayOfTheRealSevenScenesSequenceFollowed) {
  const std::string src = std::string(HVDB_SHARED_DATA) + "/sevenscenes-redkitchen-rgbd/rgbd-frames/";
  ASSERT_TRUE(fs::exists(src + "frame-000150.color.png")) << "no 7-Scenes data at " << src;
  TempDir dir;
  const int frames = 3;
  fs::create_directories(dir / "rec");
  WriteAll(dir / "rec/calibration.yml",
           "%YAML:1.0\n---\ncameras:\n   - name: kinect\n     width: 640\n     height: 480\n"
           "     K: !!opencv-matrix\n       rows: 3\n       cols: 3\n       dt: d\n"
           "       data: [ 585, 0, 320, 0, 585, 240, 0, 0, 1 ]\n"
           "     R: !!opencv-matrix\n       rows: 3\n       cols: 3\n       dt: d\n"
           "       data: [ 1, 0, 0, 0, 1, 0, 0, 0, 1 ]\n"
           "     T: !!opencv-matrix\n       rows: 3\n       cols: 1\n       dt: d\n       data: [ 0, 0, 0 ]\n"
           "     reprojection_error: 0.5\n");
  WriteAll(dir / "rec/recording.yml",
           "%YAML:1.0\n---\nformat: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\nframes: " +
               std::to_string(frames) +
               "\nfps: 30\nfirst_frame: 150\ndepth_encoding: \"png16\"\ndepth_scale: 0.001\n"
               "depth_invalid: [ 0, 65535 ]\ncameras:\n   - { name: kinect, colour: \"" + src +
               "frame-{frame:06d}.color.png\", depth: \"" + src + "frame-{frame:06d}.depth.png\", pose: \"" +
               src + "frame-{frame:06d}.pose.txt\" }\n");
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  const auto reference = Reference(*rec, dir / "ref");
  ASSERT_FALSE(reference.at(0).empty());
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::execl(HVDB_INGEST_PATH, HVDB_INGEST_PATH, "replay", (dir / "rec").c_str(), (dir / "live").c_str(),
            "--realtime", "15", "--quiet", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  auto backend = client::MakeEmbeddedBackend(dir / "data", 32 << 20);
  FollowOptions fo;
  fo.status_every = 0;
  auto rep = FollowRecording(dir / "live", *backend, Options(), fo);
  int st = 0;
  ::waitpid(pid, &st, 0);
  EXPECT_TRUE(WIFEXITED(st) && WEXITSTATUS(st) == 0);
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingest.ingested, frames);
  for (int f = 0; f < frames; ++f) EXPECT_TRUE(FramePoints(*backend, "v", f, rec->fps) == reference.at(f)) << f;
  // The copy is a recording of its own with the files renamed into place, no temporaries left.
  auto copy = OpenRecording(dir / "live");
  ASSERT_TRUE(copy.ok());
  EXPECT_EQ(copy->frames, frames);
  for (const auto& e : fs::recursive_directory_iterator(dir / "live"))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
}

// generate --realtime: the recording it writes frame by frame is the one it writes at once.
TEST(Live, GenerateRealtimeWritesTheSameRecording) {
  TempDir dir;
  GeneratorOptions g = Rig(3);
  ASSERT_TRUE(GenerateRecording(g, dir / "a").ok());
  g.realtime_fps = 20;
  const auto t0 = std::chrono::steady_clock::now();
  ASSERT_TRUE(GenerateRecording(g, dir / "b").ok());
  EXPECT_GE(std::chrono::steady_clock::now() - t0, milliseconds(100));  // frame 2 at 2/20 s
  auto a = OpenRecording(dir / "a");
  ASSERT_TRUE(a.ok());
  for (int f = 0; f < 3; ++f)
    for (const std::string& p : FrameFiles(*a, f)) {
      const std::string q = dir / "b" + p.substr((dir / "a").size());
      EXPECT_EQ(ReadAll(p), ReadAll(q)) << q;
    }
}

}  // namespace
}  // namespace hvdb::ingest
