#include "storage/wal.h"

#include "storage/coding.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

TxnRecord MakeRecord(uint64_t lsn, std::mt19937_64& rng) {
  TxnRecord t;
  t.lsn = lsn;
  FrameEffect f;
  f.frame = static_cast<uint32_t>(lsn % 5);
  f.added = testing::RandomPoints(rng, 3 + lsn % 7, f.frame);
  f.removed = testing::RandomPoints(rng, lsn % 3, f.frame);
  t.frames.push_back(f);
  return t;
}

class WalTest : public ::testing::Test {
 protected:
  std::string Write(int n) {
    std::string path = dir_.path() + "/wal.log";
    auto w = WalWriter::Open(Env::Default(), path, 1, 0, false);
    EXPECT_TRUE(w.ok());
    std::mt19937_64 rng(1);
    for (int i = 1; i <= n; ++i) EXPECT_TRUE((*w)->Append({MakeRecord(i, rng)}).ok());
    EXPECT_TRUE((*w)->Sync().ok());
    return path;
  }
  testing::TempDir dir_;
};

TEST_F(WalTest, RoundTrip) {
  std::string path = Write(20);
  auto c = ReadWal(Env::Default(), path);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->records.size(), 20u);
  EXPECT_FALSE(c->torn_tail);
  std::mt19937_64 rng(1);
  for (uint64_t i = 1; i <= 20; ++i) {
    TxnRecord want = MakeRecord(i, rng);
    const TxnRecord& got = c->records[i - 1];
    EXPECT_EQ(got.lsn, i);
    ASSERT_EQ(got.frames.size(), 1u);
    EXPECT_EQ(got.frames[0].added, want.frames[0].added);
    EXPECT_EQ(got.frames[0].removed, want.frames[0].removed);
  }
}

TEST_F(WalTest, MarkersMayRepeatTheLastLsnTransactionsMayNot) {
  std::string path = dir_.path() + "/wal.log";
  auto w = WalWriter::Open(Env::Default(), path, 1, 0, false);
  ASSERT_TRUE(w.ok());
  std::mt19937_64 rng(1);
  ASSERT_TRUE((*w)->Append({MakeRecord(1, rng)}).ok());
  TxnRecord tier;
  tier.lsn = 1;  // repeats: a compaction changes no point
  tier.tier = true;
  tier.frames.emplace_back();
  tier.frames[0].frame = 7;
  ASSERT_TRUE((*w)->Append({tier}).ok());
  ASSERT_TRUE((*w)->Append({MakeRecord(2, rng)}).ok());
  ASSERT_TRUE((*w)->Sync().ok());
  auto c = ReadWal(Env::Default(), path);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->records.size(), 3u);
  EXPECT_TRUE(c->records[1].tier);
  EXPECT_FALSE(c->records[1].bulk);
  EXPECT_EQ(c->records[1].lsn, 1u);
  EXPECT_EQ(c->records[1].frames.at(0).frame, 7u);
  EXPECT_FALSE(c->records[2].tier);
  // A transaction repeating an LSN is corruption.
  ASSERT_TRUE((*w)->Append({MakeRecord(2, rng)}).ok());
  EXPECT_FALSE(ReadWal(Env::Default(), path).ok());
}

TEST_F(WalTest, RelabelsAreLoggedAsIdsAndFlippedBits) {
  // 10 000 relabelled points with ids 1..3 apart, next to a frame effect of whole points.
  std::mt19937_64 rng(3);
  TxnRecord t;
  t.lsn = 7;
  FrameEffect f;
  f.frame = 4;
  Relabel set{0x4, 0x4, {}}, cleared{0x6, 0x0, {}};
  uint64_t id = 1000;
  for (int i = 0; i < 10000; ++i) {
    id += 1 + rng() % 3;
    (i % 4 ? set : cleared).ids.push_back(id);
  }
  f.relabels = {set, cleared};
  f.removed = testing::RandomPoints(rng, 3, 4);  // the resolution: not logged
  t.frames.push_back(f);
  FrameEffect whole;
  whole.frame = 5;
  whole.added = testing::RandomPoints(rng, 2, 5);
  t.frames.push_back(whole);
  const std::string path = dir_.path() + "/wal.log";
  auto w = WalWriter::Open(Env::Default(), path, 1, 0, false);
  ASSERT_TRUE(w.ok());
  ASSERT_TRUE((*w)->Append({t}).ok());
  ASSERT_TRUE((*w)->Sync().ok());
  // A byte a point (gaps under 128), not 128 (the point before and after).
  EXPECT_LT((*w)->size(), kWalHeaderSize + kWalRecordHeaderSize + 10000 + 200 + 2 * kPointRecordSize);
  auto c = ReadWal(Env::Default(), path);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->records.size(), 1u);
  const TxnRecord& got = c->records[0];
  ASSERT_EQ(got.frames.size(), 2u);
  ASSERT_EQ(got.frames[0].relabels.size(), 2u);
  EXPECT_TRUE(got.frames[0].removed.empty());
  for (size_t g = 0; g < 2; ++g) {
    EXPECT_EQ(got.frames[0].relabels[g].flip, f.relabels[g].flip);
    EXPECT_EQ(got.frames[0].relabels[g].after, f.relabels[g].after);
    EXPECT_EQ(got.frames[0].relabels[g].ids, f.relabels[g].ids);
  }
  EXPECT_EQ(EffectAdded(got.frames[0]), 10000u);
  EXPECT_EQ(EffectRemoved(got.frames[0]), 10000u);
  EXPECT_EQ(got.frames[1].added, whole.added);
  // The inverse flips the same bits back.
  FrameEffect inv = InverseEffect(got.frames[0]);
  EXPECT_EQ(inv.relabels[0].after, 0x0u);
  EXPECT_EQ(inv.relabels[1].after, 0x6u);
  // Bad relabels (no bit flips; a value outside the flipped bits; ids not ascending) are
  // corruption, not points relabelled wrongly.
  std::string payload;
  {
    Writer wr;
    wr.Put<uint64_t>(0);
    wr.Put<uint32_t>(1);
    wr.Put<uint32_t>(0);  // frame
    wr.Put<uint8_t>(1);   // relabels
    wr.Put<uint32_t>(1);
    wr.Put<uint32_t>(0x1);
    wr.Put<uint32_t>(0x3);  // after outside flip
    wr.Put<uint32_t>(1);
    wr.Put<uint8_t>(5);
    payload = wr.data();
  }
  EXPECT_TRUE(DecodeTxnPayload(payload, 1, true).status().IsCorruption());
  payload[payload.size() - 9] = 0x1;  // after = flip: valid
  EXPECT_TRUE(DecodeTxnPayload(payload, 1, true).ok());
  payload.back() = 0;  // a first id of 0 is allowed; a second gap of 0 is not
  payload[payload.size() - 5] = 2;
  payload += std::string(1, '\0');
  EXPECT_TRUE(DecodeTxnPayload(payload, 1, true).status().IsCorruption());
}

TEST_F(WalTest, TornTailIsDroppedAndRepaired) {
  std::string path = Write(10);
  auto size = std::filesystem::file_size(path);
  std::filesystem::resize_file(path, size - 30);  // cut into the last record
  auto c = ReadWal(Env::Default(), path);
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->torn_tail);
  EXPECT_EQ(c->records.size(), 9u);
  auto w = WalWriter::Open(Env::Default(), path, 1, c->valid_bytes, true);
  ASSERT_TRUE(w.ok());
  std::mt19937_64 rng(2);
  ASSERT_TRUE((*w)->Append({MakeRecord(10, rng)}).ok());
  auto again = ReadWal(Env::Default(), path);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->records.size(), 10u);
  EXPECT_FALSE(again->torn_tail);
}

TEST_F(WalTest, ZeroTailIsTorn) {
  // Some file systems show zeros where a crash cut an append short.
  std::string path = Write(3);
  std::ofstream(path, std::ios::app) << std::string(100, '\0');
  auto c = ReadWal(Env::Default(), path);
  ASSERT_TRUE(c.ok());
  EXPECT_TRUE(c->torn_tail);
  EXPECT_EQ(c->records.size(), 3u);
}

TEST_F(WalTest, GarbageAfterTheLastRecordIsCorruption) {
  // Not the signature of a crash (which leaves a prefix of a real record): refuse it.
  std::string path = Write(3);
  std::ofstream(path, std::ios::app) << "xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx";
  auto c = ReadWal(Env::Default(), path);
  ASSERT_FALSE(c.ok());
  EXPECT_TRUE(c.status().IsCorruption());
}

TEST_F(WalTest, CorruptionInTheMiddleIsAnError) {
  std::string path = Write(5);
  std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
  f.seekp(kWalHeaderSize + 40);
  f.put('\x5a');
  f.close();
  auto c = ReadWal(Env::Default(), path);
  ASSERT_FALSE(c.ok());
  EXPECT_TRUE(c.status().IsCorruption());
  EXPECT_NE(c.status().message().find("wal.log"), std::string::npos);
}

}  // namespace
}  // namespace hvdb
