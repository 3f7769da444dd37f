// Differential tests of the engine against a brute-force model: random inserts, deletes,
// label changes and transforms interleaved with window and slice queries at every level.
#include <gtest/gtest.h>
#include <atomic>

#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <set>
#include <thread>

#include "storage/database.h"
#include "storage/hyperslice.h"
#include "tests/storage/test_util.h"
#ifdef HVDB_TEST_RADOS
#include "tests/storage/rados_test_util.h"
#endif

namespace hvdb {
namespace {

using testing::RandomPoints;
using testing::TempDir;

constexpr double kFps = 10.0;

using Model = std::map<uint32_t, std::map<uint64_t, Point>>;  // frame -> id -> point

std::vector<Point> RunQuery(Dataset& ds, const Region& r, QueryOptions o = {}) {
  auto c = ds.Query(r, o);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  std::vector<Point> out;
  if (!c.ok()) return out;
  Batch b;
  for (;;) {
    auto more = (*c)->Next(&b);
    EXPECT_TRUE(more.ok()) << more.status().ToString();
    if (!more.ok() || !*more) break;
    EXPECT_LE(b.points.size(), o.batch_points + 2 * 1024);
    out.insert(out.end(), b.points.begin(), b.points.end());
  }
  return out;
}

Window Everything() { return testing::EverythingWindow(); }

Window FrameWindow(uint32_t f) { return testing::FrameWindow(f, kFps); }

std::set<std::pair<uint32_t, uint64_t>> Keys(const std::vector<Point>& pts) {
  std::set<std::pair<uint32_t, uint64_t>> s;
  for (const Point& p : pts) EXPECT_TRUE(s.insert({p.frame, p.id}).second) << "duplicate " << p.id;
  return s;
}

class DatasetTest : public ::testing::Test {
 protected:
  void Open(Options o = {}) {
    ds_.reset();
    db_.reset();
    o.cache_bytes = 8u << 20;
    o.block_size = 4096;
    o.t0_points = 64;  // merges are frequent
#ifdef HVDB_TEST_RADOS
    // The same tests on a RADOS pool (rados_tests): the data directory is a name prefix there.
    o.env = testing::RadosTestEnv();
#endif
    o.max_slice_frames = 1000;
    auto db = Database::Open(dir_.path(), o);
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(*db);
    auto ds = db_->GetDataset("video");
    if (!ds.ok()) {
      DatasetInfo info;
      info.name = "video";
      info.fps = kFps;
      info.space_time_scale = 2.0;
      ds = db_->CreateDataset(info);
    }
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    ds_ = *ds;
  }

  void Commit(const Transaction& t, CommitInfo* info = nullptr) {
    auto r = ds_->Commit(t);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    if (info) *info = *r;
  }

  void InsertRandom(std::mt19937_64& rng, size_t n) {
    std::vector<Point> pts;
    std::uniform_int_distribution<uint32_t> frame(0, 7);
    for (size_t i = 0; i < n; ++i) pts.push_back(testing::RandomPoint(rng, frame(rng)));
    Transaction t;
    t.Insert(pts);
    CommitInfo info;
    Commit(t, &info);
    ASSERT_EQ(info.assigned_ids.size(), pts.size());
    for (size_t i = 0; i < pts.size(); ++i) {
      pts[i].id = info.assigned_ids[i];
      model_[pts[i].frame][pts[i].id] = pts[i];
    }
  }

  std::vector<Point> ModelPoints(const std::function<bool(const Point&)>& pred) const {
    std::vector<Point> out;
    for (const auto& [f, m] : model_) {
      for (const auto& [id, p] : m) {
        if (pred(p)) out.push_back(p);
      }
    }
    return out;
  }

  // Checks a window at every level against the model.
  void CheckWindow(const Window& w) {
    auto in = [&](const Point& p) {
      double t = p.frame / kFps;
      return p.x >= w.lo[0] && p.x <= w.hi[0] && p.y >= w.lo[1] && p.y <= w.hi[1] &&
             p.z >= w.lo[2] && p.z <= w.hi[2] && t >= w.lo[3] && t <= w.hi[3];
    };
    auto want = ModelPoints(in);
    auto got = RunQuery(*ds_, w);
    ASSERT_EQ(Keys(got), Keys(want));
    std::map<std::pair<uint32_t, uint64_t>, Point> byk;
    for (const Point& p : want) byk[{p.frame, p.id}] = p;
    for (const Point& p : got) {
      EXPECT_EQ(p, (byk[{p.frame, p.id}]));
    }
    // Coarser levels: the region's share of a full-frame read at that level, on the frames
    // that temporal LOD keeps.
    std::set<uint32_t> frames;
    for (const auto& [f, m] : model_) {
      if (!m.empty() && f / kFps >= w.lo[3] && f / kFps <= w.hi[3]) frames.insert(f);
    }
    for (int lod = 1; lod <= 5; ++lod) {
      QueryOptions o;
      o.lod = lod;
      auto coarse = RunQuery(*ds_, w, o);
      std::set<std::pair<uint32_t, uint64_t>> expect;
      for (uint32_t f : frames) {
        if (frames.size() > 1 && f % (1u << lod) != 0) continue;
        QueryOptions fo;
        fo.lod = lod;
        for (const Point& p : RunQuery(*ds_, FrameWindow(f), fo)) {
          if (in(p)) expect.insert({p.frame, p.id});
        }
      }
      EXPECT_EQ(Keys(coarse), expect) << "lod " << lod;
    }
  }

  void CheckSlice(const Slice& s, int lod = 0) {
    auto g = SliceGeometry::Make(s, 2.0);
    ASSERT_TRUE(g.ok());
    QueryOptions o;
    o.lod = lod;
    auto got = RunQuery(*ds_, s, o);
    std::map<std::pair<uint32_t, uint64_t>, Point> want;
    for (const Point& p : ModelPoints([&](const Point& p) {
           return g->Selects(p.x, p.y, p.z, p.frame / kFps);
         })) {
      Point q = p;
      g->Project(&q, p.frame / kFps, 1 / kFps);
      want[{p.frame, p.id}] = q;
    }
    if (lod == 0) {
      ASSERT_EQ(got.size(), want.size());
    }
    for (const Point& p : got) {
      auto it = want.find({p.frame, p.id});
      ASSERT_NE(it, want.end()) << "extra point " << p.id;
      if (lod == 0) {
        EXPECT_NEAR(p.x, it->second.x, 1e-5);
        EXPECT_NEAR(p.y, it->second.y, 1e-5);
        EXPECT_NEAR(p.z, it->second.z, 1e-5);
        for (int i = 0; i < 6; ++i) EXPECT_NEAR(p.cov[i], it->second.cov[i], 1e-7);
      }
    }
  }

  void CheckAll() {
    auto all = RunQuery(*ds_, Everything());
    EXPECT_EQ(Keys(all), Keys(ModelPoints([](const Point&) { return true; })));
  }

  TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
  Model model_;
};

TEST_F(DatasetTest, BulkLoadThenQueryEveryLevel) {
  Open();
  std::mt19937_64 rng(1);
  for (uint32_t f = 0; f < 4; ++f) {
    auto pts = RandomPoints(rng, 5000 + 1000 * f, f);
    auto n = ds_->BulkLoad(f, pts);
    ASSERT_TRUE(n.ok()) << n.status().ToString();
  }
  // Learn the ids from a full read.
  for (const Point& p : RunQuery(*ds_, Everything())) model_[p.frame][p.id] = p;
  ASSERT_EQ(ModelPoints([](const Point&) { return true; }).size(), 5000u + 6000 + 7000 + 8000);
  std::uniform_real_distribution<double> u(0, 10);
  for (int q = 0; q < 10; ++q) {
    Window w;
    for (int a = 0; a < 3; ++a) {
      double x = u(rng), y = u(rng);
      w.lo[a] = std::min(x, y);
      w.hi[a] = std::max(x, y);
    }
    w.lo[3] = 0;
    w.hi[3] = u(rng) / 10 * 0.4;
    CheckWindow(w);
  }
  // Level sizes: about n / 2^i for a single frame.
  for (int lod = 0; lod <= 5; ++lod) {
    QueryOptions o;
    o.lod = lod;
    double n = RunQuery(*ds_, FrameWindow(3), o).size();
    EXPECT_NEAR(n / 8000.0, 1.0 / (1 << lod), 0.15 / (1 << lod)) << lod;
  }
}

// Bulk loads into new frames build their trees on the callers' threads (before the writer's
// queue): loads of different frames from several threads, while transactions fill some of
// those frames first (so a tree built for an empty frame must be read back and rebuilt), leave
// every point in exactly once, with unique ids, and survive a reopen.
TEST_F(DatasetTest, ConcurrentBulkLoadsAndInsertsKeepEveryPointOnce) {
  Open();
  constexpr uint32_t kFrames = 12;
  std::vector<std::vector<Point>> loads(kFrames);
  std::mt19937_64 rng(11);
  for (uint32_t f = 0; f < kFrames; ++f) loads[f] = RandomPoints(rng, 3000 + 100 * f, f);
  std::vector<std::thread> threads;
  std::atomic<int> failures{0};
  for (int t = 0; t < 3; ++t) {
    threads.emplace_back([&, t] {
      for (uint32_t f = static_cast<uint32_t>(t); f < kFrames; f += 3)
        if (!ds_->BulkLoad(f, loads[f]).ok()) ++failures;
    });
  }
  // Transactions into every third frame at the same time.
  std::vector<Point> extra;
  threads.emplace_back([&] {
    std::mt19937_64 r(12);
    for (int i = 0; i < 20; ++i) {
      std::vector<Point> pts;
      for (int k = 0; k < 50; ++k) pts.push_back(testing::RandomPoint(r, static_cast<uint32_t>(3 * (k % 4))));
      Transaction tx;
      tx.Insert(pts);
      if (!ds_->Commit(tx).ok()) ++failures;
      extra.insert(extra.end(), pts.begin(), pts.end());
    }
  });
  for (auto& t : threads) t.join();
  ASSERT_EQ(failures.load(), 0);
  auto check = [&] {
    std::map<uint32_t, size_t> per_frame;
    std::set<uint64_t> ids;
    for (const Point& p : RunQuery(*ds_, Everything())) {
      ++per_frame[p.frame];
      EXPECT_TRUE(ids.insert(p.id).second) << "id " << p.id << " twice";
    }
    std::map<uint32_t, size_t> want;
    for (uint32_t f = 0; f < kFrames; ++f) want[f] = loads[f].size();
    for (const Point& p : extra) ++want[p.frame];
    EXPECT_EQ(per_frame, want);
  };
  check();
  Open();  // reopen: the same
  check();
}

TEST_F(DatasetTest, RandomEditsAgainstBruteForce) {
  Open();
  std::mt19937_64 rng(1234);
  std::uniform_real_distribution<double> u(0, 10);
  for (int round = 0; round < 12; ++round) {
    InsertRandom(rng, 20 + rng() % 300);
    // Delete a few points by id + position.
    Transaction del;
    int deleted = 0;
    for (auto& [f, m] : model_) {
      if (m.empty() || deleted > 10) continue;
      auto it = std::next(m.begin(), static_cast<long>(rng() % m.size()));
      del.Delete(it->second.id, f, {it->second.x, it->second.y, it->second.z});
      m.erase(it);
      ++deleted;
    }
    if (!del.empty()) Commit(del);
    // Delete a small region with a label mask.
    Window w;
    for (int a = 0; a < 3; ++a) {
      double x = u(rng);
      w.lo[a] = x;
      w.hi[a] = x + 2;
    }
    w.lo[3] = 0;
    w.hi[3] = 1;
    Selection sel;
    sel.region = w;
    sel.label_mask = 0x3;
    Transaction dr;
    dr.DeleteSelection(sel);
    Commit(dr);
    for (auto& [f, m] : model_) {
      std::erase_if(m, [&](const auto& e) {
        const Point& p = e.second;
        return (p.label & 0x3) && p.x >= w.lo[0] && p.x <= w.hi[0] && p.y >= w.lo[1] &&
               p.y <= w.hi[1] && p.z >= w.lo[2] && p.z <= w.hi[2] && f / kFps <= 1;
      });
    }
    // Label a region of frame 2.
    Selection ls;
    Window lw = FrameWindow(2);
    lw.lo[0] = 0;
    lw.hi[0] = 5;
    ls.region = lw;
    Transaction lt;
    lt.SetLabel(ls, 0x100, true);
    Commit(lt);
    for (auto& [id, p] : model_[2]) {
      if (p.x >= 0 && p.x <= 5) p.label |= 0x100;
    }
    CheckAll();
  }
  Window all = Everything();
  CheckWindow(all);
  for (int q = 0; q < 8; ++q) {
    Window w;
    for (int a = 0; a < 3; ++a) {
      double x = u(rng), y = u(rng);
      w.lo[a] = std::min(x, y);
      w.hi[a] = std::max(x, y);
    }
    w.lo[3] = u(rng) / 20;
    w.hi[3] = w.lo[3] + u(rng) / 20;
    CheckWindow(w);
  }
  // Slices: orthogonal to t, and tilted across frames.
  Slice s;
  s.normal = {0, 0, 0, 1};
  s.offset = 2.0 * (3 / kFps);  // N . (x,y,z,s t) = s t: frame 3
  s.thickness = 0.05;
  CheckSlice(s);
  s.normal = {0.3, 0.1, 0, 0.9};
  s.offset = 1.5;
  s.thickness = 0.4;
  CheckSlice(s);
  for (int lod = 1; lod <= 5; ++lod) CheckSlice(s, lod);
  // Everything survives a restart.
  Open();
  CheckAll();
  EXPECT_TRUE(ds_->Check().empty());
}

TEST_F(DatasetTest, TransformMovesPointsAcrossFrames) {
  Open();
  std::mt19937_64 rng(5);
  InsertRandom(rng, 500);
  Selection sel;
  sel.region = FrameWindow(1);
  Affine4 shift;
  shift.c = {1.0, 0, 0, 2 / kFps};  // +1 m in x, +2 frames
  Transaction t;
  t.Transform(sel, shift);
  CommitInfo info;
  Commit(t, &info);
  auto moved = model_[1];
  model_[1].clear();
  for (auto [id, p] : moved) {
    p.x += 1;
    p.frame = 3;
    model_[3][id] = p;
  }
  CheckAll();
  auto three = RunQuery(*ds_, FrameWindow(3));
  std::map<uint64_t, Point> by_id;
  for (const Point& p : three) by_id[p.id] = p;
  for (const auto& [id, p] : model_[3]) {
    ASSERT_TRUE(by_id.count(id));
    EXPECT_FLOAT_EQ(by_id[id].x, p.x);
  }
  // Undo brings back exactly the previous state.
  auto r = ds_->Revert(info.lsn);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  for (const auto& [id, p] : moved) model_[3].erase(id);
  model_[1] = moved;
  CheckAll();
  auto one = RunQuery(*ds_, FrameWindow(1));
  for (const Point& p : one) EXPECT_EQ(p, moved[p.id]);
}

TEST_F(DatasetTest, RevertOfInsertAndOfRevert) {
  Open();
  std::mt19937_64 rng(6);
  InsertRandom(rng, 100);
  auto before = RunQuery(*ds_, Everything());
  Transaction t;
  t.Insert(RandomPoints(rng, 50, 4));
  CommitInfo info;
  Commit(t, &info);
  EXPECT_EQ(RunQuery(*ds_, Everything()).size(), 150u);
  auto undo = ds_->Revert(info.lsn);
  ASSERT_TRUE(undo.ok());
  EXPECT_EQ(Keys(RunQuery(*ds_, Everything())), Keys(before));
  auto redo = ds_->Revert(undo->lsn);
  ASSERT_TRUE(redo.ok());
  EXPECT_EQ(RunQuery(*ds_, Everything()).size(), 150u);
  EXPECT_TRUE(ds_->Revert(9999).status().IsNotFound());
}

// Undo out of order: reverting a label change whose points a later transaction relabelled
// would restore their old labels and silently drop the later change; it is refused until the
// later one is reverted (in the tree and in T0 alike: a checkpoint moves the points between).
TEST_F(DatasetTest, RevertRefusesWhenALaterTransactionChangedThePoints) {
  Open();
  std::mt19937_64 rng(8);
  InsertRandom(rng, 600);
  for (bool merged : {false, true}) {
    SCOPED_TRACE(merged ? "points in trees" : "points in T0");
    if (merged) {
      ASSERT_TRUE(ds_->Checkpoint().ok());
    }
    const uint32_t f = merged ? 2 : 1;
    Selection sel;
    sel.region = FrameWindow(f);
    Transaction a;
    a.SetLabel(sel, 1u << 0, true);
    CommitInfo ia;
    Commit(a, &ia);
    // A later change of the same bit: reverting `a` would undo it too.
    Transaction b;
    b.SetLabel(sel, 1u << 0, false);
    CommitInfo ib;
    Commit(b, &ib);
    auto r = ds_->Revert(ia.lsn);
    ASSERT_FALSE(r.ok());
    EXPECT_TRUE(r.status().IsInvalidArgument()) << r.status().ToString();
    EXPECT_NE(r.status().message().find("later transaction"), std::string::npos);
    auto now = RunQuery(*ds_, FrameWindow(f));
    ASSERT_FALSE(now.empty());
    for (const Point& p : now) EXPECT_EQ(p.label & 1u, 0u);
    // A later change of other bits does not stand in the way: labels are logged as the bits
    // that flipped, and undoing one selection leaves another alone.
    Transaction c;
    c.SetLabel(sel, 1u << 5, true);
    CommitInfo ic;
    Commit(c, &ic);
    ASSERT_TRUE(ds_->Revert(ib.lsn).ok());
    for (const Point& p : RunQuery(*ds_, FrameWindow(f))) EXPECT_EQ(p.label | 0x21u, p.label);
    // Latest first works too, and restores the labels as they were.
    ASSERT_TRUE(ds_->Revert(ic.lsn).ok());
    ASSERT_TRUE(ds_->Revert(ia.lsn).ok());
    for (const Point& p : RunQuery(*ds_, FrameWindow(f))) {
      EXPECT_EQ(p.label, model_[f][p.id].label);
    }
  }
}

TEST_F(DatasetTest, RelabellingLogsAFewBytesAPointAndSurvivesReopen) {
  Open();
  std::mt19937_64 rng(11);
  InsertRandom(rng, 3000);
  ASSERT_TRUE(ds_->Checkpoint().ok());
  Selection sel;
  sel.region = Everything();
  const uint64_t before = ds_->Stats().wal_bytes;
  Transaction t;
  t.SetLabel(sel, 1u << 7, true);
  CommitInfo info;
  Commit(t, &info);
  size_t n = 0;
  for (auto& [f, m] : model_) {
    for (auto& [id, p] : m) p.label |= 1u << 7, ++n;
  }
  ASSERT_GT(n, 2000u);
  EXPECT_EQ(info.inserted, n);
  // Ids and flipped bits: a byte or two a point, where whole points took 128.
  EXPECT_LT(ds_->Stats().wal_bytes - before, 2 * n + 512) << n << " points";
  // Recovery redoes the relabel from the log (the trees still hold the old labels).
  Open();
  CheckAll();
  // And a revert after reopening finds the points by id.
  ASSERT_TRUE(ds_->Revert(info.lsn).ok());
  for (auto& [f, m] : model_) {
    for (auto& [id, p] : m) p.label &= ~(1u << 7);
  }
  CheckAll();
  Open();
  CheckAll();
}

// Label summaries (docs/FORMAT.md, "Directory entries"): a masked query or selection reads
// only the buckets whose summary has the bits, returns what brute force does, and keeps doing
// so after relabels are merged into trees and after a reopen.
TEST_F(DatasetTest, LabelSummariesSkipBucketsWithoutTheBits) {
  Open();
  std::mt19937_64 rng(5);
  auto pts = RandomPoints(rng, 40000, 0);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = i + 1;
    pts[i].label = pts[i].x < 0.5f ? 1u << 5 : 0u;  // a slab of 5 % of the frame
    if (i % 1000 == 0) pts[i].label |= 1u << 9;    // and a few points anywhere
  }
  ASSERT_TRUE(ds_->BulkLoad(0, pts).ok());
  for (const Point& p : pts) model_[0][p.id] = p;
  auto expect_masked = [&](uint32_t mask, const std::string& what) {
    QueryOptions o;
    o.label_mask = mask;
    auto want = Keys(ModelPoints([&](const Point& p) { return (p.label & mask) != 0; }));
    EXPECT_EQ(Keys(RunQuery(*ds_, Everything(), o)), want) << what;
  };
  // Blocks read from disk by one query in a freshly opened database.
  auto misses = [&](uint32_t mask) {
    Open();
    const uint64_t before = db_->Cache().misses;
    QueryOptions o;
    o.label_mask = mask;
    RunQuery(*ds_, Everything(), o);
    return db_->Cache().misses - before;
  };
  const uint64_t all = misses(0), slab = misses(1u << 5), none = misses(1u << 20);
  EXPECT_LT(slab * 5, all) << "a 5 % slab read " << slab << " of " << all << " blocks";
  EXPECT_EQ(none, 0u) << "no tree holds bit 20: not even its directory is read";
  expect_masked(1u << 5, "slab");
  expect_masked(1u << 9, "scattered");
  // Relabel another slab (the points go through T0 and, t0_points being 64, into new trees);
  // a replace-mode selection clears the bit where it was.
  Selection sel;
  Window w = Everything();
  w.lo[1] = 2;
  w.hi[1] = 3;
  sel.region = w;
  Transaction t;
  t.SetLabel(sel, 1u << 6, true);
  Selection old;
  old.label_mask = 1u << 5;
  t.SetLabel(old, 1u << 5, false);
  Commit(t);
  for (auto& [id, p] : model_[0]) {
    if (p.y >= 2 && p.y <= 3) p.label |= 1u << 6;
    p.label &= ~(1u << 5);
  }
  expect_masked(1u << 6, "relabelled");
  expect_masked(1u << 5, "cleared");
  ASSERT_TRUE(ds_->Checkpoint().ok());
  EXPECT_TRUE(ds_->Check().empty());
  Open();
  expect_masked(1u << 6, "relabelled, after a reopen");
  expect_masked(1u << 5 | 1u << 9, "cleared and scattered, after a reopen");
  EXPECT_TRUE(ds_->Check().empty());
}

TEST_F(DatasetTest, FailedTransactionChangesNothing) {
  Open();
  std::mt19937_64 rng(7);
  InsertRandom(rng, 100);
  auto lsn = ds_->Info().last_lsn;
  Transaction t;
  t.Insert(RandomPoints(rng, 10, 0));
  t.Delete(424242, 0, {1, 2, 3});  // no such point
  auto r = ds_->Commit(t);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsNotFound());
  EXPECT_EQ(ds_->Info().last_lsn, lsn);
  CheckAll();
  Transaction bad;
  Point nan = RandomPoints(rng, 1, 0)[0];
  nan.x = NAN;
  bad.Insert({nan});
  EXPECT_TRUE(ds_->Commit(bad).status().IsInvalidArgument());
  CheckAll();
  // Explicit ids as far apart as ids go (a client may send any): not found, nothing changed.
  Transaction far;
  Selection ends;
  ends.ids = {{0, 0}, {0, UINT64_MAX}, {0, UINT64_MAX - 63}};
  far.SetLabel(ends, 1, true);
  EXPECT_TRUE(ds_->Commit(far).status().IsNotFound());
  EXPECT_EQ(ds_->Info().last_lsn, lsn);
  CheckAll();
}

TEST_F(DatasetTest, ProgressiveIsCoarseFirstAndEachPointOnce) {
  Open();
  std::mt19937_64 rng(8);
  ASSERT_TRUE(ds_->BulkLoad(0, RandomPoints(rng, 20000, 0)).ok());
  ASSERT_TRUE(ds_->BulkLoad(1, RandomPoints(rng, 20000, 1)).ok());
  QueryOptions o;
  o.progressive = true;
  o.batch_points = 1000;
  o.temporal_lod = false;
  auto c = ds_->Query(Everything(), o);
  ASSERT_TRUE(c.ok());
  Batch b;
  int last_level = 6;
  size_t total = 0;
  std::map<int, size_t> per_level;
  std::set<std::pair<uint32_t, uint64_t>> seen;
  while (true) {
    auto more = (*c)->Next(&b);
    ASSERT_TRUE(more.ok());
    if (!*more) break;
    EXPECT_LE(b.level, last_level);
    last_level = b.level;
    EXPECT_FLOAT_EQ(b.splat_scale, std::pow(2.f, b.level / 2.f));
    for (const Point& p : b.points) EXPECT_TRUE(seen.insert({p.frame, p.id}).second);
    per_level[b.level] += b.points.size();
    total += b.points.size();
  }
  EXPECT_EQ(total, 40000u);
  EXPECT_NEAR(double(per_level[0]), 20000, 1000);
  EXPECT_NEAR(double(per_level[5]), 40000 / 32.0, 200);
}

TEST_F(DatasetTest, CancelStopsTheStream) {
  Open();
  std::mt19937_64 rng(9);
  ASSERT_TRUE(ds_->BulkLoad(0, RandomPoints(rng, 20000, 0)).ok());
  QueryOptions o;
  o.batch_points = 100;
  auto c = ds_->Query(Everything(), o);
  ASSERT_TRUE(c.ok());
  Batch b;
  ASSERT_TRUE((*c)->Next(&b).ok());
  (*c)->Cancel();
  auto r = (*c)->Next(&b);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kCancelled);
}

TEST_F(DatasetTest, SnapshotIsolation) {
  Open();
  std::mt19937_64 rng(10);
  ASSERT_TRUE(ds_->BulkLoad(0, RandomPoints(rng, 5000, 0)).ok());
  QueryOptions o;
  o.batch_points = 100;
  auto c = ds_->Query(Everything(), o);
  ASSERT_TRUE(c.ok());
  // A commit that deletes half the frame, and rebuilds trees, does not change the open query.
  Selection sel;
  Window w = Everything();
  w.hi[0] = 5;
  sel.region = w;
  Transaction t;
  t.DeleteSelection(sel);
  Commit(t);
  Transaction ins;
  ins.Insert(RandomPoints(rng, 200, 0));
  Commit(ins);
  size_t n = 0;
  Batch b;
  while (true) {
    auto more = (*c)->Next(&b);
    ASSERT_TRUE(more.ok());
    if (!*more) break;
    n += b.points.size();
  }
  EXPECT_EQ(n, 5000u);
}

// The merger swaps trees in while a query holds the versions it started on: the query sees
// exactly its snapshot, the merged-away tree files live until it lets go, and then go.
TEST_F(DatasetTest, MergesSwapTreesUnderAnOpenQuery) {
  Open();
  std::mt19937_64 rng(13);
  for (int i = 0; i < 10; ++i) InsertRandom(rng, 50);
  ASSERT_TRUE(ds_->WaitForMerges().ok());
  auto want = Keys(ModelPoints([](const Point&) { return true; }));
  QueryOptions o;
  o.batch_points = 64;
  auto c = ds_->Query(Everything(), o);
  ASSERT_TRUE(c.ok());
  Batch b;
  std::set<std::pair<uint32_t, uint64_t>> got;
  ASSERT_TRUE((*c)->Next(&b).ok());  // the query has started reading
  for (const Point& p : b.points) got.insert({p.frame, p.id});
  const uint64_t merges_before = ds_->Stats().merges;
  for (int i = 0; i < 30; ++i) InsertRandom(rng, 100);
  Transaction del;  // and deletes from the trees being merged
  Selection sel;
  Window w = Everything();
  w.hi[0] = 3;
  sel.region = w;
  del.DeleteSelection(sel);
  Commit(del);
  for (auto& [f, m] : model_) std::erase_if(m, [](const auto& e) { return e.second.x <= 3; });
  ASSERT_TRUE(ds_->WaitForMerges().ok());
  EXPECT_GT(ds_->Stats().merges, merges_before);
  for (;;) {
    auto more = (*c)->Next(&b);
    ASSERT_TRUE(more.ok()) << more.status().ToString();
    for (const Point& p : b.points) EXPECT_TRUE(got.insert({p.frame, p.id}).second);
    if (!*more) break;
  }
  EXPECT_EQ(got, want) << "the open query saw the merges";
  c->reset();
  ASSERT_TRUE(ds_->Checkpoint().ok());  // the state on disk no longer lists the old trees
  EXPECT_EQ(Keys(RunQuery(*ds_, Everything())), Keys(ModelPoints([](const Point&) { return true; })));
  EXPECT_TRUE(ds_->Check().empty());
  // Only the trees the frames list are left.
  // (Listed through the store's Env: the same test runs on RADOS.)
  Env* env = Options{}.env;
#ifdef HVDB_TEST_RADOS
  env = testing::RadosTestEnv();
#endif
  if (env == nullptr) env = Env::Default();
  auto files = env->ListDir(dir_.path() + "/video/trees");
  ASSERT_TRUE(files.ok()) << files.status().ToString();
  EXPECT_EQ(files->size(), ds_->Stats().trees);
  // Reopened, the dataset is the same.
  Open();
  EXPECT_EQ(Keys(RunQuery(*ds_, Everything())), Keys(ModelPoints([](const Point&) { return true; })));
}

TEST_F(DatasetTest, SliceFrameBound) {
  Open();
  std::mt19937_64 rng(11);
  for (uint32_t f = 0; f < 20; ++f) ASSERT_TRUE(ds_->BulkLoad(f, RandomPoints(rng, 200, f)).ok());
  Slice s;
  s.normal = {1, 0, 0, 0};  // parallel to t: every frame
  s.offset = 5;
  s.thickness = 1;
  s.max_frames = 8;
  auto c = ds_->Query(s);
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), StatusCode::kLimitExceeded);
  EXPECT_NE(c.status().message().find("20 frames"), std::string::npos);
  s.on_too_many_frames = Slice::FrameBound::kClip;
  auto clipped = ds_->Query(s);
  ASSERT_TRUE(clipped.ok());
  EXPECT_TRUE((*clipped)->clipped());
  EXPECT_EQ((*clipped)->frames().size(), 8u);
  // A clip window narrows the frames instead.
  s.on_too_many_frames = Slice::FrameBound::kError;
  Window clip = Everything();
  clip.lo[3] = 0.5;
  clip.hi[3] = 1.0;
  s.clip = clip;
  auto narrow = ds_->Query(s);
  ASSERT_TRUE(narrow.ok());
  EXPECT_EQ((*narrow)->frames().size(), 6u);  // frames 5..10
}

TEST_F(DatasetTest, InvalidParameters) {
  Open();
  QueryOptions o;
  o.lod = 9;
  EXPECT_TRUE(ds_->Query(Everything(), o).status().IsInvalidArgument());
  // The one rule for a level of detail (Dataset::CheckLod), which render jobs follow too.
  const std::string range = " is out of range 0.." + std::to_string(ds_->lod_levels()) +
                            " for dataset '" + ds_->Info().name + "' (its coarsest level)";
  EXPECT_EQ(ds_->Query(Everything(), o).status().message(), "lod: 9" + range);
  EXPECT_EQ(ds_->CheckLod(-1).message(), "lod: -1" + range);
  EXPECT_TRUE(ds_->CheckLod(0).ok());
  EXPECT_TRUE(ds_->CheckLod(ds_->lod_levels()).ok());
  EXPECT_TRUE(ds_->CheckLod(ds_->lod_levels() + 1).IsInvalidArgument());
  Window w = Everything();
  w.lo[1] = NAN;
  EXPECT_TRUE(ds_->Query(w).status().IsInvalidArgument());
  Slice s;
  s.normal = {0, 0, 0, 0};
  EXPECT_TRUE(ds_->Query(s).status().IsInvalidArgument());
  DatasetInfo info;
  info.name = "../evil";
  EXPECT_TRUE(db_->CreateDataset(info).status().IsInvalidArgument());
  info.name = "x";
  info.fps = -1;
  EXPECT_TRUE(db_->CreateDataset(info).status().IsInvalidArgument());
  EXPECT_TRUE(db_->GetDataset("nope").status().IsNotFound());
}

TEST_F(DatasetTest, T0CapacityOutOfRangeIsRefused) {
  for (uint32_t bad : {0u, 63u, (4u << 20) + 1}) {
    Options o;
    o.t0_points = bad;
    auto db = Database::Open(dir_.path(), o);
    ASSERT_FALSE(db.ok()) << bad;
    EXPECT_TRUE(db.status().IsInvalidArgument());
    EXPECT_NE(db.status().message().find("t0_points must be in [64, 4194304]"), std::string::npos)
        << db.status().ToString();
  }
  // Nothing was created or locked: a valid open works right after.
  Open();
  EXPECT_EQ(db_->ListDatasets(), std::vector<std::string>{"video"});
}

// Options for the logarithmic method's tests: T0 of 64 points, so that small sets make forests.
Options ForestOptions(uint32_t fanout) {
  Options o;
  o.cache_bytes = 8u << 20;
  o.block_size = 4096;
  o.t0_points = 64;
  o.merge_fanout = fanout;
  return o;
}

// A database with one dataset, "forest".
std::pair<std::unique_ptr<Database>, std::shared_ptr<Dataset>> OpenForest(const std::string& dir,
                                                                          const Options& o) {
  auto db = Database::Open(dir, o);
  EXPECT_TRUE(db.ok()) << db.status().ToString();
  if (!db.ok()) return {};
  DatasetInfo info;
  info.name = "forest";
  info.fps = kFps;
  auto ds = (*db)->CreateDataset(info);
  EXPECT_TRUE(ds.ok()) << ds.status().ToString();
  if (!ds.ok()) return {};
  return {std::move(*db), *ds};
}

// The logarithmic method of every fan-out (Options::merge_fanout): the same points answer the
// same queries, Check() finds every tree within its slot's capacity, and a wider fan-out
// rebuilds each point fewer times (about log_k(n / 64) with T0 at 64 points).
TEST_F(DatasetTest, EveryFanOutAnswersAsBruteForceAndAWiderOneRebuildsLess) {
  std::map<uint32_t, double> rebuilds;
  for (uint32_t k : {2u, 3u, 4u, 16u}) {
    SCOPED_TRACE("fan-out " + std::to_string(k));
    TempDir dir;
    Options o = ForestOptions(k);
    auto [db, ds] = OpenForest(dir.path(), o);
    ASSERT_TRUE(ds);
    std::mt19937_64 rng(77);  // the same points for every fan-out
    std::map<uint64_t, Point> model;
    for (int set = 0; set < 240; ++set) {
      std::vector<Point> pts;
      for (int i = 0; i < 50; ++i) pts.push_back(testing::RandomPoint(rng, 0));
      Transaction t;
      t.Insert(pts);
      auto r = ds->Commit(t);
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      for (size_t i = 0; i < pts.size(); ++i) {
        pts[i].id = r->assigned_ids[i];
        model[pts[i].id] = pts[i];
      }
      if (set % 40 == 39) {  // and deletes, which the merges carry as dead ids or drop
        Transaction del;
        for (int d = 0; d < 30; ++d) {
          auto it = std::next(model.begin(), static_cast<long>(rng() % model.size()));
          del.Delete(it->first, 0, {it->second.x, it->second.y, it->second.z});
          model.erase(it);
        }
        ASSERT_TRUE(ds->Commit(del).ok());
      }
      // Each overflow merged before the next set: the same forest shape on every run.
      ASSERT_TRUE(ds->WaitForMerges().ok());
    }
    EXPECT_TRUE(ds->Check().empty());
    std::mt19937_64 wrng(5);
    std::uniform_real_distribution<double> u(0, 10);
    for (int q = 0; q < 6; ++q) {
      Window w = FrameWindow(0);
      for (int a = 0; a < 3; ++a) {
        double x = u(wrng), y = u(wrng);
        w.lo[a] = std::min(x, y);
        w.hi[a] = std::max(x, y);
      }
      std::set<std::pair<uint32_t, uint64_t>> want;
      for (const auto& [id, p] : model) {
        if (p.x >= w.lo[0] && p.x <= w.hi[0] && p.y >= w.lo[1] && p.y <= w.hi[1] &&
            p.z >= w.lo[2] && p.z <= w.hi[2]) {
          want.insert({0, id});
        }
      }
      EXPECT_EQ(Keys(RunQuery(*ds, w)), want) << "window " << q;
    }
    const DatasetStats st = ds->Stats();
    EXPECT_EQ(st.points, model.size());
    rebuilds[k] = static_cast<double>(st.merged_points) / 12000.0;
    ds.reset();
    db.reset();
    // Reopened with the other fan-out: the forest reads as it is, and grows on.
    o.merge_fanout = k == 2 ? 4 : 2;
    auto reopened = Database::Open(dir.path(), o);
    ASSERT_TRUE(reopened.ok()) << reopened.status().ToString();
    auto again = (*reopened)->GetDataset("forest");
    ASSERT_TRUE(again.ok());
    EXPECT_TRUE((*again)->Check().empty());
    EXPECT_EQ(RunQuery(**again, Everything()).size(), model.size());
  }
  for (const auto& [k, r] : rebuilds) std::printf("fan-out %u: %.3f builds a point\n", k, r);
  // A point climbs about log_k(n / p) levels, with probability (k-1)/k at each: 3/8 log2(n / p)
  // times for k = 4 against 1/2 log2(n / p) for k = 2, 0.23 log2(n / p) for k = 16.
  EXPECT_LT(rebuilds[4], 0.85 * rebuilds[2]) << rebuilds[2] << " vs " << rebuilds[4];
  EXPECT_LT(rebuilds[16], 0.7 * rebuilds[2]) << rebuilds[2] << " vs " << rebuilds[16];
  EXPECT_LT(rebuilds[3], rebuilds[2]);
  EXPECT_LT(rebuilds[16], rebuilds[4]);
}

// Commits that ran ahead of the merger leave a T0 of several times its capacity: it goes to
// the level its size needs, and the smaller trees below stay where they are instead of being
// rebuilt with it.
TEST_F(DatasetTest, AnOverfullBufferSkipsTheLevelsBelowItsSize) {
  // T0 of 64 points: level 1 holds trees of up to 256 points, level 2 of up to 1024.
  auto forest = OpenForest(dir_.path(), ForestOptions(4));
  std::shared_ptr<Dataset>& ds = forest.second;  // (a structured binding: no lambda capture in clang 14)
  ASSERT_TRUE(ds);
  std::mt19937_64 rng(9);
  auto commit = [&](int n) {
    std::vector<Point> pts;
    for (int i = 0; i < n; ++i) pts.push_back(testing::RandomPoint(rng, 0));
    Transaction t;
    t.Insert(pts);
    ASSERT_TRUE(ds->Commit(t).ok());
    ASSERT_TRUE(ds->WaitForMerges().ok());
  };
  for (int i = 0; i < 3; ++i) commit(100);  // three trees of level 1
  EXPECT_EQ(ds->Stats().trees, 3u);
  commit(600);  // one T0 of 600 points: level 2, beside them
  const DatasetStats st = ds->Stats();
  EXPECT_EQ(st.trees, 4u);
  EXPECT_EQ(st.merged_points, 900u) << "the level-1 trees were rebuilt";
  EXPECT_EQ(st.points, 900u);
  EXPECT_TRUE(ds->Check().empty());
  commit(100);  // level 1 is full: its trees and T0 go up to level 2, beside the 600
  EXPECT_EQ(ds->Stats().trees, 2u);
  EXPECT_EQ(RunQuery(*ds, Everything()).size(), 1000u);
}

// A cursor's points bound: the live points of the frames it reads (trees, less their dead ids,
// and T0), never fewer than it returns.
TEST_F(DatasetTest, ACursorsPointsBoundCountsItsFramesLivePoints) {
  Open();
  std::mt19937_64 rng(21);
  ASSERT_TRUE(ds_->BulkLoad(0, testing::RandomPoints(rng, 3000, 0)).ok());
  Transaction t;
  t.Insert(testing::RandomPoints(rng, 40, 0));
  t.Insert(testing::RandomPoints(rng, 70, 1));
  ASSERT_TRUE(ds_->Commit(t).ok());
  const Point gone = RunQuery(*ds_, FrameWindow(0)).front();
  Transaction del;
  del.Delete(gone.id, 0, {gone.x, gone.y, gone.z});
  ASSERT_TRUE(ds_->Commit(del).ok());
  auto whole = ds_->Query(FrameWindow(0));
  ASSERT_TRUE(whole.ok());
  EXPECT_EQ((*whole)->PointsBound(), RunQuery(*ds_, FrameWindow(0)).size());
  Window part = FrameWindow(1);
  part.hi[0] = 0.5;  // half of frame 1's points
  auto some = ds_->Query(part);
  ASSERT_TRUE(some.ok());
  EXPECT_EQ((*some)->PointsBound(), 70u);
  EXPECT_LT(RunQuery(*ds_, part).size(), 70u);
}

TEST_F(DatasetTest, MergeFanOutOutOfRangeIsRefused) {
  for (uint32_t bad : {0u, 1u, 17u}) {
    Options o;
    o.merge_fanout = bad;
    auto db = Database::Open(dir_.path(), o);
    ASSERT_FALSE(db.ok()) << bad;
    EXPECT_NE(db.status().message().find("merge_fanout must be in [2, 16]"), std::string::npos)
        << db.status().ToString();
  }
}

TEST_F(DatasetTest, ConcurrentCommitsAndQueries) {
  Open();
  std::mt19937_64 seed_rng(12);
  ASSERT_TRUE(ds_->BulkLoad(0, RandomPoints(seed_rng, 3000, 0)).ok());
  std::atomic<int> failures{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      std::mt19937_64 rng(100 + t);
      for (int i = 0; i < 25; ++i) {
        Transaction txn;
        txn.Insert(RandomPoints(rng, 40, static_cast<uint32_t>(t)));
        if (!ds_->Commit(txn).ok()) ++failures;
      }
    });
  }
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&] {
      for (int i = 0; i < 20; ++i) {
        auto c = ds_->Query(Everything());
        if (!c.ok()) {
          ++failures;
          continue;
        }
        Batch b;
        while (true) {
          auto more = (*c)->Next(&b);
          if (!more.ok()) ++failures;
          if (!more.ok() || !*more) break;
        }
      }
    });
  }
  for (auto& th : threads) th.join();
  EXPECT_EQ(failures.load(), 0);
  EXPECT_EQ(RunQuery(*ds_, Everything()).size(), 3000u + 4 * 25 * 40);
  EXPECT_EQ(ds_->Info().last_lsn, 101u);  // the bulk load, then 100 commits
  EXPECT_TRUE(ds_->Check().empty());
}

TEST_F(DatasetTest, DropAndList) {
  Open();
  EXPECT_EQ(db_->ListDatasets(), std::vector<std::string>{"video"});
  ds_.reset();
  ASSERT_TRUE(db_->DropDataset("video").ok());
  EXPECT_TRUE(db_->ListDatasets().empty());
}

}  // namespace
}  // namespace hvdb
