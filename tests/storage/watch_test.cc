// Watches (storage/watch.h, Dataset::Watch): events in commit order with what each change did;
// a watch resumed from an LSN gets every later change exactly once, while a writer commits and
// checkpoints (log rotation) concurrently; a follower publishes the writer's changes; a drop
// ends watches. Also compiled into rados_tests.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <mutex>
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
using Kind = ChangeEvent::Kind;

// Collects events from the watch's callback (any thread).
// The kLive event that ends a watch's replay is kept apart.
struct Sink {
  std::mutex mu;
  std::vector<ChangeEvent> events;
  std::vector<uint64_t> live;  // kLive events' LSNs, with how many events came before each
  ChangeFn fn() {
    return [this](const ChangeEvent& ev) {
      std::lock_guard<std::mutex> l(mu);
      if (ev.kind == Kind::kLive) {
        live.push_back(ev.lsn);
        live.push_back(events.size());
      } else {
        events.push_back(ev);
      }
    };
  }
  std::vector<ChangeEvent> Take() {
    std::lock_guard<std::mutex> l(mu);
    return events;
  }
};

class WatchTest : public ::testing::Test {
 protected:
  Options Opts() {
    Options o;
    o.cache_bytes = 8u << 20;
    o.block_size = 4096;
    o.t0_points = 256;
    o.wal_checkpoint_bytes = 64u << 10;  // the log rotates often
#ifdef HVDB_TEST_RADOS
    o.env = testing::RadosTestEnv();
#endif
    return o;
  }
  void SetUp() override {
    auto db = Database::Open(dir_.path(), Opts());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(*db);
    DatasetInfo info;
    info.name = "video";
    info.fps = 10;
    auto ds = db_->CreateDataset(info);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    ds_ = *ds;
  }
  // A transaction inserting n points into `frame`.
  uint64_t Insert(Dataset& ds, uint32_t frame, size_t n) {
    Transaction t;
    t.Insert(RandomPoints(rng_, n, frame));
    auto c = ds.Commit(t);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? c->lsn : 0;
  }

  TempDir dir_;
  std::mt19937_64 rng_{42};
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
};

TEST_F(WatchTest, EventsSayWhatEachChangeDidInOrder) {
  Sink sink;
  auto w = ds_->Watch(std::nullopt, sink.fn());
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  auto bulk = ds_->BulkLoad(3, RandomPoints(rng_, 500, 3));
  ASSERT_TRUE(bulk.ok());
  Transaction t;
  t.Insert(RandomPoints(rng_, 7, 1));
  t.Insert(RandomPoints(rng_, 5, 4));
  auto c = ds_->Commit(t);
  ASSERT_TRUE(c.ok());
  Transaction label;
  Selection all;
  label.SetLabel(all, 1, true);
  auto l = ds_->Commit(label);
  ASSERT_TRUE(l.ok());
  auto r = ds_->Revert(l->lsn);
  ASSERT_TRUE(r.ok()) << r.status().ToString();

  auto ev = sink.Take();
  ASSERT_EQ(ev.size(), 4u);
  EXPECT_EQ(ev[0].kind, Kind::kBulk);
  EXPECT_EQ(ev[0].lsn, 1u);  // a bulk load has an LSN of its own
  EXPECT_EQ(ev[0].frames, std::vector<uint32_t>{3});
  EXPECT_EQ(ev[0].points, 500u);
  EXPECT_EQ(ev[1].kind, Kind::kCommit);
  EXPECT_EQ(ev[1].lsn, c->lsn);
  EXPECT_EQ(ev[1].frames, (std::vector<uint32_t>{1, 4}));
  EXPECT_EQ(ev[1].points, 12u);
  EXPECT_EQ(ev[2].lsn, l->lsn);
  EXPECT_EQ(ev[2].frames, (std::vector<uint32_t>{1, 3, 4}));
  // A relabel removes and adds each point whose label changes.
  EXPECT_GT(ev[2].points, 0u);
  EXPECT_EQ(ev[2].removed, ev[2].points);
  EXPECT_EQ(ev[3].kind, Kind::kRevert);
  EXPECT_EQ(ev[3].reverts, l->lsn);
  EXPECT_EQ(ev[3].removed, ev[2].points);
  for (const auto& e : ev) EXPECT_EQ(e.dataset, "video");
  // Which changes only flipped labels (a graph cut's cache keeps its graph through those).
  EXPECT_FALSE(ev[0].labels_only);
  EXPECT_FALSE(ev[1].labels_only);
  EXPECT_EQ(ev[1].label_bits, 0u);
  EXPECT_TRUE(ev[2].labels_only);
  EXPECT_EQ(ev[2].label_bits, 1u);
  EXPECT_TRUE(ev[3].labels_only);
  EXPECT_EQ(ev[3].label_bits, 1u);
  EXPECT_STREQ(ChangeKindName(ev[0].kind), "bulk");
  EXPECT_EQ(ds_->Info().last_lsn, r->lsn);
}

TEST_F(WatchTest, ResumeFromAnLsnLosesAndRepeatsNothingWhileTheWriterGoesOn) {
  // History across several log segments first.
  uint64_t last = 0;
  for (int i = 0; i < 40; ++i) last = Insert(*ds_, static_cast<uint32_t>(i % 5), 60);
  // The merger rotates the log in the background, after the commit that asked for it: on a
  // loaded machine (or RADOS) it may not have yet. Wait for it, up to 30 s.
  for (int i = 0; i < 600 && ds_->Stats().checkpoints == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  ASSERT_GT(ds_->Stats().checkpoints, 0u) << "the test needs rotated log segments";
  for (uint64_t from : {uint64_t{0}, uint64_t{1}, uint64_t{17}, last - 1, last}) {
    SCOPED_TRACE("from_lsn " + std::to_string(from));
    Sink sink;
    // A writer goes on while the watch replays and turns live.
    std::atomic<bool> stop{false};
    std::atomic<uint64_t> written{last};
    std::thread writer([&] {
      std::mt19937_64 rng(from);
      for (int i = 0; i < 30 && !stop; ++i) {
        Transaction t;
        t.Insert(RandomPoints(rng, 50, static_cast<uint32_t>(i % 3)));
        auto c = ds_->Commit(t);
        ASSERT_TRUE(c.ok());
        written = c->lsn;
        if (i % 10 == 5) {
          ASSERT_TRUE(ds_->Checkpoint().ok());
        }
      }
    });
    auto w = ds_->Watch(from, sink.fn());
    ASSERT_TRUE(w.ok()) << w.status().ToString();
    writer.join();
    last = written;
    auto ev = sink.Take();
    ASSERT_EQ(ev.size(), last - from);
    for (size_t i = 0; i < ev.size(); ++i) ASSERT_EQ(ev[i].lsn, from + 1 + i);
    // One kLive event, after the replayed ones (those up to its LSN).
    ASSERT_EQ(sink.live.size(), 2u);
    EXPECT_EQ(sink.live[1], sink.live[0] - from);
  }
}

TEST_F(WatchTest, AResumePastTheLastLsnIsAnError) {
  Insert(*ds_, 0, 10);
  Sink sink;
  auto w = ds_->Watch(5, sink.fn());
  ASSERT_FALSE(w.ok());
  EXPECT_TRUE(w.status().IsInvalidArgument());
  EXPECT_NE(w.status().message().find("past"), std::string::npos) << w.status().ToString();
}

TEST_F(WatchTest, UnsubscribedWatchGetsNothingMore) {
  Sink sink;
  {
    auto w = ds_->Watch(std::nullopt, sink.fn());
    ASSERT_TRUE(w.ok());
    Insert(*ds_, 0, 10);
  }
  Insert(*ds_, 0, 10);
  EXPECT_EQ(sink.Take().size(), 1u);
}

TEST_F(WatchTest, ADropEndsWatchesWithADroppedEvent) {
  Sink sink, all;
  auto w = ds_->Watch(std::nullopt, sink.fn());
  ASSERT_TRUE(w.ok());
  auto wa = db_->WatchAll(all.fn());
  Insert(*ds_, 0, 10);
  ASSERT_TRUE(db_->DropDataset("video").ok());
  auto ev = sink.Take();
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[1].kind, Kind::kDropped);
  EXPECT_TRUE((*w)->ended());
  auto ea = all.Take();
  ASSERT_EQ(ea.size(), 2u);
  EXPECT_EQ(ea[1].kind, Kind::kDropped);
  EXPECT_EQ(ea[1].dataset, "video");
}

TEST_F(WatchTest, WatchAllSeesEveryOpenDataset) {
  DatasetInfo info;
  info.name = "other";
  auto other = db_->CreateDataset(info);
  ASSERT_TRUE(other.ok());
  Sink all;
  auto w = db_->WatchAll(all.fn());
  Insert(*ds_, 0, 3);
  Insert(**other, 2, 4);
  auto ev = all.Take();
  ASSERT_EQ(ev.size(), 2u);
  EXPECT_EQ(ev[0].dataset, "video");
  EXPECT_EQ(ev[1].dataset, "other");
  EXPECT_EQ(ev[1].points, 4u);
}

TEST_F(WatchTest, BulkLoadLsnsSurviveReopenAndReplayFromTheLog) {
  ASSERT_TRUE(ds_->BulkLoad(0, RandomPoints(rng_, 100, 0)).ok());
  Insert(*ds_, 1, 10);
  ASSERT_TRUE(ds_->BulkLoad(2, RandomPoints(rng_, 30, 2)).ok());
  ds_.reset();
  db_.reset();
  auto db = Database::Open(dir_.path(), Opts());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("video");
  ASSERT_TRUE(ds.ok());
  EXPECT_EQ((*ds)->Info().last_lsn, 3u);
  Sink sink;
  auto w = (*ds)->Watch(0, sink.fn());
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  auto ev = sink.Take();
  ASSERT_EQ(ev.size(), 3u);
  EXPECT_EQ(ev[0].kind, Kind::kBulk);
  EXPECT_EQ(ev[0].points, 100u);
  EXPECT_EQ(ev[1].kind, Kind::kCommit);
  EXPECT_EQ(ev[2].kind, Kind::kBulk);
  EXPECT_EQ(ev[2].frames, std::vector<uint32_t>{2});
  EXPECT_EQ(Insert(**ds, 0, 1), 4u);
}

TEST_F(WatchTest, AFollowerPublishesTheWritersChanges) {
  Insert(*ds_, 0, 10);
  Options o = Opts();
  o.follow = true;
  auto fdb = Database::Open(dir_.path(), o);
  ASSERT_TRUE(fdb.ok()) << fdb.status().ToString();
  ASSERT_TRUE((*fdb)->follower());
  auto f = (*fdb)->GetDataset("video");
  ASSERT_TRUE(f.ok());
  Sink sink;
  auto w = (*f)->Watch(0, sink.fn());
  ASSERT_TRUE(w.ok());
  ASSERT_EQ(sink.Take().size(), 1u);
  // Tailing the log, then a reload after a checkpoint rotated it.
  Insert(*ds_, 1, 10);
  ASSERT_TRUE(ds_->BulkLoad(4, RandomPoints(rng_, 20, 4)).ok());
  ASSERT_TRUE((*fdb)->Refresh().ok());
  Insert(*ds_, 2, 10);
  ASSERT_TRUE(ds_->Checkpoint().ok());
  Insert(*ds_, 3, 10);
  ASSERT_TRUE((*fdb)->Refresh().ok());
  auto ev = sink.Take();
  ASSERT_EQ(ev.size(), 5u);
  for (size_t i = 0; i < ev.size(); ++i) EXPECT_EQ(ev[i].lsn, i + 1);
  EXPECT_EQ(ev[2].kind, Kind::kBulk);
  EXPECT_EQ(ev[2].points, 20u);
  EXPECT_EQ((*f)->Info().last_lsn, ds_->Info().last_lsn);
  // The writer drops it: the follower's next look ends the watch.
  ASSERT_TRUE(db_->DropDataset("video").ok());
  ASSERT_TRUE((*fdb)->Refresh().ok());
  ev = sink.Take();
  ASSERT_EQ(ev.size(), 6u);
  EXPECT_EQ(ev[5].kind, Kind::kDropped);
}

}  // namespace
}  // namespace hvdb
