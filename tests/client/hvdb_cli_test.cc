// Runs the real `hvdb` binary on a temporary data directory, as a user would, and through the
// real `hvdb-server` with --server.
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "formats/image_io.h"
#include "formats/ply.h"
#include "formats/point_files.h"
#include "render/metrics.h"
#include "tests/edit/scene.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const std::string kPanoptic =
    std::string(HVDB_SHARED_DATA) + "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/";
const std::string kFrame380 = kPanoptic + "ptcloud_hd00000380.ply";
const std::string kFrame381 = kPanoptic + "ptcloud_hd00000381.ply";
constexpr double kFps = 30;
const char* const kEverything = "--box -10 10 -10 10 -10 10 -1 10";

std::string Quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

struct RunResult {
  int code = -1;
  std::string out, err;
};

class HvdbCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_cli_test_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  // Runs `hvdb ARGS` in the temporary directory (so the default ./data lands there).
  RunResult Run(const std::string& args) {
    std::string err_path = dir_ + "/stderr.txt";
    std::string cmd =
        "cd " + Quote(dir_) + " && " + Quote(HVDB_CLI_PATH) + " " + args + " 2>" + Quote(err_path);
    RunResult r;
    FILE* p = popen(cmd.c_str(), "r");
    if (p == nullptr) return r;
    char buf[4096];
    size_t n;
    while ((n = fread(buf, 1, sizeof(buf), p)) > 0) r.out.append(buf, n);
    int status = pclose(p);
    r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    r.err = ReadFile(err_path);
    return r;
  }

  // Runs a command that must succeed and print one JSON document.
  json RunJson(const std::string& args) {
    RunResult r = Run(args + " --json");
    EXPECT_EQ(r.code, 0) << "hvdb " << args << "\nstderr: " << r.err;
    json j = json::parse(r.out, nullptr, /*allow_exceptions=*/false);
    EXPECT_FALSE(j.is_discarded()) << "hvdb " << args << " printed: " << r.out;
    return j;
  }

  std::string Path(const std::string& name) const { return dir_ + "/" + name; }

  std::string dir_;
};

bool HaveData() { return fs::exists(kFrame380) && fs::exists(kFrame381); }

std::vector<Point> ReadCm(const std::string& path) {
  formats::ReadOptions opts;
  opts.scale = 0.01;
  Result<std::vector<Point>> pts = formats::ReadPly(path, opts);
  EXPECT_TRUE(pts.ok()) << pts.status().ToString();
  return pts.ok() ? *pts : std::vector<Point>{};
}

size_t CountYAbove(const std::vector<Point>& pts, double y0) {
  return static_cast<size_t>(std::count_if(pts.begin(), pts.end(), [y0](const Point& p) {
    return static_cast<double>(p.y) >= y0 && static_cast<double>(p.y) <= 10;
  }));
}

TEST_F(HvdbCliTest, ImportQueryEditUndoCheck) {
  ASSERT_TRUE(HaveData()) << "test data not found under " << kPanoptic << " (../shared/data)";
  std::vector<Point> f0 = ReadCm(kFrame380), f1 = ReadCm(kFrame381);
  ASSERT_FALSE(f0.empty());
  ASSERT_FALSE(f1.empty());
  const size_t total = f0.size() + f1.size();

  RunResult r = Run("create walk --fps 30");
  ASSERT_EQ(r.code, 0) << r.err;
  r = Run("import walk --frame 0 --units-scale 0.01 " + Quote(kFrame380) + " " + Quote(kFrame381));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("imported " + std::to_string(total) + " points"), std::string::npos)
      << r.out;

  json info = RunJson("describe walk");
  EXPECT_EQ(info["name"], "walk");
  EXPECT_EQ(info["frames"], 2);
  EXPECT_EQ(info["points"], total);
  EXPECT_DOUBLE_EQ(info["fps"].get<double>(), kFps);
  EXPECT_NEAR(info["bounds_min"][1].get<double>(), -1.73, 0.01);
  r = Run("describe walk");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("walk"), std::string::npos);

  json ds = RunJson("datasets");
  ASSERT_EQ(ds.size(), 1u);
  EXPECT_EQ(ds[0]["name"], "walk");

  // A window around everything returns every point of both frames.
  json w = RunJson("window walk " + std::string(kEverything));
  EXPECT_EQ(w["points"], total);
  EXPECT_EQ(w["frames_read"], 2);
  EXPECT_TRUE(w["levels"].is_object());
  EXPECT_TRUE(w["elapsed_ms"].is_number());
  r = Run("window walk " + std::string(kEverything));
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find(std::to_string(total) + " points"), std::string::npos) << r.out;

  // A slice orthogonal to t through frame 1 returns exactly frame 1.
  char slice[256];
  std::snprintf(slice, sizeof(slice),
                "slice walk --normal 0 0 0 1 --offset %.17g --thickness %.17g", 1 / kFps,
                0.4 / kFps);
  json s = RunJson(slice);
  EXPECT_EQ(s["points"], f1.size());
  EXPECT_EQ(s["frames"], json::array({1}));
  EXPECT_EQ(s["clipped"], false);

  // Exports: the window's ids are unique, the slice's are those of frame 1.
  r = Run("window walk " + std::string(kEverything) + " --out all.ply");
  ASSERT_EQ(r.code, 0) << r.err;
  Result<std::vector<Point>> all = formats::ReadPly(Path("all.ply"));
  ASSERT_TRUE(all.ok()) << all.status().ToString();
  ASSERT_EQ(all->size(), total);
  std::set<uint64_t> ids_all, ids_f1;
  for (const Point& p : *all) {
    EXPECT_NE(p.id, 0u);
    ids_all.insert(p.id);
    if (p.frame == 1) ids_f1.insert(p.id);
  }
  EXPECT_EQ(ids_all.size(), total);
  EXPECT_EQ(ids_f1.size(), f1.size());
  r = Run(std::string(slice) + " --out " + Quote(Path("slice.ply")));
  ASSERT_EQ(r.code, 0) << r.err;
  Result<std::vector<Point>> sl = formats::ReadPly(Path("slice.ply"));
  ASSERT_TRUE(sl.ok()) << sl.status().ToString();
  std::set<uint64_t> ids_slice;
  for (const Point& p : *sl) ids_slice.insert(p.id);
  EXPECT_EQ(ids_slice, ids_f1);
  r = Run("window walk " + std::string(kEverything) + " --out all.csv");
  ASSERT_EQ(r.code, 0) << r.err;
  std::string csv = ReadFile(Path("all.csv"));
  EXPECT_EQ(static_cast<size_t>(std::count(csv.begin(), csv.end(), '\n')), total + 1);

  // Delete the legs (y >= -0.5 m; y points down) in both frames, then undo it.
  const size_t legs = CountYAbove(f0, -0.5) + CountYAbove(f1, -0.5);
  ASSERT_GT(legs, 0u);
  json e = RunJson("edit walk --delete-box -10 10 -0.5 10 -10 10 -1 10");
  ASSERT_TRUE(e["lsn"].is_number());
  EXPECT_EQ(e["removed"], legs);
  EXPECT_EQ(RunJson("window walk " + std::string(kEverything))["points"], total - legs);
  json u = RunJson("undo walk " + std::to_string(e["lsn"].get<uint64_t>()));
  EXPECT_GT(u["lsn"].get<uint64_t>(), e["lsn"].get<uint64_t>());
  EXPECT_EQ(RunJson("window walk " + std::string(kEverything))["points"], total);

  // Label the legs and query by label; move frame 0 by 10 m in x; paste frame 380 at frame 4.
  e = RunJson("edit walk --label-box -10 10 -0.5 10 -10 10 -1 10 --set-label 0x4");
  EXPECT_EQ(RunJson("window walk --label-mask 4 " + std::string(kEverything))["points"], legs);
  e = RunJson("edit walk --box -10 10 -10 10 -10 10 -0.01 0.01 --translate 10 0 0 0");
  EXPECT_EQ(RunJson("window walk --box 5 15 -10 10 -10 10 -1 10")["points"], f0.size());
  r = Run("edit walk --paste " + Quote(kFrame380) + " --frame 4 --units-scale 0.01");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("committed lsn"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("inserted " + std::to_string(f0.size())), std::string::npos) << r.out;
  EXPECT_EQ(RunJson("describe walk")["frames"], 5);
  EXPECT_EQ(RunJson("window walk --box -10 10 -10 10 -10 10 0.1 0.2")["points"], f0.size());

  json st = RunJson("stats walk");
  ASSERT_EQ(st["datasets"].size(), 1u);
  EXPECT_TRUE(st["datasets"][0]["points"].is_number());
  EXPECT_TRUE(st["cache"]["capacity_bytes"].is_number());
  r = Run("--cache-mb 16 stats");
  EXPECT_EQ(r.code, 0) << r.err;

  // The cold tier: every frame compressed, the same answers, the bytes shown per tier.
  const json before = RunJson("window walk " + std::string(kEverything));
  json c = RunJson("compact walk");
  EXPECT_EQ(c["frames"], 3);  // 0, 1 and 4 hold points
  EXPECT_LT(c["bytes_after"].get<double>(), 0.35 * c["bytes_before"].get<double>());
  EXPECT_EQ(RunJson("compact walk --frames 0 4")["already"], 3);
  // --photos codes photos as video instead (tests/storage/photo_video_test.cc): walk has none.
  json pv = RunJson("compact walk --photos");
  EXPECT_EQ(pv["photo_runs"], 0);
  EXPECT_EQ(pv["photo_pictures"], 0);
  st = RunJson("stats walk");
  EXPECT_EQ(st["datasets"][0]["cold_frames"], 3);
  EXPECT_EQ(st["datasets"][0]["hot_tree_bytes"], 0);
  r = Run("stats walk");
  EXPECT_NE(r.out.find("cold tier: 3 frames"), std::string::npos) << r.out;
  json d = RunJson("describe walk");
  EXPECT_EQ(d["storage"]["cold"]["frames"], 3);
  EXPECT_EQ(d["storage"]["hot"]["tree_bytes"], 0);
  // Hot points outside trees are the buffer's, and counted as its bytes.
  EXPECT_EQ(d["storage"]["hot"]["buffer_bytes"].get<uint64_t>(),
            64 * d["storage"]["hot"]["buffered_points"].get<uint64_t>());
  EXPECT_EQ(d["storage"]["hot"]["buffered_points"], d["storage"]["hot"]["points"]);
  EXPECT_GT(d["storage"]["cold"]["tree_bytes"].get<double>(), 0);
  EXPECT_EQ(RunJson("window walk " + std::string(kEverything))["points"], before["points"]);
  EXPECT_EQ(RunJson("window walk --label-mask 4 " + std::string(kEverything))["points"], legs);

  r = Run("check");
  EXPECT_EQ(r.code, 0) << r.out << r.err;
  EXPECT_EQ(r.out, "ok\n");
  EXPECT_EQ(RunJson("check walk")["ok"], true);
}

TEST_F(HvdbCliTest, BadArgumentsExitTwoWithAMessage) {
  struct Case {
    std::string args, expect;
  };
  const std::vector<Case> cases = {
      {"", "a command is required"},
      {"frobnicate", "frobnicate"},
      {"create walk", "--fps"},
      {"create walk --fps -3", "--fps"},
      {"window walk --box 1 2 3", "--box"},
      {"window walk --box 1 0 0 1 0 1 0 1", "X0 must be <= X1"},
      {"window walk --box 0 1 0 1 0 1 0 1 --lod -1", "--lod"},
      {"slice walk --normal 0 0 0 0 --offset 0 --thickness 1", "all zero"},
      {"import walk a.ply", "--frame"},
      {"edit walk", "nothing to do"},
      {"edit walk --translate 1 0 0 0", "--box"},
      {"edit walk --label-box 0 1 0 1 0 1 0 1", "--set-label"},
      {"--server localhost datasets", "HOST:PORT"},
      {"--server localhost:http datasets", "bad port"},
      {"--server 127.0.0.1:7000 --data d datasets", "not both"},
      {"--server 127.0.0.1:7000 --cache-mb 64 stats", "--cache-mb"},
      {"--token secret datasets", "--token is for --server"},
      {"--server 127.0.0.1:7000 check", "cannot run through --server"},
      {"ping", "ping needs --server"},
      {"compact walk --frames 3 1", "A <= B"},
      {"compact walk --frames 3", "--frames"},
      {"compact walk --photos --frames 3 1", "A <= B"},
  };
  ASSERT_EQ(Run("create walk --fps 30").code, 0);
  for (const Case& c : cases) {
    RunResult r = Run(c.args);
    EXPECT_EQ(r.code, 2) << "hvdb " << c.args << "\nstdout: " << r.out << "\nstderr: " << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos)
        << "hvdb " << c.args << "\nstderr: " << r.err;
    EXPECT_EQ(r.err.rfind("hvdb", 0), 0u) << r.err;
  }
  // A level past the dataset's coarsest is storage's to refuse (exit 1), in its own words.
  RunResult deep = Run("window walk --box 0 1 0 1 0 1 0 1 --lod 12");
  EXPECT_EQ(deep.code, 1) << deep.err;
  EXPECT_EQ(deep.err,
            "hvdb: InvalidArgument: lod: 12 is out of range 0..5 for dataset 'walk' (its "
            "coarsest level)\n");
  RunResult r = Run("--help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("slice"), std::string::npos) << r.out;
  r = Run("slice --help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("--thickness"), std::string::npos) << r.out;
}

TEST_F(HvdbCliTest, ErrorsExitOneNamingTheCulprit) {
  RunResult r = Run("describe walk");  // no data directory yet
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("data"), std::string::npos) << r.err;

  ASSERT_EQ(Run("create walk --fps 30").code, 0);
  for (const std::string& args :
       {std::string("describe nosuch"), std::string("window nosuch ") + kEverything,
        std::string("undo nosuch 1"), std::string("check nosuch")}) {
    r = Run(args);
    EXPECT_EQ(r.code, 1) << args;
    EXPECT_NE(r.err.find("nosuch"), std::string::npos) << args << ": " << r.err;
    EXPECT_EQ(r.err.rfind("hvdb: NotFound: ", 0), 0u) << r.err;
  }
  r = Run("create walk --fps 30");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("walk"), std::string::npos) << r.err;
  r = Run("import walk --frame 0 missing.ply");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("missing.ply"), std::string::npos) << r.err;
  r = Run("window walk " + std::string(kEverything) + " --out x.txt");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find(".ply or .csv"), std::string::npos) << r.err;
}

// A PLY with NaN or infinite coordinates is refused, naming the file and the way out, and
// nothing of it is loaded; --skip-invalid loads the rest and says how many points it left out.
TEST_F(HvdbCliTest, ImportRefusesNonFiniteUnlessSkipInvalid) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n";
  {
    std::ofstream(Path("ok.ply")) << header << "0 0 0\n1 0 0\n0 1 0\n0 0 1\n1 1 1\n";
    std::ofstream(Path("holes.ply")) << header << "0 0 0\nnan nan nan\n0 1 0\n0 0 inf\n1 1 1\n";
  }
  ASSERT_EQ(Run("create walk --fps 30").code, 0);
  RunResult r = Run("import walk --frame 0 ok.ply holes.ply");
  EXPECT_EQ(r.code, 1);
  EXPECT_EQ(r.err.rfind("hvdb: InvalidArgument: holes.ply: 2 of 5 vertices have a NaN or "
                        "infinite coordinate (the first: vertex 1, x = nan)",
                        0),
            0u)
      << r.err;
  EXPECT_NE(r.err.find("--skip-invalid"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("(frames 0..0 were loaded)"), std::string::npos) << r.err;
  json info = RunJson("describe walk");
  EXPECT_EQ(info["frames"], 1);  // ok.ply's frame, and no part of holes.ply's
  EXPECT_EQ(info["points"], 5);

  r = Run("import walk --frame 1 --skip-invalid holes.ply --json");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("skipped 2 points with a NaN or infinite coordinate in holes.ply"),
            std::string::npos)
      << r.err;
  json imp = json::parse(r.out, nullptr, /*allow_exceptions=*/false);
  ASSERT_FALSE(imp.is_discarded()) << r.out;
  EXPECT_EQ(imp["points"], 3);
  EXPECT_EQ(imp["skipped_invalid"], 2);
  EXPECT_EQ(imp["frames"][0]["skipped_invalid"], 2);
  info = RunJson("describe walk");
  EXPECT_EQ(info["frames"], 2);
  EXPECT_EQ(info["points"], 8);

  r = Run("import walk --frame 2 --skip-invalid ok.ply holes.ply");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("imported 8 points into frames 2..3 of 'walk'"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("(skipped 2 with a NaN or infinite coordinate)"), std::string::npos)
      << r.out;

  // edit --paste and composite read PLY files by the same rule.
  r = Run("edit walk --paste holes.ply --frame 0");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("holes.ply: 2 of 5 vertices"), std::string::npos) << r.err;
  r = Run("composite walk --ply holes.ply --first-frame 0 --frames 1");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("holes.ply: 2 of 5 vertices"), std::string::npos) << r.err;
  r = Run("edit walk --paste holes.ply --frame 0 --skip-invalid");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("skipped 2 points"), std::string::npos) << r.err;
  r = Run("composite walk --ply holes.ply --first-frame 1 --frames 1 --skip-invalid");
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("skipped 2 points"), std::string::npos) << r.err;
  EXPECT_EQ(RunJson("describe walk")["points"], 8 + 8 + 3 + 3);
}

// ---------------------------------------------------------------------------------------------
// Server mode.

// hvdb-server, from CMake (packagers build into other output directories).
std::string ServerPath() { return HVDB_SERVER_PATH; }

// A port on 127.0.0.1 where nothing listens (bound, then released).
int ClosedPort() {
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof(a);
  int port = -1;
  if (bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
      getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0) {
    port = ntohs(a.sin_port);
  }
  close(fd);
  return port;
}

// The real hvdb-server on 127.0.0.1, any free port, with its own data directory.
class ServerProcess {
 public:
  ServerProcess() = default;
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;
  ~ServerProcess() {
    if (pid_ > 0) {
      kill(pid_, SIGKILL);
      waitpid(pid_, nullptr, 0);
    }
  }

  // Starts it and waits (up to 60 s) for its port file; "" on success, else what went wrong.
  std::string Start(const std::string& data_dir, const std::string& work_dir) {
    const std::string binary = ServerPath();
    if (binary.empty() || !fs::exists(binary)) {
      return "hvdb-server not found at '" + binary + "' (build the hvdb-server target)";
    }
    const std::string port_file = work_dir + "/server.port";
    err_path_ = work_dir + "/server.stderr";
    // TCP and the Unix socket in the data directory: `hvdb --server 127.0.0.1:PORT` moves to
    // the local fast path by itself, as it does for users.
    std::vector<std::string> args = {binary,      "--listen",     "127.0.0.1:0", "--listen",
                                      "unix:",     "--port-file",
                                      port_file,   "--data",       data_dir,      "--io-threads",
                                      "2",         "--workers",    "2"};
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_addopen(&fa, STDOUT_FILENO, (work_dir + "/server.stdout").c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&fa, STDERR_FILENO, err_path_.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    int rc = posix_spawn(&pid_, binary.c_str(), &fa, nullptr, argv.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    if (rc != 0) {
      pid_ = -1;
      return "posix_spawn " + binary + ": " + std::strerror(rc);
    }
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < deadline) {
      std::string text = ReadFile(port_file);
      if (!text.empty() && text.back() == '\n') {  // written whole
        port_ = std::atoi(text.c_str());
        return port_ > 0 ? "" : "bad port file: " + text;
      }
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return "hvdb-server exited before listening: " + ReadFile(err_path_);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return "hvdb-server did not write its port file within 60 s: " + ReadFile(err_path_);
  }

  // SIGTERM, then its exit status (-1: killed by a signal or still running after 60 s).
  int Terminate() {
    if (pid_ <= 0) return -1;
    kill(pid_, SIGTERM);
    auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < deadline) {
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return -1;  // the destructor kills it
  }

  int port() const { return port_; }
  std::string log() const { return ReadFile(err_path_); }

 private:
  pid_t pid_ = -1;
  int port_ = 0;
  std::string err_path_;
};

// What must not differ between the modes: everything but timings and the --out path.
json Comparable(json j) {
  if (j.is_object()) {
    j.erase("elapsed_ms");
    j.erase("timings_ms");
    j.erase("out");
    // How much of a dataset's hot tier is still buffered, and in how many tree bytes, depends
    // on when the background merger ran: the totals must agree, that split need not.
    if (j.contains("storage") && j["storage"].contains("hot")) {
      for (const char* k : {"buffer_bytes", "buffered_points", "tree_bytes"}) {
        j["storage"]["hot"].erase(k);
      }
    }
  }
  return j;
}

// Points in a canonical order, to compare exports whose batches may come in another order.
std::vector<Point> Sorted(std::vector<Point> pts) {
  std::sort(pts.begin(), pts.end(), [](const Point& a, const Point& b) {
    return std::tie(a.frame, a.id) < std::tie(b.frame, b.id);
  });
  return pts;
}

std::vector<std::string> SortedLines(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  std::sort(lines.begin(), lines.end());
  return lines;
}

// The same commands on a data directory and through hvdb-server on an identical one (created by
// the same commands) must print the same results.
TEST_F(HvdbCliTest, ServerModeMatchesEmbedded) {
  ASSERT_TRUE(HaveData()) << "test data not found under " << kPanoptic << " (../shared/data)";
  std::vector<Point> f0 = ReadCm(kFrame380), f1 = ReadCm(kFrame381);
  ASSERT_FALSE(f0.empty());
  ASSERT_FALSE(f1.empty());
  const size_t total = f0.size() + f1.size();

  ServerProcess server;
  fs::create_directories(Path("srvdata"));
  std::string started = server.Start(Path("srvdata"), dir_);
  ASSERT_EQ(started, "");
  const std::string address = "127.0.0.1:" + std::to_string(server.port());
  const std::string remote = "--server " + address + " ";

  // Runs ARGS in both modes, each of which must succeed; returns {embedded, server}.
  auto both = [&](const std::string& args) {
    RunResult e = Run(args), s = Run(remote + args);
    EXPECT_EQ(e.code, 0) << "hvdb " << args << "\nstderr: " << e.err;
    EXPECT_EQ(s.code, 0) << "hvdb " << remote << args << "\nstderr: " << s.err
                         << "\nserver log:\n" << server.log();
    return std::make_pair(e, s);
  };
  // Runs ARGS --json in both modes; expects the same document (but timings); returns it.
  auto same = [&](const std::string& args) {
    json e = RunJson(args), s = RunJson(remote + args);
    EXPECT_EQ(Comparable(e), Comparable(s)) << "hvdb [" << remote << "] " << args;
    return s;
  };

  auto [ec, sc] = both("create walk --fps 30");
  EXPECT_EQ(ec.out, sc.out);
  json imp = same("import walk --frame 0 --units-scale 0.01 " + Quote(kFrame380) + " " +
                  Quote(kFrame381));
  EXPECT_EQ(imp["points"], total);
  EXPECT_EQ(imp["frames"].size(), 2u);

  json info = same("describe walk");
  EXPECT_EQ(info["name"], "walk");
  EXPECT_EQ(info["frames"], 2);
  EXPECT_EQ(info["points"], total);
  EXPECT_NEAR(info["bounds_min"][1].get<double>(), -1.73, 0.01);
  auto [ed, sd] = both("describe walk");
  EXPECT_EQ(ed.out, sd.out);
  json ds = same("datasets");
  ASSERT_EQ(ds.size(), 1u);
  EXPECT_EQ(ds[0]["points"], total);
  auto [el, sl] = both("datasets");
  EXPECT_EQ(el.out, sl.out);

  json w = same("window walk " + std::string(kEverything));
  EXPECT_EQ(w["points"], total);
  EXPECT_EQ(w["frames_read"], 2);
  auto [ew, sw] = both("window walk " + std::string(kEverything));
  EXPECT_NE(sw.out.find(std::to_string(total) + " points from 2 frames"), std::string::npos)
      << sw.out;

  char slice[256];
  std::snprintf(slice, sizeof(slice),
                "slice walk --normal 0 0 0 1 --offset %.17g --thickness %.17g", 1 / kFps,
                0.4 / kFps);
  json s = same(slice);
  EXPECT_EQ(s["points"], f1.size());
  EXPECT_EQ(s["frames"], json::array({1}));
  EXPECT_EQ(s["clipped"], false);
  EXPECT_LT(same(std::string(slice) + " --lod 2")["points"].get<size_t>(), f1.size());
  EXPECT_FALSE(same("window walk --progressive --lod 1 " + std::string(kEverything))["levels"]
                   .empty());

  // Exports through the server hold the same points, every field of them.
  for (const std::string& query : {"window walk " + std::string(kEverything), std::string(slice)}) {
    RunResult e = Run(query + " --out emb.ply"), r = Run(remote + query + " --out srv.ply");
    ASSERT_EQ(e.code, 0) << e.err;
    ASSERT_EQ(r.code, 0) << r.err;
    Result<std::vector<Point>> pe = formats::ReadPly(Path("emb.ply")), ps = formats::ReadPly(Path("srv.ply"));
    ASSERT_TRUE(pe.ok()) << pe.status().ToString();
    ASSERT_TRUE(ps.ok()) << ps.status().ToString();
    EXPECT_EQ(ps->size(), query == std::string(slice) ? f1.size() : total);
    EXPECT_TRUE(Sorted(*pe) == Sorted(*ps)) << query;
  }
  ASSERT_EQ(Run("window walk " + std::string(kEverything) + " --out emb.csv").code, 0);
  ASSERT_EQ(Run(remote + "window walk " + std::string(kEverything) + " --out srv.csv").code, 0);
  std::vector<std::string> csv_e = SortedLines(ReadFile(Path("emb.csv")));
  EXPECT_EQ(csv_e.size(), total + 1);
  EXPECT_TRUE(csv_e == SortedLines(ReadFile(Path("srv.csv"))));

  // Edits and their undo get the same lsns and counts.
  const size_t legs = CountYAbove(f0, -0.5) + CountYAbove(f1, -0.5);
  json e = same("edit walk --delete-box -10 10 -0.5 10 -10 10 -1 10");
  EXPECT_EQ(e["removed"], legs);
  EXPECT_EQ(same("window walk " + std::string(kEverything))["points"], total - legs);
  json u = same("undo walk " + std::to_string(e["lsn"].get<uint64_t>()));
  EXPECT_GT(u["lsn"].get<uint64_t>(), e["lsn"].get<uint64_t>());
  EXPECT_EQ(same("window walk " + std::string(kEverything))["points"], total);
  same("edit walk --label-box -10 10 -0.5 10 -10 10 -10 10 --set-label 0x4");
  EXPECT_EQ(same("window walk --label-mask 4 " + std::string(kEverything))["points"], legs);
  same("edit walk --box -10 10 -10 10 -10 10 -0.01 0.01 --translate 10 0 0 0");
  EXPECT_EQ(same("window walk --box 5 15 -10 10 -10 10 -1 10")["points"], f0.size());
  json paste = same("edit walk --paste " + Quote(kFrame380) + " --frame 4 --units-scale 0.01");
  EXPECT_EQ(paste["inserted"], f0.size());
  EXPECT_EQ(same("describe walk")["frames"], 5);

  // Stats: the dataset's storage statistics are the same; the server adds its counters.
  json se = RunJson("stats walk"), ss = RunJson(remote + "stats walk");
  ASSERT_EQ(ss["datasets"].size(), 1u);
  json de = se["datasets"][0], dr = ss["datasets"][0];
  // All but the layout: each embedded run checkpoints when it closes, the server later (the
  // log's size), and the server's background merger may have moved the buffered points into a
  // tree before the stats were taken, or not yet (trees, their bytes, buffered points, and the
  // deleted ids a tree still lists until a merge drops them).
  json de_same = de, dr_same = dr;
  for (const char* layout : {"wal_bytes", "trees", "tree_bytes", "hot_tree_bytes",
                             "buffered_points", "tombstones", "leaf_utilisation"}) {
    de_same.erase(layout);
    dr_same.erase(layout);
  }
  EXPECT_EQ(de_same, dr_same);
  EXPECT_EQ(dr["last_lsn"], paste["lsn"]);
  EXPECT_GT(dr["tree_bytes"].get<uint64_t>(), 0u);
  EXPECT_TRUE(dr["leaf_utilisation"].is_number());
  EXPECT_TRUE(ss["cache"]["capacity_bytes"].is_number());
  double hit_rate = ss["cache"]["hit_rate"].get<double>();
  EXPECT_GE(hit_rate, 0.0);
  EXPECT_LE(hit_rate, 1.0);
  const json& sv = ss["server"];
  EXPECT_EQ(sv["address"], address);
  EXPECT_GE(sv["connections_open"].get<uint64_t>(), 1u);
  EXPECT_GT(sv["connections_total"].get<uint64_t>(), 10u);
  EXPECT_GT(sv["bytes_in"].get<uint64_t>(), 0u);
  EXPECT_GT(sv["bytes_out"].get<uint64_t>(), 0u);
  std::set<std::string> kinds;
  for (const json& r : sv["requests"]) {
    kinds.insert(r["kind"].get<std::string>());
    EXPECT_GT(r["count"].get<uint64_t>(), 0u) << r;
    EXPECT_LE(r["p50_ms"].get<double>(), r["p95_ms"].get<double>()) << r;
    EXPECT_LE(r["p95_ms"].get<double>(), r["p99_ms"].get<double>()) << r;
  }
  for (const char* kind : {"create", "describe", "ingest", "query", "edit", "revert"}) {
    EXPECT_EQ(kinds.count(kind), 1u) << kind << " missing from " << sv["requests"];
  }
  RunResult st = Run(remote + "stats");
  EXPECT_EQ(st.code, 0) << st.err;
  EXPECT_NE(st.out.find("walk: 3 frames with data"), std::string::npos) << st.out;
  EXPECT_NE(st.out.find("p99 ms"), std::string::npos) << st.out;

  // ping: a round trip through --server; on a data directory a usage error.
  json p = RunJson(remote + "ping --count 3");
  EXPECT_EQ(p["count"], 3);
  EXPECT_EQ(p["rtt_ms"].size(), 3u);
  EXPECT_GE(p["min_ms"].get<double>(), 0.0);
  EXPECT_LE(p["min_ms"].get<double>(), p["max_ms"].get<double>());
  RunResult pt = Run(remote + "ping");
  EXPECT_EQ(pt.code, 0) << pt.err;
  // The server is on this machine: the CLI took its Unix socket and shared memory by itself.
  EXPECT_EQ(pt.out.rfind("pong from " + address + " (unix ", 0), 0u) << pt.out;
  EXPECT_NE(pt.out.find("/hvdb.sock + shared memory) in "), std::string::npos) << pt.out;
  EXPECT_EQ(Run("ping").code, 2);

  // Errors read the same, naming the server instead of the directory.
  for (const std::string& args :
       {std::string("describe nosuch"), std::string("window nosuch ") + kEverything,
        std::string("undo nosuch 1"), std::string("drop nosuch"),
        std::string("import nosuch --frame 0 ") + Quote(kFrame380)}) {
    RunResult r = Run(remote + args);
    EXPECT_EQ(r.code, 1) << args;
    EXPECT_EQ(r.err.rfind("hvdb: NotFound: no dataset 'nosuch' on " + address, 0), 0u)
        << args << ": " << r.err;
  }
  RunResult dup = Run(remote + "create walk --fps 30");
  EXPECT_EQ(dup.code, 1);
  EXPECT_NE(dup.err.find("walk"), std::string::npos) << dup.err;
  RunResult too_many = Run(remote + "slice walk --normal 0 0 0 1 --offset 0 --thickness 10 "
                                    "--max-frames 1");
  EXPECT_EQ(too_many.code, 1);
  EXPECT_NE(too_many.err.find("--clip-frames"), std::string::npos) << too_many.err;
  RunResult check = Run(remote + "check");
  EXPECT_EQ(check.code, 2);
  EXPECT_NE(check.err.find("--server"), std::string::npos) << check.err;

  RunResult dropped = Run(remote + "drop walk");
  EXPECT_EQ(dropped.code, 0) << dropped.err;
  EXPECT_EQ(dropped.out, "dropped dataset 'walk'\n");
  EXPECT_EQ(RunJson(remote + "datasets"), json::array());

  // SIGTERM: a graceful shutdown, exit status 0; then the address refuses connections.
  EXPECT_EQ(server.Terminate(), 0) << server.log();
  RunResult gone = Run(remote + "ping");
  EXPECT_EQ(gone.code, 1) << gone.out;
  EXPECT_EQ(gone.err.rfind("hvdb: IOError: connect to " + address, 0), 0u) << gone.err;
  EXPECT_NE(gone.err.find("hvdb-server"), std::string::npos) << gone.err;
}

// ---------------------------------------------------------------------------------------------
// Editing operators: select, graphcut, copy/cut, paste, composite, undo/redo.

// The look-at camera the editing test draws through: 3 m above the scene's middle, looking down,
// world +y up in the image; 200 x 200 pixels, 60 degrees vertically. Pixel of a point:
struct TopCamera {
  static constexpr double kHalf = 99.5;  // cx = cy
  double f = 100 / std::tan(30 * M_PI / 180);
  std::array<double, 2> Project(const Point& p) const {
    double depth = 3 - static_cast<double>(p.z);
    return {f * (static_cast<double>(p.x) - 0.5) / depth + kHalf,
            f * -(static_cast<double>(p.y) - 0.5) / depth + kHalf};
  }
  const char* look_at = "--look-at 0.5 0.5 3 0.5 0.5 0 --fov 60 --size 200 200 --up 0 1 0";
  // The same camera as a --camera file.
  json File() const {
    return {{"fx", f},
            {"fy", f},
            {"cx", kHalf},
            {"cy", kHalf},
            {"width", 200},
            {"height", 200},
            {"world_from_camera", {1, 0, 0, 0.5, 0, -1, 0, 0.5, 0, 0, -1, 3, 0, 0, 0, 1}}};
  }
};

bool InBox(const Point& p, const std::array<double, 6>& b) {
  double x = p.x, y = p.y, z = p.z;
  return x >= b[0] && x <= b[1] && y >= b[2] && y <= b[3] && z >= b[4] && z <= b[5];
}

std::string BoxArg(const std::array<double, 6>& b, double t0, double t1) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "--box %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g", b[0],
                b[1], b[2], b[3], b[4], b[5], t0, t1);
  return buf;
}

// The same editing session on a data directory and through hvdb-server, on a generated scene (a
// sphere rolling over a plane, three frames) whose sphere points are known: strokes with select,
// the object by graph cut, then cut, paste, undo, redo and composite; every command prints the
// same in both modes (but timings).
TEST_F(HvdbCliTest, EditingOperatorsEmbeddedAndThroughServer) {
  constexpr uint32_t kFrames = 3;
  std::vector<testing::ScenePoint> scene = testing::MovingSphereScene(kFrames, 0.02);
  std::vector<std::vector<Point>> frames(kFrames);
  std::set<uint64_t> sphere;
  uint64_t next_id = 1;
  for (const testing::ScenePoint& s : scene) {
    Point p = s.p;
    p.id = next_id++;  // kept on import, so that the test knows which points are the sphere
    if (s.sphere) sphere.insert(p.id);
    frames[p.frame].push_back(p);
  }
  const size_t total = scene.size();
  std::string files;
  for (uint32_t f = 0; f < kFrames; ++f) {
    std::string path = Path("scene" + std::to_string(f) + ".ply");
    ASSERT_TRUE(formats::WritePly(path, frames[f]).ok());
    files += " " + Quote(path);
  }

  ServerProcess server;
  fs::create_directories(Path("srvdata"));
  ASSERT_EQ(server.Start(Path("srvdata"), dir_), "");
  const std::string address = "127.0.0.1:" + std::to_string(server.port());
  const std::string remote = "--server " + address + " ";
  auto both = [&](const std::string& args) {
    RunResult e = Run(args), s = Run(remote + args);
    EXPECT_EQ(e.code, 0) << "hvdb " << args << "\nstderr: " << e.err;
    EXPECT_EQ(s.code, 0) << "hvdb " << remote << args << "\nstderr: " << s.err << "\nserver log:\n"
                         << server.log();
    EXPECT_EQ(e.out, s.out) << "hvdb [" << remote << "] " << args;
    return s;
  };
  auto same = [&](const std::string& args) {
    json e = RunJson(args), s = RunJson(remote + args);
    EXPECT_EQ(Comparable(e), Comparable(s)) << "hvdb [" << remote << "] " << args;
    return s;
  };
  // Both modes must fail with exit status `code` and a message containing `expect` (with
  // WHERE replaced by the data directory or the server's address).
  auto fail_both = [&](const std::string& args, int code, const std::string& expect) {
    for (bool srv : {false, true}) {
      RunResult r = Run((srv ? remote : std::string()) + args);
      EXPECT_EQ(r.code, code) << (srv ? remote : "") << args << "\nstderr: " << r.err;
      std::string want = expect;
      size_t at = want.find("WHERE");
      if (at != std::string::npos) want.replace(at, 5, srv ? "on " + address : "in ./data");
      EXPECT_NE(r.err.find(want), std::string::npos)
          << (srv ? remote : "") << args << "\nstderr: " << r.err;
      EXPECT_EQ(r.err.rfind("hvdb", 0), 0u) << r.err;
      EXPECT_EQ(r.out, "") << args;
    }
  };
  auto all_count = [&](const std::string& box) {
    return same("window scene " + box)["points"].get<size_t>();
  };
  const std::string everything = "--box -10 10 -10 10 -10 10 -1 10";

  both("create scene --fps 30");
  EXPECT_EQ(same("import scene --frame 0 --keep-ids" + files)["points"], total);

  // Strokes: a box on the top of the sphere in frame 0 (bit 1), one on the floor (bit 2).
  const std::array<double, 6> top{0.25, 0.35, 0.45, 0.55, 0.28, 1};
  const std::array<double, 6> floor{0.69, 1.01, -0.01, 0.29, -1, 0.001};
  auto count_in = [&](uint32_t f, const std::array<double, 6>& b) {
    return static_cast<size_t>(std::count_if(frames[f].begin(), frames[f].end(),
                                             [&](const Point& p) { return InBox(p, b); }));
  };
  json st = same("select scene --bit 1 " + BoxArg(top, 0, 0));
  EXPECT_EQ(st["matched"], count_in(0, top));
  EXPECT_GT(st["matched"].get<size_t>(), 10u);
  EXPECT_EQ(st["selected"], st["matched"]);
  EXPECT_EQ(st["shape"], "region");
  EXPECT_GT(st["lsn"].get<uint64_t>(), 0u);
  EXPECT_FALSE(st.contains("brush_center"));
  json sf = same("select scene --bit 2 --mode add " + BoxArg(floor, 0, 0));
  EXPECT_EQ(sf["matched"], count_in(0, floor));
  EXPECT_GT(sf["matched"].get<size_t>(), 100u);
  EXPECT_EQ(sf["lsn"].get<uint64_t>(), st["lsn"].get<uint64_t>() + 1);
  // Adding what is there already changes nothing: no commit.
  json again = same("select scene --bit 2 --mode add " + BoxArg(floor, 0, 0));
  EXPECT_EQ(again["lsn"], 0);
  EXPECT_EQ(again["selected"], sf["selected"]);
  RunResult text = both("select scene --bit 2 --mode add " + BoxArg(floor, 0, 0));
  EXPECT_NE(text.out.find("nothing changed"), std::string::npos) << text.out;
  EXPECT_EQ(same("window scene --label-mask 2 " + everything)["points"], st["matched"]);

  // The graph cut finds the sphere in all three frames from the strokes in frame 0.
  json gc = same("graphcut scene --fg-bit 1 --bg-bit 2 --out-bit 0 " + everything +
                 " --intra-radius 0.05 --inter-radius 0.08");
  EXPECT_EQ(gc["roi_points"], total);
  EXPECT_GT(gc["lsn"].get<uint64_t>(), 0u);
  EXPECT_GT(gc["intra_edges"].get<uint64_t>(), 0u);
  EXPECT_GT(gc["inter_edges"].get<uint64_t>(), 0u);
  EXPECT_TRUE(gc["energy"].is_number());
  for (const char* step : {"load", "neighbours", "gmm", "graph", "maxflow", "commit"}) {
    EXPECT_TRUE(gc["timings_ms"][step].is_number()) << step << ": " << gc;
  }
  const size_t selected = gc["selected"].get<size_t>();
  EXPECT_EQ(same("window scene --label-mask 1 " + everything)["points"], selected);
  std::set<uint64_t> ids[2];
  for (int srv = 0; srv < 2; ++srv) {
    RunResult r = Run((srv ? remote : std::string()) + "window scene --label-mask 1 " + everything +
                      " --out sel.ply");
    ASSERT_EQ(r.code, 0) << r.err;
    Result<std::vector<Point>> sel = formats::ReadPly(Path("sel.ply"));
    ASSERT_TRUE(sel.ok()) << sel.status().ToString();
    for (const Point& p : *sel) ids[srv].insert(p.id);
  }
  EXPECT_EQ(ids[0], ids[1]);
  size_t tp = 0;
  for (uint64_t id : ids[0]) tp += sphere.count(id);
  ASSERT_EQ(ids[0].size(), selected);
  EXPECT_GE(static_cast<double>(tp) / static_cast<double>(selected), 0.95)
      << tp << " of " << selected << " selected are sphere points";
  EXPECT_GE(static_cast<double>(tp) / static_cast<double>(sphere.size()), 0.95)
      << tp << " of the " << sphere.size() << " sphere points selected";
  RunResult gct = Run(remote + "graphcut scene --fg-bit 1 --bg-bit 2 --out-bit 0 " + everything +
                      " --intra-radius 0.05 --inter-radius 0.08");
  EXPECT_EQ(gct.code, 0) << gct.err;
  EXPECT_NE(gct.out.find(std::to_string(selected) + " of " + std::to_string(total) +
                         " points in the ROI selected into bit 0"),
            std::string::npos)
      << gct.out;
  EXPECT_NE(gct.out.find("max-flow"), std::string::npos) << gct.out;
  EXPECT_NE(gct.out.find("nothing changed"), std::string::npos) << gct.out;  // already so

  // Shapes through a camera in frame 0: a marquee around the sphere (points above the plane),
  // then a lasso on its left part intersected with it, through the same camera from a file.
  const TopCamera cam;
  std::ofstream(Path("camera.json")) << cam.File().dump();
  const std::array<double, 6> above{-10, 10, -10, 10, 0.001, 10};
  size_t sphere0 = 0, left0 = 0;
  for (const Point& p : frames[0]) {
    if (!sphere.count(p.id)) continue;
    ++sphere0;
    auto [u, v] = cam.Project(p);
    left0 += u > 70 && u < 87 && v > 85 && v < 115;
  }
  ASSERT_GT(left0, 10u);
  ASSERT_LT(left0, sphere0);
  json rect =
      same("select scene --bit 3 " + BoxArg(above, 0, 0) + " --rect 105 115 70 85 " + cam.look_at);
  EXPECT_EQ(rect["shape"], "rect");
  EXPECT_EQ(rect["matched"], sphere0);
  EXPECT_EQ(rect["selected"], sphere0);
  json lasso = same("select scene --bit 3 --mode intersect " + BoxArg(above, 0, 0) +
                    " --lasso 70 85 87 85 87 115 70 115 --camera " + Quote(Path("camera.json")));
  EXPECT_EQ(lasso["matched"], left0);
  EXPECT_EQ(lasso["selected"], left0);
  EXPECT_GT(lasso["lsn"].get<uint64_t>(), rect["lsn"].get<uint64_t>());
  EXPECT_EQ(same("window scene --label-mask 8 " + everything)["points"], left0);
  json sub = same("select scene --bit 3 --mode subtract " + BoxArg(above, 0, 0) +
                  " --rect 60 60 140 140 " + cam.look_at);
  EXPECT_EQ(sub["selected"], 0);
  // The brush on the top of the sphere: its centre is the surface under the pixel.
  auto [bu, bv] = cam.Project([] {
    Point p;
    p.x = 0.3f;
    p.y = 0.5f;
    p.z = 0.31f;
    return p;
  }());
  char brush[160];
  std::snprintf(brush, sizeof(brush),
                " --brush %.6f %.6f --pixel-radius 3 --radius 0.05 --nearest ", bu, bv);
  json br = same("select scene --bit 4 " + BoxArg({-10, 10, -10, 10, -10, 10}, 0, 0) + brush +
                 cam.look_at);
  ASSERT_TRUE(br["brush_center"].is_array()) << br;
  EXPECT_NEAR(br["brush_center"][0].get<double>(), 0.3, 0.02);
  EXPECT_NEAR(br["brush_center"][1].get<double>(), 0.5, 0.02);
  EXPECT_NEAR(br["brush_center"][2].get<double>(), 0.31, 0.02);
  EXPECT_GT(br["matched"].get<size_t>(), 5u);
  EXPECT_LT(br["matched"].get<size_t>(), sphere0);
  RunResult brt = both("select scene --bit 4 " + BoxArg({-10, 10, -10, 10, -10, 10}, 0, 0) + brush +
                       cam.look_at);
  EXPECT_NE(brt.out.find("brush centre ("), std::string::npos) << brt.out;
  // A slice as the region: frame 1, all of it.
  json sl = same(
      "select scene --bit 5 --normal 0 0 0 1 --offset 0.033333333333333333 "
      "--thickness 0.001");
  EXPECT_EQ(sl["matched"], frames[1].size());

  // Cut the object to a clipboard (a file of each data directory), then paste it 1 m higher.
  json cut = same("cut scene --bit 0 --clipboard ball");
  EXPECT_EQ(cut["points"], selected);
  const uint64_t cut_lsn = cut["lsn"].get<uint64_t>();
  EXPECT_GT(cut_lsn, 0u);
  EXPECT_TRUE(fs::exists(Path("data/clipboards/ball.hvc")));
  EXPECT_TRUE(fs::exists(Path("srvdata/clipboards/ball.hvc")));
  EXPECT_EQ(all_count(everything), total - selected);
  EXPECT_EQ(same("window scene --label-mask 1 " + everything)["points"], 0);
  json copy = same("copy scene --bit 2 --clipboard floor " + BoxArg(floor, -1, 10));
  EXPECT_EQ(copy["points"], sf["matched"]);
  EXPECT_EQ(copy["lsn"], 0);
  const std::string lifted = "--box -10 10 -10 10 0.9 2 -1 10";
  json paste = same("paste scene --clipboard ball --translate 0 0 1 0");
  EXPECT_EQ(paste["inserted"], selected);
  EXPECT_EQ(all_count(lifted), selected);
  // Undo and redo of the paste, through the log.
  json undo = same("undo scene " + std::to_string(paste["lsn"].get<uint64_t>()));
  EXPECT_EQ(undo["removed"], selected);
  EXPECT_EQ(all_count(lifted), 0u);
  json redo = same("redo scene " + std::to_string(undo["lsn"].get<uint64_t>()));
  EXPECT_EQ(redo["redone"], undo["lsn"]);
  EXPECT_EQ(redo["inserted"], selected);
  EXPECT_GT(redo["lsn"].get<uint64_t>(), undo["lsn"].get<uint64_t>());
  EXPECT_EQ(all_count(lifted), selected);
  RunResult redo_text = both("undo scene " + std::to_string(redo["lsn"].get<uint64_t>()));
  EXPECT_NE(redo_text.out.find("reverted lsn"), std::string::npos) << redo_text.out;
  EXPECT_EQ(all_count(lifted), 0u);
  // Undo of the cut: the object is back where it was.
  same("undo scene " + std::to_string(cut_lsn));
  EXPECT_EQ(all_count(everything), total);
  EXPECT_EQ(same("window scene --label-mask 1 " + everything)["points"], selected);
  // A matrix (x doubled) before the translation; a time shift moves points to later frames.
  same("paste scene --clipboard ball --matrix 2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1 --translate 5 0 0 0");
  EXPECT_EQ(all_count("--box 4.9 7.1 -10 10 -10 10 -1 10"), selected);
  json later = same("paste scene --clipboard floor --translate 0 0 0 0.1");
  EXPECT_EQ(later["inserted"], sf["matched"]);
  EXPECT_EQ(same("describe scene")["frames"], 4);  // frame 0 + 3 frames (0.1 s at 30 fps)
  RunResult pt = both("paste scene --clipboard floor --translate 0 0 5 0");
  EXPECT_EQ(pt.out.rfind("pasted " + std::to_string(sf["matched"].get<size_t>()) +
                             " points from clipboard 'floor': committed lsn ",
                         0),
            0u)
      << pt.out;

  // Composite a 5 x 5 x 5 cube (centimetres) along a trajectory through frames 0..2.
  std::vector<Point> cube;
  for (int i = 0; i < 125; ++i) {
    Point p;
    p.x = static_cast<float>(i % 5);
    p.y = static_cast<float>(i / 5 % 5);
    p.z = static_cast<float>(i / 25);
    p.r = 255;
    cube.push_back(p);
  }
  ASSERT_TRUE(formats::WritePly(Path("cube.ply"), cube, /*ascii=*/true).ok());
  std::ofstream(Path("path.csv")) << "# dx,dy,dz\n0.5,0.5,2\n0.6, 0.5, 2\n\n0.7,0.5,2\n";
  json comp = same("composite scene --ply " + Quote(Path("cube.ply")) +
                   " --units-scale 0.01 --first-frame 0 --frames 3 --trajectory " +
                   Quote(Path("path.csv")));
  EXPECT_EQ(comp["object_points"], 125);
  EXPECT_EQ(comp["inserted"], 375);
  EXPECT_EQ(comp["last_frame"], 2);
  EXPECT_EQ(all_count("--box 0.49 0.75 0.49 0.55 1.99 2.05 -1 10"), 375u);
  EXPECT_EQ(all_count("--box 0.69 0.75 0.49 0.55 1.99 2.05 0.05 0.07"), 125u);  // frame 2
  json still =
      same("composite scene --ply " + Quote(Path("cube.ply")) + " --first-frame 1 --frames 2");
  EXPECT_EQ(still["inserted"], 250);
  EXPECT_EQ(all_count("--box -0.01 4.01 -0.01 4.01 3.99 4.01 -1 10"), 50u);  // cube tops
  same("undo scene " + std::to_string(still["lsn"].get<uint64_t>()));
  EXPECT_EQ(all_count("--box -0.01 4.01 -0.01 4.01 3.99 4.01 -1 10"), 0u);

  // Errors of the data or of files: exit status 1, the same message in both modes.
  fail_both("paste scene --clipboard nosuch", 1, "no clipboard 'nosuch' WHERE");
  fail_both("select nosuch --bit 1 " + everything, 1, "NotFound: no dataset 'nosuch'");
  fail_both("cut nosuch --bit 1 --clipboard c", 1, "no dataset 'nosuch'");
  fail_both("graphcut scene --fg-bit 9 --bg-bit 2 --out-bit 0 " + everything, 1, "graph cut");
  fail_both("select scene --bit 4 " + everything + " --brush -1000 -1000 " + cam.look_at, 1,
            "NotFound: brush: no surface under pixel");
  fail_both("redo scene 999999", 1, "999999");
  fail_both("composite scene --ply " + Quote(Path("cube.ply")) +
                " --first-frame 0 --frames 2 --trajectory " + Quote(Path("path.csv")),
            1, "has 3 offsets for --frames 2");
  std::ofstream(Path("bad_path.csv")) << "0,0,0\n1;2;3\n";
  fail_both("composite scene --ply " + Quote(Path("cube.ply")) +
                " --first-frame 0 --frames 2 --trajectory " + Quote(Path("bad_path.csv")),
            1, "bad_path.csv:2: expected 'dx,dy,dz'");
  fail_both("composite scene --ply " + Quote(Path("missing.ply")) + " --first-frame 0 --frames 1",
            1, "missing.ply");
  json skew = cam.File();
  skew["world_from_camera"][0] = 2;
  std::ofstream(Path("skew.json")) << skew.dump();
  fail_both("select scene --bit 3 " + everything + " --rect 0 0 10 10 --camera " +
                Quote(Path("skew.json")),
            1, "not orthonormal");
  std::ofstream(Path("nofx.json")) << R"({"fy": 1, "cx": 0, "cy": 0})";
  fail_both("select scene --bit 3 " + everything + " --rect 0 0 10 10 --camera " +
                Quote(Path("nofx.json")),
            1, "\"fx\" is not a number");

  // Usage errors: exit status 2, before any request.
  const std::string look = std::string(" ") + cam.look_at;
  const std::vector<std::pair<std::string, std::string>> usage = {
      {"select scene --bit 1", "a region is required"},
      {"select scene " + everything, "--bit"},
      {"select scene --bit 32 " + everything, "--bit"},
      {"select scene --bit 1 --mode sideways " + everything, "--mode"},
      {"select scene --bit 1 " + everything + " --normal 0 0 0 1 --offset 0 --thickness 1",
       "excludes"},
      {"select scene --bit 1 --normal 0 0 0 1", "--offset"},
      {"select scene --bit 1 --normal 0 0 0 0 --offset 0 --thickness 1", "all zero"},
      {"select scene --bit 1 --box 1 0 0 1 0 1 0 1", "X0 must be <= X1"},
      {"select scene --bit 1 " + everything + " --rect 0 0 10 10", "through a camera"},
      {"select scene --bit 1 " + everything + look, "is for --lasso, --rect or --brush"},
      {"select scene --bit 1 " + everything + " --lasso 0 0 10 10" + look, "at least 3"},
      {"select scene --bit 1 " + everything + " --lasso 0 0 10 10 5" + look, "pairs"},
      {"select scene --bit 1 " + everything + " --rect 0 0 0 10" + look, "must differ"},
      {"select scene --bit 1 " + everything + " --rect 0 0 1 1 --brush 3 3" + look, "excludes"},
      {"select scene --bit 1 " + everything + " --radius 0.1", "--brush"},
      {"select scene --bit 1 " + everything + " --rect 0 0 1 1 --look-at 0 0 1 0 0 0", "--fov"},
      {"select scene --bit 1 " + everything +
           " --rect 0 0 1 1 --look-at 0 0 1 0 0 0 --fov 50 "
           "--size 10 10 --up 0 0 1",
       "parallel"},
      {"select scene --bit 1 " + everything +
           " --rect 0 0 1 1 --look-at 0 0 0 0 0 0 --fov 50 "
           "--size 10 10",
       "must differ"},
      {"select scene --bit 1 " + everything + " --rect 0 0 1 1 --camera c.json" + look, "excludes"},
      {"graphcut scene --fg-bit 1 --bg-bit 1 --out-bit 0 " + everything, "must differ"},
      {"graphcut scene --fg-bit 1 --bg-bit 2 --out-bit 0", "region of interest is required"},
      {"graphcut scene --fg-bit 1 --bg-bit 2 " + everything, "--out-bit"},
      {"graphcut scene --fg-bit 1 --bg-bit 2 --out-bit 0 --k 0 " + everything, "--k"},
      {"graphcut scene --fg-bit 1 --bg-bit 2 --out-bit 0 --intra-radius -1 " + everything,
       "--intra-radius"},
      {"copy scene --bit 1", "--clipboard"},
      {"copy scene --bit 1 --clipboard ../x", "clipboard name"},
      {"cut scene --clipboard c", "--bit"},
      {"paste scene", "--clipboard"},
      {"paste scene --clipboard c --translate 1 2", "--translate"},
      {"paste scene --clipboard c --matrix 1 2 3", "--matrix"},
      {"composite scene --ply x.ply --first-frame 0", "--frames"},
      {"composite scene --ply x.ply --first-frame 0 --frames 0", "--frames"},
      {"composite scene --ply x.ply --first-frame 4294967295 --frames 2", "passes frame"},
      {"redo scene", "lsn"},
      {"redo scene abc", "lsn"},
  };
  for (const auto& [args, expect] : usage) {
    for (bool srv : {false, true}) {
      RunResult r = Run((srv ? remote : std::string()) + args);
      EXPECT_EQ(r.code, 2) << args << "\nstdout: " << r.out << "\nstderr: " << r.err;
      EXPECT_NE(r.err.find(expect), std::string::npos) << args << "\nstderr: " << r.err;
      EXPECT_EQ(r.err.rfind("hvdb", 0), 0u) << r.err;
    }
  }
  for (const char* cmd : {"select", "graphcut", "copy", "cut", "paste", "composite", "redo"}) {
    RunResult r = Run(std::string(cmd) + " --help");
    EXPECT_EQ(r.code, 0) << cmd;
    EXPECT_NE(r.out.find("--json"), std::string::npos) << cmd << ": " << r.out;
  }
  EXPECT_NE(Run("redo --help").out.find("transaction log"), std::string::npos);

  // The server stayed up and the data directories agree.
  EXPECT_EQ(same("describe scene")["points"], RunJson("describe scene")["points"]);
  EXPECT_EQ(RunJson("check scene")["ok"], true);
  EXPECT_EQ(server.Terminate(), 0) << server.log();
}

// ---------------------------------------------------------------------------------------------
// Rendering.

// A PNG written by `hvdb render`, decoded (empty on failure, which the test reports).
render::Srgb8Image ReadPng(const std::string& path) {
  Result<render::Srgb8Image> img = formats::ReadSrgb8(path);
  EXPECT_TRUE(img.ok()) << path << ": " << img.status().ToString();
  return img.ok() ? *img : render::Srgb8Image{};
}

// Pixels that are not pure black (the default background).
size_t Covered(const render::Srgb8Image& img) {
  size_t n = 0;
  for (size_t i = 0; i + img.channels <= img.data.size(); i += img.channels) {
    n += (img.data[i] | img.data[i + 1] | img.data[i + 2]) != 0;
  }
  return n;
}

// What must not differ between the modes' `render --json`: all but times and file names.
json ComparableRender(json j) {
  j.erase("elapsed_ms");
  j.erase("render_ms");
  for (json& image : j["images"]) {
    image.erase("render_ms");
    image.erase("file");
  }
  return j;
}

// `hvdb render` on a data directory and through hvdb-server, on the rolling-sphere scene loaded
// the same way into both: the same request gives the same images (the CPU renderer, so that
// the test does not depend on an OpenGL driver), single images and camera paths, PNG and EXR,
// and the same errors.
TEST_F(HvdbCliTest, RenderEmbeddedAndThroughServer) {
  constexpr uint32_t kFrames = 3;
  std::vector<testing::ScenePoint> scene = testing::MovingSphereScene(kFrames, 0.01);
  std::vector<std::vector<Point>> frames(kFrames);
  uint64_t next_id = 1;
  for (const testing::ScenePoint& sp : scene) {
    Point p = sp.p;
    p.id = next_id++;
    frames[p.frame].push_back(p);
  }
  std::string files;
  for (uint32_t f = 0; f < kFrames; ++f) {
    std::string path = Path("scene" + std::to_string(f) + ".ply");
    ASSERT_TRUE(formats::WritePly(path, frames[f]).ok());
    files += " " + Quote(path);
  }

  ServerProcess server;
  fs::create_directories(Path("srvdata"));
  ASSERT_EQ(server.Start(Path("srvdata"), dir_), "");
  const std::string address = "127.0.0.1:" + std::to_string(server.port());
  const std::string remote = "--server " + address + " ";
  for (const std::string& mode : {std::string(), remote}) {
    RunResult r = Run(mode + "create scene --fps 10");
    ASSERT_EQ(r.code, 0) << mode << r.err;
    r = Run(mode + "import scene --frame 0 --keep-ids --sigma 0.006" + files);
    ASSERT_EQ(r.code, 0) << mode << r.err;
  }

  // Frame 1 (t = 0.1 s) from above the near edge of the floor, looking at the sphere.
  const std::string view =
      " --box -1 2 -1 2 -1 1 0.05 0.15 --look-at 0.5 -0.9 1.2 0.5 0.5 0.05 --fov 50 --up 0 0 1 "
      "--size 160 120 --renderer cpu";
  json e = RunJson("render scene" + view + " --out e.png");
  json s = RunJson(remote + "render scene" + view + " --out s.png");
  EXPECT_EQ(ComparableRender(e), ComparableRender(s)) << e << "\n" << s;
  EXPECT_EQ(e["dataset"], "scene");
  EXPECT_EQ(e["renderer"].get<std::string>().rfind("cpu", 0), 0u) << e;
  EXPECT_EQ(e["fallback"], false);
  ASSERT_EQ(e["images"].size(), 1u);
  EXPECT_EQ(e["images"][0]["file"], "e.png");
  EXPECT_EQ(e["images"][0]["width"], 160);
  EXPECT_EQ(e["images"][0]["height"], 120);
  EXPECT_EQ(e["points"], frames[1].size());
  EXPECT_TRUE(e["render_ms"].is_number());
  EXPECT_TRUE(e["elapsed_ms"].is_number());
  render::Srgb8Image pe = ReadPng(Path("e.png")), ps = ReadPng(Path("s.png"));
  EXPECT_EQ(pe.width, 160u);
  EXPECT_EQ(pe.height, 120u);
  EXPECT_EQ(ps.width, 160u);
  EXPECT_EQ(ps.height, 120u);
  EXPECT_TRUE(pe.data == ps.data) << "the embedded and the server's images differ: PSNR "
                                  << render::Psnr(pe, ps) << " dB";
  const size_t covered = Covered(pe);
  EXPECT_GT(covered, size_t{pe.width} * pe.height / 10) << "mostly background";
  EXPECT_LT(covered, size_t{pe.width} * pe.height);  // the floor ends before the top edge
  // A background colour shows where nothing is drawn; the points look the same.
  RunResult r = Run("render scene" + view + " --background 0 0 1 --out blue.png");
  ASSERT_EQ(r.code, 0) << r.err;
  render::Srgb8Image blue = ReadPng(Path("blue.png"));
  ASSERT_EQ(blue.data.size(), pe.data.size());
  EXPECT_EQ(blue.data[2], 255);  // the top-left corner: empty
  EXPECT_EQ(blue.data[0], 0);
  // Plain output: the file, the size, the points, the time and the renderer.
  for (const std::string& mode : {std::string(), remote}) {
    r = Run(mode + "render scene" + view + " --out text.png");
    EXPECT_EQ(r.code, 0) << mode << r.err;
    EXPECT_EQ(
        r.out.rfind(
            "rendered text.png (160x120): " + std::to_string(frames[1].size()) + " points in ", 0),
        0u)
        << r.out;
    EXPECT_NE(r.out.find(" ms with cpu ("), std::string::npos) << r.out;
  }
  // The region may be a hyperslice too: t = 0.1 s is frame 1.
  const std::string slice =
      " --normal 0 0 0 1 --offset 0.1 --thickness 0.01 --look-at 0.5 -0.9 1.2 0.5 0.5 0.05 "
      "--fov 50 --up 0 0 1 --size 160 120 --renderer cpu";
  json se = RunJson("render scene" + slice + " --out se.png");
  json ss = RunJson(remote + "render scene" + slice + " --out ss.png");
  EXPECT_EQ(ComparableRender(se), ComparableRender(ss));
  EXPECT_EQ(se["points"], frames[1].size());
  render::Srgb8Image sle = ReadPng(Path("se.png"));
  EXPECT_TRUE(sle.data == ReadPng(Path("ss.png")).data);
  EXPECT_GT(Covered(sle), size_t{sle.width} * sle.height / 10);
  // EXR: float channels, the same in both modes.
  EXPECT_EQ(Run("render scene" + view + " --out e.exr").code, 0);
  EXPECT_EQ(Run(remote + "render scene" + view + " --out s.exr").code, 0);
  std::string exr = ReadFile(Path("e.exr"));
  ASSERT_GT(exr.size(), 4u);
  EXPECT_EQ(exr.substr(0, 4), std::string("\x76\x2f\x31\x01", 4));
  EXPECT_TRUE(exr == ReadFile(Path("s.exr")));

  // A camera path over the three frames, and frame 2 again from the side: four files.
  json path = {{"cameras", json::array()}};
  for (uint32_t f = 0; f < kFrames; ++f) {
    path["cameras"].push_back({{"frame", f},
                               {"look_at",
                                {{"eye", {0.5, -0.9, 1.2}},
                                 {"target", {0.5, 0.5, 0.05}},
                                 {"up", {0, 0, 1}},
                                 {"fov_y_deg", 50},
                                 {"width", 96},
                                 {"height", 72}}}});
  }
  path["cameras"].push_back({{"frame", 2},
                             {"look_at",
                              {{"eye", {-1.2, 0.5, 0.6}},
                               {"target", {0.36, 0.5, 0.15}},
                               {"up", {0, 0, 1}},
                               {"fov_y_deg", 40},
                               {"width", 96},
                               {"height", 72}}}});
  std::ofstream(Path("cameras.json")) << path.dump(2);
  const std::string seq = " --path cameras.json --renderer cpu --json --out-dir ";
  RunResult re = Run("render scene" + seq + "fe"), rs = Run(remote + "render scene" + seq + "fs");
  ASSERT_EQ(re.code, 0) << re.err;
  ASSERT_EQ(rs.code, 0) << rs.err;
  json je = json::parse(re.out), js = json::parse(rs.out);
  EXPECT_EQ(ComparableRender(je), ComparableRender(js));
  ASSERT_EQ(je["images"].size(), 4u);
  EXPECT_EQ(je["images"][3]["file"], "fe/frame_0003.png");
  size_t n_files = 0;
  for (const auto& entry : fs::directory_iterator(Path("fe"))) n_files += entry.is_regular_file();
  EXPECT_EQ(n_files, 4u);
  std::vector<render::Srgb8Image> seq_images;
  for (uint32_t i = 0; i < 4; ++i) {
    const std::string name = "frame_000" + std::to_string(i) + ".png";
    render::Srgb8Image fe = ReadPng(Path("fe/" + name)), fsrv = ReadPng(Path("fs/" + name));
    EXPECT_EQ(fe.width, 96u) << name;
    EXPECT_EQ(fe.height, 72u) << name;
    EXPECT_TRUE(fe.data == fsrv.data) << name << " differs between the modes";
    EXPECT_GT(Covered(fe), 96u * 72 / 10) << name;
    EXPECT_EQ(je["images"][i]["points"], frames[i == 3 ? 2 : i].size());
    seq_images.push_back(std::move(fe));
  }
  EXPECT_FALSE(seq_images[0].data == seq_images[1].data);  // the sphere rolls
  EXPECT_FALSE(seq_images[2].data == seq_images[3].data);  // another camera
  // Plain output: one line per image, then the total.
  r = Run("render scene --path cameras.json --renderer cpu --out-dir plain --size 48 36");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("plain/frame_0000.png (48x36): "), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("rendered 4 images into plain with cpu ("), std::string::npos) << r.out;
  EXPECT_EQ(ReadPng(Path("plain/frame_0003.png")).width, 48u);

  // Usage errors (exit 2) are found before anything is opened, in both modes.
  const std::vector<std::pair<std::string, std::string>> usage = {
      {"render scene --look-at 0 0 -3 0 0 0 --fov 50 --out x.png", "a region is required"},
      {"render scene --box 0 1 0 1 0 1 0 1 --out x.png", "a camera is required"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1", "--out"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --out x.jpg", ".png or .exr"},
      {"render scene --box 0 1 0 1 0 1 0 1 --look-at 0 0 -3 0 0 0 --out x.png", "--fov"},
      {"render scene --box 1 0 0 1 0 1 0 1 --dataset-camera 1 --out x.png", "X0 must be <= X1"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --mode fuzzy --out x.png", "--mode"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --renderer vulkan --out x.png",
       "--renderer"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --size 0 10 --out x.png", "--size"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --lod -1 --out x.png", "--lod"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 1 --background 2 0 0 --out x.png",
       "--background"},
      {"render scene --box 0 1 0 1 0 1 0 1 --look-at 0 0 -3 0 0 0 --fov 50 --up 0 0 1 "
       "--out x.png",
       "parallel"},
      {"render scene --box 0 1 0 1 0 1 0 1 --look-at 0 0 -3 0 0 0 --fov 50 --dataset-camera 1 "
       "--out x.png",
       "excludes"},
      {"render scene --path cameras.json", "--out-dir"},
      {"render scene --out-dir d", "--path"},
      {"render scene --path cameras.json --out-dir d --out x.png", "excludes"},
      {"render scene --normal 0 0 0 1 --offset 0 --thickness 0.1 --path cameras.json "
       "--out-dir d",
       "must be a --box"},
  };
  for (const auto& [args, expect] : usage) {
    for (const std::string& mode : {std::string(), remote}) {
      r = Run(mode + args);
      EXPECT_EQ(r.code, 2) << "hvdb " << mode << args << "\nstderr: " << r.err;
      EXPECT_NE(r.err.find(expect), std::string::npos) << "hvdb " << mode << args << "\n" << r.err;
      EXPECT_EQ(r.out, "") << args;
    }
  }
  EXPECT_FALSE(fs::exists(Path("d")));
  EXPECT_FALSE(fs::exists(Path("x.png")));

  // Errors (exit 1): an unknown dataset, a camera the dataset lacks, an unreadable path file.
  const std::vector<std::pair<std::string, std::string>> errors = {
      {"render nosuch" + view + " --out x.png", "NotFound: no dataset 'nosuch'"},
      {"render scene --box 0 1 0 1 0 1 0 1 --dataset-camera 7 --out x.png",
       "render.view.dataset_camera"},
      {"render scene" + view + " --view-dependent --out x.png", "declares no cameras"},
      {"render scene --path missing.json --out-dir d", "missing.json"},
      {"render scene" + view + " --out no/such/dir/x.png", "cannot write 'no/such/dir/x.png'"},
      // A level past the dataset's coarsest: storage's one rule, the same words as a query's.
      {"render scene" + view + " --lod 40 --out x.png",
       "InvalidArgument: lod: 40 is out of range 0..5 for dataset 'scene' (its coarsest level)"},
  };
  for (const auto& [args, expect] : errors) {
    for (const std::string& mode : {std::string(), remote}) {
      r = Run(mode + args);
      EXPECT_EQ(r.code, 1) << "hvdb " << mode << args << "\nstderr: " << r.err;
      EXPECT_NE(r.err.find(expect), std::string::npos) << "hvdb " << mode << args << "\n" << r.err;
      EXPECT_EQ(r.err.rfind("hvdb: ", 0), 0u) << r.err;
    }
  }
  EXPECT_FALSE(fs::exists(Path("x.png")));
  EXPECT_FALSE(fs::exists(Path("d")));

  EXPECT_NE(Run("render --help").out.find("--dataset-camera"), std::string::npos);
  EXPECT_EQ(server.Terminate(), 0) << server.log();
}

// hvdb7 (docs/CODEC.md) at the command line: export of frames (temporal), import of the
// streams, compressed query output, and results sent compressed by a server (--wire hvdb7).
TEST_F(HvdbCliTest, CompressedExportImportAndWire) {
  ASSERT_TRUE(HaveData()) << "test data not found under " << kPanoptic << " (../shared/data)";
  ASSERT_EQ(Run("create walk --fps 30").code, 0);
  RunResult r = Run("import walk --frame 0 --units-scale 0.01 " + Quote(kFrame380) + " " +
                    Quote(kFrame381));
  ASSERT_EQ(r.code, 0) << r.err;
  r = Run("export walk " + Quote(Path("out")) + " --temporal --qp 18");
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("exported 2 frames"), std::string::npos) << r.out;
  ASSERT_TRUE(fs::exists(Path("out/walk_000000.hv7")));
  ASSERT_TRUE(fs::exists(Path("out/walk_000001.hv7")));
  // Far smaller than the 64-byte records.
  EXPECT_LT(fs::file_size(Path("out/walk_000001.hv7")), 73000u * 64 / 4);
  // The second file is temporal: alone it is refused, naming what is missing.
  ASSERT_EQ(Run("create back --fps 30").code, 0);
  r = Run("import back --frame 0 " + Quote(Path("out/walk_000001.hv7")));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("reference"), std::string::npos) << r.err;
  r = Run("import back --frame 0 " + Quote(Path("out/walk_000000.hv7")) + " " +
          Quote(Path("out/walk_000001.hv7")));
  ASSERT_EQ(r.code, 0) << r.err;
  const std::string box = " --box -9 9 -9 9 -9 9 0 1";
  ASSERT_EQ(Run("window walk" + box + " --out " + Quote(Path("a.ply"))).code, 0);
  ASSERT_EQ(Run("window back" + box + " --out " + Quote(Path("b.ply"))).code, 0);
  auto a = formats::ReadPly(Path("a.ply")), b = formats::ReadPly(Path("b.ply"));
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->size(), b->size());
  // Positions on an 18-bit grid over a frame's extent (< 2 m: errors within 4 micrometres),
  // colours and frames exact; the points come back in another order, so sums are compared.
  double sa = 0, sb = 0;
  uint64_t ca = 0, cb = 0;
  for (const Point& p : *a) sa += p.x + p.y + p.z, ca += p.r + p.g + p.b + p.frame;
  for (const Point& p : *b) sb += p.x + p.y + p.z, cb += p.r + p.g + p.b + p.frame;
  EXPECT_EQ(ca, cb);
  EXPECT_NEAR(sa / a->size(), sb / b->size(), 4e-6);

  r = Run("export walk " + Quote(Path("bad")) + " --codec draco --temporal");
  EXPECT_EQ(r.code, 2);  // temporal coding is hvdb7's
  EXPECT_NE(r.err.find("--temporal is for --codec hvdb7"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(Path("bad")));

  // Draco files export and import too (positions at 16 bits, colours, ids, frames).
  r = Run("export walk " + Quote(Path("drc")) + " --codec draco");
  ASSERT_EQ(r.code, 0) << r.err;
  ASSERT_EQ(Run("create viadraco --fps 30").code, 0);
  r = Run("import viadraco --frame 0 " + Quote(Path("drc/walk_000000.drc")) + " " +
          Quote(Path("drc/walk_000001.drc")));
  ASSERT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.out.find("imported " + std::to_string(a->size()) + " points"), std::string::npos)
      << r.out;

  // Compressed query output, read back by the library.
  r = Run("window walk" + box + " --codec hvdb7 --qp 20 --out " + Quote(Path("w.hv7")));
  ASSERT_EQ(r.code, 0) << r.err;
  auto w = formats::ReadHvdb7File(Path("w.hv7"));
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  EXPECT_EQ(w->size(), a->size());
  r = Run("window walk" + box + " --codec hvdb7");
  EXPECT_EQ(r.code, 2);  // needs --out

  // Through a server, results travelling as hvdb7: the same points as records.
  ServerProcess server;
  std::string started = server.Start(Path("data"), dir_);
  ASSERT_EQ(started, "");
  const std::string remote = "--server 127.0.0.1:" + std::to_string(server.port()) + " ";
  json plain = RunJson(remote + "window walk" + box);
  json coded = RunJson(remote + "--wire hvdb7 window walk" + box);
  EXPECT_EQ(plain["points"], coded["points"]);
  r = Run("--wire hvdb7 window walk" + box);
  EXPECT_EQ(r.code, 2);  // --wire is for --server
}

TEST_F(HvdbCliTest, ServerNotListeningExitsOne) {
  int port = ClosedPort();
  ASSERT_GT(port, 0);
  const std::string address = "127.0.0.1:" + std::to_string(port);
  for (const std::string& args : {std::string("datasets"), std::string("ping"),
                                  std::string("describe walk"), std::string("create walk --fps 30")}) {
    auto start = std::chrono::steady_clock::now();
    RunResult r = Run("--server " + address + " " + args);
    EXPECT_EQ(r.code, 1) << args;
    EXPECT_EQ(r.out, "") << args;
    EXPECT_EQ(r.err.rfind("hvdb: IOError: connect to " + address + ": ", 0), 0u) << r.err;
    EXPECT_NE(r.err.find("is hvdb-server running there?"), std::string::npos) << r.err;
    // Refused at once, not after the reconnection backoff.
    EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(2)) << args;
  }
  EXPECT_FALSE(fs::exists(Path("data")));  // no data directory was made on the way
}

}  // namespace
}  // namespace hvdb
