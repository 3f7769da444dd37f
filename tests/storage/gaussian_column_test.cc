// The Gaussian column (storage/gaussian_column.h): records stored bit for bit and read back by
// id through every path that moves points, durable before their points (crash and power loss
// at every step of a load, through the fault Env), corruption named, edits it cannot follow
// that turn splats writing their turned records (undone bit for bit).
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <thread>

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include "storage/database.h"
#include "storage/gaussian_column.h"
#include "storage/gaussian_sh.h"
#include "tests/storage/fault_env.h"
#include "tests/storage/test_util.h"

namespace hvdb::testing {
namespace {

// n splats of SH degree `degree`: anisotropic, varied opacity, random SH (seeded).
void MakeSplats(uint64_t seed, size_t n, int degree, std::vector<Point>* pts,
                GaussianColumns* cols) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0.f, 1.f);
  pts->clear();
  cols->sh_degree = degree;
  cols->values.assign(n * cols->stride(), 0.f);
  for (size_t i = 0; i < n; ++i) {
    float* rec = cols->record(i);
    for (size_t k = 0; k < cols->stride(); ++k) rec[k] = g(rng);
    for (int k = 0; k < 3; ++k) rec[kGsScale + k] = -4.f + 0.5f * g(rng);
    Point p = RandomPoint(rng, 0);
    p.id = 0;
    p.cov = GaussianCovariance(rec);
    p.flags = kFlagHasCovariance;
    pts->push_back(p);
  }
}

// The records of a frame's points, ordered by id (= load order).
struct Read {
  std::vector<Point> points;
  GaussianColumns cols;
  uint64_t derived = 0;
};
Read ReadFrame(Dataset& ds, uint32_t frame) {
  Read r;
  auto cur = ds.Query(FrameWindow(frame, ds.Info().fps));
  EXPECT_TRUE(cur.ok()) << cur.status().ToString();
  if (!cur.ok()) return r;
  Batch b;
  while (true) {
    auto more = (*cur)->Next(&b);
    EXPECT_TRUE(more.ok());
    if (!more.ok() || !*more) break;
    r.points.insert(r.points.end(), b.points.begin(), b.points.end());
  }
  std::sort(r.points.begin(), r.points.end(),
            [](const Point& x, const Point& y) { return x.id < y.id; });
  auto cols = ds.ReadGaussians(r.points, &r.derived);
  EXPECT_TRUE(cols.ok()) << cols.status().ToString();
  if (cols.ok()) r.cols = std::move(cols).value();
  return r;
}

bool SameBits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), 4 * a.size()) == 0;
}

// The one segment file of dataset `name` in data directory `dir`.
std::string OnlySegment(const std::string& dir, const std::string& name) {
  std::string seg;
  for (const auto& e : std::filesystem::directory_iterator(dir + "/" + name + "/gaussians")) {
    EXPECT_TRUE(seg.empty()) << "more than one segment";
    seg = e.path();
  }
  EXPECT_FALSE(seg.empty());
  return seg;
}

// Overwrites one byte of a file in place (damage on disk).
void PatchByte(const std::string& path, std::streamoff at, char value) {
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(at);
  f.write(&value, 1);
}

std::shared_ptr<Dataset> MakeGaussianDataset(Database& db, const std::string& name) {
  DatasetInfo info;
  info.name = name;
  info.fps = 30;
  info.gaussians = true;
  auto ds = db.CreateDataset(info);
  EXPECT_TRUE(ds.ok()) << ds.status().ToString();
  return ds.ok() ? *ds : nullptr;
}

TEST(GaussianColumnTest, RecordsComeBackBitForBitAfterMergesColdTierAndReopen) {
  TempDir dir;
  std::vector<Point> pts3, pts0;
  GaussianColumns c3, c0;
  MakeSplats(1, 5000, 3, &pts3, &c3);
  MakeSplats(2, 1200, 0, &pts0, &c0);
  Options o;
  o.t0_points = 256;
  {
    auto db = Database::Open(dir.path(), o);
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds);
    ASSERT_TRUE(ds->BulkLoadGaussians(0, pts3, c3).ok());
    ASSERT_TRUE(ds->BulkLoadGaussians(1, pts0, c0).ok());
    // A second load into a frame that holds points goes through the merger's path.
    std::vector<Point> more(pts0.begin(), pts0.begin() + 100);
    GaussianColumns cm = c0;
    cm.values.resize(100 * cm.stride());
    ASSERT_TRUE(ds->BulkLoadGaussians(1, more, cm).ok());
    ASSERT_TRUE(ds->WaitForMerges().ok());
    ASSERT_TRUE(ds->Compact(0, 1).ok());
    DatasetStats s = ds->Stats();
    EXPECT_EQ(s.gaussian_segments, 3u);
    EXPECT_EQ(s.gaussian_records, 5000u + 1200 + 100);
    EXPECT_GT(s.gaussian_bytes, 5000u * 4 * GaussianRecordFloats(3));
  }
  auto db = Database::Open(dir.path(), o);
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("splats");
  ASSERT_TRUE(ds.ok());
  EXPECT_TRUE((*ds)->Info().gaussians);
  Read r0 = ReadFrame(**ds, 0);
  ASSERT_EQ(r0.points.size(), 5000u);
  EXPECT_EQ(r0.derived, 0u);
  EXPECT_EQ(r0.cols.sh_degree, 3);
  EXPECT_TRUE(SameBits(r0.cols.values, c3.values));
  for (size_t i = 0; i < pts3.size(); ++i) {
    ASSERT_EQ(r0.points[i].x, pts3[i].x);
    ASSERT_EQ(r0.points[i].cov, pts3[i].cov);
  }
  Read r1 = ReadFrame(**ds, 1);
  ASSERT_EQ(r1.points.size(), 1300u);
  EXPECT_EQ(r1.cols.sh_degree, 0);
  std::vector<float> want = c0.values;
  want.insert(want.end(), c0.values.begin(), c0.values.begin() + 100 * c0.stride());
  EXPECT_TRUE(SameBits(r1.cols.values, want));
  EXPECT_TRUE((*ds)->Check().empty());

  // Both frames at once: degree 0 records padded to degree 3 with zeros, each channel's run.
  std::vector<Point> both = {r0.points[7], r1.points[3]};
  auto mixed = (*ds)->ReadGaussians(both);
  ASSERT_TRUE(mixed.ok());
  ASSERT_EQ(mixed->sh_degree, 3);
  EXPECT_EQ(0, std::memcmp(mixed->record(0), c3.record(7), 4 * c3.stride()));
  const float* rec = mixed->record(1);
  EXPECT_EQ(0, std::memcmp(rec, c0.record(3), 4 * kGsRest));
  for (size_t k = kGsRest; k < mixed->stride(); ++k) EXPECT_EQ(rec[k], 0.f);
}

TEST(GaussianColumnTest, EditsKeepRecords) {
  TempDir dir;
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  auto ds = MakeGaussianDataset(**db, "splats");
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(3, 300, 2, &pts, &cols);
  ASSERT_TRUE(ds->BulkLoadGaussians(4, pts, cols).ok());
  Read before = ReadFrame(*ds, 4);

  // A move in space and time keeps each point's record (the column is keyed by id).
  Transaction move;
  Affine4 shift;
  shift.c = {0.5, 0, 0, 1.0 / 30};
  move.Transform(Selection{}, shift);
  auto moved = ds->Commit(move);
  ASSERT_TRUE(moved.ok()) << moved.status().ToString();
  Read after = ReadFrame(*ds, 5);
  ASSERT_EQ(after.points.size(), 300u);
  EXPECT_EQ(after.derived, 0u);
  EXPECT_TRUE(SameBits(after.cols.values, before.cols.values));

  // Delete, then undo: the records come back with the points.
  Transaction del;
  del.DeleteSelection(Selection{});
  auto d = ds->Commit(del);
  ASSERT_TRUE(d.ok());
  EXPECT_TRUE(ReadFrame(*ds, 5).points.empty());
  ASSERT_TRUE(ds->Revert(d->lsn).ok());
  EXPECT_TRUE(SameBits(ReadFrame(*ds, 5).cols.values, before.cols.values));

  // A point an edit inserts without a record reads as its derived Gaussian.
  Transaction ins;
  Point p = pts[0];
  p.id = 0;
  p.frame = 9;
  ins.Insert({p});
  ASSERT_TRUE(ds->Commit(ins).ok());
  Read nine = ReadFrame(*ds, 9);
  ASSERT_EQ(nine.points.size(), 1u);
  EXPECT_EQ(nine.derived, 1u);
}

// A transform of 4x4 row-major `a3` (the spatial block) and translation c.
Affine4 Linear(const std::array<double, 9>& a3, std::array<double, 3> c = {0, 0, 0}) {
  Affine4 m;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.a[4 * i + j] = a3[3 * i + j];
  }
  m.c = {c[0], c[1], c[2], 0};
  return m;
}

// Checks that `after` is `before` moved by the linear map a: the covariance A Sigma A^T, opacity
// and DC colour to the bit, and (for an orthogonal a) every direction's colour kept: the colour
// seen along a d afterwards is the one seen along d before (brute force over directions).
void ExpectTurned(const std::array<double, 9>& a, int degree, const float* before,
                  const float* after, bool orthogonal_times_k) {
  EXPECT_EQ(after[kGsOpacity], before[kGsOpacity]);
  for (int c = 0; c < 3; ++c) EXPECT_EQ(after[kGsDc + c], before[kGsDc + c]);
  const std::array<float, 6> c0 = GaussianCovariance(before), c1 = GaussianCovariance(after);
  const double s[3][3] = {{c0[0], c0[1], c0[2]}, {c0[1], c0[3], c0[4]}, {c0[2], c0[4], c0[5]}};
  const int idx[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
  double scale = 0;
  for (int e = 0; e < 6; ++e) scale = std::max(scale, std::fabs(double(c1[e])));
  for (int e = 0; e < 6; ++e) {
    const int i = idx[e][0], j = idx[e][1];
    double want = 0;
    for (int k = 0; k < 3; ++k) {
      for (int l = 0; l < 3; ++l) want += a[3 * i + k] * s[k][l] * a[3 * j + l];
    }
    EXPECT_NEAR(c1[e], want, 2e-5 * scale) << "covariance entry " << e;
  }
  if (!orthogonal_times_k || degree == 0) return;
  const double k = std::cbrt(std::fabs(a[0] * (a[4] * a[8] - a[5] * a[7]) -
                                      a[1] * (a[3] * a[8] - a[5] * a[6]) +
                                      a[2] * (a[3] * a[7] - a[4] * a[6])));
  const size_t per = (GaussianRecordFloats(degree) - kGsRest) / 3;
  std::mt19937_64 rng(5);
  std::normal_distribution<double> g;
  for (int t = 0; t < 20; ++t) {
    std::array<double, 3> d = {g(rng), g(rng), g(rng)};
    const double n = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (double& v : d) v /= n;
    std::array<double, 3> ad{};
    for (int i = 0; i < 3; ++i) ad[i] = (a[3 * i] * d[0] + a[3 * i + 1] * d[1] + a[3 * i + 2] * d[2]) / k;
    for (size_t ch = 0; ch < 3; ++ch) {
      EXPECT_NEAR(EvalShRest(degree, after + kGsRest + ch * per, ad),
                  EvalShRest(degree, before + kGsRest + ch * per, d), 2e-5);
    }
  }
}

// Rotations, mirrors, uniform and unequal scales of a Gaussian dataset write each splat's turned
// record under a new id; undo brings back the old points and records bit for bit, and both
// survive a reopen.
TEST(GaussianColumnTest, TransformsTurnSplatsAndUndoRestoresThem) {
  TempDir dir;
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(31, 400, 3, &pts, &cols);
  const std::array<double, 9> quarter = {0, -1, 0, 1, 0, 0, 0, 0, 1};  // 90 degrees about z
  const double c = std::cos(0.7), sn = std::sin(0.7);
  const std::array<double, 9> tilt_scaled = {1.5, 0, 0, 0, 1.5 * c, -1.5 * sn, 0, 1.5 * sn, 1.5 * c};
  const std::array<double, 9> mirror = {-1, 0, 0, 0, 1, 0, 0, 0, 1};
  const std::array<double, 9> unequal = {2, 0.3, 0, 0, 1, 0, 0, 0, 0.5};
  struct Case {
    std::array<double, 9> a;
    bool similarity;
  };
  std::vector<uint64_t> lsns;
  Read redone;
  {
    auto db = Database::Open(dir.path());
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds->BulkLoadGaussians(2, pts, cols).ok());
    const Read original = ReadFrame(*ds, 2);
    for (const Case& cs : {Case{quarter, true}, Case{tilt_scaled, true}, Case{mirror, true},
                           Case{unequal, false}}) {
      const Read before = ReadFrame(*ds, 2);
      Transaction t;
      t.Transform(Selection{}, Linear(cs.a, {0.25, 0, 0}));
      auto done = ds->Commit(t);
      ASSERT_TRUE(done.ok()) << done.status().ToString();
      lsns.push_back(done->lsn);
      const Read after = ReadFrame(*ds, 2);
      ASSERT_EQ(after.points.size(), before.points.size());
      EXPECT_EQ(after.derived, 0u);
      EXPECT_EQ(after.cols.sh_degree, 3);
      // Each new point is the old one moved (matched by position), with a new id.
      std::map<std::array<float, 3>, size_t> by_position;
      for (size_t i = 0; i < before.points.size(); ++i) {
        const Point& p = before.points[i];
        std::array<float, 3> q;
        for (int k = 0; k < 3; ++k) {  // in storage/affine.cc's order
          double y = k == 0 ? 0.25 : 0;
          y += cs.a[3 * k] * double(p.x);
          y += cs.a[3 * k + 1] * double(p.y);
          y += cs.a[3 * k + 2] * double(p.z);
          q[k] = static_cast<float>(y);
        }
        by_position[q] = i;
      }
      for (size_t i = 0; i < after.points.size(); ++i) {
        const Point& q = after.points[i];
        auto it = by_position.find({q.x, q.y, q.z});
        ASSERT_NE(it, by_position.end()) << "point " << q.id << " is no moved point";
        const size_t j = it->second;
        EXPECT_GT(q.id, before.points.back().id);
        EXPECT_EQ(q.label, before.points[j].label);
        EXPECT_EQ(q.cov, GaussianCovariance(after.cols.record(i)));
        ExpectTurned(cs.a, 3, before.cols.record(j), after.cols.record(i), cs.similarity);
      }
    }
    // Undo, latest first: the original points and records, bit for bit.
    uint64_t last_undo = 0;
    for (auto it = lsns.rbegin(); it != lsns.rend(); ++it) {
      auto undone = ds->Revert(*it);
      ASSERT_TRUE(undone.ok()) << undone.status().ToString();
      last_undo = undone->lsn;
    }
    const Read back = ReadFrame(*ds, 2);
    ASSERT_EQ(back.points.size(), original.points.size());
    for (size_t i = 0; i < back.points.size(); ++i) ASSERT_EQ(back.points[i], original.points[i]);
    EXPECT_TRUE(SameBits(back.cols.values, original.cols.values));
    // Redo of the first (undo of its undo): its records are still there.
    ASSERT_TRUE(ds->Revert(last_undo).ok());
    redone = ReadFrame(*ds, 2);
  }
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("splats");
  ASSERT_TRUE(ds.ok());
  const Read reopened = ReadFrame(**ds, 2);
  ASSERT_EQ(reopened.points.size(), pts.size());
  EXPECT_EQ(reopened.derived, 0u);
  for (size_t i = 0; i < reopened.points.size(); ++i) ASSERT_EQ(reopened.points[i], redone.points[i]);
  EXPECT_TRUE(SameBits(reopened.cols.values, redone.cols.values));
  EXPECT_GT(reopened.points[0].id, pts.size());  // the first transform's points
  EXPECT_TRUE((*ds)->Check().empty());
  // Every segment is kept: the load's and the four transforms' (undo needs them).
  EXPECT_EQ((*ds)->Stats().gaussian_segments, 5u);
}

// A crash between any two mutating calls of a commit that turns splats, then a power loss:
// the frame is the turned one with every record, or the one before with no segment left.
TEST(GaussianColumnTest, CrashAtEveryCallOfATurnLeavesItWholeOrAbsent) {
  TempDir tmp;
  const std::string path = tmp.path() + "/db";
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(32, 1500, 2, &pts, &cols);
  FaultEnv env(tmp.path() + "/aside");
  Options o;
  o.env = &env;
  Transaction turn;
  turn.Transform(Selection{}, Linear({0, -1, 0, 1, 0, 0, 0, 0, 1}));
  auto fresh = [&]() {
    std::filesystem::remove_all(path);
    env.Reset();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds);
    ASSERT_TRUE(ds->BulkLoadGaussians(0, pts, cols).ok());
  };
  uint64_t total = 0;
  {
    fresh();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset("splats");
    const uint64_t before = env.mutating_calls();
    ASSERT_TRUE((*ds)->Commit(turn).ok());
    total = env.mutating_calls() - before;
  }
  ASSERT_GT(total, 4u);
  int whole = 0, absent = 0;
  for (uint64_t k = 1; k <= total + 1; ++k) {
    SCOPED_TRACE("crash after call " + std::to_string(k) + " of " + std::to_string(total));
    fresh();
    if (HasFatalFailure()) return;
    Read original;
    bool acked = false;
    {
      auto db = Database::Open(path, o);
      ASSERT_TRUE(db.ok());
      auto ds = (*db)->GetDataset("splats");
      ASSERT_TRUE(ds.ok());
      original = ReadFrame(**ds, 0);
      env.CrashAfter(k);
      acked = (*ds)->Commit(turn).ok();
    }
    env.PowerLoss();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset("splats");
    ASSERT_TRUE(ds.ok());
    Read r = ReadFrame(**ds, 0);
    ASSERT_EQ(r.points.size(), pts.size());
    EXPECT_EQ(r.derived, 0u);
    if (r.points[0].id == original.points[0].id) {
      EXPECT_FALSE(acked);
      ++absent;
      EXPECT_TRUE(SameBits(r.cols.values, original.cols.values));
      EXPECT_EQ((*ds)->Stats().gaussian_segments, 1u) << "an orphan segment was left";
    } else {
      ++whole;
      EXPECT_GT(r.points[0].id, original.points.back().id);
      EXPECT_EQ((*ds)->Stats().gaussian_segments, 2u);
    }
    EXPECT_TRUE((*ds)->Check().empty());
  }
  EXPECT_GT(whole, 0);
  EXPECT_GT(absent, 0);
  std::printf("[ fault ] Gaussian turn: %llu mutating calls; %d crashes left it whole, %d absent\n",
              static_cast<unsigned long long>(total), whole, absent);
}

TEST(GaussianColumnTest, PlainDatasetsRefuseSplatsAndDeriveGaussians) {
  TempDir dir;
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  DatasetInfo info;
  info.name = "plain";
  auto ds = (*db)->CreateDataset(info);
  ASSERT_TRUE(ds.ok());
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(4, 10, 0, &pts, &cols);
  auto st = (*ds)->BulkLoadGaussians(0, pts, cols);
  ASSERT_FALSE(st.ok());
  EXPECT_NE(st.status().message().find("--gaussians"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(dir.path() + "/plain/gaussians"));  // pays nothing

  // Derived: the covariance the record implies is the point's.
  Point p;
  p.flags = kFlagHasCovariance;
  p.cov = {4e-4f, 1e-4f, -5e-5f, 2e-4f, 3e-5f, 1e-4f};
  p.r = 200, p.g = 100, p.b = 0;
  float rec[GaussianRecordFloats(0)];
  DeriveGaussian(p, rec);
  std::array<float, 6> back = GaussianCovariance(rec);
  for (int k = 0; k < 6; ++k) EXPECT_NEAR(back[k], p.cov[k], 1e-8) << k;
  EXPECT_NEAR(0.5 + 0.28209479177387814 * rec[kGsDc], 200 / 255.0, 1e-6);
  EXPECT_NEAR(1 / (1 + std::exp(-rec[kGsOpacity])), 0.99, 1e-6);

  // A load whose counts disagree, or with a NaN, is refused whole.
  auto gds = MakeGaussianDataset(**db, "g");
  GaussianColumns short_cols = cols;
  short_cols.values.resize(5 * cols.stride());
  EXPECT_FALSE(gds->BulkLoadGaussians(0, pts, short_cols).ok());
  GaussianColumns nan_cols = cols;
  nan_cols.values[3] = std::nanf("");
  auto nan = gds->BulkLoadGaussians(0, pts, nan_cols);
  ASSERT_FALSE(nan.ok());
  EXPECT_NE(nan.status().message().find("splat 0"), std::string::npos);
  EXPECT_EQ(gds->Info().point_count, 0u);
}

TEST(GaussianColumnTest, CorruptSegmentIsNamed) {
  TempDir dir;
  std::string seg;
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(5, 3000, 1, &pts, &cols);
  {
    auto db = Database::Open(dir.path());
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds->BulkLoadGaussians(0, pts, cols).ok());
  }
  seg = OnlySegment(dir.path(), "splats");
  ASSERT_FALSE(seg.empty());
  PatchByte(seg, 64 + 4 * 1500 * GaussianRecordFloats(1), 0x5a);  // in block 1
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("splats");
  ASSERT_TRUE(ds.ok());
  auto cur = (*ds)->Query(EverythingWindow());
  ASSERT_TRUE(cur.ok());
  Batch b;
  std::vector<Point> all;
  while (*(*cur)->Next(&b)) all.insert(all.end(), b.points.begin(), b.points.end());
  auto cols_read = (*ds)->ReadGaussians(all);
  ASSERT_FALSE(cols_read.ok());
  EXPECT_EQ(cols_read.status().code(), StatusCode::kCorruption);
  EXPECT_NE(cols_read.status().message().find(seg), std::string::npos);
  EXPECT_NE(cols_read.status().message().find("block 1"), std::string::npos);
  auto problems = (*ds)->Check();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find("block 1 checksum mismatch"), std::string::npos);
}

// A crash between any two mutating calls of a Gaussian load, then a power loss: the frame is
// whole with every record, or absent with no segment left behind.
TEST(GaussianColumnTest, CrashAtEveryCallOfALoadLeavesItWholeOrAbsent) {
  TempDir tmp;
  const std::string path = tmp.path() + "/db";
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(6, 2500, 3, &pts, &cols);
  FaultEnv env(tmp.path() + "/aside");
  Options o;
  o.env = &env;
  auto fresh = [&]() {
    std::filesystem::remove_all(path);
    env.Reset();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds);
    // One committed load before: it must survive every crash of the next one.
    std::vector<Point> first(pts.begin(), pts.begin() + 10);
    GaussianColumns fc = cols;
    fc.values.resize(10 * fc.stride());
    ASSERT_TRUE(ds->BulkLoadGaussians(0, first, fc).ok());
  };
  uint64_t total = 0;
  {
    fresh();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset("splats");
    const uint64_t before = env.mutating_calls();
    ASSERT_TRUE((*ds)->BulkLoadGaussians(1, pts, cols).ok());
    total = env.mutating_calls() - before;
  }
  ASSERT_GT(total, 4u);
  int whole = 0, absent = 0;
  for (uint64_t k = 1; k <= total + 1; ++k) {
    SCOPED_TRACE("crash after call " + std::to_string(k) + " of " + std::to_string(total));
    fresh();
    if (HasFatalFailure()) return;
    bool acked = false;
    {
      auto db = Database::Open(path, o);
      ASSERT_TRUE(db.ok());
      auto ds = (*db)->GetDataset("splats");
      ASSERT_TRUE(ds.ok());
      env.CrashAfter(k);
      acked = (*ds)->BulkLoadGaussians(1, pts, cols).ok();
    }
    env.PowerLoss();
    auto db = Database::Open(path, o);
    ASSERT_TRUE(db.ok());
    auto ds = (*db)->GetDataset("splats");
    ASSERT_TRUE(ds.ok());
    Read r0 = ReadFrame(**ds, 0);
    ASSERT_EQ(r0.points.size(), 10u);
    EXPECT_EQ(r0.derived, 0u);
    Read r1 = ReadFrame(**ds, 1);
    if (r1.points.empty()) {
      EXPECT_FALSE(acked);
      ++absent;
      EXPECT_EQ((*ds)->Stats().gaussian_segments, 1u) << "an orphan segment was left";
    } else {
      ++whole;
      ASSERT_EQ(r1.points.size(), pts.size());
      EXPECT_EQ(r1.derived, 0u);
      EXPECT_TRUE(SameBits(r1.cols.values, cols.values));
    }
    EXPECT_TRUE((*ds)->Check().empty());
  }
  EXPECT_GT(whole, 0);
  EXPECT_GT(absent, 0);
  std::printf("[ fault ] Gaussian load: %llu mutating calls; %d crashes left it whole, %d absent\n",
              static_cast<unsigned long long>(total), whole, absent);
}

// A follower reads the writer's records as they come (its reloads keep the column it reads
// through), and becomes the writer of them.
TEST(GaussianColumnTest, AFollowerReadsNewRecordsAndIsPromoted) {
  TempDir dir;
  std::vector<Point> p0, p1, p2;
  GaussianColumns c0, c1, c2;
  MakeSplats(11, 2000, 3, &p0, &c0);
  MakeSplats(12, 1500, 1, &p1, &c1);
  MakeSplats(13, 100, 0, &p2, &c2);
  auto writer = Database::Open(dir.path());
  ASSERT_TRUE(writer.ok());
  auto wds = MakeGaussianDataset(**writer, "splats");
  ASSERT_TRUE(wds->BulkLoadGaussians(0, p0, c0).ok());
  Options fo;
  fo.follow = true;
  auto follower = Database::Open(dir.path(), fo);
  ASSERT_TRUE(follower.ok()) << follower.status().ToString();
  ASSERT_TRUE((*follower)->follower());
  auto fds = (*follower)->GetDataset("splats");
  ASSERT_TRUE(fds.ok());
  EXPECT_TRUE(SameBits(ReadFrame(**fds, 0).cols.values, c0.values));
  // The writer loads and checkpoints (a full reload for the follower) while it reads.
  ASSERT_TRUE(wds->BulkLoadGaussians(1, p1, c1).ok());
  ASSERT_TRUE(wds->Checkpoint().ok());
  ASSERT_TRUE((*follower)->Refresh().ok());
  Read r1 = ReadFrame(**fds, 1);
  ASSERT_EQ(r1.points.size(), p1.size());
  EXPECT_EQ(r1.derived, 0u);
  EXPECT_TRUE(SameBits(r1.cols.values, c1.values));
  EXPECT_TRUE(SameBits(ReadFrame(**fds, 0).cols.values, c0.values));
  // The writer goes; the follower takes over and loads.
  wds.reset();
  writer->reset();
  auto promoted = (*follower)->TryPromote();
  ASSERT_TRUE(promoted.ok()) << promoted.status().ToString();
  ASSERT_TRUE(*promoted);
  ASSERT_TRUE((*fds)->BulkLoadGaussians(2, p2, c2).ok());
  EXPECT_TRUE(SameBits(ReadFrame(**fds, 2).cols.values, c2.values));
  EXPECT_EQ((*fds)->Stats().gaussian_segments, 3u);
  EXPECT_TRUE((*fds)->Check().empty());
}

// A damaged segment leaves the dataset open: its points read as derived Gaussians and check
// names it; reads that would need too many blocks are refused, not done.
TEST(GaussianColumnTest, ADamagedSegmentIsReportedNotFatalAndReadsAreBounded) {
  TempDir dir;
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(14, 5000, 2, &pts, &cols);
  {
    auto db = Database::Open(dir.path());
    ASSERT_TRUE(db.ok());
    auto ds = MakeGaussianDataset(**db, "splats");
    ASSERT_TRUE(ds->BulkLoadGaussians(0, pts, cols).ok());
    // 5000 records are 5 blocks: a read of one id in each needs 5.
    Read r = ReadFrame(*ds, 0);
    std::vector<uint64_t> ids;
    for (size_t k = 0; k < 5; ++k) ids.push_back(r.points[k * 1024].id);
    GaussianColumns out;
    std::vector<bool> found;
    EXPECT_TRUE(ds->ReadGaussianRecords(ids, &out, &found, 5).ok());
    Status st = ds->ReadGaussianRecords(ids, &out, &found, 4);
    EXPECT_EQ(st.code(), StatusCode::kLimitExceeded) << st.ToString();
  }
  const std::string seg = OnlySegment(dir.path(), "splats");
  PatchByte(seg, 13, 7);  // the degree, in the checksummed header
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok()) << db.status().ToString();
  auto ds = (*db)->GetDataset("splats");
  ASSERT_TRUE(ds.ok()) << ds.status().ToString();
  Read r = ReadFrame(**ds, 0);
  EXPECT_EQ(r.points.size(), pts.size());
  EXPECT_EQ(r.derived, pts.size());
  auto problems = (*ds)->Check();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems[0].find(seg), std::string::npos) << problems[0];
  EXPECT_NE(problems[0].find("header checksum"), std::string::npos) << problems[0];
}

// A process killed (SIGKILL) at points through a large Gaussian load: on reopen the frame is
// whole with every record or absent, no orphan segment or temporary file is left, twice stable.
TEST(GaussianColumnTest, KillDuringALoadLeavesItWholeOrAbsent) {
  std::vector<Point> pts;
  GaussianColumns cols;
  MakeSplats(8, 150000, 3, &pts, &cols);  // 35 MB of records, 9.6 MB of points
  double load_ms = 0;
  int whole = 0, absent = 0;
  for (double fraction : {2.0, 0.1, 0.3, 0.5, 0.7, 0.9, 0.97}) {
    SCOPED_TRACE("kill at " + std::to_string(fraction) + " of the load");
    TempDir tmp;
    const std::string dir = tmp.path() + "/db";
    {
      auto db = Database::Open(dir);
      ASSERT_TRUE(db.ok());
      ASSERT_TRUE(MakeGaussianDataset(**db, "splats"));
    }
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    std::fflush(stdout);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::close(fds[0]);
      auto db = Database::Open(dir);
      if (!db.ok()) ::_exit(2);
      auto ds = (*db)->GetDataset("splats");
      if (!ds.ok()) ::_exit(3);
      char c = 'o';
      if (::write(fds[1], &c, 1) != 1) ::_exit(4);
      if (!(*ds)->BulkLoadGaussians(1, pts, cols).ok()) ::_exit(5);
      c = 'd';
      if (::write(fds[1], &c, 1) != 1) ::_exit(6);
      ::_exit(0);
    }
    ::close(fds[1]);
    char c = 0;
    ASSERT_EQ(::read(fds[0], &c, 1), 1);  // opened: the load starts now
    const auto t0 = std::chrono::steady_clock::now();
    if (fraction >= 1.5) {
      ASSERT_EQ(::read(fds[0], &c, 1), 1);
      EXPECT_EQ(c, 'd');
      load_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0)
                    .count();
    } else {
      std::this_thread::sleep_for(std::chrono::microseconds(
          static_cast<int64_t>(fraction * load_ms * 1000)));
      ::kill(pid, SIGKILL);
    }
    int status = 0;
    ::waitpid(pid, &status, 0);
    ::close(fds[0]);
    ASSERT_TRUE(WIFSIGNALED(status) || (WIFEXITED(status) && WEXITSTATUS(status) == 0));
    for (int open = 0; open < 2; ++open) {
      auto db = Database::Open(dir);
      ASSERT_TRUE(db.ok()) << db.status().ToString();
      auto ds = (*db)->GetDataset("splats");
      ASSERT_TRUE(ds.ok()) << ds.status().ToString();
      Read r = ReadFrame(**ds, 1);
      if (r.points.empty()) {
        EXPECT_EQ((*ds)->Stats().gaussian_segments, 0u) << "an orphan segment was left";
        if (open == 0) ++absent;
      } else {
        ASSERT_EQ(r.points.size(), pts.size());
        EXPECT_EQ(r.derived, 0u);
        EXPECT_TRUE(SameBits(r.cols.values, cols.values));
        if (open == 0) ++whole;
      }
      EXPECT_TRUE((*ds)->Check().empty());
      for (const auto& e : std::filesystem::directory_iterator(dir + "/splats/gaussians")) {
        EXPECT_FALSE(e.path().string().ends_with(".tmp")) << e.path();
      }
    }
  }
  EXPECT_GT(whole, 0);
  std::printf("[ kill ] Gaussian load of 150k splats: %.0f ms undisturbed; after the kills %d "
              "whole, %d absent\n", load_ms, whole, absent);
}

}  // namespace
}  // namespace hvdb::testing
