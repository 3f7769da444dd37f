// The hvdb7 coder (codec/): round trips at every rate against the quantisation bound, lossless
// mode bit-exact, progressive prefixes, temporal streams, and clear errors for corrupt,
// truncated and foreign data. Real data: a Panoptic frame; synthetic sets with seeds.
#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "codec/codec.h"
#include "codec/metrics.h"
#include "formats/ply.h"
#include "tests/codec/codec_test_util.h"

namespace hvdb::codec {
namespace {

using namespace testing_util;

// Points on a wavy sheet with every field random (seeded).
std::vector<Point> Synthetic(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  std::vector<Point> pts(n);
  for (size_t i = 0; i < n; ++i) {
    Point& p = pts[i];
    p.id = rng();
    p.x = u(rng) * 2 - 1;
    p.y = u(rng) * 2 - 1;
    p.z = 0.1f * std::sin(3 * p.x) * std::cos(2 * p.y) + 0.001f * u(rng);
    p.frame = static_cast<uint32_t>(rng() % 3);
    p.r = static_cast<uint8_t>(128 + 100 * std::sin(5 * p.x));
    p.g = static_cast<uint8_t>(rng());
    p.b = static_cast<uint8_t>(200 * u(rng));
    p.normal_oct = EncodeNormal(u(rng) - 0.5f, u(rng) - 0.5f, 1.f);
    float t1[3] = {0.01f * u(rng), 0.002f, 0}, t2[3] = {0, 0.01f * u(rng) + 1e-4f, 0.001f},
          t3[3] = {0, 0, 0.001f + 0.001f * u(rng)};
    p.cov = CovarianceFromSpanning(t1, t2, t3);
    p.label = static_cast<uint32_t>(rng());
    p.camera = static_cast<uint16_t>(rng() % 8);
    p.flags = kFlagHasNormal | kFlagHasCovariance;
  }
  return pts;
}

TEST(CodecTest, LosslessModeIsBitExact) {
  for (const auto& pts : {Synthetic(5001, 1), Panoptic(380)}) {
    EncodeOptions o;
    o.qp = 0;
    o.qc = 8;
    o.qn = 16;
    o.qcov = 0;
    o.attributes = kAllAttributes;
    for (bool progressive : {false, true}) {
      o.progressive = progressive;
      std::vector<Point> back = MustDecode(MustEncode(pts, o));
      ASSERT_EQ(back.size(), pts.size());
      auto a = ById(pts), b = ById(back);
      ASSERT_EQ(a.size(), b.size());
      for (const auto& [id, p] : a) {
        ASSERT_TRUE(b.count(id)) << id;
        EXPECT_EQ(p, b[id]) << "point " << id;
      }
    }
  }
}

// Every rate: each decoded position within half a grid step of the original per axis, colours
// within the luma/chroma step, normals within the octahedral step; exact fields exact.
TEST(CodecTest, EveryRateStaysWithinItsQuantisationBound) {
  const std::vector<Point> pts = Synthetic(3000, 2);
  float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
  for (const Point& p : pts) {
    const float v[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
  }
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
  for (int qp : {1, 4, 8, 11, 16, 20, 24, 30}) {
    for (int qc : {1, 4, 7, 8}) {
      EncodeOptions o;
      o.qp = qp;
      o.qc = qc;
      o.qn = qp % 16 + 1;
      o.attributes = kAllAttributes;
      o.progressive = qp % 2 == 0;
      auto a = ById(pts), b = ById(MustDecode(MustEncode(pts, o)));
      ASSERT_EQ(b.size(), a.size()) << "qp " << qp;
      const double step = extent / ((uint64_t{1} << qp) - 1);
      const int cstep = 1 << (8 - qc + 1);  // chroma step bounds the RGB error
      for (const auto& [id, p] : a) {
        const Point& q = b[id];
        EXPECT_LE(std::abs(p.x - q.x), step / 2 + 1e-6) << "qp " << qp;
        EXPECT_LE(std::abs(p.y - q.y), step / 2 + 1e-6) << "qp " << qp;
        EXPECT_LE(std::abs(p.z - q.z), step / 2 + 1e-6) << "qp " << qp;
        if (qc == 8) {
          EXPECT_EQ(p.r, q.r);
          EXPECT_EQ(p.g, q.g);
          EXPECT_EQ(p.b, q.b);
        } else {
          EXPECT_LE(std::abs(p.g - q.g), 2 * cstep) << "qc " << qc;
        }
        const int nstep = 1 << (16 - o.qn);
        EXPECT_LE(std::abs(p.normal_oct[0] - q.normal_oct[0]), nstep / 2 + 1);
        EXPECT_EQ(p.frame, q.frame);
        EXPECT_EQ(p.label, q.label);
        EXPECT_EQ(p.camera, q.camera);
        EXPECT_EQ(p.flags, q.flags);
        // Covariance: log-Cholesky at 2^-6: each diagonal within 2 % (2^(1/64) ~ 1.1 % per
        // factor), and positive semi-definite.
        EXPECT_NEAR(q.cov[0] / p.cov[0], 1.0, 0.03);
        EXPECT_GE(q.cov[0] * q.cov[3] - q.cov[1] * q.cov[1], -1e-12);
      }
    }
  }
}

// The shortest prefix that decodes (found by bisection): the root layer of a pair stream, the
// geometry of an octree stream.
size_t ShortestPrefix(const std::string& s) {
  size_t lo = 1, hi = s.size();
  while (lo < hi) {
    const size_t mid = (lo + hi) / 2;
    DecodeOptions d;
    d.max_bytes = mid;
    std::vector<Point> part;
    if (Decode(s, &part, d).ok()) {
      hi = mid;
    } else {
      lo = mid + 1;
    }
  }
  return lo;
}

TEST(CodecTest, ProgressivePrefixesDecodeToCoarserCompleteSets) {
  const std::vector<Point> pts = Panoptic(381);
  for (auto geometry : {EncodeOptions::Geometry::kPairs, EncodeOptions::Geometry::kOctree}) {
    SCOPED_TRACE(geometry == EncodeOptions::Geometry::kPairs ? "pairs" : "octree");
    EncodeOptions o;
    o.qp = 12;
    o.qc = 6;
    o.progressive = true;
    o.chunk = 1024;
    o.geometry = geometry;
    const std::string s = MustEncode(pts, o);
    EncodeOptions fixed = o;
    fixed.progressive = false;
    // Same points from the fixed-rate stream, a few per cent fewer bytes.
    const std::string f = MustEncode(pts, fixed);
    EXPECT_EQ(MustDecode(s), MustDecode(f));
    EXPECT_LT(f.size(), s.size());
    EXPECT_LT(static_cast<double>(s.size()), 1.05 * static_cast<double>(f.size()));
    // Pair streams decode from their root layer on; octree streams from their geometry on
    // (segment 0), the other attributes refining level by level after it.
    const size_t first = ShortestPrefix(s);
    if (geometry == EncodeOptions::Geometry::kPairs) {
      EXPECT_LT(first, s.size() / 20);
    } else {
      EXPECT_LT(first, s.size() * 3 / 4);
    }
    size_t last_points = 0;
    double last_psnr = 0;
    for (double frac : {0.0, 0.05, 0.1, 0.25, 0.5, 0.75, 0.99, 1.0}) {
      DecodeOptions d;
      d.max_bytes = first + static_cast<size_t>(frac * static_cast<double>(s.size() - first));
      std::vector<Point> part;
      Status st = Decode(s, &part, d);
      ASSERT_TRUE(st.ok()) << frac << ": " << st.ToString();
      EXPECT_GE(part.size(), last_points) << frac;
      const double psnr = Compare(pts, part).position_psnr;
      EXPECT_GE(psnr + 0.5, last_psnr) << frac;
      last_points = part.size();
      last_psnr = psnr;
    }
    EXPECT_EQ(last_points, pts.size());
    // A shorter prefix is refused, clearly.
    DecodeOptions tiny;
    tiny.max_bytes = first - 1;
    std::vector<Point> none;
    Status st = Decode(s, &none, tiny);
    EXPECT_TRUE(st.IsInvalidArgument()) << st.ToString();
    // Fixed-rate streams have no prefixes.
    tiny.max_bytes = f.size() / 2;
    st = Decode(f, &none, tiny);
    EXPECT_TRUE(st.IsInvalidArgument()) << st.ToString();
  }
}

TEST(CodecTest, TemporalStreamsNeedTheirReference) {
  EncodeOptions o;
  o.qp = 11;
  o.qc = 7;
  o.qn = 8;
  Reference ref;
  ref.points = MustDecode(MustEncode(Panoptic(380), o));
  const std::vector<Point> next = Panoptic(381);
  const std::string t = MustEncode(next, o, &ref);
  StreamInfo info;
  ASSERT_TRUE(ReadInfo(t, &info).ok());
  EXPECT_TRUE(info.temporal);
  DecodeOptions d;
  d.reference = &ref;
  // The same points as intra coding gives: temporal coding changes only the bits.
  EXPECT_EQ(MustDecode(t, d), MustDecode(MustEncode(next, o)));
  std::vector<Point> out;
  Status st = Decode(t, &out);
  EXPECT_TRUE(st.IsInvalidArgument()) << st.ToString();
  Reference wrong = ref;
  wrong.points[17].r ^= 1;
  d.reference = &wrong;
  st = Decode(t, &out, d);
  EXPECT_TRUE(st.IsInvalidArgument()) << st.ToString();
}

// threads = 1 (the browser's WebAssembly build, which has no std::thread: a spawn there
// aborts, so web/ tests that none happens) decodes the same points as the threaded decoder,
// for intra, progressive and temporal streams; a negative count is refused.
TEST(CodecTest, OneThreadDecodesWhatTheThreadedDecoderDoes) {
  EncodeOptions o;
  o.qp = 16;
  o.attributes = kAllAttributes;
  const std::vector<Point> first = Panoptic(380);
  DecodeOptions one;
  one.threads = 1;
  for (bool progressive : {false, true}) {
    o.progressive = progressive;
    const std::string s = MustEncode(first, o);
    EXPECT_EQ(MustDecode(s, one), MustDecode(s));
  }
  Reference ref;
  ref.points = MustDecode(MustEncode(first, o));
  const std::string t = MustEncode(Panoptic(381), o, &ref);
  DecodeOptions d;
  d.reference = &ref;
  one.reference = &ref;
  EXPECT_EQ(MustDecode(t, one), MustDecode(t, d));
  DecodeOptions bad;
  bad.threads = -1;
  std::vector<Point> out;
  Status st = Decode(MustEncode(first, o), &out, bad);
  EXPECT_TRUE(st.IsInvalidArgument()) << st.ToString();
  EXPECT_NE(st.message().find("threads"), std::string::npos) << st.ToString();
}

TEST(CodecTest, SmallAndDegenerateSets) {
  for (size_t n : {0, 1, 2, 3, 5, 7, 64, 513, 1025}) {
    std::vector<Point> pts = Synthetic(n, 10 + n);
    for (bool progressive : {false, true}) {
      EncodeOptions o;
      o.qp = 0;
      o.qn = 16;
      o.qcov = 0;
      o.attributes = kAllAttributes;
      o.progressive = progressive;
      o.chunk = 64;
      std::vector<Point> back = MustDecode(MustEncode(pts, o));
      auto a = ById(pts), b = ById(back);
      EXPECT_EQ(a, b) << n;
    }
  }
  // Every point in one place, and a line: the planes are degenerate.
  std::vector<Point> same(1000);
  std::vector<Point> line(1000);
  for (size_t i = 0; i < same.size(); ++i) {
    same[i].id = i;
    same[i].x = 1.5f;
    line[i].id = i;
    line[i].x = static_cast<float>(i) * 0.01f;
  }
  for (const auto& pts : {same, line}) {
    EncodeOptions o;
    o.attributes = kPosition | kId;
    o.qp = 0;
    auto a = ById(pts), b = ById(MustDecode(MustEncode(pts, o)));
    EXPECT_EQ(a, b);
  }
}

TEST(CodecTest, BadInputGetsClearErrors) {
  std::vector<Point> pts = Synthetic(100, 3);
  std::string s;
  EncodeOptions o;
  o.qp = 31;
  EXPECT_TRUE(Encode(pts, o, &s).IsInvalidArgument());
  o = {};
  o.qc = 0;
  EXPECT_TRUE(Encode(pts, o, &s).IsInvalidArgument());
  o = {};
  pts[5].y = std::nanf("");
  Status st = Encode(pts, o, &s);
  EXPECT_TRUE(st.IsInvalidArgument());
  EXPECT_NE(st.message().find("non-finite"), std::string::npos) << st.ToString();
  uint32_t mask = 0;
  EXPECT_TRUE(ParseAttributes("position,colour,normal", &mask).ok());
  EXPECT_EQ(mask, kPosition | kColor | kNormal);
  EXPECT_TRUE(ParseAttributes("position,texture", &mask).IsInvalidArgument());
  EXPECT_EQ(AttributeNames(kPosition | kLabel), "position,label");
}

TEST(CodecTest, CorruptTruncatedAndForeignStreamsAreRefused) {
  const std::vector<Point> pts = Synthetic(4000, 4);
  EncodeOptions o;
  o.attributes = kAllAttributes;
  const std::string good = MustEncode(pts, o);
  std::vector<Point> out;
  EXPECT_TRUE(Decode("PLY whatever", &out).IsInvalidArgument());
  EXPECT_FALSE(Decode(good.substr(0, 30), &out).ok());
  EXPECT_TRUE(Decode(good.substr(0, good.size() - 1), &out).IsCorruption());
  EXPECT_TRUE(Decode(good + "x", &out).IsCorruption());
  // Every byte flipped somewhere in the stream is caught (header or segment checksums).
  std::mt19937 rng(5);
  for (int i = 0; i < 200; ++i) {
    std::string bad = good;
    size_t at = rng() % bad.size();
    bad[at] = static_cast<char>(bad[at] ^ (1 + rng() % 255));
    Status st = Decode(bad, &out);
    EXPECT_FALSE(st.ok()) << "flip at " << at;
  }
  std::string v3 = good;
  v3[4] = 3;
  EXPECT_EQ(Decode(v3, &out).code(), StatusCode::kUnsupported);
  DecodeOptions small;
  small.max_points = 100;
  EXPECT_EQ(Decode(good, &out, small).code(), StatusCode::kLimitExceeded);
}

TEST(CodecTest, MetricsFollowTheThesis) {
  std::vector<Point> a = Synthetic(2000, 6);
  EXPECT_TRUE(std::isinf(Compare(a, a).position_psnr));
  std::vector<Point> b = a;
  for (Point& p : b) p.x += 0.001f;  // far below the spacing: nearly every match is the self
  Quality q = Compare(a, b);
  EXPECT_NEAR(q.position_rmse, 0.001, 1e-4);
  EXPECT_NEAR(q.position_psnr, 20 * std::log10(std::sqrt(8.0 + 0.04) / 0.001), 0.5);
  EXPECT_GT(q.y_psnr, 40);
}

}  // namespace
}  // namespace hvdb::codec
