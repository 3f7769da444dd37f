// Several hvdb-servers on one dataset: the first to start writes, the others serve reads, follow
// its commits and refuse writes with NOT_LEADER naming it; when it dies (kill -9) one of them
// takes over with every acknowledged commit. Real processes, real sockets, the real CLI, real
// Panoptic frames. Built twice: in server_tests on a data directory (`--follow`), and in
// rados_tests on a RADOS pool of the one-node cluster (`--store rados:...`, lease 5 s).
#include <signal.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "tests/run_command.h"
#include "tests/server/server_child.h"

namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using hvdb::testing::CommandRun;
using hvdb::testing::ServerChild;
using hvdb::testing::WaitUntil;
using std::chrono::milliseconds;

const std::string kFrames = HVDB_SHARED_DATA "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/";
const std::string kPly = kFrames + "ptcloud_hd00000380.ply";
const std::string kEverything = " --box -9 9 -9 9 -9 9 -1 100";

class FollowerServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string t = (fs::temp_directory_path() / "hvdb_follow_XXXXXX").string();
    ASSERT_NE(mkdtemp(t.data()), nullptr);
    work_ = t;
#ifdef HVDB_TEST_RADOS
    const char* conf = std::getenv("HVDB_CEPH_CONF");
    ASSERT_NE(conf, nullptr) << "run through CTest: the fixture `ceph` starts the cluster";
    args_ = {"--store", std::string("rados:hvdb-server-tests?conf=") + conf + "&lease=5",
             "--data", "follow-" + std::to_string(std::random_device{}())};
    takeover_ = milliseconds(30000);  // the dead writer's lease (5 s) runs out first
#else
    args_ = {"--data", work_ + "/data", "--follow"};
    takeover_ = milliseconds(10000);  // the lock is free when the writer's process is gone
#endif
  }
  void TearDown() override { fs::remove_all(work_); }
  std::unique_ptr<ServerChild> Server(const std::string& name) {
    return std::make_unique<ServerChild>(name, args_, work_);
  }
  static CommandRun Cli(const std::string& address, const std::string& args) {
    return hvdb::testing::RunCommand(std::string(HVDB_CLI_PATH) + " --server " + address + " " +
                                     args);
  }
  static json Json(const std::string& address, const std::string& args) {
    CommandRun r = Cli(address, args + " --json");
    EXPECT_EQ(r.code, 0) << args << ": " << r.out;
    return r.code == 0 ? json::parse(r.out) : json::object();
  }
  static std::string Role(const std::string& address) {
    json j = Json(address, "stats");
    return j.contains("server") ? j["server"]["role"].get<std::string>() : "";
  }
  static uint64_t Points(const std::string& address) {
    json j = Json(address, "window walk" + kEverything);
    return j.contains("points") ? j["points"].get<uint64_t>() : UINT64_MAX;
  }
  // Until `reader` has what `writer` has (it follows every follow interval).
  static bool CaughtUp(const std::string& reader, uint64_t lsn, uint64_t points) {
    return WaitUntil(milliseconds(10000), [&] {
      json d = Json(reader, "describe walk");
      return d.contains("last_lsn") && d["last_lsn"] == lsn && d["points"] == points;
    });
  }

  std::string work_;
  std::vector<std::string> args_;
  milliseconds takeover_{0};
};

TEST_F(FollowerServerTest, ReaderFollowsRefusesWritesAndTakesOverAfterKill9) {
  auto a = Server("a");
  ASSERT_EQ(a->Start(), "");
  ASSERT_EQ(Cli(a->Address(), "create walk --fps 30").code, 0);
  CommandRun r = Cli(a->Address(), "import walk --frame 0 --units-scale 0.01 " + kPly + " " +
                                       kFrames + "ptcloud_hd00000381.ply");
  ASSERT_EQ(r.code, 0) << r.out;

  // A second server on the same data starts as a reader and has what the writer has.
  auto b = Server("b");
  ASSERT_EQ(b->Start(), "");
  EXPECT_EQ(Role(a->Address()), "writer");
  EXPECT_EQ(Role(b->Address()), "reader");
  json d = Json(a->Address(), "describe walk");
  ASSERT_TRUE(CaughtUp(b->Address(), d["last_lsn"], d["points"]));
  EXPECT_EQ(Points(b->Address()), d["points"].get<uint64_t>());
  // Every read serves there: a hyperslice, a render.
  EXPECT_EQ(Json(b->Address(), "slice walk --normal 0 0 0 1 --offset 0 --thickness 0.001")["points"],
            Json(a->Address(), "slice walk --normal 0 0 0 1 --offset 0 --thickness 0.001")["points"]);
  r = Cli(b->Address(), "render walk --box -9 9 -9 9 -9 9 0 0 --look-at -0.4 -0.9 -3 -0.4 -0.9 0 "
                        "--fov 40 --size 160 120 --out " + work_ + "/reader.png");
  EXPECT_EQ(r.code, 0) << r.out;
  EXPECT_GT(fs::file_size(work_ + "/reader.png"), 1000u);

  // Writes on the reader are refused, naming the writer; nothing of them lands.
  r = Cli(b->Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("NotLeader"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find(a->Address()), std::string::npos) << r.out;
  EXPECT_NE(Cli(b->Address(), "create other --fps 30").code, 0);
  EXPECT_EQ(Json(b->Address(), "stats")["server"]["leader"], a->Address());

  // The writer's commits reach the reader, each whole.
  r = Cli(a->Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  ASSERT_EQ(r.code, 0) << r.out;
  r = Cli(a->Address(), "edit walk --paste " + kPly + " --frame 5 --units-scale 0.01");
  ASSERT_EQ(r.code, 0) << r.out;
  // A clipboard lives with the data: the server that takes over pastes it.
  ASSERT_EQ(Cli(a->Address(), "select walk --bit 3 --box -9 9 -9 9 -9 9 0.1 0.2").code, 0);
  const json copied = Json(a->Address(), "copy walk --bit 3 --clipboard c1");
  ASSERT_GT(copied["points"].get<uint64_t>(), 0u);
  const json before = Json(a->Address(), "describe walk");
  ASSERT_TRUE(CaughtUp(b->Address(), before["last_lsn"], before["points"]))
      << Json(b->Address(), "describe walk").dump();
  EXPECT_EQ(Points(b->Address()), before["points"].get<uint64_t>());

  // The writer dies without a word: the reader takes over with every acknowledged commit.
  a->Kill(SIGKILL);
  ASSERT_TRUE(WaitUntil(takeover_, [&] { return Role(b->Address()) == "writer"; }))
      << "no takeover: " << b->Log();
  const json after = Json(b->Address(), "describe walk");
  EXPECT_EQ(after["points"], before["points"]);
  EXPECT_EQ(after["last_lsn"], before["last_lsn"]);
  EXPECT_EQ(Points(b->Address()), before["points"].get<uint64_t>());
  // And it takes writes, which a server started next follows.
  const json pasted = Json(b->Address(), "paste walk --clipboard c1 --translate 0 0 1 0");
  EXPECT_EQ(pasted["inserted"], copied["points"]);
  r = Cli(b->Address(), "undo walk " + std::to_string(pasted["lsn"].get<uint64_t>()));
  EXPECT_EQ(r.code, 0) << r.out;
  auto c = Server("c");
  ASSERT_EQ(c->Start(), "");
  EXPECT_EQ(Role(c->Address()), "reader");
  const json undone = Json(b->Address(), "describe walk");
  EXPECT_TRUE(CaughtUp(c->Address(), undone["last_lsn"], undone["points"]));
  r = Cli(c->Address(), "undo walk 1");
  EXPECT_NE(r.out.find(b->Address()), std::string::npos) << r.out;
}

// Two readers answer window queries while the writer commits 75 k-point pastes: every answer
// is a whole number of commits (never part of one), and a reader's answers never go back.
TEST_F(FollowerServerTest, ReadersSeeWholeCommitsWhileTheWriterCommits) {
  auto a = Server("a");
  ASSERT_EQ(a->Start(), "");
  ASSERT_EQ(Cli(a->Address(), "create walk --fps 30").code, 0);
  auto b = Server("b"), c = Server("c");
  ASSERT_EQ(b->Start(), "");
  ASSERT_EQ(c->Start(), "");
  const int kCommits = 8;
  std::atomic<int> done{0};
  std::atomic<uint64_t> per_commit{0};
  std::thread writer([&] {
    for (int i = 0; i < kCommits; ++i) {
      CommandRun r = Cli(a->Address(), "edit walk --paste " + kPly + " --frame " +
                                           std::to_string(i % 3) + " --units-scale 0.01 --json");
      ASSERT_EQ(r.code, 0) << r.out;
      per_commit = json::parse(r.out)["inserted"].get<uint64_t>();
      done = i + 1;
    }
  });
  std::vector<uint64_t> last(2, 0);
  int answers = 0;
  while (done < kCommits && !HasFailure()) {
    for (int k = 0; k < 2; ++k) {
      const uint64_t n = Points((k == 0 ? b : c)->Address());
      const uint64_t unit = per_commit.load();
      if (unit == 0) continue;
      EXPECT_EQ(n % unit, 0u) << "a reader saw part of a commit: " << n << " points";
      EXPECT_GE(n, last[static_cast<size_t>(k)]) << "a reader's answers went back in time";
      last[static_cast<size_t>(k)] = n;
      ++answers;
    }
  }
  writer.join();
  EXPECT_GT(answers, 2);
  const json d = Json(a->Address(), "describe walk");
  EXPECT_EQ(d["points"].get<uint64_t>(), kCommits * per_commit.load());
  EXPECT_TRUE(CaughtUp(b->Address(), d["last_lsn"], d["points"]));
  EXPECT_TRUE(CaughtUp(c->Address(), d["last_lsn"], d["points"]));
}

// kill -9 of the writer while commits stream in and its merger turns them into trees: the
// reader that takes over has every acknowledged commit whole and the one in flight whole or
// not at all.
TEST_F(FollowerServerTest, Kill9DuringCommitsAndMergesLosesNothingAcknowledged) {
  auto a = Server("a");
  ASSERT_EQ(a->Start(), "");
  ASSERT_EQ(Cli(a->Address(), "create walk --fps 30").code, 0);
  auto b = Server("b");
  ASSERT_EQ(b->Start(), "");
  // Each paste (one commit, 73 k points) overfills frame f's buffer T0: the merger builds a
  // tree of it while the next commits arrive.
  std::vector<uint32_t> acknowledged;
  uint64_t per_commit = 0;
  std::atomic<bool> stop{false};
  std::thread writer([&] {
    for (uint32_t f = 0; f < 400 && !stop; ++f) {
      CommandRun r = Cli(a->Address(), "edit walk --paste " + kPly + " --frame " +
                                           std::to_string(f) + " --units-scale 0.01 --json");
      if (r.code != 0) break;  // the server is gone
      per_commit = json::parse(r.out)["inserted"].get<uint64_t>();
      acknowledged.push_back(f);
    }
  });
  ASSERT_TRUE(WaitUntil(milliseconds(30000), [&] {
    json s = Json(a->Address(), "stats walk");
    return s.contains("datasets") && !s["datasets"].empty() &&
           s["datasets"][0]["trees"].get<uint64_t>() >= 2 && acknowledged.size() >= 3;
  })) << "the merger built no trees";
  a->Kill(SIGKILL);
  stop = true;
  writer.join();
  ASSERT_TRUE(WaitUntil(takeover_, [&] { return Role(b->Address()) == "writer"; }))
      << "no takeover: " << b->Log();
  const uint32_t last = acknowledged.back();
  for (uint32_t f = 0; f <= last + 1; ++f) {
    const std::string t0 = std::to_string((f - 0.3) / 30.0), t1 = std::to_string((f + 0.3) / 30.0);
    json w = Json(b->Address(), "window walk --box -9 9 -9 9 -9 9 " + t0 + " " + t1);
    const uint64_t n = w.contains("points") ? w["points"].get<uint64_t>() : 0;
    if (f <= last) {
      EXPECT_EQ(n, per_commit) << "acknowledged frame " << f;
    } else {
      EXPECT_TRUE(n == 0 || n == per_commit) << "the commit in flight is half there: " << n;
    }
  }
  const uint64_t total = Json(b->Address(), "describe walk")["points"].get<uint64_t>();
  EXPECT_TRUE(total == acknowledged.size() * per_commit ||
              total == (acknowledged.size() + 1) * per_commit)
      << total;
}

}  // namespace
