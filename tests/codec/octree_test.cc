// The octree geometry (codec/octree.h) and hvdb7 version 2 streams: Morton codes against a
// brute-force bit loop, octree round trips on random cells (duplicates, every depth, one or
// two threads), lossless grid coding of real frames bit-exact and equal to the pair coder's,
// temporal streams that predict a static background, and corrupt payloads refused.
#include <algorithm>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "codec/codec.h"
#include "codec/octree.h"
#include "formats/ply.h"
#include "tests/codec/codec_test_util.h"

namespace hvdb::codec {
namespace {

using namespace testing_util;

uint64_t SlowMorton(uint32_t x, uint32_t y, uint32_t z) {
  uint64_t m = 0;
  for (int i = 0; i < 21; ++i) {
    m |= uint64_t{(x >> i) & 1} << (3 * i + 2);
    m |= uint64_t{(y >> i) & 1} << (3 * i + 1);
    m |= uint64_t{(z >> i) & 1} << (3 * i);
  }
  return m;
}

TEST(OctreeTest, MortonCodesMatchTheBitLoop) {
  std::mt19937 rng(1);
  for (int i = 0; i < 10000; ++i) {
    const uint32_t x = rng() & 0x1FFFFF, y = rng() & 0x1FFFFF, z = rng() & 0x1FFFFF;
    const uint64_t m = MortonCode(x, y, z);
    ASSERT_EQ(m, SlowMorton(x, y, z));
    uint32_t a, b, c;
    MortonDecode(m, &a, &b, &c);
    ASSERT_EQ(a, x);
    ASSERT_EQ(b, y);
    ASSERT_EQ(c, z);
  }
}

// Random cells of a 2^depth grid: clustered (a surface-like blob) or uniform, with repeats.
std::vector<uint64_t> RandomCells(size_t n, int depth, bool clustered, uint64_t seed) {
  std::mt19937_64 rng(seed);
  const uint32_t side = 1u << depth;
  std::vector<uint64_t> codes(n);
  std::normal_distribution<double> g(0, side / 16.0);
  for (size_t i = 0; i < n; ++i) {
    uint32_t c[3];
    for (uint32_t& v : c) {
      const double d = clustered ? side / 2.0 + g(rng) : static_cast<double>(rng() % side);
      v = static_cast<uint32_t>(std::clamp(d, 0.0, side - 1.0));
    }
    codes[i] = MortonCode(c[0], c[1], c[2]);
    if (i > 0 && rng() % 10 == 0) codes[i] = codes[rng() % i];  // several points in one cell
  }
  std::sort(codes.begin(), codes.end());
  return codes;
}

TEST(OctreeTest, RoundTripsEveryDepthWithDuplicates) {
  for (int depth : {1, 2, 3, 5, 8, 10, 13, 16, 21}) {
    for (bool clustered : {false, true}) {
      for (size_t n : {size_t{1}, size_t{7}, size_t{3000}, size_t{70000}}) {
        SCOPED_TRACE(testing::Message() << "depth " << depth << " n " << n << " clustered " << clustered);
        const auto codes = RandomCells(n, depth, clustered, depth * 1000 + n);
        std::string one, two;
        EncodeOctree(codes, depth, nullptr, 1, &one);
        EncodeOctree(codes, depth, nullptr, 2, &two);
        ASSERT_EQ(one, two);  // the bytes do not depend on the threads
        for (int threads : {1, 2}) {
          std::vector<uint64_t> back;
          Status st = DecodeOctree(one, depth, codes.size(), nullptr, threads, &back);
          ASSERT_TRUE(st.ok()) << st.ToString();
          ASSERT_EQ(back, codes);
        }
      }
    }
  }
  std::string empty;
  EncodeOctree({}, 10, nullptr, 2, &empty);
  std::vector<uint64_t> back{1, 2};
  ASSERT_TRUE(DecodeOctree(empty, 10, 0, nullptr, 2, &back).ok());
  EXPECT_TRUE(back.empty());
}

TEST(OctreeTest, CorruptPayloadsAreRefusedWithoutCrashing) {
  const auto codes = RandomCells(20000, 10, true, 7);
  std::string good;
  EncodeOctree(codes, 10, nullptr, 2, &good);
  std::vector<uint64_t> out;
  // Every truncation is caught (the chunk table sums the lengths).
  for (size_t cut = 0; cut < good.size(); cut += 1 + cut / 8) {
    EXPECT_TRUE(DecodeOctree(good.substr(0, cut), 10, codes.size(), nullptr, 2, &out).IsCorruption()) << cut;
  }
  EXPECT_TRUE(DecodeOctree(good, 10, codes.size() + 1, nullptr, 2, &out).IsCorruption());
  // Flipped bytes: a clear error, or (inside a chunk's coded bytes, which carry no checksum
  // of their own: hvdb7 segments do) a tree of the same point count.
  std::mt19937 rng(3);
  for (int i = 0; i < 300; ++i) {
    std::string bad = good;
    const size_t at = rng() % bad.size();
    bad[at] = static_cast<char>(bad[at] ^ (1 + rng() % 255));
    Status st = DecodeOctree(bad, 10, codes.size(), nullptr, 2, &out);
    if (st.ok()) {
      EXPECT_EQ(out.size(), codes.size());
    } else {
      EXPECT_TRUE(st.IsCorruption()) << st.ToString();
    }
  }
}

std::vector<Point> Bunny() {
  auto r = formats::ReadPly(HVDB_SHARED_DATA "/stanford-bunny/reconstruction/bun_zipper.ply");
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  std::vector<Point> pts = r.ok() ? std::move(r).value() : std::vector<Point>{};
  for (size_t i = 0; i < pts.size(); ++i) pts[i].id = i;
  return pts;
}

// Lossless on the grid: the octree stream decodes to exactly what the pair stream decodes to
// (both quantise the same way), every attribute exact, point for point by id; and the octree
// takes fewer bits for the positions.
TEST(OctreeTest, GridLosslessStreamsAreBitExactOnRealFrames) {
  for (const auto& pts : {Panoptic(380), Bunny()}) {
    for (int qp : {10, 16}) {
      SCOPED_TRACE(testing::Message() << pts.size() << " points, qp " << qp);
      EncodeOptions o;
      o.qp = qp;
      o.qc = 8;
      o.qn = 16;
      o.qcov = 0;
      o.attributes = kAllAttributes;
      o.geometry = EncodeOptions::Geometry::kOctree;
      const std::string oct = MustEncode(pts, o);
      o.geometry = EncodeOptions::Geometry::kPairs;
      const std::string pairs = MustEncode(pts, o);
      StreamInfo info;
      ASSERT_TRUE(ReadInfo(oct, &info).ok());
      EXPECT_EQ(info.version, 2);
      EXPECT_TRUE(info.octree);
      DecodeOptions single;
      single.threads = 1;
      const auto a = MustDecode(oct), a1 = MustDecode(oct, single), b = MustDecode(pairs);
      ASSERT_EQ(a, a1);
      ASSERT_EQ(a.size(), pts.size());
      auto ma = ById(a), mb = ById(b);
      ASSERT_EQ(ma.size(), pts.size());
      for (const auto& [id, p] : mb) {
        ASSERT_TRUE(ma.count(id)) << id;
        ASSERT_EQ(ma[id], p) << "point " << id;
      }
    }
  }
}

// Captured frames (Panoptic's fused depth maps): the octree codes positions in fewer bits
// than the pair hierarchy (bench/README.md has the figures for every data set).
TEST(OctreeTest, PositionsTakeFewerBitsThanThePairHierarchy) {
  const auto pts = Panoptic(384);
  EncodeOptions o;
  o.qp = 10;
  o.attributes = kPosition;
  o.geometry = EncodeOptions::Geometry::kPairs;
  const size_t pair_bytes = MustEncode(pts, o).size();
  o.geometry = EncodeOptions::Geometry::kAuto;
  const size_t oct_bytes = MustEncode(pts, o).size();
  EXPECT_LT(static_cast<double>(oct_bytes), 0.95 * static_cast<double>(pair_bytes));
}

TEST(OctreeTest, OptionsOutsideTheOctreeAreRefused) {
  const auto pts = Bunny();
  EncodeOptions o;
  o.geometry = EncodeOptions::Geometry::kOctree;
  std::string s;
  o.qp = 0;
  EXPECT_TRUE(Encode(pts, o, &s).IsInvalidArgument());
  o.qp = 22;
  EXPECT_TRUE(Encode(pts, o, &s).IsInvalidArgument());
  o.qp = 21;
  EXPECT_TRUE(Encode(pts, o, &s).ok());
  // Auto: exact floats and finer grids go to the pair hierarchy.
  o.geometry = EncodeOptions::Geometry::kAuto;
  StreamInfo info;
  o.qp = 0;
  ASSERT_TRUE(Encode(pts, o, &s).ok());
  ASSERT_TRUE(ReadInfo(s, &info).ok());
  EXPECT_FALSE(info.octree);
  o.qp = 12;
  ASSERT_TRUE(Encode(pts, o, &s).ok());
  ASSERT_TRUE(ReadInfo(s, &info).ok());
  EXPECT_TRUE(info.octree);
}

// A room (floor and two walls, textured) that does not move and a sphere that does: frame f's
// sphere is centred 5 cm further along x than frame f - 1's.
std::vector<Point> StaticRoom(int frame) {
  std::vector<Point> pts;
  std::mt19937_64 rng(42);  // the same background samples in every frame
  std::uniform_real_distribution<float> u(0.f, 1.f);
  for (int i = 0; i < 60000; ++i) {
    Point p;
    const float s = u(rng) * 4 - 2, t = u(rng) * 2;
    switch (i % 3) {
      case 0: p.x = s, p.y = 0, p.z = t; break;      // floor
      case 1: p.x = s, p.y = t, p.z = 0; break;      // back wall
      default: p.x = -2, p.y = t, p.z = s / 2 + 1;   // side wall
    }
    p.r = static_cast<uint8_t>(128 + 100 * std::sin(7 * p.x + 3 * p.z));
    p.g = static_cast<uint8_t>(128 + 90 * std::cos(5 * p.y));
    p.b = static_cast<uint8_t>(60 + (i % 97));
    p.id = static_cast<uint64_t>(i);
    pts.push_back(p);
  }
  std::mt19937_64 srng(1000 + frame);  // the sphere is sampled anew every frame
  std::normal_distribution<float> g(0.f, 1.f);
  for (int i = 0; i < 8000; ++i) {
    float v[3] = {g(srng), g(srng), g(srng)};
    const float n = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) + 1e-6f;
    Point p;
    p.x = -0.5f + 0.05f * static_cast<float>(frame) + 0.3f * v[0] / n;
    p.y = 0.6f + 0.3f * v[1] / n;
    p.z = 0.8f + 0.3f * v[2] / n;
    p.r = 200, p.g = static_cast<uint8_t>(100 + 50 * v[1] / n), p.b = 30;
    p.id = 1000000 + static_cast<uint64_t>(i);
    pts.push_back(p);
  }
  return pts;
}

TEST(OctreeTest, TemporalStreamsPredictWhatDidNotMove) {
  for (uint32_t attrs : {uint32_t{kPosition}, uint32_t{kPosition | kColor}}) {
    SCOPED_TRACE(AttributeNames(attrs));
    EncodeOptions o;
    o.qp = 11;
    o.attributes = attrs;
    const std::string first = MustEncode(StaticRoom(0), o);
    Reference ref;
    ref.points = MustDecode(first);
    StreamInfo info;
    ASSERT_TRUE(ReadInfo(first, &info).ok());
    for (int a = 0; a < 3; ++a) ref.origin[a] = info.origin[a];
    ref.step = info.step;
    ref.qp = info.qp;
    const auto next = StaticRoom(1);
    const std::string intra = MustEncode(next, o);
    const std::string temporal = MustEncode(next, o, &ref);
    // Far below intra: the room costs next to nothing.
    EXPECT_LT(static_cast<double>(temporal.size()), 0.5 * static_cast<double>(intra.size()))
        << temporal.size() << " vs " << intra.size();
    DecodeOptions d;
    d.reference = &ref;
    const auto back = MustDecode(temporal, d);
    // The same points as the intra stream decodes to (same grid: the room's extent).
    auto mi = ById(MustDecode(intra)), mt = ById(back);
    ASSERT_EQ(mi.size(), mt.size());
    for (const auto& [id, p] : mi) ASSERT_EQ(mt[id], p) << id;
    // Without its reference, or with another frame, it is refused clearly.
    std::vector<Point> out;
    EXPECT_TRUE(Decode(temporal, &out).IsInvalidArgument());
    Reference wrong;
    wrong.points = MustDecode(intra);
    d.reference = &wrong;
    EXPECT_TRUE(Decode(temporal, &out, d).IsInvalidArgument());
  }
}

}  // namespace
}  // namespace hvdb::codec
