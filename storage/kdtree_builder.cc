#include "storage/kdtree_builder.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>

#include "storage/coding.h"
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

float Coord(const Point& p, int axis) { return axis == 0 ? p.x : axis == 1 ? p.y : p.z; }

Box3 BoundsOf(std::span<const Point> pts) {
  Box3 b;
  b.lo = {std::numeric_limits<float>::max(), std::numeric_limits<float>::max(),
          std::numeric_limits<float>::max()};
  b.hi = {std::numeric_limits<float>::lowest(), std::numeric_limits<float>::lowest(),
          std::numeric_limits<float>::lowest()};
  for (const Point& p : pts) {
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = std::min(b.lo[a], Coord(p, a));
      b.hi[a] = std::max(b.hi[a], Coord(p, a));
    }
  }
  return b;
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
  std::vector<std::pair<size_t, size_t>> buckets;  // [begin, end) into the points, DFS order
};

Ref BuildKd(std::vector<Point>& pts, size_t begin, size_t end, uint64_t cap, TmpTree* t) {
  size_t q = end - begin;
  if (q <= cap) {
    t->buckets.emplace_back(begin, end);
    return {ChildType::kBucket, static_cast<uint32_t>(t->buckets.size() - 1)};
  }
  size_t left = LeftChildSize(q, cap);
  auto span = std::span<const Point>(pts.data() + begin, q);
  Box3 box = BoundsOf(span);
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (box.hi[a] - box.lo[a] > box.hi[axis] - box.lo[axis]) axis = a;
  }
  auto first = pts.begin() + static_cast<std::ptrdiff_t>(begin);
  auto mid = first + static_cast<std::ptrdiff_t>(left);
  std::nth_element(first, mid, pts.begin() + static_cast<std::ptrdiff_t>(end),
                   [axis](const Point& a, const Point& b) { return Coord(a, axis) < Coord(b, axis); });
  // Left points are <= split <= right points.
  float split = Coord(*mid, axis);
  auto idx = static_cast<uint32_t>(t->nodes.size());
  t->nodes.push_back({static_cast<uint8_t>(axis), split, {}, {}});
  Ref l = BuildKd(pts, begin, begin + left, cap, t);
  Ref r = BuildKd(pts, begin + left, end, cap, t);
  t->nodes[idx].left = l;
  t->nodes[idx].right = r;
  return {ChildType::kNode, idx};
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

}  // namespace

Status BuildTreeFile(Env* env, const std::string& path, std::vector<Point>& points,
                     const TreeBuildParams& params, bool sync) {
  const uint32_t bs = params.block_size;
  const uint32_t b = bs / static_cast<uint32_t>(kPointRecordSize);
  const auto levels = static_cast<uint32_t>(params.lod_levels + 1);
  TmpTree tree;
  BuildKd(points, 0, points.size(), 2ull * b, &tree);

  TreeHeader h;
  h.block_size = bs;
  h.point_count = points.size();
  h.bucket_count = static_cast<uint32_t>(tree.buckets.size());
  h.levels = levels;
  h.points_per_block = b;
  h.frame = params.frame;
  h.tree_seq = params.tree_seq;
  h.bbox = BoundsOf(points);
  h.min_id = std::numeric_limits<uint64_t>::max();
  for (const Point& p : points) {
    h.min_id = std::min(h.min_id, p.id);
    h.max_id = std::max(h.max_id, p.id);
  }

  // Multiresolution sets of every bucket.
  std::vector<DirEntry> dir(tree.buckets.size());
  std::vector<std::vector<std::vector<Point>>> bucket_levels(tree.buckets.size());
  for (size_t i = 0; i < tree.buckets.size(); ++i) {
    auto [begin, end] = tree.buckets[i];
    std::span<Point> span(points.data() + begin, end - begin);
    dir[i].box = BoundsOf(span);
    bucket_levels[i] = SplitIntoLevels(span, params.lod_levels);
  }
  // Level segments, coarsest first, each starting on a block boundary (fig. 8.11).
  uint32_t block = 1;  // block 0: header
  for (int k = static_cast<int>(levels) - 1; k >= 0; --k) {
    uint32_t n = 0;
    for (size_t i = 0; i < dir.size(); ++i) {
      dir[i].start[k] = n;
      dir[i].count[k] = static_cast<uint32_t>(bucket_levels[i][k].size());
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
  h.dir_block_count = static_cast<uint32_t>((dir.size() + per_dir - 1) / per_dir);
  block += h.dir_block_count;
  h.crc_block_start = block;
  uint32_t crc_per_block = bs / 4;
  // The table covers every block including its own (entries for the header and the table
  // are 0): solve for the table size.
  uint32_t ncrc = 1;
  while (uint64_t{ncrc} * crc_per_block < uint64_t{block} + ncrc) ++ncrc;
  h.crc_block_count = ncrc;
  h.total_blocks = block + ncrc;

  std::string file(size_t{h.total_blocks} * bs, '\0');
  auto* base = reinterpret_cast<uint8_t*>(file.data());
  for (int k = static_cast<int>(levels) - 1; k >= 0; --k) {
    uint8_t* dst = base + size_t{h.level_start_block[k]} * bs;
    for (size_t i = 0; i < dir.size(); ++i) {
      const auto& pts = bucket_levels[i][k];
      EncodePoints(pts, dst);
      dst += pts.size() * kPointRecordSize;
    }
  }
  for (size_t nb = 0; nb < packer.blocks().size(); ++nb) {
    uint8_t* dst = base + size_t{h.node_block_start + nb} * bs;
    const auto& nodes = packer.blocks()[nb];
    EncodeLE(dst, static_cast<uint32_t>(nodes.size()));
    for (size_t j = 0; j < nodes.size(); ++j) {
      EncodeNode(nodes[j], dst + kNodeBlockHeader + j * kNodeRecordSize);
    }
  }
  for (size_t i = 0; i < dir.size(); ++i) {
    uint8_t* dst = base + size_t{h.dir_block_start + i / per_dir} * bs +
                   (i % per_dir) * h.DirEntrySize();
    EncodeDirEntry(dir[i], levels, dst);
  }
  uint8_t* crc_base = base + size_t{h.crc_block_start} * bs;
  for (uint32_t blk = 1; blk < h.crc_block_start; ++blk) {
    EncodeLE(crc_base + 4 * size_t{blk},
             crc32c::Mask(crc32c::Value(base + size_t{blk} * bs, bs)));
  }
  h.crc_table_crc = crc32c::Mask(crc32c::Value(crc_base, size_t{ncrc} * bs));
  EncodeTreeHeader(h, base);
  if (sync) return WriteFileAtomic(env, path, file);
  HVDB_ASSIGN_OR_RETURN(auto f, env->OpenWrite(path, /*truncate=*/true));
  return f->Append(file);
}

}  // namespace hvdb
