#include "storage/kdtree_format.h"

#include <cmath>
#include <cstring>

#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb {

void EncodeTreeHeader(const TreeHeader& h, uint8_t* d) {
  std::memset(d, 0, kTreeHeaderSize);
  std::memcpy(d, kTreeMagic, 8);
  EncodeLE(d + 8, h.version);
  EncodeLE(d + 12, h.block_size);
  EncodeLE(d + 16, h.point_count);
  EncodeLE(d + 24, h.bucket_count);
  EncodeLE(d + 28, h.levels);
  EncodeLE(d + 32, h.points_per_block);
  EncodeLE(d + 36, h.frame);
  EncodeLE(d + 40, h.tree_seq);
  EncodeLE(d + 48, h.min_id);
  EncodeLE(d + 56, h.max_id);
  for (int a = 0; a < 3; ++a) {
    EncodeLE(d + 64 + 4 * a, h.bbox.lo[a]);
    EncodeLE(d + 76 + 4 * a, h.bbox.hi[a]);
  }
  d[88] = static_cast<uint8_t>(h.root_type);
  EncodeLE(d + 92, h.root_ref);
  EncodeLE(d + 96, h.node_block_start);
  EncodeLE(d + 100, h.node_block_count);
  EncodeLE(d + 104, h.dir_block_start);
  EncodeLE(d + 108, h.dir_block_count);
  EncodeLE(d + 112, h.crc_block_start);
  EncodeLE(d + 116, h.crc_block_count);
  EncodeLE(d + 120, h.total_blocks);
  EncodeLE(d + 124, h.crc_table_crc);
  for (int k = 0; k < kMaxLevels; ++k) {
    EncodeLE(d + 128 + 8 * k, h.level_count[k]);
    EncodeLE(d + 132 + 8 * k, h.level_start_block[k]);
  }
  EncodeLE(d + 200, h.label_summaries() ? h.labels : 0u);
  EncodeLE(d + 252, crc32c::Mask(crc32c::Value(d, 252)));
}

Result<TreeHeader> DecodeTreeHeader(const uint8_t* d, const std::string& what) {
  auto corrupt = [&](const std::string& m) {
    return Status::Corruption(what + ": block 0 (header): " + m);
  };
  if (std::memcmp(d, kTreeMagic, 8) != 0) return corrupt("bad magic, not a tree file");
  if (crc32c::Unmask(DecodeLE<uint32_t>(d + 252)) != crc32c::Value(d, 252)) {
    return corrupt("checksum mismatch");
  }
  uint32_t version = DecodeLE<uint32_t>(d + 8);
  if (version < kTreeVersionNoLabels || version > kTreeVersionCompressed) {
    return corrupt("unsupported version " + std::to_string(version) + " (this build reads 1 to " +
                   std::to_string(kTreeVersionCompressed) + ")");
  }
  TreeHeader h;
  h.version = version;
  h.block_size = DecodeLE<uint32_t>(d + 12);
  h.point_count = DecodeLE<uint64_t>(d + 16);
  h.bucket_count = DecodeLE<uint32_t>(d + 24);
  h.levels = DecodeLE<uint32_t>(d + 28);
  h.points_per_block = DecodeLE<uint32_t>(d + 32);
  h.frame = DecodeLE<uint32_t>(d + 36);
  h.tree_seq = DecodeLE<uint64_t>(d + 40);
  h.min_id = DecodeLE<uint64_t>(d + 48);
  h.max_id = DecodeLE<uint64_t>(d + 56);
  for (int a = 0; a < 3; ++a) {
    h.bbox.lo[a] = DecodeLE<float>(d + 64 + 4 * a);
    h.bbox.hi[a] = DecodeLE<float>(d + 76 + 4 * a);
  }
  h.root_type = static_cast<ChildType>(d[88]);
  h.root_ref = DecodeLE<uint32_t>(d + 92);
  h.node_block_start = DecodeLE<uint32_t>(d + 96);
  h.node_block_count = DecodeLE<uint32_t>(d + 100);
  h.dir_block_start = DecodeLE<uint32_t>(d + 104);
  h.dir_block_count = DecodeLE<uint32_t>(d + 108);
  h.crc_block_start = DecodeLE<uint32_t>(d + 112);
  h.crc_block_count = DecodeLE<uint32_t>(d + 116);
  h.total_blocks = DecodeLE<uint32_t>(d + 120);
  h.crc_table_crc = DecodeLE<uint32_t>(d + 124);
  for (int k = 0; k < kMaxLevels; ++k) {
    h.level_count[k] = DecodeLE<uint32_t>(d + 128 + 8 * k);
    h.level_start_block[k] = DecodeLE<uint32_t>(d + 132 + 8 * k);
  }
  h.labels = h.label_summaries() ? DecodeLE<uint32_t>(d + 200) : ~0u;
  if (h.block_size < 4096 || h.block_size > (1u << 20) || (h.block_size & (h.block_size - 1))) {
    return corrupt("block size " + std::to_string(h.block_size) + " out of range");
  }
  if (h.points_per_block != h.block_size / 64) return corrupt("points per block mismatch");
  if (h.levels < 1 || h.levels > kMaxLevels) return corrupt("bad level count");
  if (static_cast<uint8_t>(h.root_type) > 2) return corrupt("bad root type");
  uint64_t sum = 0;
  for (uint32_t k = 0; k < h.levels; ++k) sum += h.level_count[k];
  if (sum != h.point_count) return corrupt("level sizes do not add up to the point count");
  if (h.crc_block_start + h.crc_block_count != h.total_blocks) return corrupt("bad block map");
  return h;
}

void EncodeNode(const NodeRecord& n, uint8_t* d) {
  d[0] = n.axis;
  d[1] = static_cast<uint8_t>(n.left_type);
  d[2] = static_cast<uint8_t>(n.right_type);
  d[3] = 0;
  EncodeLE(d + 4, n.split);
  EncodeLE(d + 8, n.left);
  EncodeLE(d + 12, n.right);
}

NodeRecord DecodeNode(const uint8_t* d) {
  NodeRecord n;
  n.axis = d[0];
  n.left_type = static_cast<ChildType>(d[1]);
  n.right_type = static_cast<ChildType>(d[2]);
  n.split = DecodeLE<float>(d + 4);
  n.left = DecodeLE<uint32_t>(d + 8);
  n.right = DecodeLE<uint32_t>(d + 12);
  return n;
}

void EncodeDirEntry(const DirEntry& e, const TreeHeader& h, uint8_t* d) {
  const uint32_t levels = h.levels;
  for (int a = 0; a < 3; ++a) {
    EncodeLE(d + 4 * a, e.box.lo[a]);
    EncodeLE(d + 12 + 4 * a, e.box.hi[a]);
  }
  for (uint32_t k = 0; k < levels; ++k) {
    EncodeLE(d + 24 + 8 * k, e.start[k]);
    EncodeLE(d + 28 + 8 * k, e.count[k]);
  }
  if (h.label_summaries()) EncodeLE(d + 24 + 8 * levels, e.labels);
}

DirEntry DecodeDirEntry(const uint8_t* d, const TreeHeader& h) {
  const uint32_t levels = h.levels;
  DirEntry e;
  for (int a = 0; a < 3; ++a) {
    e.box.lo[a] = DecodeLE<float>(d + 4 * a);
    e.box.hi[a] = DecodeLE<float>(d + 12 + 4 * a);
  }
  for (uint32_t k = 0; k < levels; ++k) {
    e.start[k] = DecodeLE<uint32_t>(d + 24 + 8 * k);
    e.count[k] = DecodeLE<uint32_t>(d + 28 + 8 * k);
  }
  e.labels = h.label_summaries() ? DecodeLE<uint32_t>(d + 24 + 8 * levels) : ~0u;
  return e;
}

}  // namespace hvdb
