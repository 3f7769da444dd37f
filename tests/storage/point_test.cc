#include "storage/point.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <random>

#include "storage/coding.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

Point Sample() {
  Point p;
  p.id = 0x0102030405060708ull;
  p.x = 1.5f;
  p.y = -2.25f;
  p.z = 3.0f;
  p.frame = 0x0A0B0C0D;
  p.cov = {1e-4f, 2e-5f, -3e-5f, 4e-4f, 5e-6f, 6e-4f};
  p.normal_oct = EncodeNormal(0.f, 0.6f, 0.8f);
  p.label = 0xDEADBEEF;
  p.r = 10;
  p.g = 20;
  p.b = 30;
  p.flags = kFlagHasNormal | kFlagHasCovariance;
  p.camera = 0x1234;
  return p;
}

TEST(PointTest, RecordIs64Bytes) { EXPECT_EQ(sizeof(Point), 64u); }

TEST(PointTest, RoundTrip) {
  Point p = Sample();
  uint8_t buf[64];
  EncodePoint(p, buf);
  EXPECT_EQ(DecodePoint(buf), p);
}

TEST(PointTest, FastDecodeEqualsFieldwiseDecode) {
  // The inline decode (one copy) against the portable one, on random bytes: every field,
  // and the reserved bytes read as 0 by both.
  std::mt19937_64 rng(41);
  for (int i = 0; i < 1000; ++i) {
    uint8_t buf[64];
    for (uint8_t& b : buf) b = static_cast<uint8_t>(rng());
    Point a = DecodePoint(buf), b = DecodePointFieldwise(buf);
    EXPECT_EQ(std::memcmp(&a, &b, sizeof(Point)), 0);
    EXPECT_EQ(a.reserved, 0);
  }
}

TEST(PointTest, LittleEndianByteLayout) {
  // docs/FORMAT.md, "Point record": offsets and byte order, checked byte by byte.
  Point p = Sample();
  uint8_t b[64];
  EncodePoint(p, b);
  EXPECT_EQ(b[0], 0x08);  // id, least significant byte first
  EXPECT_EQ(b[7], 0x01);
  EXPECT_EQ(DecodeLE<uint32_t>(b + 8), 0x3FC00000u);  // 1.5f
  EXPECT_EQ(DecodeLE<uint32_t>(b + 12), 0xC0100000u);  // -2.25f
  EXPECT_EQ(DecodeLE<uint32_t>(b + 16), 0x40400000u);  // 3.0f
  EXPECT_EQ(b[20], 0x0D);  // frame
  EXPECT_EQ(b[23], 0x0A);
  EXPECT_EQ(DecodeLE<float>(b + 24), 1e-4f);  // cov xx
  EXPECT_EQ(DecodeLE<float>(b + 44), 6e-4f);  // cov zz
  EXPECT_EQ(DecodeLE<int16_t>(b + 48), p.normal_oct[0]);
  EXPECT_EQ(DecodeLE<int16_t>(b + 50), p.normal_oct[1]);
  EXPECT_EQ(b[52], 0xEF);  // label
  EXPECT_EQ(b[55], 0xDE);
  EXPECT_EQ(b[56], 10);
  EXPECT_EQ(b[57], 20);
  EXPECT_EQ(b[58], 30);
  EXPECT_EQ(b[59], kFlagHasNormal | kFlagHasCovariance);
  EXPECT_EQ(b[60], 0x34);  // camera
  EXPECT_EQ(b[61], 0x12);
  EXPECT_EQ(b[62], 0);  // reserved
  EXPECT_EQ(b[63], 0);
}

TEST(PointTest, ArrayEncodingMatchesPerPoint) {
  std::mt19937_64 rng(3);
  auto pts = testing::RandomPoints(rng, 100, 4);
  for (auto& p : pts) p.reserved = 0xFFFF;  // never written
  std::vector<uint8_t> a(pts.size() * 64), b(pts.size() * 64);
  EncodePoints(pts, a.data());
  for (size_t i = 0; i < pts.size(); ++i) EncodePoint(pts[i], b.data() + 64 * i);
  EXPECT_EQ(a, b);
  std::vector<Point> back(pts.size());
  DecodePoints(a.data(), pts.size(), back.data());
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].reserved = 0;
    EXPECT_EQ(back[i], pts[i]);
  }
}

TEST(PointTest, OctahedralNormalsAreAccurate) {
  std::mt19937_64 rng(11);
  std::normal_distribution<float> n(0.f, 1.f);
  for (int i = 0; i < 10000; ++i) {
    float v[3] = {n(rng), n(rng), n(rng)};
    float len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    auto d = DecodeNormal(EncodeNormal(v[0], v[1], v[2]));
    float dot = (d[0] * v[0] + d[1] * v[1] + d[2] * v[2]) / len;
    EXPECT_GT(dot, 0.99999f);
  }
  auto up = DecodeNormal(EncodeNormal(0, 0, 0));
  EXPECT_FLOAT_EQ(up[2], 1.f);
}

TEST(PointTest, CovarianceFromSpanningVectors) {
  float t1[3] = {1, 0, 0}, t2[3] = {0, 2, 0}, t3[3] = {0, 1, 3};
  auto c = CovarianceFromSpanning(t1, t2, t3);
  EXPECT_FLOAT_EQ(c[0], 1);
  EXPECT_FLOAT_EQ(c[3], 5);  // yy = 4 + 1
  EXPECT_FLOAT_EQ(c[4], 3);  // yz
  EXPECT_FLOAT_EQ(c[5], 9);
}

}  // namespace
}  // namespace hvdb
