// Runs the real `hvdb` binary on a temporary data directory, as a user would.
#include <sys/wait.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
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
      {"--server localhost:7000 datasets", "--server needs hvdb-server (not built yet)"},
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

}  // namespace
}  // namespace hvdb
