// Constants and records of a tree file (*.kdt). See docs/FORMAT.md, "Tree file", for the
// layout byte by byte. A tree file is written once by the builder and never modified.
#ifndef HVDB_STORAGE_KDTREE_FORMAT_H_
#define HVDB_STORAGE_KDTREE_FORMAT_H_

#include <array>
#include <cstdint>
#include <functional>
#include <string>

#include "storage/status.h"

namespace hvdb {

inline constexpr char kTreeMagic[8] = {'H', 'V', 'D', 'B', 'K', 'D', 'T', '\0'};
// Versions 3 and 4 carry label summaries: every directory entry ends with a u32, the OR of its
// bucket's points' labels, and the header holds the OR over the tree. Files of versions 1 and 2
// (written before summaries existed) read as if every bucket held every bit; builds from before
// summaries refuse versions 3 and 4 instead of misreading the longer entries.
inline constexpr uint32_t kTreeVersion = 3;
// The cold tier's compressed tree file (storage/cold_tree.h): the same tree, its blocks coded.
inline constexpr uint32_t kTreeVersionCompressed = 4;
inline constexpr uint32_t kTreeVersionNoLabels = 1;
inline constexpr uint32_t kTreeVersionCompressedNoLabels = 2;
inline constexpr int kMaxLevels = 9;  // l <= 8
inline constexpr size_t kTreeHeaderSize = 256;
inline constexpr size_t kNodeRecordSize = 16;
inline constexpr size_t kNodeBlockHeader = 8;

enum class ChildType : uint8_t { kNode = 0, kNodeBlock = 1, kBucket = 2 };

struct Box3 {
  std::array<float, 3> lo{}, hi{};
};

// How a query region relates to a box: prunes subtrees, skips per-point tests when inside.
enum class Relation { kOutside, kInside, kCrosses };
using BoxTest = std::function<Relation(const Box3&)>;

struct TreeHeader {
  uint32_t version = kTreeVersion;
  uint32_t block_size = 0;
  uint64_t point_count = 0;
  uint32_t bucket_count = 0;
  uint32_t levels = 0;  // l + 1
  uint32_t points_per_block = 0;
  uint32_t frame = 0;
  uint64_t tree_seq = 0;
  uint64_t min_id = 0, max_id = 0;
  Box3 bbox;
  ChildType root_type = ChildType::kBucket;
  uint32_t root_ref = 0;
  uint32_t node_block_start = 0, node_block_count = 0;
  uint32_t dir_block_start = 0, dir_block_count = 0;
  uint32_t crc_block_start = 0, crc_block_count = 0;
  uint32_t total_blocks = 0;
  std::array<uint32_t, kMaxLevels> level_count{};        // points in each level's segment
  std::array<uint32_t, kMaxLevels> level_start_block{};  // first block of each segment
  uint32_t crc_table_crc = 0;  // masked CRC-32C of the checksum table's bytes
  // OR of every point's label (a superset: weak deletes do not clear it); ~0 without summaries.
  uint32_t labels = ~0u;

  bool label_summaries() const { return version == kTreeVersion || version == kTreeVersionCompressed; }
  bool compressed() const {
    return version == kTreeVersionCompressed || version == kTreeVersionCompressedNoLabels;
  }
  uint32_t DirEntrySize() const { return 24 + 8 * levels + (label_summaries() ? 4 : 0); }
  uint32_t DirEntriesPerBlock() const { return block_size / DirEntrySize(); }
  uint32_t NodesPerBlock() const {
    return static_cast<uint32_t>((block_size - kNodeBlockHeader) / kNodeRecordSize);
  }
};

// Encodes into 256 bytes, the last 4 being the masked CRC-32C of the first 252.
void EncodeTreeHeader(const TreeHeader& h, uint8_t* dst);
// Checks magic, version, checksum and internal consistency; `what` names the file in errors.
Result<TreeHeader> DecodeTreeHeader(const uint8_t* src, const std::string& what);

struct NodeRecord {
  uint8_t axis = 0;
  ChildType left_type = ChildType::kBucket, right_type = ChildType::kBucket;
  float split = 0;
  uint32_t left = 0, right = 0;
};
void EncodeNode(const NodeRecord& n, uint8_t* dst);
NodeRecord DecodeNode(const uint8_t* src);

struct DirEntry {
  Box3 box;
  std::array<uint32_t, kMaxLevels> start{}, count{};
  // OR of the labels of the bucket's points at every level; ~0 in files without summaries.
  // Lets label-masked scans (selections, replace-mode edits) skip buckets without the bits.
  uint32_t labels = ~0u;
};
// The entry's layout depends on the header's levels and version.
void EncodeDirEntry(const DirEntry& e, const TreeHeader& h, uint8_t* dst);
DirEntry DecodeDirEntry(const uint8_t* src, const TreeHeader& h);

}  // namespace hvdb

#endif  // HVDB_STORAGE_KDTREE_FORMAT_H_
