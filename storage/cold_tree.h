// The cold tier: a tree file whose blocks are stored compressed (docs/FORMAT.md, "Compressed
// tree file"). It holds the same tree as the raw format, block for block: the header, node and
// directory blocks and level segments keep their block numbers, and each block is stored as a
// payload that decodes to exactly the B bytes the raw file would hold there (the checksum of
// those bytes is kept and checked after decoding). So everything above KdTree's block loader
// (queries, levels of detail, the buffer pool, prefetching) is unchanged: a window decodes only
// the blocks it touches, coarse levels still come first, and the pool caches decoded blocks.
//
// Level-segment blocks are coded as record blocks (blockcode/record_block.h), lossless for
// every field; other blocks are stored up to their last non-zero byte.
#ifndef HVDB_STORAGE_COLD_TREE_H_
#define HVDB_STORAGE_COLD_TREE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "storage/env.h"
#include "storage/kdtree_builder.h"
#include "storage/kdtree_format.h"

namespace hvdb {

inline constexpr size_t kColdTableEntrySize = 16;
// First byte of a block's payload.
enum class ColdCoding : uint8_t {
  kTrimmed = 0,  // the block's bytes up to its last non-zero one; the rest is zero
  kRecords = 1,  // a record block of the block's points; the rest is zero
};

// Writes `image` (a raw tree file image) at `path` in the compressed format. sync: via path.tmp,
// sync, rename, as BuildTreeFile. Reorders the image's points within each bucket's range of a
// level (the order there is free), to the order that codes smaller.
Status WriteCompressedTree(Env* env, const std::string& path, TreeImage& image, bool sync);

// The block table of a compressed file.
struct ColdBlockTable {
  uint64_t data_start = 0;            // first payload byte (after the header and the table)
  std::vector<uint64_t> end;          // block i's payload is [Start(i), end[i])
  std::vector<uint32_t> payload_crc;  // masked CRC-32C of each payload
  uint64_t Start(uint32_t blk) const { return blk == 0 ? data_start : end[blk - 1]; }
};

// Reads and checks the table (its checksum, offsets within the file).
Result<ColdBlockTable> ReadColdBlockTable(RandomAccessFile* file, const TreeHeader& h,
                                          std::vector<uint32_t>* block_crcs);

// Decodes block `blk` from its payload into dst (B bytes), checking the payload's checksum, the
// decoding and the decoded block's checksum `block_crc` (masked); `what` names the file.
Status DecodeColdBlock(const TreeHeader& h, uint32_t blk, const uint8_t* payload, size_t len,
                       uint32_t payload_crc, uint32_t block_crc, uint8_t* dst,
                       const std::string& what);

}  // namespace hvdb

#endif  // HVDB_STORAGE_COLD_TREE_H_
