// Followers (database.h): a second Database on a directory another one writes. Differential:
// after every random step of the writer (commits, reverts, bulk loads, merges, checkpoints) and
// a Refresh, the follower answers exactly what the writer answers. Also compiled into
// rados_tests, where both sit on a RADOS pool.
#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <map>
#include <random>
#include <thread>

#include "storage/database.h"
#include "tests/storage/test_util.h"
#ifdef HVDB_TEST_RADOS
#include "tests/storage/rados_test_util.h"
#endif

namespace hvdb {
namespace {

using testing::RandomPoints;
using testing::TempDir;

constexpr double kFps = 10.0;

// (frame, id) -> the 64-byte record, of everything a query returns.
std::map<std::pair<uint32_t, uint64_t>, std::string> Dump(Dataset& ds) {
  std::map<std::pair<uint32_t, uint64_t>, std::string> out;
  auto c = ds.Query(testing::EverythingWindow());
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  if (!c.ok()) return out;
  Batch b;
  for (;;) {
    auto more = (*c)->Next(&b);
    EXPECT_TRUE(more.ok()) << more.status().ToString();
    if (!more.ok() || !*more) break;
    for (const Point& p : b.points) {
      std::string rec(kPointRecordSize, '\0');
      EncodePoints(std::span<const Point>(&p, 1), reinterpret_cast<uint8_t*>(rec.data()));
      EXPECT_TRUE(out.emplace(std::make_pair(p.frame, p.id), rec).second) << "duplicate " << p.id;
    }
  }
  return out;
}

class FollowerTest : public ::testing::Test {
 protected:
  Options Opts() {
    Options o;
    o.cache_bytes = 8u << 20;
    o.block_size = 4096;
    o.t0_points = 256;  // merges happen all the time
#ifdef HVDB_TEST_RADOS
    o.env = testing::RadosTestEnv();
#endif
    return o;
  }
  std::unique_ptr<Database> OpenDb(bool follow) {
    Options o = Opts();
    o.follow = follow;
    auto db = Database::Open(dir_.path(), o);
    EXPECT_TRUE(db.ok()) << db.status().ToString();
    return db.ok() ? std::move(*db) : nullptr;
  }
  void SetUp() override {
    writer_ = OpenDb(false);
    ASSERT_TRUE(writer_);
    DatasetInfo info;
    info.name = "video";
    info.fps = kFps;
    auto ds = writer_->CreateDataset(info);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    w_ = *ds;
    ASSERT_TRUE(w_->BulkLoad(0, RandomPoints(rng_, 900, 0)).ok());
    follower_db_ = OpenDb(true);
    ASSERT_TRUE(follower_db_);
    ASSERT_TRUE(follower_db_->follower());
    auto f = follower_db_->GetDataset("video");
    ASSERT_TRUE(f.ok()) << f.status().ToString();
    f_ = *f;
  }
  void ExpectSame() {
    Status st = follower_db_->Refresh();
    ASSERT_TRUE(st.ok()) << st.ToString();
    EXPECT_EQ(f_->Info().last_lsn, w_->Info().last_lsn);
    auto want = Dump(*w_), got = Dump(*f_);
    size_t missing = 0, extra = 0, differ = 0;
    for (const auto& [k, v] : want) {
      auto it = got.find(k);
      if (it == got.end()) {
        ++missing;
      } else if (it->second != v) {
        ++differ;
      }
    }
    for (const auto& [k, v] : got) extra += want.count(k) ? 0 : 1;
    EXPECT_TRUE(missing == 0 && extra == 0 && differ == 0)
        << "the follower lacks " << missing << " points, has " << extra << " more and "
        << differ << " different, of " << want.size();
  }

  TempDir dir_;
  std::mt19937_64 rng_{20261125};
  std::unique_ptr<Database> writer_, follower_db_;
  std::shared_ptr<Dataset> w_, f_;
};

TEST_F(FollowerTest, AnswersWhatTheWriterAnswersAfterEveryStep) {
  ExpectSame();
  std::vector<uint64_t> lsns;
  for (int step = 0; step < 40; ++step) {
    const int kind = static_cast<int>(rng_() % 8);
    const uint32_t frame = static_cast<uint32_t>(rng_() % 4);
    if (kind <= 2) {  // inserts over two frames
      Transaction t;
      t.Insert(RandomPoints(rng_, 60 + rng_() % 200, frame));
      t.Insert(RandomPoints(rng_, 30, (frame + 1) % 4));
      auto c = w_->Commit(t);
      ASSERT_TRUE(c.ok()) << c.status().ToString();
      lsns.push_back(c->lsn);
    } else if (kind == 3) {  // a region deleted, another moved and relabelled
      Selection del;
      Window box = testing::FrameWindow(frame, kFps);
      box.lo[0] = 0;
      box.hi[0] = 2;
      del.region = box;
      Selection all;
      all.region = testing::FrameWindow((frame + 2) % 4, kFps);
      Affine4 move;
      move.c = {0.5, 0, 0, 0};
      Transaction t;
      t.DeleteSelection(del);
      t.Transform(all, move);
      t.SetLabel(all, 0x100, true);
      auto c = w_->Commit(t);
      ASSERT_TRUE(c.ok()) << c.status().ToString();
      lsns.push_back(c->lsn);
    } else if (kind == 4 && !lsns.empty()) {  // undo of the last transaction
      auto c = w_->Revert(lsns.back());
      lsns.pop_back();
      if (c.ok()) lsns.push_back(c->lsn);
    } else if (kind == 5) {
      ASSERT_TRUE(w_->BulkLoad(frame, RandomPoints(rng_, 500, frame)).ok());
    } else if (kind == 7) {  // into the cold tier (a later write brings it back)
      ASSERT_TRUE(w_->Compact(frame, frame).ok());
    } else {
      ASSERT_TRUE(w_->WaitForMerges().ok());
      ASSERT_TRUE(w_->Checkpoint().ok());
    }
    SCOPED_TRACE("step " + std::to_string(step) + " kind " + std::to_string(kind));
    ExpectSame();
    if (HasFatalFailure()) return;
  }
  EXPECT_GT(w_->Stats().merges, 0u);
}

TEST_F(FollowerTest, FollowsACompactionWithoutAReload) {
  ExpectSame();
  auto c = w_->Compact(0, 0);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->frames, 1u);
  ExpectSame();
  // The tier marker moved it to the new tree: the writer's old files are gone, and the
  // follower reads the compressed one.
  EXPECT_EQ(f_->Stats().cold_frames, 1u);
  EXPECT_EQ(f_->Stats().cold_tree_bytes, w_->Stats().cold_tree_bytes);
}

TEST_F(FollowerTest, RefusesWritesWithNotLeader) {
  Transaction t;
  t.Insert(RandomPoints(rng_, 5, 0));
  EXPECT_EQ(f_->Commit(t).status().code(), StatusCode::kNotLeader);
  EXPECT_EQ(f_->BulkLoad(1, RandomPoints(rng_, 5, 1)).status().code(), StatusCode::kNotLeader);
  EXPECT_EQ(f_->Revert(1).status().code(), StatusCode::kNotLeader);
  DatasetInfo info;
  info.name = "other";
  EXPECT_EQ(follower_db_->CreateDataset(info).status().code(), StatusCode::kNotLeader);
  EXPECT_EQ(follower_db_->DropDataset("video").code(), StatusCode::kNotLeader);
  // Nothing of it reached the files: the writer sees its own data only.
  ExpectSame();
  EXPECT_EQ(writer_->ListDatasets(), std::vector<std::string>{"video"});
}

TEST_F(FollowerTest, PublishesTheWritersAddress) {
  ASSERT_TRUE(writer_->SetLeaderAddress("127.0.0.1:7001").ok());
  ASSERT_TRUE(follower_db_->Refresh().ok());
  EXPECT_EQ(follower_db_->Leader(), "127.0.0.1:7001");
  EXPECT_EQ(follower_db_->SetLeaderAddress("x").code(), StatusCode::kNotLeader);
}

// A damaged LEADER file: a follower refuses to open (or refresh) with an error naming it, and
// the writer and its data are untouched.
TEST_F(FollowerTest, ADamagedLeaderFileIsAClearError) {
  Options o = Opts();
  Env* env = o.env ? o.env : Env::Default();
  const std::string leader = dir_.path() + "/LEADER";
  auto good = ReadWholeFile(env, leader);
  ASSERT_TRUE(good.ok()) << good.status().ToString();
  std::string bad = *good;
  bad[bad.size() / 2] ^= 0x40;
  ASSERT_TRUE(WriteFileAtomic(env, leader, bad).ok());
  Status st = follower_db_->Refresh();
  EXPECT_EQ(st.code(), StatusCode::kCorruption) << st.ToString();
  EXPECT_NE(st.message().find("LEADER"), std::string::npos) << st.ToString();
  o.follow = true;
  auto another = Database::Open(dir_.path(), o);
  ASSERT_FALSE(another.ok());
  EXPECT_NE(another.status().message().find("LEADER"), std::string::npos);
  // The writer goes on, and publishing its address repairs the file.
  Transaction t;
  t.Insert(RandomPoints(rng_, 10, 1));
  ASSERT_TRUE(w_->Commit(t).ok());
  ASSERT_TRUE(writer_->SetLeaderAddress("127.0.0.1:7001").ok());
  ExpectSame();
}

TEST_F(FollowerTest, TakesOverOnceTheWriterIsGone) {
  auto promoted = follower_db_->TryPromote();
  ASSERT_TRUE(promoted.ok());
  EXPECT_FALSE(*promoted) << "the writer still holds the directory";
  Transaction t;
  t.Insert(RandomPoints(rng_, 100, 2));
  ASSERT_TRUE(w_->Commit(t).ok());
  auto want = Dump(*w_);
  const uint64_t lsn = w_->Info().last_lsn;
  w_.reset();
  writer_.reset();  // releases the lock
  promoted = follower_db_->TryPromote();
  ASSERT_TRUE(promoted.ok()) << promoted.status().ToString();
  ASSERT_TRUE(*promoted);
  EXPECT_FALSE(follower_db_->follower());
  EXPECT_EQ(Dump(*f_), want);
  EXPECT_EQ(f_->Info().last_lsn, lsn);
  // It writes now, and what it writes survives its reopening.
  Transaction more;
  more.Insert(RandomPoints(rng_, 50, 3));
  auto c = f_->Commit(more);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->lsn, lsn + 1);
  want = Dump(*f_);
  f_.reset();
  follower_db_.reset();
  writer_ = OpenDb(false);
  ASSERT_TRUE(writer_);
  auto ds = writer_->GetDataset("video");
  ASSERT_TRUE(ds.ok());
  EXPECT_EQ(Dump(**ds), want);
}

TEST_F(FollowerTest, ForgetsADroppedDataset) {
  w_.reset();
  ASSERT_TRUE(writer_->DropDataset("video").ok());
  f_.reset();
  ASSERT_TRUE(follower_db_->Refresh().ok());
  EXPECT_TRUE(follower_db_->GetDataset("video").status().IsNotFound());
  EXPECT_TRUE(follower_db_->ListDatasets().empty());
}

// Queries on the follower while the writer commits: every answer is the state after some
// whole commit (generation g replaces generation g-1 in three frames at once), and answers
// never go back in time.
TEST_F(FollowerTest, QueriesSeeWholeCommitsOnly) {
  std::atomic<bool> stop{false};
  std::atomic<int> written{0};
  std::thread writer([&] {
    std::mt19937_64 rng(7);
    for (uint32_t g = 1; g <= 60 && !stop; ++g) {
      Transaction t;
      Selection old;
      old.label_mask = 1u << 20;
      t.DeleteSelection(old);
      for (uint32_t f = 0; f < 3; ++f) {
        auto pts = RandomPoints(rng, 100, f);
        for (Point& p : pts) p.label = (1u << 20) | g;
        t.Insert(std::move(pts));
      }
      auto c = w_->Commit(t);
      ASSERT_TRUE(c.ok()) << c.status().ToString();
      written = static_cast<int>(g);
      if (g % 20 == 0) {
        ASSERT_TRUE(w_->Checkpoint().ok());
      }
    }
  });
  struct Join {  // the writer thread ends before the test does, whatever fails
    std::atomic<bool>& stop;
    std::thread& t;
    ~Join() {
      stop = true;
      if (t.joinable()) t.join();
    }
  } join{stop, writer};
  uint32_t last_seen = 0;
  int answers = 0;
  while (written < 60 && !HasFailure()) {
    Status st = follower_db_->Refresh();
    ASSERT_TRUE(st.ok()) << st.ToString();
    QueryOptions qo;
    qo.label_mask = 1u << 20;
    auto c = f_->Query(testing::EverythingWindow(), qo);
    ASSERT_TRUE(c.ok());
    std::map<uint32_t, int> per_generation;
    Batch b;
    while (*(*c)->Next(&b)) {
      for (const Point& p : b.points) ++per_generation[p.label & 0xFFFF];
    }
    if (per_generation.empty()) continue;  // before the first commit
    ASSERT_EQ(per_generation.size(), 1u) << "a query saw two generations at once";
    EXPECT_EQ(per_generation.begin()->second, 300) << "a query saw part of a commit";
    EXPECT_GE(per_generation.begin()->first, last_seen) << "answers went back in time";
    last_seen = per_generation.begin()->first;
    ++answers;
  }
  stop = true;
  writer.join();
  EXPECT_GT(answers, 3);
  ExpectSame();
}

TEST_F(FollowerTest, ReplacedTreesOutliveTheirGrace) {
  // A writer that keeps replaced trees for 400 ms: a follower's query that started on the old
  // state reads them after a checkpoint replaced them.
  w_.reset();
  f_.reset();
  follower_db_.reset();
  writer_.reset();
  Options o = Opts();
  o.retired_grace_ms = 400;
  auto w = Database::Open(dir_.path(), o);
  ASSERT_TRUE(w.ok());
  writer_ = std::move(*w);
  w_ = *writer_->GetDataset("video");
  follower_db_ = OpenDb(true);
  f_ = *follower_db_->GetDataset("video");
  auto want = Dump(*f_);
  auto c = f_->Query(testing::EverythingWindow());
  ASSERT_TRUE(c.ok());
  // More than the level of the frame's one tree holds (fan-out 2 or the default 4, T0 at 256
  // points): the load takes that tree into its own.
  ASSERT_TRUE(w_->BulkLoad(0, RandomPoints(rng_, 1500, 0)).ok());
  Options io = Opts();
  Env* env = io.env ? io.env : Env::Default();
  const std::string trees = dir_.path() + "/video/trees";
  EXPECT_EQ(env->ListDir(trees)->size(), 2u) << "the replaced tree is kept";
  std::map<std::pair<uint32_t, uint64_t>, std::string> got;
  Batch b;
  while (*(*c)->Next(&b)) {
    for (const Point& p : b.points) got[{p.frame, p.id}];
  }
  EXPECT_EQ(got.size(), want.size());
  c->reset();
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  EXPECT_EQ(env->ListDir(trees)->size(), 1u) << "deleted once its grace ran out";
  ExpectSame();
}

}  // namespace
}  // namespace hvdb
