// The RADOS store (storage/rados_env.h) against a real one-node Ceph cluster (CTest fixture
// `ceph`: scripts/ceph-dev.sh): each Env operation as the POSIX store behaves, directory
// listings from omap, big objects in pieces, the lock's exclusivity and lease.
#include <chrono>
#include <cstring>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "storage/rados_env.h"
#include "tests/storage/rados_test_util.h"

namespace hvdb {
namespace {

class RadosEnvTest : public ::testing::Test {
 protected:
  void SetUp() override {
    env_ = testing::RadosTestEnv();
    ASSERT_NE(env_, nullptr);
    // A fresh prefix per test.
    dir_ = "rados-env-test/" + std::string(::testing::UnitTest::GetInstance()->current_test_info()->name()) +
           "-" + std::to_string(std::random_device{}());
    ASSERT_TRUE(env_->CreateDirs(dir_).ok());
  }
  void TearDown() override {
    if (env_) {
      EXPECT_TRUE(env_->RemoveTree(dir_).ok());
    }
  }
  std::string P(const std::string& n) const { return dir_ + "/" + n; }
  std::string ReadAll(const std::string& path) {
    auto f = env_->OpenRead(path);
    EXPECT_TRUE(f.ok()) << f.status().ToString();
    if (!f.ok()) return "";
    std::string s((*f)->size(), '\0');
    EXPECT_TRUE((*f)->Read(0, s.size(), s.data()).ok());
    return s;
  }

  Env* env_ = nullptr;
  std::string dir_;
};

TEST_F(RadosEnvTest, WriteAppendReadTruncate) {
  auto w = env_->OpenWrite(P("a"), true);
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  ASSERT_TRUE((*w)->Append("hello ").ok());
  ASSERT_TRUE((*w)->Append("world").ok());
  ASSERT_TRUE((*w)->WriteAt(0, "H").ok());
  ASSERT_TRUE((*w)->WriteAt(14, "!").ok());  // past the end: the gap reads as zeros
  ASSERT_TRUE((*w)->Sync().ok());
  EXPECT_EQ((*w)->size(), 15u);
  EXPECT_EQ(ReadAll(P("a")), std::string("Hello world\0\0\0!", 15));
  ASSERT_TRUE((*w)->Truncate(5).ok());
  EXPECT_EQ(ReadAll(P("a")), "Hello");
  // Reopened for appending: continues at the end.
  auto w2 = env_->OpenWrite(P("a"), false);
  ASSERT_TRUE(w2.ok());
  EXPECT_EQ((*w2)->size(), 5u);
  ASSERT_TRUE((*w2)->Append("!").ok());
  EXPECT_EQ(ReadAll(P("a")), "Hello!");
  // A read past the end is a truncation, a missing object NotFound.
  auto f = env_->OpenRead(P("a"));
  ASSERT_TRUE(f.ok());
  char buf[10];
  EXPECT_TRUE((*f)->Read(0, 10, buf).IsCorruption());
  EXPECT_EQ(env_->OpenRead(P("missing")).status().code(), StatusCode::kNotFound);
}

TEST_F(RadosEnvTest, ReadBatchScattersInParallel) {
  std::string data(3 << 20, '\0');
  std::mt19937 rng(1);
  for (char& c : data) c = static_cast<char>(rng());
  ASSERT_TRUE(env_->WriteNewFile(P("blocks"), data, true).ok());
  auto f = env_->OpenRead(P("blocks"));
  ASSERT_TRUE(f.ok());
  std::vector<std::vector<uint8_t>> bufs(64, std::vector<uint8_t>(4096));
  std::vector<uint8_t> tail(8192);
  std::vector<ReadRequest> reqs(33);
  for (int i = 0; i < 32; ++i) {
    reqs[i].offset = static_cast<uint64_t>(i) * 65536;
    reqs[i].buffers = {bufs[2 * i], bufs[2 * i + 1]};
  }
  reqs[32].offset = data.size() - 4096;  // runs past the end: truncated
  reqs[32].buffers = {tail};
  (*f)->ReadBatch(reqs);
  for (int i = 0; i < 32; ++i) {
    ASSERT_TRUE(reqs[i].status.ok()) << reqs[i].status.ToString();
    EXPECT_EQ(std::memcmp(bufs[2 * i].data(), data.data() + i * 65536, 4096), 0);
    EXPECT_EQ(std::memcmp(bufs[2 * i + 1].data(), data.data() + i * 65536 + 4096, 4096), 0);
  }
  EXPECT_TRUE(reqs[32].status.IsCorruption());
}

TEST_F(RadosEnvTest, BigObjectsGoInPieces) {
  std::string data(40u << 20, '\0');
  for (size_t i = 0; i < data.size(); i += 4096) data[i] = static_cast<char>(i >> 12);
  ASSERT_TRUE(env_->WriteNewFile(P("big"), data, true).ok());
  EXPECT_EQ(ReadAll(P("big")), data);
}

TEST_F(RadosEnvTest, DirectoriesRenameRemove) {
  ASSERT_TRUE(env_->CreateDirs(P("d1/d2")).ok());
  ASSERT_TRUE(env_->WriteNewFile(P("d1/x"), "1", true).ok());
  ASSERT_TRUE(env_->WriteNewFile(P("d1/d2/y"), "2", true).ok());
  auto list = env_->ListDir(P("d1"));
  ASSERT_TRUE(list.ok());
  EXPECT_EQ(*list, (std::vector<std::string>{"d2", "x"}));
  EXPECT_TRUE(env_->Exists(P("d1/d2")));
  EXPECT_TRUE(env_->Exists(P("d1/x")));
  EXPECT_FALSE(env_->Exists(P("d1/z")));
  // Rename replaces the target; the source is gone from the listing.
  ASSERT_TRUE(env_->WriteNewFile(P("d1/z"), "old", true).ok());
  ASSERT_TRUE(env_->Rename(P("d1/x"), P("d1/z")).ok());
  EXPECT_EQ(ReadAll(P("d1/z")), "1");
  EXPECT_FALSE(env_->Exists(P("d1/x")));
  EXPECT_EQ(*env_->ListDir(P("d1")), (std::vector<std::string>{"d2", "z"}));
  EXPECT_TRUE(env_->Remove(P("d1/absent")).ok());
  ASSERT_TRUE(env_->RemoveTree(P("d1")).ok());
  EXPECT_FALSE(env_->Exists(P("d1")));
  EXPECT_FALSE(env_->Exists(P("d1/d2/y")));
  EXPECT_EQ(*env_->ListDir(dir_), std::vector<std::string>{});
  // Paths are normalised as the file system would: "a//./b" is "a/b".
  ASSERT_TRUE(env_->WriteNewFile(dir_ + "//./n", "n", true).ok());
  EXPECT_EQ(ReadAll(P("n")), "n");
}

TEST_F(RadosEnvTest, LockIsExclusiveAndALeaseThatRuns) {
  // A second client (its own connection) cannot take the lock while the first holds it.
  RadosSpec spec;
  spec.pool = "hvdb-tests";
  spec.conf = testing::CephConf();
  spec.lock_lease = std::chrono::seconds(6);
  auto other = OpenRadosEnv(spec);
  ASSERT_TRUE(other.ok()) << other.status().ToString();
  {
    auto held = env_->Lock(P("LOCK"));
    ASSERT_TRUE(held.ok()) << held.status().ToString();
    // Held past its lease: the holder renews it.
    std::this_thread::sleep_for(std::chrono::seconds(8));
    auto second = (*other)->Lock(P("LOCK"));
    EXPECT_FALSE(second.ok());
    EXPECT_NE(second.status().message().find("held by another process"), std::string::npos);
  }
  // Released: the other client gets it.
  auto again = (*other)->Lock(P("LOCK"));
  EXPECT_TRUE(again.ok()) << again.status().ToString();
}

TEST(RadosSpecTest, ParsesAndRefuses) {
  RadosSpec s;
  ASSERT_TRUE(ParseRadosSpec("rados:hvdb?conf=/etc/ceph/ceph.conf&lease=10", &s).ok());
  EXPECT_EQ(s.pool, "hvdb");
  EXPECT_EQ(s.conf, "/etc/ceph/ceph.conf");
  EXPECT_EQ(s.lock_lease.count(), 10);
  EXPECT_TRUE(ParseRadosSpec("rados:hvdb", &s).IsInvalidArgument());
  EXPECT_TRUE(ParseRadosSpec("rados:?conf=x", &s).IsInvalidArgument());
  EXPECT_TRUE(ParseRadosSpec("file:x", &s).IsInvalidArgument());
  EXPECT_TRUE(ParseRadosSpec("rados:p?conf=x&lease=1", &s).IsInvalidArgument());
  EXPECT_TRUE(ParseRadosSpec("rados:p?conf=x&color=red", &s).IsInvalidArgument());
  EXPECT_FALSE(OpenRadosEnv(RadosSpec{"p", "/nonexistent/ceph.conf"}).ok());
}

}  // namespace
}  // namespace hvdb
