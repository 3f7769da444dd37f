// Record blocks (blockcode/record_block.h): bit-exact round trips of random and real records, and
// damage refused instead of decoded into garbage or a crash.
#include "blockcode/record_block.h"

#include <algorithm>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "formats/ply.h"
#include "storage/point.h"

namespace hvdb::blockcode {
namespace {

std::vector<uint8_t> Records(const std::vector<Point>& pts) {
  std::vector<uint8_t> out(pts.size() * kRecordSize);
  EncodePoints(pts, out.data());
  return out;
}

void ExpectRoundTrip(const std::vector<uint8_t>& recs, size_t* coded_bytes = nullptr) {
  const auto n = static_cast<uint32_t>(recs.size() / kRecordSize);
  std::string coded;
  EncodeRecordBlock(recs.data(), n, &coded);
  std::vector<uint8_t> back(recs.size() + kRecordSize, 0xAB);
  uint32_t got = 0;
  std::string err;
  ASSERT_TRUE(DecodeRecordBlock(reinterpret_cast<const uint8_t*>(coded.data()), coded.size(),
                                back.data(), n + 1, &got, &err))
      << err;
  ASSERT_EQ(got, n);
  ASSERT_EQ(0, std::memcmp(back.data(), recs.data(), recs.size()));
  if (coded_bytes) *coded_bytes += coded.size();
}

Point RandomPoint(std::mt19937_64& rng) {
  Point p;
  p.id = rng();
  auto f = [&] {
    uint32_t bits = static_cast<uint32_t>(rng());
    float v;
    std::memcpy(&v, &bits, 4);  // every bit pattern: NaNs, infinities, -0, denormals
    return v;
  };
  p.x = f();
  p.y = f();
  p.z = f();
  p.frame = static_cast<uint32_t>(rng());
  for (float& c : p.cov) c = f();
  p.normal_oct = {static_cast<int16_t>(rng()), static_cast<int16_t>(rng())};
  p.label = static_cast<uint32_t>(rng());
  p.r = static_cast<uint8_t>(rng());
  p.g = static_cast<uint8_t>(rng());
  p.b = static_cast<uint8_t>(rng());
  p.flags = static_cast<uint8_t>(rng());
  p.camera = static_cast<uint16_t>(rng());
  return p;
}

TEST(RecordBlock, RandomRecordsOfEverySize) {
  std::mt19937_64 rng(7);
  for (uint32_t n : {1u, 2u, 3u, 17u, 1000u, 1024u, 4096u}) {
    std::vector<Point> pts(n);
    for (Point& p : pts) p = RandomPoint(rng);
    ExpectRoundTrip(Records(pts));
  }
}

TEST(RecordBlock, ConstantAndSmoothFields) {
  std::vector<Point> pts(1024);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = 1000 + i;
    pts[i].x = 0.001f * static_cast<float>(i) - 0.5f;  // crosses zero: sign handling
    pts[i].y = -2.0f;
    pts[i].z = 3.0f;
    pts[i].frame = 12;
    pts[i].cov = {1e-4f, 0, 0, 1e-4f, 0, 1e-4f};
    pts[i].r = static_cast<uint8_t>(i);
    pts[i].g = static_cast<uint8_t>(i + 1);
    pts[i].b = static_cast<uint8_t>(i + 2);
  }
  size_t bytes = 0;
  ExpectRoundTrip(Records(pts), &bytes);
  // Constant and arithmetic fields cost next to nothing; x's steps of ~2^13 ulps dominate.
  EXPECT_LT(bytes, 1024u * 4);
}

TEST(RecordBlock, RealFramesAtLessThanAQuarter) {
  std::string path = std::string(HVDB_SHARED_DATA) +
                     "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/ptcloud_hd00000380.ply";
  auto pts = formats::ReadPly(path);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  std::vector<Point> all = *pts;
  for (size_t i = 0; i < all.size(); ++i) {
    all[i].id = 5000 + i;
    all[i].frame = 380;
  }
  size_t bytes = 0;
  for (size_t s = 0; s < all.size(); s += 1024) {
    std::vector<Point> blk(all.begin() + static_cast<std::ptrdiff_t>(s),
                           all.begin() + static_cast<std::ptrdiff_t>(std::min(all.size(), s + 1024)));
    ExpectRoundTrip(Records(blk), &bytes);
  }
  const double ratio = static_cast<double>(bytes) / static_cast<double>(all.size() * kRecordSize);
  std::printf("panoptic 380 in file order: %.1f bits/point, %.3f of raw\n",
              8.0 * static_cast<double>(bytes) / static_cast<double>(all.size()), ratio);
  EXPECT_LT(ratio, 0.25);
}

TEST(RecordBlock, DamageIsRefused) {
  std::mt19937_64 rng(11);
  std::vector<Point> pts(300);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i] = RandomPoint(rng);
    pts[i].id = i * 3;
    pts[i].x = static_cast<float>(i);
  }
  auto recs = Records(pts);
  std::string coded;
  EncodeRecordBlock(recs.data(), 300, &coded);
  std::vector<uint8_t> out(300 * kRecordSize);
  uint32_t n = 0;
  std::string err;
  // Every truncation is detected.
  for (size_t len = 0; len < coded.size(); ++len) {
    EXPECT_FALSE(DecodeRecordBlock(reinterpret_cast<const uint8_t*>(coded.data()), len,
                                   out.data(), 300, &n, &err))
        << len;
  }
  // Trailing bytes too, and a block larger than the room given.
  std::string longer = coded + "x";
  EXPECT_FALSE(DecodeRecordBlock(reinterpret_cast<const uint8_t*>(longer.data()), longer.size(),
                                 out.data(), 300, &n, &err));
  EXPECT_FALSE(DecodeRecordBlock(reinterpret_cast<const uint8_t*>(coded.data()), coded.size(),
                                 out.data(), 299, &n, &err));
  // Flipped bits: refused, or decoded into records that differ (the caller's checksum).
  for (int trial = 0; trial < 2000; ++trial) {
    std::string bad = coded;
    bad[rng() % bad.size()] ^= static_cast<char>(1u << (rng() % 8));
    if (DecodeRecordBlock(reinterpret_cast<const uint8_t*>(bad.data()), bad.size(), out.data(),
                          300, &n, &err)) {
      EXPECT_EQ(n, 300u);
    }
  }
}

}  // namespace
}  // namespace hvdb::blockcode
