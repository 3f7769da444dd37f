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
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/ply.h"

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
  ply::ReadOptions opts;
  opts.scale = 0.01;
  Result<std::vector<Point>> pts = ply::ReadPly(path, opts);
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
  Result<std::vector<Point>> all = ply::ReadPly(Path("all.ply"));
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
  Result<std::vector<Point>> sl = ply::ReadPly(Path("slice.ply"));
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
      {"window walk --box 0 1 0 1 0 1 0 1 --lod 12", "--lod"},
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
  };
  ASSERT_EQ(Run("create walk --fps 30").code, 0);
  for (const Case& c : cases) {
    RunResult r = Run(c.args);
    EXPECT_EQ(r.code, 2) << "hvdb " << c.args << "\nstdout: " << r.out << "\nstderr: " << r.err;
    EXPECT_NE(r.err.find(c.expect), std::string::npos)
        << "hvdb " << c.args << "\nstderr: " << r.err;
    EXPECT_EQ(r.err.rfind("hvdb", 0), 0u) << r.err;
  }
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

// ---------------------------------------------------------------------------------------------
// Server mode.

// hvdb-server, built next to hvdb: build/client/hvdb -> build/server/hvdb-server.
std::string ServerPath() {
  std::string p = HVDB_CLI_PATH;
  const std::string cli = "client/hvdb", server = "server/hvdb-server";
  size_t at = p.rfind(cli);
  return at == std::string::npos ? std::string() : p.replace(at, cli.size(), server);
}

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
    std::vector<std::string> args = {binary,      "--listen",     "127.0.0.1:0", "--port-file",
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
    j.erase("out");
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
    Result<std::vector<Point>> pe = ply::ReadPly(Path("emb.ply")), ps = ply::ReadPly(Path("srv.ply"));
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
  // All but the log's size: each embedded run checkpoints when it closes, the server later.
  de.erase("wal_bytes");
  dr.erase("wal_bytes");
  EXPECT_EQ(de, dr);
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
  EXPECT_EQ(pt.out.rfind("pong from " + address + " in ", 0), 0u) << pt.out;
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
