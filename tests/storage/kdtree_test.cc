#include <gtest/gtest.h>
#include <sys/stat.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "storage/buffer_pool.h"
#include "storage/kdtree_builder.h"
#include "storage/kdtree_reader.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using testing::RandomPoints;
using testing::TempDir;

std::shared_ptr<KdTree> Build(const std::string& path, std::vector<Point> pts, BufferPool* pool,
                              uint32_t block_size, int levels = 5) {
  TreeBuildParams params;
  params.block_size = block_size;
  params.lod_levels = levels;
  params.frame = 0;
  params.tree_seq = 1;
  EXPECT_TRUE(BuildTreeFile(Env::Default(), path, pts, params, /*sync=*/true).ok());
  auto t = KdTree::Open(Env::Default(), path, pool);
  EXPECT_TRUE(t.ok()) << t.status().ToString();
  return t.ok() ? *t : nullptr;
}

TEST(KdTreeTest, LeftChildGetsAPowerOfTwoOfFullBuckets) {
  const uint64_t c = 128;
  EXPECT_EQ(LeftChildSize(100, c), 100u);
  EXPECT_EQ(LeftChildSize(129, c), 128u);
  EXPECT_EQ(LeftChildSize(256, c), 128u);
  EXPECT_EQ(LeftChildSize(4 * c, c), 2 * c);
  EXPECT_EQ(LeftChildSize(5 * c, c), 4 * c);
  for (uint64_t q = c + 1; q < 40 * c; q += 7) {
    uint64_t l = LeftChildSize(q, c);
    EXPECT_EQ(l % c, 0u);
    EXPECT_TRUE(std::has_single_bit(l / c)) << q;
    EXPECT_LT(l, q);
    // The thesis formula, c * 2^floor(log2(q/c - 1)), for q >= 2c.
    if (q >= 2 * c) {
      EXPECT_EQ(l, c << static_cast<int>(std::floor(std::log2(double(q) / c - 1)))) << q;
    }
  }
}

TEST(KdTreeTest, WindowQueriesMatchBruteForce) {
  TempDir dir;
  BufferPool pool(8u << 20, 4096);
  std::mt19937_64 rng(42);
  auto pts = RandomPoints(rng, 100000, 0);
  for (size_t i = 0; i < pts.size(); ++i) pts[i].id = i + 1;
  auto tree = Build(dir.path() + "/t.kdt", pts, &pool, 4096);
  ASSERT_TRUE(tree);
  EXPECT_GT(tree->header().node_block_count, 1u);  // small blocks: the node tree spans blocks
  EXPECT_TRUE(tree->Verify().empty());
  std::uniform_real_distribution<float> u(0.f, 10.f);
  for (int q = 0; q < 50; ++q) {
    Box3 w;
    for (int a = 0; a < 3; ++a) {
      float x = u(rng), y = u(rng);
      w.lo[a] = std::min(x, y);
      w.hi[a] = std::max(x, y);
    }
    auto in = [&](const Point& p) {
      float c[3] = {p.x, p.y, p.z};
      for (int a = 0; a < 3; ++a) {
        if (c[a] < w.lo[a] || c[a] > w.hi[a]) return false;
      }
      return true;
    };
    BoxTest test = [&](const Box3& b) {
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        if (b.hi[a] < w.lo[a] || b.lo[a] > w.hi[a]) return Relation::kOutside;
        if (b.lo[a] < w.lo[a] || b.hi[a] > w.hi[a]) inside = false;
      }
      return inside ? Relation::kInside : Relation::kCrosses;
    };
    std::vector<KdTree::BucketHit> hits;
    ASSERT_TRUE(tree->FindBuckets(test, &hits).ok());
    std::set<uint64_t> got, want;
    for (const auto& h : hits) {
      for (uint32_t k = 0; k < tree->header().levels; ++k) {
        ASSERT_TRUE(tree->ReadRange(static_cast<int>(k), h.entry.start[k], h.entry.count[k],
                                    [&](const uint8_t* rec, size_t n) {
                                      for (size_t j = 0; j < n; ++j) {
                                        Point p = DecodePoint(rec + 64 * j);
                                        if (h.inside) {
                                          EXPECT_TRUE(in(p));
                                        }
                                        if (in(p)) got.insert(p.id);
                                      }
                                    }).ok());
      }
    }
    for (const Point& p : pts) {
      if (in(p)) want.insert(p.id);
    }
    EXPECT_EQ(got, want) << "query " << q;
  }
}

TEST(KdTreeTest, LargeTreeUtilisationAtLeast97Percent) {
  TempDir dir;
  BufferPool pool(8u << 20, 65536);
  std::mt19937_64 rng(5);
  auto pts = RandomPoints(rng, 500000, 0);
  auto tree = Build(dir.path() + "/t.kdt", pts, &pool, 65536);
  ASSERT_TRUE(tree);
  const TreeHeader& h = tree->header();
  uint64_t leaf_blocks = 0;
  for (uint32_t k = 0; k < h.levels; ++k) {
    leaf_blocks += (h.level_count[k] + h.points_per_block - 1) / h.points_per_block;
  }
  double util = double(h.point_count) / double(leaf_blocks * h.points_per_block);
  EXPECT_GE(util, 0.97) << "leaf blocks " << leaf_blocks;
  // Every bucket but the last holds exactly 2b points.
  EXPECT_EQ(h.bucket_count, (500000 + 2047) / 2048);
  EXPECT_TRUE(tree->Verify().empty());
  // The file is within 1.02x of the raw point bytes.
  EXPECT_LT(double(tree->file_bytes()), 1.02 * 500000 * 64 + 4 * 65536);
}

TEST(KdTreeTest, LevelSizesHalve) {
  TempDir dir;
  BufferPool pool(16u << 20, 65536);
  std::mt19937_64 rng(6);
  const size_t n = 1 << 18;
  auto tree = Build(dir.path() + "/t.kdt", RandomPoints(rng, n, 0), &pool, 65536);
  ASSERT_TRUE(tree);
  const TreeHeader& h = tree->header();
  // Levels >= i together hold n / 2^i points.
  for (uint32_t i = 0; i < h.levels; ++i) {
    uint64_t sum = 0;
    for (uint32_t k = i; k < h.levels; ++k) sum += h.level_count[k];
    EXPECT_EQ(sum, n >> i) << "level " << i;
  }
}

TEST(KdTreeTest, SingleBucketTreeAndTinyInputs) {
  TempDir dir;
  BufferPool pool(8u << 20, 4096);
  std::mt19937_64 rng(8);
  for (size_t n : {1u, 2u, 5u, 127u, 128u, 129u}) {
    auto pts = RandomPoints(rng, n, 0);
    auto tree = Build(dir.path() + "/t" + std::to_string(n) + ".kdt", pts, &pool, 4096);
    ASSERT_TRUE(tree);
    std::vector<Point> all;
    ASSERT_TRUE(tree->ReadAll(&all).ok());
    EXPECT_EQ(all.size(), n);
    EXPECT_TRUE(tree->Verify().empty());
  }
}

// A small frame's tree is mostly zero tails of 64 KiB blocks (a block per level segment, the
// header, directory and checksums): the builder leaves them as holes, so the frame's disk cost
// is its points plus at most 64 KiB (issue 35), durable (direct I/O) or not, and reads back.
TEST(KdTreeTest, SmallFrameTreeFileIsSparse) {
  TempDir dir;
  BufferPool pool(8u << 20, 64u << 10);
  std::mt19937_64 rng(7);
  auto pts = RandomPoints(rng, 2000, 0);
  for (size_t i = 0; i < pts.size(); ++i) pts[i].id = i + 1;
  for (bool sync : {true, false}) {
    const std::string path = dir.path() + (sync ? "/durable.kdt" : "/merged.kdt");
    TreeBuildParams params;
    params.block_size = 64u << 10;
    params.lod_levels = 5;
    std::vector<Point> copy = pts;
    ASSERT_TRUE(BuildTreeFile(Env::Default(), path, copy, params, sync).ok());
    struct stat st;
    ASSERT_EQ(::stat(path.c_str(), &st), 0);
    auto tree = KdTree::Open(Env::Default(), path, &pool);
    ASSERT_TRUE(tree.ok()) << tree.status().ToString();
    EXPECT_GE((*tree)->header().total_blocks, 8u);  // the dense file would be >= 512 KiB
    EXPECT_EQ(static_cast<uint64_t>(st.st_size),
              uint64_t{(*tree)->header().total_blocks} * params.block_size);
    const uint64_t allocated = static_cast<uint64_t>(st.st_blocks) * 512;
    EXPECT_LE(allocated, pts.size() * kPointRecordSize + (64u << 10)) << "sync " << sync;
    EXPECT_TRUE((*tree)->Verify().empty());  // the holes read as zeros: checksums match
    std::vector<Point> all;
    ASSERT_TRUE((*tree)->ReadAll(&all).ok());
    EXPECT_EQ(all.size(), pts.size());
  }
}

// Each bucket's label summary is exactly the OR of its points' labels, the header's the OR of
// all, raw or compressed; a file written without summaries (versions 1 and 2, before they
// existed) reads every bucket as holding every bit, and its points and checks are the same.
TEST(KdTreeTest, LabelSummariesAreTheBucketsLabelsAndOldFilesStillRead) {
  TempDir dir;
  BufferPool pool(8u << 20, 4096);
  std::mt19937_64 rng(3);
  auto pts = RandomPoints(rng, 20000, 0);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = i + 1;
    pts[i].label = (pts[i].z < 0.5f ? 1u << 3 : 0u) | (i % 777 == 0 ? 1u << 30 : 0u);
  }
  auto everything = [](const Box3&) { return Relation::kCrosses; };
  for (int mode = 0; mode < 4; ++mode) {  // with and without summaries, raw and compressed
    const bool summaries = (mode & 1) == 0, compressed = (mode & 2) != 0;
    const std::string path = dir.path() + "/t" + std::to_string(mode) + ".kdt";
    TreeBuildParams params;
    params.block_size = 4096;
    params.label_summaries = summaries;
    params.compressed = compressed;
    std::vector<Point> copy = pts;
    ASSERT_TRUE(BuildTreeFile(Env::Default(), path, copy, params, true).ok());
    auto tree = KdTree::Open(Env::Default(), path, &pool);
    ASSERT_TRUE(tree.ok()) << tree.status().ToString();
    const TreeHeader& h = (*tree)->header();
    EXPECT_EQ(h.label_summaries(), summaries);
    EXPECT_EQ(h.version, compressed ? (summaries ? kTreeVersionCompressed : kTreeVersionCompressedNoLabels)
                                    : (summaries ? kTreeVersion : kTreeVersionNoLabels));
    EXPECT_EQ((*tree)->compressed(), compressed);
    EXPECT_EQ(h.labels, summaries ? (1u << 3 | 1u << 30) : ~0u);
    std::vector<KdTree::BucketHit> hits;
    ASSERT_TRUE((*tree)->FindBuckets(everything, &hits).ok());
    ASSERT_EQ(hits.size(), h.bucket_count);
    size_t with_bit3 = 0;
    for (const auto& hit : hits) {
      uint32_t labels = 0;
      for (uint32_t k = 0; k < h.levels; ++k) {
        ASSERT_TRUE((*tree)->ReadRange(static_cast<int>(k), hit.entry.start[k], hit.entry.count[k],
                                       [&](const uint8_t* rec, size_t n) {
                                         for (size_t j = 0; j < n; ++j) labels |= DecodePoint(rec + 64 * j).label;
                                       }).ok());
      }
      EXPECT_EQ(hit.entry.labels, summaries ? labels : ~0u) << "bucket " << hit.bucket;
      with_bit3 += (hit.entry.labels & (1u << 3)) != 0;
    }
    if (summaries) {
      EXPECT_LT(with_bit3 * 3, hits.size());  // z < 0.5 is a slab of the frame
    }
    EXPECT_TRUE((*tree)->Verify().empty());
    std::vector<Point> all;
    ASSERT_TRUE((*tree)->ReadAll(&all).ok());
    EXPECT_EQ(all.size(), pts.size());
  }
}

TEST(KdTreeTest, DuplicatePositionsAreAllFound) {
  TempDir dir;
  BufferPool pool(8u << 20, 4096);
  std::vector<Point> pts(1000);
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = i + 1;
    pts[i].x = 1.f;
    pts[i].y = static_cast<float>(i % 3);
    pts[i].z = 2.f;
  }
  auto tree = Build(dir.path() + "/t.kdt", pts, &pool, 4096);
  ASSERT_TRUE(tree);
  std::vector<KdTree::BucketHit> hits;
  ASSERT_TRUE(tree->FindBuckets(
                      [](const Box3& b) {
                        return (b.lo[1] <= 1.f && b.hi[1] >= 1.f) ? Relation::kCrosses
                                                                  : Relation::kOutside;
                      },
                      &hits)
                  .ok());
  size_t found = 0;
  for (const auto& h : hits) {
    for (uint32_t k = 0; k < tree->header().levels; ++k) {
      (void)tree->ReadRange(static_cast<int>(k), h.entry.start[k], h.entry.count[k],
                            [&](const uint8_t* rec, size_t n) {
                              for (size_t j = 0; j < n; ++j) found += DecodePoint(rec + 64 * j).y == 1.f;
                            });
    }
  }
  EXPECT_EQ(found, 333u);
}

}  // namespace
}  // namespace hvdb
