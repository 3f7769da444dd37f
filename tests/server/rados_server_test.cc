// hvdb-server on a RADOS pool (--store rados:POOL?conf=FILE) against the real one-node cluster
// of the CTest fixture `ceph`: imports through it survive kill -9 of the writer and failover
// to the reading server that takes its lease; a paused writer is fenced; an OSD stopped under
// load. (Readers following the writer, NOT_LEADER and failover under merges:
// follower_server_test.cc, run on the pool too.)
#include <signal.h>

#include <atomic>
#include <chrono>
#include <cstdio>
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

const std::string kFrames = HVDB_SHARED_DATA "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/";

using ShRun = hvdb::testing::CommandRun;
using hvdb::testing::RunCommand;
using hvdb::testing::WaitUntil;
ShRun Sh(const std::string& cmd) { return RunCommand(cmd); }

// A server on the pool: the writer if it is the first, else a reader that takes over once the
// writer's lease runs out.
class RadosServer : public hvdb::testing::ServerChild {
 public:
  RadosServer(std::string name, const std::string& store, const std::string& data,
              std::string work)
      : ServerChild(std::move(name), {"--store", store, "--data", data}, std::move(work)) {}
};

class RadosServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const char* conf = std::getenv("HVDB_CEPH_CONF");
    ASSERT_NE(conf, nullptr) << "run through CTest: the fixture `ceph` starts the cluster";
    // A short lease, so that the failover below takes seconds.
    store_ = std::string("rados:hvdb-server-tests?conf=") + conf + "&lease=5";
    data_ = "srv-" + std::to_string(std::random_device{}());
    std::string t = (fs::temp_directory_path() / "hvdb_rados_server_XXXXXX").string();
    ASSERT_NE(mkdtemp(t.data()), nullptr);
    work_ = t;
  }
  void TearDown() override { fs::remove_all(work_); }
  ShRun Cli(const std::string& address, const std::string& args) {
    return Sh(std::string(HVDB_CLI_PATH) + " --server " + address + " " + args);
  }
  // Until the server at `address` holds the lease (a reader takes over from a dead writer).
  bool BecomesWriter(const std::string& address) {
    return WaitUntil(std::chrono::seconds(30), [&] {
      ShRun r = Cli(address, "stats --json");
      return r.code == 0 && json::parse(r.out)["server"]["role"] == "writer";
    });
  }
  std::string store_, data_, work_;
};

// kill -9 while commits stream in: every acknowledged commit is there after the failover, and
// the one in flight is there whole or not at all.
TEST_F(RadosServerTest, Kill9DuringCommitsLosesNothingAcknowledged) {
  RadosServer a("a", store_, data_, work_);
  ASSERT_EQ(a.Start(), "");
  ASSERT_EQ(Cli(a.Address(), "create walk --fps 30").code, 0);
  const std::string ply = kFrames + "ptcloud_hd00000380.ply";
  ShRun first = Cli(a.Address(), "import walk --frame 0 --units-scale 0.01 " + ply + " --json");
  ASSERT_EQ(first.code, 0) << first.out;
  const uint64_t per_frame = json::parse(first.out)["points"].get<uint64_t>();
  RadosServer b("b", store_, data_, work_);  // a reader until a is gone
  ASSERT_EQ(b.Start(), "");
  std::vector<uint32_t> acknowledged = {0};
  std::atomic<bool> stop{false};
  std::atomic<int> acked{0};
  std::thread writer([&] {
    for (uint32_t f = 1; f < 200 && !stop; ++f) {
      ShRun r = Cli(a.Address(), "import walk --frame " + std::to_string(f) +
                                     " --units-scale 0.01 " + ply);
      if (r.code != 0) break;  // the server is gone
      acknowledged.push_back(f);
      ++acked;
    }
  });
  // The kill comes once two more commits are acknowledged (a loaded machine takes longer than
  // a fixed wait), with the next one on its way.
  WaitUntil(std::chrono::seconds(60), [&] { return acked >= 2; });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  a.Kill(SIGKILL);
  stop = true;
  writer.join();
  ASSERT_GE(acknowledged.size(), 2u) << "no commit was acknowledged before the kill";

  ASSERT_TRUE(BecomesWriter(b.Address())) << "no failover within 30 s: " << b.Log();
  const uint32_t last = acknowledged.back();
  for (uint32_t f = 0; f <= last + 1; ++f) {
    // Frame f's time f/30 s, within a third of a frame either side.
    const std::string t0s = std::to_string((f - 0.3) / 30.0), t1s = std::to_string((f + 0.3) / 30.0);
    ShRun r = Cli(b.Address(), "window walk --box -9 9 -9 9 -9 9 " + t0s + " " + t1s + " --json");
    ASSERT_EQ(r.code, 0) << r.out;
    const uint64_t n = json::parse(r.out)["points"].get<uint64_t>();
    if (f <= last) {
      EXPECT_EQ(n, per_frame) << "acknowledged frame " << f;
    } else {
      EXPECT_TRUE(n == 0 || n == per_frame) << "frame in flight half there: " << n;
    }
  }
}

// Fencing: a writer that was only paused (SIGSTOP: a stalled process, a partitioned host) while
// its lease ran out and another server took over must not write when it wakes.
TEST_F(RadosServerTest, APausedWriterIsFencedAfterTakeover) {
  RadosServer a("a", store_, data_, work_);
  ASSERT_EQ(a.Start(), "");
  ASSERT_EQ(Cli(a.Address(), "create walk --fps 30").code, 0);
  ShRun r = Cli(a.Address(), "import walk --frame 0 --units-scale 0.01 " + kFrames +
                                 "ptcloud_hd00000380.ply --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const uint64_t points = json::parse(r.out)["points"].get<uint64_t>();
  RadosServer b("b", store_, data_, work_);
  ASSERT_EQ(b.Start(), "");
  a.Signal(SIGSTOP);
  ASSERT_TRUE(BecomesWriter(b.Address())) << "no takeover within 30 s: " << b.Log();
  a.Signal(SIGCONT);
  // The old writer wakes up and tries to commit: the cluster refuses it.
  r = Cli(a.Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  EXPECT_EQ(r.code, 1) << r.out;
  r = Cli(b.Address(), "describe walk --json");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(json::parse(r.out)["points"].get<uint64_t>(), points);
  // The bulk load (LSN 1) only: the fenced edit left no trace.
  EXPECT_EQ(json::parse(r.out)["last_lsn"].get<uint64_t>(), 1u);
  r = Cli(b.Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  EXPECT_EQ(r.code, 0) << r.out;
}

// The OSD fails under a serving server: queries and commits fail after the store's timeout with
// an error that names the object, the server keeps serving; once the OSD is back everything
// works and nothing was lost or half-applied.
TEST_F(RadosServerTest, OsdStoppedAndRestartedUnderLoad) {
  const std::string conf = std::getenv("HVDB_CEPH_CONF");
  const std::string cluster = fs::path(conf).parent_path().string();
  const std::string script = HVDB_SOURCE_DIR "/scripts/ceph-dev.sh";
  RadosServer a("a", store_ + "&timeout=3", data_, work_);
  ASSERT_EQ(a.Start(), "");
  ASSERT_EQ(Cli(a.Address(), "create walk --fps 30").code, 0);
  ShRun r = Cli(a.Address(), "import walk --frame 0 --units-scale 0.01 " + kFrames +
                                 "ptcloud_hd00000380.ply " + kFrames + "ptcloud_hd00000381.ply --json");
  ASSERT_EQ(r.code, 0) << r.out;
  const uint64_t points = json::parse(r.out)["points"].get<uint64_t>();
  const std::string box = " --box -9 9 -9 9 -9 9 0 1";

  r = Sh("bash " + script + " osd-stop " + cluster);
  ASSERT_EQ(r.code, 0) << r.out;
  // A query: waits, then fails clearly (or, from the buffer pool, answers in full).
  r = Cli(a.Address(), "window walk" + box + " --json");
  if (r.code == 0) {
    EXPECT_EQ(json::parse(r.out)["points"].get<uint64_t>(), points);
  } else {
    EXPECT_EQ(r.code, 1) << r.out;
    EXPECT_NE(r.out.find("(rados)"), std::string::npos) << r.out;
  }
  // A commit cannot be made durable: refused, not acknowledged.
  r = Cli(a.Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  EXPECT_EQ(r.code, 1) << r.out;
  EXPECT_NE(r.out.find("(rados)"), std::string::npos) << r.out;

  r = Sh("bash " + script + " osd-start " + cluster);
  ASSERT_EQ(r.code, 0) << r.out;
  r = Cli(a.Address(), "window walk" + box + " --json");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_EQ(json::parse(r.out)["points"].get<uint64_t>(), points);  // the refused edit left nothing
  r = Cli(a.Address(), "edit walk --delete-box -9 9 -1.0 -0.9 -9 9 0 1");
  EXPECT_EQ(r.code, 0) << r.out;
  r = Cli(a.Address(), "describe walk --json");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_LT(json::parse(r.out)["points"].get<uint64_t>(), points);
}

// A server on the pool starts, serves and stops on SIGTERM with status 0, again and again: an
// executable that exported its Boost.Asio statics had librados bind to them, and Ceph's
// io_context_pool thread then aborted in rados_shutdown ("free(): invalid pointer") at every
// exit once OpenCV's imgcodecs no longer happened to be loaded (CMakeLists.txt, --exclude-libs).
TEST_F(RadosServerTest, StartsAndStopsCleanly) {
  for (int round = 0; round < 3; ++round) {
    RadosServer server("clean" + std::to_string(round) + "-", store_,
                       data_ + "-" + std::to_string(round), work_);
    ASSERT_EQ(server.Start(), "") << server.Log();
    ShRun ping = Cli(server.Address(), "ping");
    EXPECT_EQ(ping.code, 0) << ping.out << server.Log();
    const int st = server.Kill(SIGTERM);
    ASSERT_TRUE(WIFEXITED(st)) << "round " << round << ": the server died of signal "
                               << (WIFSIGNALED(st) ? WTERMSIG(st) : 0) << "\n" << server.Log();
    EXPECT_EQ(WEXITSTATUS(st), 0) << server.Log();
    EXPECT_EQ(server.Log().find("invalid pointer"), std::string::npos) << server.Log();
  }
}

TEST_F(RadosServerTest, BadStoreIsAClearError) {
  ShRun r = Sh(std::string(HVDB_SERVER_PATH) + " --store rados:p --data x --listen 127.0.0.1:0");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("conf=FILE"), std::string::npos) << r.out;
  r = Sh(std::string(HVDB_SERVER_PATH) + " --store rados:p?conf=/nonexistent.conf --data x "
         "--listen 127.0.0.1:0");
  EXPECT_NE(r.code, 0);
  EXPECT_NE(r.out.find("/nonexistent.conf"), std::string::npos) << r.out;
}

}  // namespace
