#include "storage/buffer_pool.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <thread>

namespace hvdb {
namespace {

constexpr uint32_t kBlock = 4096;

BufferPool::Loader Fill(uint8_t value, std::atomic<int>* loads = nullptr) {
  return [value, loads](uint8_t* dst) {
    if (loads) ++*loads;
    std::memset(dst, value, kBlock);
    return Status::OK();
  };
}

TEST(BufferPoolTest, HitAfterMiss) {
  BufferPool pool(16 * kBlock, kBlock);
  uint64_t f = pool.NewFileId();
  std::atomic<int> loads{0};
  {
    auto a = pool.Fetch(f, 3, Fill(7, &loads));
    ASSERT_TRUE(a.ok());
    EXPECT_EQ(a->data()[100], 7);
  }
  auto b = pool.Fetch(f, 3, Fill(9, &loads));
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->data()[0], 7);  // cached, not reloaded
  EXPECT_EQ(loads.load(), 1);
  EXPECT_EQ(pool.Stats().hits, 1u);
  EXPECT_EQ(pool.Stats().misses, 1u);
}

TEST(BufferPoolTest, EvictsOnlyUnpinnedAndStaysBounded) {
  BufferPool pool(4 * kBlock, kBlock);
  uint64_t f = pool.NewFileId();
  auto pinned = pool.Fetch(f, 0, Fill(1));
  ASSERT_TRUE(pinned.ok());
  for (uint32_t i = 1; i < 100; ++i) {
    auto r = pool.Fetch(f, i, Fill(static_cast<uint8_t>(i)));
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->data()[5], static_cast<uint8_t>(i));
  }
  EXPECT_EQ(pinned->data()[5], 1);  // never evicted while pinned
  CacheStats s = pool.Stats();
  EXPECT_LE(s.resident_blocks, 4u);
  EXPECT_GT(s.evictions, 90u);
}

TEST(BufferPoolTest, AllPinnedIsAClearError) {
  BufferPool pool(2 * kBlock, kBlock);
  uint64_t f = pool.NewFileId();
  auto a = pool.Fetch(f, 0, Fill(1));
  auto b = pool.Fetch(f, 1, Fill(2));
  ASSERT_TRUE(a.ok() && b.ok());
  auto c = pool.Fetch(f, 2, Fill(3));
  ASSERT_FALSE(c.ok());
  EXPECT_EQ(c.status().code(), StatusCode::kLimitExceeded);
  EXPECT_NE(c.status().message().find("pinned"), std::string::npos);
}

TEST(BufferPoolTest, FailedLoadIsNotCached) {
  BufferPool pool(4 * kBlock, kBlock);
  uint64_t f = pool.NewFileId();
  auto bad = pool.Fetch(f, 0, [](uint8_t*) { return Status::Corruption("x: block 0: bad"); });
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(bad.status().IsCorruption());
  auto good = pool.Fetch(f, 0, Fill(5));
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(good->data()[0], 5);
}

TEST(BufferPoolTest, ConcurrentFetchesLoadOnce) {
  BufferPool pool(64 * kBlock, kBlock);
  uint64_t f = pool.NewFileId();
  std::atomic<int> loads{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&] {
      for (uint32_t i = 0; i < 32; ++i) {
        auto r = pool.Fetch(f, i, Fill(static_cast<uint8_t>(i), &loads));
        ASSERT_TRUE(r.ok());
        ASSERT_EQ(r->data()[kBlock - 1], static_cast<uint8_t>(i));
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(loads.load(), 32);
}

TEST(BufferPoolTest, ForgetDropsAFilesBlocks) {
  BufferPool pool(8 * kBlock, kBlock);
  uint64_t f = pool.NewFileId(), g = pool.NewFileId();
  { auto a = pool.Fetch(f, 0, Fill(1)); }
  { auto b = pool.Fetch(g, 0, Fill(2)); }
  pool.Forget(f);
  std::atomic<int> loads{0};
  { auto a = pool.Fetch(f, 0, Fill(3, &loads)); EXPECT_EQ(a->data()[0], 3); }
  { auto b = pool.Fetch(g, 0, Fill(4, &loads)); EXPECT_EQ(b->data()[0], 2); }
  EXPECT_EQ(loads.load(), 1);
}

}  // namespace
}  // namespace hvdb
