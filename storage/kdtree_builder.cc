#include "storage/kdtree_builder.h"

#include <sys/mman.h>

#include <algorithm>
#include <bit>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <thread>

#include "storage/coding.h"
#include "storage/cold_tree.h"
#include "storage/crc32c.h"
#include "storage/kdtree_format.h"
#include "storage/lod.h"

namespace hvdb {

uint64_t LeftChildSize(uint64_t q, uint64_t c) {
  if (q <= c) return q;
  if (q < 2 * c) return c;
  // floor(log2(q/c - 1)) equals floor(log2(floor((q - c) / c))): powers of two are integers.
  uint64_t m = (q - c) / c;
  return c << (std::bit_width(m) - 1);
}

namespace {

// The build moves 16-byte (x, y, z, index) records (lod.h's OrderRec), not 64-byte points:
// the partitioning passes of the kd-tree and of the in-bucket order touch a quarter of the
// memory, and each point is copied once, straight to its final place in the file.
using Rec = OrderRec;

Box3 BoundsOf(std::span<const Rec> recs) {
  Box3 b;
  b.lo = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
          std::numeric_limits<float>::max()};
  b.hi = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
          std::numeric_limits<float>::lowest()};
  for (const Rec& r : recs) {
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], r.c[a]);
      b.hi[a] = std::max(b.hi[a], r.c[a]);
    }
  }
  return b;
}

int WidestAxis(const Box3& box) {
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (box.hi[a] - box.lo[a] > box.hi[axis] - box.lo[axis]) axis = a;
  }
  return axis;
}

struct Ref {
  ChildType type;
  uint32_t idx;  // kNode: index into TmpTree::nodes; kBucket: bucket number
};

struct TmpNode {
  uint8_t axis;
  float split;
  Ref left, right;
};

struct TmpTree {
  std::vector<TmpNode> nodes;
  std::vector<std::pair<size_t, size_t>> buckets;  // [begin, end) into the records, DFS order
};

// Splits recs[begin, end) at its left child's size; returns the split node (not yet linked).
TmpNode Split(std::vector<Rec>& recs, size_t begin, size_t end, uint64_t cap, size_t* mid) {
  const size_t left = LeftChildSize(end - begin, cap);
  const int axis = WidestAxis(BoundsOf(std::span<const Rec>(recs.data() + begin, end - begin)));
  auto first = recs.begin() + static_cast<std::ptrdiff_t>(begin);
  auto m = first + static_cast<std::ptrdiff_t>(left);
  std::nth_element(first, m, recs.begin() + static_cast<std::ptrdiff_t>(end),
                   [axis](const Rec& a, const Rec& b) { return a.c[axis] < b.c[axis]; });
  *mid = begin + left;
  return {static_cast<uint8_t>(axis), m->c[axis], {}, {}};  // left <= split <= right
}

Ref BuildKd(std::vector<Rec>& recs, size_t begin, size_t end, uint64_t cap, TmpTree* t) {
  if (end - begin <= cap) {
    t->buckets.emplace_back(begin, end);
    return {ChildType::kBucket, static_cast<uint32_t>(t->buckets.size() - 1)};
  }
  size_t mid;
  TmpNode n = Split(recs, begin, end, cap, &mid);
  auto idx = static_cast<uint32_t>(t->nodes.size());
  t->nodes.push_back(n);
  Ref l = BuildKd(recs, begin, mid, cap, t);
  Ref r = BuildKd(recs, mid, end, cap, t);
  t->nodes[idx].left = l;
  t->nodes[idx].right = r;
  return {ChildType::kNode, idx};
}

// The root's two subtrees on two threads (the disjoint halves of `recs`), then joined.
void BuildKdParallel(std::vector<Rec>& recs, uint64_t cap, TmpTree* t) {
  if (recs.size() <= cap || recs.size() < (1u << 16)) {
    BuildKd(recs, 0, recs.size(), cap, t);
    return;
  }
  size_t mid;
  t->nodes.push_back(Split(recs, 0, recs.size(), cap, &mid));
  TmpTree lt, rt;
  Ref l, r;
  std::thread left([&] { l = BuildKd(recs, 0, mid, cap, &lt); });
  r = BuildKd(recs, mid, recs.size(), cap, &rt);
  left.join();
  auto shift = [](Ref x, uint32_t nodes, uint32_t buckets) {
    x.idx += x.type == ChildType::kNode ? nodes : buckets;
    return x;
  };
  const auto lnodes = static_cast<uint32_t>(lt.nodes.size());
  const auto lbuckets = static_cast<uint32_t>(lt.buckets.size());
  for (TmpNode n : lt.nodes) {
    n.left = shift(n.left, 1, 0);
    n.right = shift(n.right, 1, 0);
    t->nodes.push_back(n);
  }
  for (TmpNode n : rt.nodes) {
    n.left = shift(n.left, 1 + lnodes, lbuckets);
    n.right = shift(n.right, 1 + lnodes, lbuckets);
    t->nodes.push_back(n);
  }
  t->buckets = std::move(lt.buckets);
  t->buckets.insert(t->buckets.end(), rt.buckets.begin(), rt.buckets.end());
  t->nodes[0].left = shift(l, 1, 0);
  t->nodes[0].right = shift(r, 1 + lnodes, lbuckets);
}

// Packs inner nodes depth-first into blocks of `cap` nodes (fig. 8.6/8.7).
class NodePacker {
 public:
  NodePacker(const TmpTree& t, uint32_t cap) : t_(t), cap_(cap) {}
  uint32_t PackBlock(uint32_t tmp) {
    auto b = static_cast<uint32_t>(blocks_.size());
    blocks_.emplace_back();
    Dfs(tmp, b);
    return b;
  }
  const std::vector<std::vector<NodeRecord>>& blocks() const { return blocks_; }

 private:
  uint32_t Dfs(uint32_t tmp, uint32_t b) {
    auto idx = static_cast<uint32_t>(blocks_[b].size());
    blocks_[b].emplace_back();
    const TmpNode& n = t_.nodes[tmp];
    NodeRecord rec;
    rec.axis = n.axis;
    rec.split = n.split;
    auto place = [&](Ref child, ChildType* type, uint32_t* ref) {
      if (child.type == ChildType::kBucket) {
        *type = ChildType::kBucket;
        *ref = child.idx;
      } else if (blocks_[b].size() < cap_) {
        *type = ChildType::kNode;
        *ref = Dfs(child.idx, b);
      } else {
        *type = ChildType::kNodeBlock;
        *ref = PackBlock(child.idx);
      }
    };
    place(n.left, &rec.left_type, &rec.left);
    place(n.right, &rec.right_type, &rec.right);
    blocks_[b][idx] = rec;
    return idx;
  }
  const TmpTree& t_;
  const uint32_t cap_;
  std::vector<std::vector<NodeRecord>> blocks_;
};

// Runs fn(i) for i in [0, n) on two threads (the machine's cores; more would only contend).
template <typename F>
void ParallelFor(size_t n, F fn) {
  std::thread other([&] {
    for (size_t i = 1; i < n; i += 2) fn(i);
  });
  for (size_t i = 0; i < n; i += 2) fn(i);
  other.join();
}

// The byte ranges of a tree image that can hold non-zero bytes, in 4 KiB pages (the unit of
// a file system's holes and of direct I/O), ascending and merged: the file is written sparse.
class UsedExtents {
 public:
  void Add(uint64_t offset, uint64_t length) {
    if (length == 0) return;
    const uint64_t lo = offset / kPage * kPage;
    const uint64_t hi = (offset + length + kPage - 1) / kPage * kPage;
    if (!v_.empty() && v_.back().offset + v_.back().length >= lo) {
      v_.back().length = std::max(v_.back().length, hi - v_.back().offset);
    } else {
      v_.push_back({lo, hi - lo});
    }
  }
  const std::vector<FileExtent>& extents() const { return v_; }

 private:
  static constexpr uint64_t kPage = 4096;
  std::vector<FileExtent> v_;
};

}  // namespace

Status BuildTreeImage(std::vector<Point>& points, const TreeBuildParams& params,
                      TreeImage* out) {
  const uint32_t bs = params.block_size;
  const uint32_t b = bs / static_cast<uint32_t>(kPointRecordSize);
  const auto levels = static_cast<uint32_t>(params.lod_levels + 1);
  const int max_level = params.lod_levels;
  std::vector<Rec> recs(points.size());
  TreeHeader h;
  if (!params.label_summaries) h.version = kTreeVersionNoLabels;
  h.min_id = std::numeric_limits<uint64_t>::max();
  for (size_t i = 0; i < points.size(); ++i) {
    const Point& p = points[i];
    recs[i] = {{p.x, p.y, p.z}, static_cast<uint32_t>(i)};
    h.min_id = std::min(h.min_id, p.id);
    h.max_id = std::max(h.max_id, p.id);
  }
  h.bbox = BoundsOf(recs);
  TmpTree tree;
  BuildKdParallel(recs, 2ull * b, &tree);
  const size_t nb = tree.buckets.size();

  h.block_size = bs;
  h.point_count = points.size();
  h.bucket_count = static_cast<uint32_t>(nb);
  h.levels = levels;
  h.points_per_block = b;
  h.frame = params.frame;
  h.tree_seq = params.tree_seq;

  // Each bucket's multiresolution order (lod.h) on the records; a level's size in a bucket
  // depends only on the bucket's size.
  std::vector<DirEntry> dir(nb);
  ParallelFor(nb, [&](size_t i) {
    auto [begin, end] = tree.buckets[i];
    std::span<Rec> span(recs.data() + begin, end - begin);
    dir[i].box = BoundsOf(span);
    KdOrder(span, points);
    uint32_t labels = 0;
    for (size_t m = 0; m < span.size(); ++m) {
      ++dir[i].count[LevelOfRank(m, max_level)];
      labels |= points[span[m].idx].label;
    }
    dir[i].labels = labels;
  });
  h.labels = 0;
  for (const DirEntry& e : dir) h.labels |= e.labels;
  if (!h.label_summaries()) h.labels = ~0u;
  // Level segments, coarsest first, each starting on a block boundary (fig. 8.11).
  uint32_t block = 1;  // block 0: header
  for (int k = static_cast<int>(levels) - 1; k >= 0; --k) {
    uint32_t n = 0;
    for (size_t i = 0; i < nb; ++i) {
      dir[i].start[k] = n;
      n += dir[i].count[k];
    }
    h.level_count[k] = n;
    h.level_start_block[k] = block;
    block += (n + b - 1) / b;
  }
  NodePacker packer(tree, h.NodesPerBlock());
  if (tree.nodes.empty()) {
    h.root_type = ChildType::kBucket;
    h.root_ref = 0;
  } else {
    packer.PackBlock(0);
    h.root_type = ChildType::kNodeBlock;
    h.root_ref = 0;
  }
  h.node_block_start = block;
  h.node_block_count = static_cast<uint32_t>(packer.blocks().size());
  block += h.node_block_count;
  h.dir_block_start = block;
  uint32_t per_dir = h.DirEntriesPerBlock();
  h.dir_block_count = static_cast<uint32_t>((nb + per_dir - 1) / per_dir);
  block += h.dir_block_count;
  h.crc_block_start = block;
  uint32_t crc_per_block = bs / 4;
  // The table covers every block including its own (entries for the header and the table
  // are 0): solve for the table size.
  uint32_t ncrc = 1;
  while (uint64_t{ncrc} * crc_per_block < uint64_t{block} + ncrc) ++ncrc;
  h.crc_block_count = ncrc;
  h.total_blocks = block + ncrc;

  // The file image, not zero-filled first: every byte is written once below (records, or
  // zeros for the tails of level segments and the other blocks).
  const size_t file_bytes = size_t{h.total_blocks} * bs;
  // 4 KiB-aligned, so that a durable write can go straight to the device (Env::WriteNewFile).
  // A large image on transparent huge pages where the kernel offers them (madvise mode): its
  // first touches are a fifth of a merge's time on 4 KiB pages (a fault and a clear per page).
  constexpr size_t kHuge = size_t{2} << 20;
  const size_t align = file_bytes >= 4 * kHuge ? kHuge : 4096;
  const size_t alloc_bytes = (file_bytes + align - 1) / align * align;
  out->data.reset(static_cast<uint8_t*>(std::aligned_alloc(align, alloc_bytes)));
  if (out->data && align == kHuge) (void)madvise(out->data.get(), alloc_bytes, MADV_HUGEPAGE);
  if (!out->data) return Status::IOError("out of memory for a " + std::to_string(file_bytes) + "-byte tree");
  out->bytes = file_bytes;
  uint8_t* base = out->data.get();
  for (uint32_t k = 0; k < levels; ++k) {
    const size_t used = size_t{h.level_count[k]} * kPointRecordSize;
    const size_t seg = size_t{(h.level_count[k] + b - 1) / b} * bs;
    std::memset(base + size_t{h.level_start_block[k]} * bs + used, 0, seg - used);
  }
  std::memset(base, 0, bs);
  std::memset(base + size_t{h.node_block_start} * bs, 0,
              size_t{h.total_blocks - h.node_block_start} * bs);
  // Every point straight to its place: bucket i's rank-m point goes to level k's position
  // start[k] + (its rank among the bucket's level-k points).
  ParallelFor(nb, [&](size_t i) {
    auto [begin, end] = tree.buckets[i];
    uint32_t next[kMaxLevels] = {};
    for (size_t m = 0; m < end - begin; ++m) {
      // The gather from `points` is random access: ask for a later record's point early.
      if (m + 8 < end - begin) __builtin_prefetch(&points[recs[begin + m + 8].idx]);
      const int k = LevelOfRank(m, max_level);
      uint8_t* dst = base + size_t{h.level_start_block[k]} * bs +
                     size_t{dir[i].start[k] + next[k]++} * kPointRecordSize;
      EncodePoint(points[recs[begin + m].idx], dst);
    }
  });
  for (size_t nbk = 0; nbk < packer.blocks().size(); ++nbk) {
    uint8_t* dst = base + size_t{h.node_block_start + nbk} * bs;
    const auto& nodes = packer.blocks()[nbk];
    EncodeLE(dst, static_cast<uint32_t>(nodes.size()));
    for (size_t j = 0; j < nodes.size(); ++j) {
      EncodeNode(nodes[j], dst + kNodeBlockHeader + j * kNodeRecordSize);
    }
  }
  for (size_t i = 0; i < nb; ++i) {
    uint8_t* dst = base + size_t{h.dir_block_start + i / per_dir} * bs +
                   (i % per_dir) * h.DirEntrySize();
    EncodeDirEntry(dir[i], h, dst);
  }
  uint8_t* crc_base = base + size_t{h.crc_block_start} * bs;
  ParallelFor(h.crc_block_start, [&](size_t blk) {
    if (blk == 0) return;
    EncodeLE(crc_base + 4 * blk, crc32c::Mask(crc32c::Value(base + blk * bs, bs)));
  });
  h.crc_table_crc = crc32c::Mask(crc32c::Value(crc_base, size_t{ncrc} * bs));
  EncodeTreeHeader(h, base);
  // Only the used bytes of each block need to reach the disk: a 2 000-point frame fills
  // ~130 KiB of its 9 blocks (one per level segment, plus header, directory and checksums).
  UsedExtents used;
  used.Add(0, kTreeHeaderSize);
  for (int k = static_cast<int>(levels) - 1; k >= 0; --k) {
    used.Add(uint64_t{h.level_start_block[k]} * bs, uint64_t{h.level_count[k]} * kPointRecordSize);
  }
  for (size_t nbk = 0; nbk < packer.blocks().size(); ++nbk) {
    used.Add(uint64_t{h.node_block_start + nbk} * bs,
             kNodeBlockHeader + packer.blocks()[nbk].size() * kNodeRecordSize);
  }
  for (uint32_t d = 0; d < h.dir_block_count; ++d) {
    const uint64_t entries = std::min<uint64_t>(per_dir, nb - uint64_t{d} * per_dir);
    used.Add(uint64_t{h.dir_block_start + d} * bs, entries * h.DirEntrySize());
  }
  used.Add(uint64_t{h.crc_block_start} * bs, uint64_t{h.total_blocks} * 4);
  out->used = used.extents();
  out->header = h;
  return Status::OK();
}

Status BuildTreeFile(Env* env, const std::string& path, std::vector<Point>& points,
                     const TreeBuildParams& params, bool sync) {
  TreeImage image;
  HVDB_RETURN_IF_ERROR(BuildTreeImage(points, params, &image));
  if (params.compressed) return WriteCompressedTree(env, path, image, sync);
  return env->WriteNewSparseFile(
      path, std::string_view(reinterpret_cast<const char*>(image.data.get()), image.bytes),
      image.used, sync);
}

}  // namespace hvdb
