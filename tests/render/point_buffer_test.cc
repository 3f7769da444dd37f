// PointBuffer: the render job's gathered points (render/point_buffer.h).
#include "render/point_buffer.h"

#include <gtest/gtest.h>

#include <utility>

namespace hvdb::render {
namespace {

Point Numbered(uint64_t i) {
  Point p;
  p.id = i;
  p.x = static_cast<float>(i);
  return p;
}

TEST(PointBufferTest, GrowsKeepingItsPoints) {
  PointBuffer b;
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(std::span<const Point>(b).size(), 0u);
  // Appends of odd sizes across several growths (each one an mremap).
  uint64_t next = 0;
  for (size_t n : {1u, 7u, 40000u, 100000u, 3u, 500000u}) {
    Point* at = b.Append(n);
    for (size_t k = 0; k < n; ++k) at[k] = Numbered(next++);
  }
  ASSERT_EQ(b.size(), next);
  EXPECT_GE(b.capacity(), b.size());
  for (uint64_t i = 0; i < next; ++i) ASSERT_EQ(b.data()[i].id, i) << i;
  EXPECT_EQ(b.front().id, 0u);
  EXPECT_EQ(b.end() - b.begin(), static_cast<ptrdiff_t>(next));
  // A short read gives back what it did not fill.
  b.Append(10);
  b.Shrink(10);
  EXPECT_EQ(b.size(), next);
  const size_t cap = b.capacity();
  b.Reserve(cap / 2);  // never shrinks
  EXPECT_EQ(b.capacity(), cap);
  b.clear();
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(b.capacity(), cap);  // kept for the next query
}

TEST(PointBufferTest, MovesOwnership) {
  PointBuffer a;
  a.Append(3)[2] = Numbered(42);
  PointBuffer b(std::move(a));
  EXPECT_EQ(a.size(), 0u);
  EXPECT_EQ(a.capacity(), 0u);
  ASSERT_EQ(b.size(), 3u);
  EXPECT_EQ(b.data()[2].id, 42u);
  PointBuffer c;
  c.Append(5);
  c = std::move(b);  // c's own memory is unmapped
  ASSERT_EQ(c.size(), 3u);
  EXPECT_EQ(c.data()[2].id, 42u);
  std::swap(a, c);
  EXPECT_EQ(a.size(), 3u);
  EXPECT_TRUE(c.empty());
}

}  // namespace
}  // namespace hvdb::render
