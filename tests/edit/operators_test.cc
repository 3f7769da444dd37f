// The editing operators on a real dataset, each checked against a brute-force model, and undo
// (Revert) bringing back exactly the previous state.
#include "edit/operators.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <cstring>
#include <filesystem>
#include <random>
#include <set>

#include "tests/edit/scene.h"
#include "tests/storage/test_util.h"

namespace hvdb::edit {
namespace {

constexpr double kFps = 10;
using Key = std::pair<uint32_t, uint64_t>;

Window Everything() { return testing::EverythingWindow(); }

std::map<Key, Point> ReadAll(Dataset& ds) {
  std::map<Key, Point> out;
  auto c = ds.Query(Everything());
  EXPECT_TRUE(c.ok());
  Batch b;
  while (*(*c)->Next(&b)) {
    for (const Point& p : b.points) out[{p.frame, p.id}] = p;
  }
  return out;
}

std::set<Key> WithBit(const std::map<Key, Point>& all, int bit) {
  std::set<Key> s;
  for (const auto& [k, p] : all) {
    if (p.label & (1u << bit)) s.insert(k);
  }
  return s;
}

// A camera 2 m above (0.5, 0.5, 0) looking straight down: camera x = world x, camera y =
// world -y, camera z (forward) = world -z.
CameraInfo TopCamera() {
  CameraInfo c;
  c.width = c.height = 500;
  c.fx = c.fy = 500;
  c.cx = c.cy = 250;
  c.world_from_camera = {1, 0, 0, 0.5, 0, -1, 0, 0.5, 0, 0, -1, 2, 0, 0, 0, 1};
  return c;
}

class OperatorsTest : public ::testing::Test {
 protected:
  void SetUp() override {
    Options o;
    o.cache_bytes = 32u << 20;
    auto db = Database::Open(dir_.path(), o);
    ASSERT_TRUE(db.ok());
    db_ = std::move(*db);
    DatasetInfo info;
    info.name = "scene";
    info.fps = kFps;
    ds_ = *db_->CreateDataset(info);
    auto scene = testing::MovingSphereScene(3, 0.02);
    for (uint32_t f = 0; f < 3; ++f) {
      std::vector<Point> pts;
      for (const auto& s : scene) {
        if (s.p.frame == f) pts.push_back(s.p);
      }
      ASSERT_TRUE(ds_->BulkLoad(f, pts).ok());
    }
    for (const auto& [k, p] : ReadAll(*ds_)) {
      // The sphere is everything above the plane.
      if (p.z > 0.001) sphere_.insert(k);
    }
    ASSERT_GT(sphere_.size(), 100u);
  }
  // Graph-cut strokes: a dab on the sphere in frame 0 (bit 1), one on the plane (bit 2).
  void PaintStrokes() {
    SelectRequest dab;
    Window top = Everything();
    top.lo = {0.25, 0.45, 0.28, 0};
    top.hi = {0.35, 0.55, 1, 0};
    dab.region = top;
    dab.bit = 1;
    ASSERT_TRUE(Select(*ds_, dab).ok());
    Window floor = Everything();
    floor.lo = {0.7, 0.0, -1, 0};
    floor.hi = {1.0, 0.3, 0.001, 0};
    dab.region = floor;
    dab.bit = 2;
    ASSERT_TRUE(Select(*ds_, dab).ok());
  }
  // A cut over everything from those strokes into bit 0.
  static GraphCutRequest SphereCut() {
    GraphCutRequest gc;
    gc.roi = Everything();
    gc.out_bit = 0;
    gc.params.intra_radius = 0.05;  // this scene is sampled every 2 cm
    gc.params.inter_radius = 0.08;
    return gc;
  }
  testing::TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
  std::set<Key> sphere_;
};

TEST_F(OperatorsTest, RegionSelectionModesMatchTheModel) {
  auto before = ReadAll(*ds_);
  auto in_box = [](const Point& p, double x0, double x1) { return p.x >= x0 && p.x <= x1; };
  Window a = Everything(), b = Everything();
  a.hi[0] = 0.5;
  b.lo[0] = 0.3;
  SelectRequest r;
  r.bit = 3;
  r.region = a;
  // What a client applying each reply's flips shows (the page's label-only refresh).
  std::set<Key> shown;
  auto select = [&]() -> SelectResult {
    r.return_flips = true;
    auto res = Select(*ds_, r);
    EXPECT_TRUE(res.ok()) << res.status().ToString();
    if (!res.ok()) return {};
    for (const LabelFlips& f : res->flips) {
      EXPECT_TRUE(std::is_sorted(f.ids.begin(), f.ids.end()));
      for (uint64_t id : f.ids) {
        if (f.set) {
          EXPECT_TRUE(shown.insert({f.frame, id}).second) << id << " set twice";
        } else {
          EXPECT_EQ(shown.erase({f.frame, id}), 1u) << id << " cleared but not set";
        }
      }
    }
    return *res;
  };
  select();
  std::set<Key> model;
  for (const auto& [k, p] : before) {
    if (in_box(p, -1e9, 0.5)) model.insert(k);
  }
  EXPECT_EQ(WithBit(ReadAll(*ds_), 3), model);
  EXPECT_EQ(shown, model);
  r.region = b;
  r.mode = SelectMode::kIntersect;
  SelectResult res = select();
  std::erase_if(model, [&](const Key& k) { return !in_box(before[k], 0.3, 1e9); });
  EXPECT_EQ(WithBit(ReadAll(*ds_), 3), model);
  EXPECT_EQ(res.selected, model.size());
  EXPECT_EQ(shown, model);
  r.mode = SelectMode::kSubtract;
  Window c = Everything();
  c.lo[0] = 0.4;
  r.region = c;
  select();
  std::erase_if(model, [&](const Key& k) { return before[k].x >= 0.4; });
  EXPECT_EQ(WithBit(ReadAll(*ds_), 3), model);
  EXPECT_EQ(shown, model);
  r.mode = SelectMode::kAdd;
  Window d = Everything();
  d.lo[0] = 0.9;
  r.region = d;
  select();
  for (const auto& [k, p] : before) {
    if (p.x >= 0.9) model.insert(k);
  }
  EXPECT_EQ(WithBit(ReadAll(*ds_), 3), model);
  EXPECT_EQ(shown, model);
  // Replace: the old selection's points outside the new region come back as cleared.
  r.mode = SelectMode::kReplace;
  r.region = a;
  res = select();
  model.clear();
  for (const auto& [k, p] : before) {
    if (in_box(p, -1e9, 0.5)) model.insert(k);
  }
  EXPECT_EQ(WithBit(ReadAll(*ds_), 3), model);
  EXPECT_EQ(shown, model);
  // Without return_flips, none.
  r.return_flips = false;
  r.region = b;
  auto plain = Select(*ds_, r);
  ASSERT_TRUE(plain.ok());
  EXPECT_TRUE(plain->flips.empty());
  // A region of frame 0: the replace also clears the bit in frames 1 and 2, but the flips list
  // only the region's frame (what a client showing it redraws).
  Window f0 = Everything();
  f0.lo[3] = f0.hi[3] = 0;
  r.region = f0;
  r.return_flips = true;
  auto one = Select(*ds_, r);
  ASSERT_TRUE(one.ok());
  ASSERT_FALSE(one->flips.empty());
  for (const LabelFlips& f : one->flips) EXPECT_EQ(f.frame, 0u);
  const auto now = WithBit(ReadAll(*ds_), 3);
  ASSERT_FALSE(now.empty());
  for (const Key& k : now) EXPECT_EQ(k.first, 0u);
  // Labels aside, nothing moved.
  auto after = ReadAll(*ds_);
  ASSERT_EQ(after.size(), before.size());
  for (auto& [k, p] : after) {
    Point q = p;
    q.label = before[k].label;
    EXPECT_EQ(q, before[k]);
  }
}

TEST_F(OperatorsTest, MarqueeThroughACamera) {
  auto all = ReadAll(*ds_);
  Lasso lasso;
  lasso.camera = TopCamera();
  lasso.polygon = {{100, 100}, {200, 100}, {200, 200}, {100, 200}};
  SelectRequest r;
  Window f1 = Everything();
  f1.lo[3] = f1.hi[3] = 1 / kFps;
  r.region = f1;
  r.shape = lasso;
  r.bit = 4;
  auto res = Select(*ds_, r);
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  std::set<Key> model;
  for (const auto& [k, p] : all) {
    if (p.frame != 1) continue;
    double depth = 2.0 - p.z;
    double u = 500 * (p.x - 0.5) / depth + 250, v = 500 * (0.5 - p.y) / depth + 250;
    if (u >= 100 && u <= 200 && v >= 100 && v <= 200) model.insert(k);
  }
  EXPECT_GT(model.size(), 10u);
  EXPECT_EQ(WithBit(ReadAll(*ds_), 4), model);
}

TEST_F(OperatorsTest, PaintbrushNearestAndMedianDepth) {
  // Under the sphere's top (frame 0: centre x 0.3, y 0.5): the front surface is the sphere.
  Brush brush;
  brush.camera = TopCamera();
  double u = 500 * (0.3 - 0.5) / (2.0 - 0.31) + 250, v = 250;
  brush.u = u;
  brush.v = v;
  brush.pixel_radius = 6;
  brush.radius = 0.05;
  brush.depth = Brush::Depth::kNearest;
  Window f0 = Everything();
  f0.lo[3] = f0.hi[3] = 0;
  SelectRequest r;
  r.region = f0;
  r.shape = brush;
  r.bit = 5;
  auto res = Select(*ds_, r);
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  ASSERT_TRUE(res->brush_center);
  EXPECT_NEAR((*res->brush_center)[2], 0.31, 0.02);  // on the sphere's top
  for (const Key& k : WithBit(ReadAll(*ds_), 5)) EXPECT_TRUE(sphere_.count(k));
  // Far from the sphere the brush lands on the plane.
  brush.u = 500 * (0.9 - 0.5) / 2.0 + 250;
  brush.v = 500 * (0.5 - 0.1) / 2.0 + 250;
  brush.depth = Brush::Depth::kMedian;
  r.shape = brush;
  r.bit = 6;
  res = Select(*ds_, r);
  ASSERT_TRUE(res.ok());
  EXPECT_NEAR((*res->brush_center)[2], 0.0, 0.01);
  EXPECT_NEAR((*res->brush_center)[0], 0.9, 0.02);
  // Nothing under the brush: a clear error.
  brush.u = -1000;
  r.shape = brush;
  EXPECT_TRUE(Select(*ds_, r).status().IsNotFound());
}

TEST_F(OperatorsTest, GraphCutSelectionAndUndo) {
  auto before = ReadAll(*ds_);
  PaintStrokes();
  if (HasFatalFailure()) return;
  auto strokes = ReadAll(*ds_);
  const GraphCutRequest gc = SphereCut();
  auto res = GraphCutSelect(*ds_, gc);
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  EXPECT_EQ(res->roi_points, before.size());
  auto sel = WithBit(ReadAll(*ds_), 0);
  size_t tp = 0;
  for (const Key& k : sel) tp += sphere_.count(k);
  double precision = double(tp) / sel.size(), recall = double(tp) / sphere_.size();
  EXPECT_GE(precision, 0.95);
  EXPECT_GE(recall, 0.95);
  // Undo: exactly the state before the cut.
  ASSERT_TRUE(ds_->Revert(res->lsn).ok());
  EXPECT_EQ(ReadAll(*ds_), strokes);
}

// The thesis's workflow: cut, paint one more stroke, cut again. With a cache the second cut
// reuses the first's graph and flow (the query returns the points in another order, as the
// first cut relabelled them) and selects exactly what a cut from scratch selects.
TEST_F(OperatorsTest, CutAgainAfterAnotherStrokeReusesTheGraph) {
  PaintStrokes();
  if (HasFatalFailure()) return;
  SelectRequest dab;
  dab.bit = 2;
  const GraphCutRequest gc = SphereCut();
  GraphCutCache cache;
  auto first = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  EXPECT_FALSE(first->cut.warm);
  // One more stroke, on the floor in the last frame.
  Window far = Everything();
  far.lo = {0.0, 0.7, -1, 0.2};
  far.hi = {0.3, 1.0, 0.001, 10};
  dab.region = far;
  ASSERT_TRUE(Select(*ds_, dab).ok());
  auto again = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE(again->cut.warm);
  EXPECT_TRUE(again->labels_only);  // only a stroke (labels) changed since the first cut
  EXPECT_EQ(again->cut.neighbours_ms, 0);
  const auto warm = WithBit(ReadAll(*ds_), 0);
  // From scratch, on the same labels.
  auto cold = GraphCutSelect(*ds_, gc);
  ASSERT_TRUE(cold.ok());
  EXPECT_FALSE(cold->cut.warm);
  EXPECT_EQ(cold->lsn, 0u) << "a cut from scratch changed the re-cut's selection";
  EXPECT_EQ(WithBit(ReadAll(*ds_), 0), warm);
  EXPECT_NEAR(again->cut.energy, cold->cut.energy, 1e-6 * cold->cut.energy);
  // Other points (a moved point) are not the cached graph's: a new one is built.
  Transaction t;
  Selection one;
  one.ids = {ReadAll(*ds_).begin()->first};
  Affine4 up;
  up.c = {0, 0, 0.001, 0};
  t.Transform(one, up);
  ASSERT_TRUE(ds_->Commit(t).ok());
  auto moved = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(moved.ok());
  EXPECT_FALSE(moved->cut.warm);
  EXPECT_FALSE(moved->labels_only);
}

// A re-cut that reads only labels still leaves exactly a cut's selection in the output bit when
// other edits flipped that bit since the last cut, and reads the whole region again once a
// change was not labels only (an undone transform: the same points, but not only labels).
TEST_F(OperatorsTest, AReCutReadingLabelsOnlyStillSeesOtherEdits) {
  PaintStrokes();
  if (HasFatalFailure()) return;
  const GraphCutRequest gc = SphereCut();
  GraphCutCache cache;
  auto first = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(first.ok()) << first.status().ToString();
  EXPECT_FALSE(first->labels_only);
  const auto cut = WithBit(ReadAll(*ds_), 0);
  ASSERT_FALSE(cut.empty());
  // Another edit clears the output bit on part of the selection and sets it on the floor.
  SelectRequest other;
  other.bit = 0;
  other.mode = SelectMode::kSubtract;
  Window half = Everything();
  half.hi[0] = 0.5;
  other.region = half;
  ASSERT_TRUE(Select(*ds_, other).ok());
  other.mode = SelectMode::kAdd;
  Window corner = Everything();
  corner.lo = {0.8, 0.8, -1, 0};
  corner.hi = {1.0, 1.0, 0.001, 10};
  other.region = corner;
  ASSERT_TRUE(Select(*ds_, other).ok());
  ASSERT_NE(WithBit(ReadAll(*ds_), 0), cut);
  auto again = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE(again->labels_only);
  EXPECT_NE(again->lsn, 0u);
  EXPECT_EQ(WithBit(ReadAll(*ds_), 0), cut);
  // Nothing changed since: labels only, nothing to commit.
  auto same = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(same.ok());
  EXPECT_TRUE(same->labels_only);
  EXPECT_EQ(same->lsn, 0u);
  // A transform and its undo: the points are the same again, but the change was not labels
  // only, so the region is read whole (and the graph, the same points, reused).
  Transaction t;
  Selection one;
  one.ids = {*cut.begin()};
  Affine4 up;
  up.c = {0, 0, 0.001, 0};
  t.Transform(one, up);
  auto moved = ds_->Commit(t);
  ASSERT_TRUE(moved.ok());
  ASSERT_TRUE(ds_->Revert(moved->lsn).ok());
  auto reread = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(reread.ok());
  EXPECT_FALSE(reread->labels_only);
  EXPECT_TRUE(reread->cut.warm);
  EXPECT_EQ(WithBit(ReadAll(*ds_), 0), cut);
  // Another region: read whole.
  GraphCutRequest part = gc;
  std::get<Window>(part.roi).hi[0] = 0.9;
  auto other_roi = GraphCutSelect(*ds_, part, &cache);
  ASSERT_TRUE(other_roi.ok());
  EXPECT_FALSE(other_roi->labels_only);
}

// A cut that fails (no background stroke) after a change that was not labels only must not
// leave the output bit as the last successful cut knew it: here a point of the selection was
// deleted and inserted again without the bit (the same point otherwise, so the graph is kept).
TEST_F(OperatorsTest, AFailedCutForgetsWhereTheOutputBitWas) {
  PaintStrokes();
  if (HasFatalFailure()) return;
  const GraphCutRequest gc = SphereCut();
  GraphCutCache cache;
  ASSERT_TRUE(GraphCutSelect(*ds_, gc, &cache).ok());
  const auto cut = WithBit(ReadAll(*ds_), 0);
  ASSERT_FALSE(cut.empty());
  Point p = ReadAll(*ds_).at(*cut.begin());
  Transaction del;
  del.Delete(p.id, p.frame, {p.x, p.y, p.z});
  ASSERT_TRUE(ds_->Commit(del).ok());
  p.label &= ~1u;
  Transaction ins;
  ins.Insert({p});
  ASSERT_TRUE(ds_->Commit(ins).ok());
  ASSERT_FALSE(WithBit(ReadAll(*ds_), 0).count(*cut.begin()));
  // No background stroke: the cut fails, after reading the region (the graph is kept).
  SelectRequest clear;
  clear.region = Everything();
  clear.bit = 2;
  clear.mode = SelectMode::kSubtract;
  ASSERT_TRUE(Select(*ds_, clear).ok());
  EXPECT_FALSE(GraphCutSelect(*ds_, gc, &cache).ok());
  // The stroke again (labels only): a re-cut that reads labels, and the point gets its bit.
  PaintStrokes();
  if (HasFatalFailure()) return;
  auto again = GraphCutSelect(*ds_, gc, &cache);
  ASSERT_TRUE(again.ok()) << again.status().ToString();
  EXPECT_TRUE(again->labels_only);
  EXPECT_EQ(WithBit(ReadAll(*ds_), 0), cut);
}

TEST_F(OperatorsTest, CutPasteAndRedo) {
  auto before = ReadAll(*ds_);
  SelectRequest r;
  Window above = Everything();
  above.lo[2] = 0.001;
  r.region = above;
  r.bit = 7;
  ASSERT_TRUE(Select(*ds_, r).ok());
  ClipboardStore store(dir_.path());
  auto cut = Copy(*ds_, 7, std::nullopt, store, "ball", /*cut=*/true);
  ASSERT_TRUE(cut.ok()) << cut.status().ToString();
  EXPECT_EQ(cut->points, sphere_.size());
  auto now = ReadAll(*ds_);
  EXPECT_EQ(now.size(), before.size() - sphere_.size());
  for (const Key& k : sphere_) EXPECT_FALSE(now.count(k));
  EXPECT_EQ(store.List(), std::vector<std::string>{"ball"});
  // Paste into another dataset, 1 m further in x and one frame later.
  DatasetInfo info;
  info.name = "other";
  info.fps = kFps;
  auto other = *db_->CreateDataset(info);
  auto clip = store.Get("ball");
  ASSERT_TRUE(clip.ok());
  Affine4 move;
  move.c = {1.0, 0, 0, 1 / kFps};
  auto pasted = Paste(*other, *clip, move);
  ASSERT_TRUE(pasted.ok()) << pasted.status().ToString();
  auto got = ReadAll(*other);
  ASSERT_EQ(got.size(), clip->points.size());
  EXPECT_EQ(clip->gaussians, nullptr);  // plain points: no records
  std::multiset<std::tuple<uint32_t, float, float, float>> want, have;
  for (const Point& p : clip->points) want.insert({p.frame + 1, p.x + 1.0f, p.y, p.z});
  for (const auto& [k, p] : got) have.insert({p.frame, p.x, p.y, p.z});
  EXPECT_EQ(have, want);
  // Undo the paste, redo it.
  auto undo = other->Revert(pasted->lsn);
  ASSERT_TRUE(undo.ok());
  EXPECT_TRUE(ReadAll(*other).empty());
  ASSERT_TRUE(other->Revert(undo->lsn).ok());
  EXPECT_EQ(ReadAll(*other).size(), clip->points.size());
  // Undo the cut: the sphere is back exactly.
  ASSERT_TRUE(ds_->Revert(cut->lsn).ok());
  auto restored = ReadAll(*ds_);
  for (const Key& k : sphere_) {
    ASSERT_TRUE(restored.count(k));
    Point p = restored[k];
    EXPECT_EQ(p.x, before[k].x);
  }
  EXPECT_TRUE(store.Get("nope").status().IsNotFound());
}

// Copy and paste in a Gaussian-splat dataset: the clipboard keeps each splat's record, and a
// paste with a rotation and scale inserts the records turned as a transform turns stored
// splats; into a plain dataset only the points go; a damaged clipboard file is named.
TEST_F(OperatorsTest, CopyPasteCarriesSplatRecordsTurned) {
  DatasetInfo info;
  info.name = "splats";
  info.fps = kFps;
  info.gaussians = true;
  auto splats = *db_->CreateDataset(info);
  std::mt19937_64 rng(17);
  std::normal_distribution<float> g;
  constexpr size_t kN = 300;
  std::vector<Point> pts(kN);
  GaussianColumns cols;
  cols.sh_degree = 3;
  cols.values.resize(kN * cols.stride());
  for (size_t i = 0; i < kN; ++i) {
    float* rec = cols.record(i);
    for (size_t k = 0; k < cols.stride(); ++k) rec[k] = g(rng);
    for (int k = 0; k < 3; ++k) rec[kGsScale + k] = -4 + 0.5f * g(rng);
    pts[i].x = g(rng), pts[i].y = g(rng), pts[i].z = g(rng);
    pts[i].cov = GaussianCovariance(rec);
    pts[i].flags = kFlagHasCovariance;
  }
  ASSERT_TRUE(splats->BulkLoadGaussians(0, pts, cols).ok());
  SelectRequest r;
  r.region = Everything();
  r.bit = 4;
  ASSERT_TRUE(Select(*splats, r).ok());
  ClipboardStore store(dir_.path());
  auto copied = Copy(*splats, 4, std::nullopt, store, "splats", /*cut=*/false);
  ASSERT_TRUE(copied.ok()) << copied.status().ToString();
  auto clip = store.Get("splats");
  ASSERT_TRUE(clip.ok()) << clip.status().ToString();
  ASSERT_NE(clip->gaussians, nullptr);
  ASSERT_EQ(clip->points.size(), kN);
  auto source = splats->ReadGaussians(clip->points);
  ASSERT_TRUE(source.ok());
  EXPECT_EQ(source->values, clip->gaussians->values);

  // 90 degrees about z, scaled by 2, one frame later.
  Affine4 move;
  move.a = {0, -2, 0, 0, 2, 0, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1};
  move.c = {0, 0, 0, 1 / kFps};
  auto pasted = Paste(*splats, *clip, move);
  ASSERT_TRUE(pasted.ok()) << pasted.status().ToString();
  ASSERT_EQ(pasted->assigned_ids.size(), kN);
  std::vector<Point> got;
  for (const auto& [k, p] : ReadAll(*splats)) {
    if (p.frame == 1) got.push_back(p);
  }
  ASSERT_EQ(got.size(), kN);
  uint64_t derived = 0;
  auto records = splats->ReadGaussians(got, &derived);
  ASSERT_TRUE(records.ok());
  EXPECT_EQ(derived, 0u);
  const GaussianRecordMap turn({0, -2, 0, 2, 0, 0, 0, 0, 2});
  std::map<uint64_t, size_t> clip_index;  // pasted id -> clipboard index (ids in paste order)
  for (size_t i = 0; i < kN; ++i) clip_index[pasted->assigned_ids[i]] = i;
  for (size_t i = 0; i < got.size(); ++i) {
    const size_t j = clip_index.at(got[i].id);
    std::vector<float> want(clip->gaussians->record(j), clip->gaussians->record(j) + cols.stride());
    ASSERT_TRUE(turn.Apply(3, want.data()));
    EXPECT_EQ(0, std::memcmp(want.data(), records->record(i), 4 * want.size())) << i;
    EXPECT_FLOAT_EQ(got[i].x, -2 * clip->points[j].y);
    EXPECT_EQ(got[i].cov, GaussianCovariance(records->record(i)));
  }
  // Undo the paste: frame 1 is empty again; redo brings the same records.
  auto undo = splats->Revert(pasted->lsn);
  ASSERT_TRUE(undo.ok());
  ASSERT_TRUE(splats->Revert(undo->lsn).ok());
  auto again = splats->ReadGaussians(got);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->values, records->values);

  // Into a plain dataset: the points, no records.
  DatasetInfo plain_info;
  plain_info.name = "plain";
  plain_info.fps = kFps;
  auto plain = *db_->CreateDataset(plain_info);
  ASSERT_TRUE(Paste(*plain, *clip, Affine4{}).ok());
  EXPECT_EQ(ReadAll(*plain).size(), kN);

  // A clipboard file cut short is named as damaged.
  const std::string file = dir_.path() + "/clipboards/splats.hvc";
  std::filesystem::resize_file(file, std::filesystem::file_size(file) - 100);
  auto bad = store.Get("splats");
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kCorruption);
  EXPECT_NE(bad.status().message().find("splats.hvc"), std::string::npos);
}

TEST_F(OperatorsTest, CompositeAlongATrajectory) {
  std::vector<Point> object(50);
  for (size_t i = 0; i < object.size(); ++i) {
    object[i].x = static_cast<float>(i) * 0.01f;
    object[i].r = 255;
  }
  auto before = ReadAll(*ds_).size();
  std::vector<std::array<double, 3>> path = {{0, 0, 1}, {0.1, 0, 1}, {0.2, 0, 1}, {0.3, 0, 1}};
  auto r = Composite(*ds_, object, 1, 4, path);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->inserted, 200u);
  auto all = ReadAll(*ds_);
  EXPECT_EQ(all.size(), before + 200);
  for (uint32_t f = 1; f <= 4; ++f) {
    size_t n = 0;
    for (const auto& [k, p] : all) {
      if (k.first == f && p.z == 1.0f) {
        ++n;
        EXPECT_GE(p.x, 0.1f * (f - 1) - 1e-6f);
      }
    }
    EXPECT_EQ(n, 50u);
  }
  EXPECT_TRUE(Composite(*ds_, object, 0, 3, path).status().IsInvalidArgument());
  EXPECT_TRUE(Composite(*ds_, {}, 0, 1).status().IsInvalidArgument());
}

TEST_F(OperatorsTest, BadParameters) {
  SelectRequest r;
  r.region = Everything();
  r.bit = 32;
  EXPECT_TRUE(Select(*ds_, r).status().IsInvalidArgument());
  r.bit = 0;
  Lasso l;
  l.camera = TopCamera();
  l.polygon = {{0, 0}, {1, 1}};
  r.shape = l;
  EXPECT_TRUE(Select(*ds_, r).status().IsInvalidArgument());
  GraphCutRequest gc;
  gc.roi = Everything();
  gc.foreground_bit = gc.background_bit = 1;
  EXPECT_TRUE(GraphCutSelect(*ds_, gc).status().IsInvalidArgument());
  gc.background_bit = 2;  // no strokes at all
  EXPECT_TRUE(GraphCutSelect(*ds_, gc).status().IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb::edit
