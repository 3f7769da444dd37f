// The cold tier (storage/cold_tree.h, storage/dataset_tier.cc): compressed frames answer every
// query exactly as their raw copies, edits of them work and are undoable, damage is named.
// Crash safety: compaction is in the fault-injection and kill -9 workloads
// (fault_injection_test.cc, crash_test.cc). rados_tests runs this file on a RADOS pool.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <tuple>

#include "formats/ply.h"
#include "storage/database.h"
#include "tests/storage/test_util.h"
#ifdef HVDB_TEST_RADOS
#include "tests/storage/rados_test_util.h"
#endif

namespace hvdb {
namespace {

using testing::TempDir;

constexpr double kFps = 10.0;
constexpr uint32_t kFrames = 6;  // 0-3: Panoptic frames 380-383; 4-5: random points

std::vector<Point> RunQuery(Dataset& ds, const Region& r, const QueryOptions& o,
                       std::vector<std::tuple<int, bool, size_t>>* batches = nullptr) {
  auto c = ds.Query(r, o);
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  std::vector<Point> out;
  if (!c.ok()) return out;
  Batch b;
  for (;;) {
    auto more = (*c)->Next(&b);
    EXPECT_TRUE(more.ok()) << more.status().ToString();
    if (!more.ok() || !*more) break;
    if (batches) batches->push_back({b.level, b.level_done, b.points.size()});
    out.insert(out.end(), b.points.begin(), b.points.end());
  }
  return out;
}

std::vector<Point> Sorted(std::vector<Point> pts) {
  std::sort(pts.begin(), pts.end(), [](const Point& a, const Point& b) {
    return std::tie(a.frame, a.id) < std::tie(b.frame, b.id);
  });
  return pts;
}

std::vector<Point> FramePoints(uint32_t f) {
  std::vector<Point> pts;
  if (f < 4) {
    char name[64];
    std::snprintf(name, sizeof(name), "ptcloud_hd%08u.ply", 380 + f);
    auto r = formats::ReadPly(std::string(HVDB_SHARED_DATA) +
                              "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/" + name);
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    if (r.ok()) pts = *r;
  } else {
    std::mt19937_64 rng(f);
    pts = testing::RandomPoints(rng, 30000, f, 2.0f);
  }
  for (Point& p : pts) p.frame = f;
  return pts;
}

class ColdTierTest : public ::testing::Test {
 protected:
  void Close() {
    cold_.reset();
    raw_.reset();
    db_.reset();
  }
  // cold_after_s 0: only Compact() compresses.
  void Reopen(uint32_t cold_after_s = 0) {
    Close();
    Options o;
    o.cache_bytes = 16u << 20;
    o.t0_points = 4096;
    o.cold_after_s = cold_after_s;
#ifdef HVDB_TEST_RADOS
    o.env = testing::RadosTestEnv();
#endif
    auto db = Database::Open(dir_.path(), o);
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(*db);
    auto raw = db_->GetDataset("raw"), cold = db_->GetDataset("cold");
    if (raw.ok()) raw_ = *raw;
    if (cold.ok()) cold_ = *cold;
  }

  void SetUp() override {
    Reopen();
    if (HasFatalFailure()) return;
    for (const char* name : {"raw", "cold"}) {
      DatasetInfo info;
      info.name = name;
      info.fps = kFps;
      auto ds = db_->CreateDataset(info);
      ASSERT_TRUE(ds.ok()) << ds.status().ToString();
      (std::string(name) == "raw" ? raw_ : cold_) = *ds;
    }
    // The same bulk loads: the same trees, so that every level of detail can be compared.
    for (uint32_t f = 0; f < kFrames; ++f) {
      auto pts = FramePoints(f);
      ASSERT_TRUE(raw_->BulkLoad(f, pts).ok());
      ASSERT_TRUE(cold_->BulkLoad(f, pts).ok());
    }
  }

  // Both datasets, the same query: the same points, and the same batches of levels.
  void ExpectSame(const Region& r, const QueryOptions& o, const std::string& what) {
    std::vector<std::tuple<int, bool, size_t>> rb, cb;
    auto a = RunQuery(*raw_, r, o, &rb);
    auto b = RunQuery(*cold_, r, o, &cb);
    ASSERT_EQ(a.size(), b.size()) << what;
    EXPECT_EQ(rb, cb) << what;
    EXPECT_TRUE(Sorted(a) == Sorted(b)) << what;
  }

  TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> raw_, cold_;
};

TEST_F(ColdTierTest, EveryQueryAnswersAsOnTheRawCopy) {
  auto info = cold_->Compact(0, kFrames - 1);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->frames, kFrames);
  const DatasetStats st = cold_->Stats();
  EXPECT_EQ(st.cold_frames, kFrames);
  EXPECT_EQ(st.cold_trees, st.trees);
  EXPECT_EQ(st.cold_points, st.points);
  // The Panoptic frames (positions in cm, normals, colours) and the random ones: a fifth.
  EXPECT_LT(static_cast<double>(st.cold_tree_bytes), 0.3 * static_cast<double>(st.points * 64));
  std::printf("[ cold ] %llu points: raw trees %llu bytes, compressed %llu (%.3f of 64 B/point)\n",
              static_cast<unsigned long long>(st.points),
              static_cast<unsigned long long>(raw_->Stats().tree_bytes),
              static_cast<unsigned long long>(st.cold_tree_bytes),
              static_cast<double>(st.cold_tree_bytes) / static_cast<double>(st.points * 64));
  // Compacting again finds nothing to do.
  auto again = cold_->Compact(0, kFrames - 1);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->frames, 0u);
  EXPECT_EQ(again->already, kFrames);

  std::mt19937_64 rng(42);
  std::uniform_real_distribution<double> u(0, 1);
  auto random_window = [&] {
    Window w;
    // Panoptic spans x -81..-6, y -173..-7, z -72..78 (cm); the random frames 0..2.
    const double lo[3] = {-90, -180, -80}, span[3] = {95, 185, 165};
    for (int a = 0; a < 3; ++a) {
      const double c = lo[a] + span[a] * u(rng), h = span[a] * (0.02 + 0.3 * u(rng));
      w.lo[a] = c - h;
      w.hi[a] = c + h;
    }
    const double f0 = std::floor(u(rng) * kFrames);
    w.lo[3] = f0 / kFps;
    w.hi[3] = (f0 + std::floor(u(rng) * 3)) / kFps;
    return w;
  };
  for (int i = 0; i < 40; ++i) {
    QueryOptions o;
    o.lod = static_cast<int>(rng() % 6);
    o.progressive = rng() % 3 == 0;
    o.temporal_lod = rng() % 2 == 0;
    o.label_mask = rng() % 4 == 0 ? static_cast<uint32_t>(1u << (rng() % 4)) : 0;
    o.batch_points = 1000 + rng() % 20000;
    ExpectSame(random_window(), o, "window " + std::to_string(i));
    if (HasFatalFailure()) return;
  }
  // Whole frames, every level, and the progressive stream over all of them.
  for (int lod = 0; lod <= 5; ++lod) {
    QueryOptions o;
    o.lod = lod;
    ExpectSame(testing::EverythingWindow(), o, "everything at level " + std::to_string(lod));
    o.progressive = true;
    ExpectSame(testing::EverythingWindow(), o, "progressive to level " + std::to_string(lod));
  }
  // Hyperslices: orthogonal to t, and tilted through several frames.
  for (int i = 0; i < 12; ++i) {
    Slice s;
    s.normal = {u(rng) - 0.5, u(rng) - 0.5, u(rng) - 0.5, i % 3 == 0 ? 1.0 : u(rng)};
    s.offset = (u(rng) - 0.5) * 40;
    s.thickness = 0.05 + 20 * u(rng);
    s.on_too_many_frames = Slice::FrameBound::kClip;
    QueryOptions o;
    o.lod = static_cast<int>(rng() % 4);
    ExpectSame(s, o, "slice " + std::to_string(i));
  }
  EXPECT_TRUE(cold_->Check().empty());
}

TEST_F(ColdTierTest, EditsOfACompressedFrameWorkAreUndoableAndThawIt) {
  ASSERT_TRUE(cold_->Compact(0, kFrames - 1).ok());
  // The same edits on both: a delete, a relabel and an insert into frame 1.
  auto frame1 = Sorted(RunQuery(*cold_, testing::FrameWindow(1, kFps), {}));
  ASSERT_GT(frame1.size(), 1000u);
  Transaction t;
  for (size_t i = 0; i < frame1.size(); i += 97) {
    t.Delete(frame1[i].id, 1, {frame1[i].x, frame1[i].y, frame1[i].z});
  }
  Selection sel;
  for (size_t i = 5; i < frame1.size(); i += 13) {
    if (i % 97 != 0) sel.ids.push_back({1, frame1[i].id});  // not one deleted above
  }
  t.SetLabel(sel, 1u << 3, true);
  std::mt19937_64 rng(3);
  auto extra = testing::RandomPoints(rng, 500, 1, 50.f);
  for (size_t i = 0; i < extra.size(); ++i) extra[i].id = 10'000'000 + i;
  t.Insert(extra);
  auto a = raw_->Commit(t);
  auto b = cold_->Commit(t);
  ASSERT_TRUE(a.ok()) << a.status().ToString();
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  auto same_full_resolution = [&](const std::string& what) {
    for (uint32_t f = 0; f < kFrames; ++f) {
      QueryOptions o;
      EXPECT_TRUE(Sorted(RunQuery(*raw_, testing::FrameWindow(f, kFps), o)) ==
                  Sorted(RunQuery(*cold_, testing::FrameWindow(f, kFps), o)))
          << what << ", frame " << f;
      o.label_mask = 1u << 3;
      EXPECT_TRUE(Sorted(RunQuery(*raw_, testing::FrameWindow(f, kFps), o)) ==
                  Sorted(RunQuery(*cold_, testing::FrameWindow(f, kFps), o)))
          << what << ", labelled points of frame " << f;
    }
  };
  same_full_resolution("after the edit");
  // The write brings frame 1 back to the hot tier (the merger thaws it); the others stay cold.
  for (int i = 0; i < 200 && cold_->Stats().cold_trees == kFrames; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(cold_->Stats().cold_trees, kFrames - 1);
  same_full_resolution("after the thaw");
  // Undo on both.
  ASSERT_TRUE(raw_->Revert(a->lsn).ok());
  auto undo = cold_->Revert(b->lsn);
  ASSERT_TRUE(undo.ok()) << undo.status().ToString();
  same_full_resolution("after the undo");
  EXPECT_EQ(Sorted(RunQuery(*cold_, testing::FrameWindow(1, kFps), {})), frame1);
  // And it survives a reopen with the frames in both tiers.
  ASSERT_TRUE(cold_->Compact(0, kFrames - 1).ok());
  Reopen();
  ASSERT_TRUE(raw_ && cold_);
  EXPECT_EQ(cold_->Stats().cold_frames, kFrames);
  same_full_resolution("after a reopen");
  EXPECT_TRUE(cold_->Check().empty());
}

TEST_F(ColdTierTest, IdleFramesGoColdInTheBackground) {
  Reopen(/*cold_after_s=*/1);
  ASSERT_TRUE(cold_);
  for (int i = 0; i < 300 && cold_->Stats().cold_frames < kFrames; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(cold_->Stats().cold_frames, kFrames);
}

#ifndef HVDB_TEST_RADOS  // damages a file in place: a local directory
TEST_F(ColdTierTest, ACorruptCompressedBlockIsDetectedAndNamed) {
  ASSERT_TRUE(cold_->Compact(4, 4).ok());
  Close();
  // Flip a byte in the middle of frame 4's compressed tree (inside a block's payload).
  std::string victim;
  for (const auto& e : std::filesystem::directory_iterator(dir_.path() + "/cold/trees")) {
    if (e.path().filename().string().rfind("00000004-", 0) == 0) victim = e.path().string();
  }
  ASSERT_FALSE(victim.empty());
  const auto size = std::filesystem::file_size(victim);
  {
    std::fstream f(victim, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(size * 2 / 3));
    char c = 0;
    f.read(&c, 1);
    f.seekp(static_cast<std::streamoff>(size * 2 / 3));
    c = static_cast<char>(c ^ 0x10);
    f.write(&c, 1);
  }
  Reopen();
  ASSERT_TRUE(cold_);
  auto problems = cold_->Check();
  ASSERT_FALSE(problems.empty());
  EXPECT_NE(problems[0].find(victim.substr(victim.rfind('/') + 1)), std::string::npos)
      << problems[0];
  EXPECT_NE(problems[0].find("block"), std::string::npos) << problems[0];
  // A query over the damaged frame fails with that error; the other frames still answer.
  auto c = cold_->Query(testing::FrameWindow(4, kFps), {});
  bool failed = !c.ok();
  if (c.ok()) {
    Batch b;
    for (;;) {
      auto more = (*c)->Next(&b);
      if (!more.ok()) {
        failed = true;
        EXPECT_EQ(more.status().code(), StatusCode::kCorruption) << more.status().ToString();
        break;
      }
      if (!*more) break;
    }
  }
  EXPECT_TRUE(failed);
  EXPECT_EQ(RunQuery(*cold_, testing::FrameWindow(5, kFps), {}).size(), 30000u);
}
#endif

}  // namespace
}  // namespace hvdb
