// FrameVersion: one frame's Bkd-tree (thesis 8.3.2) as an immutable snapshot, and its file.
//
// A frame is a forest: slot i holds a kd-tree of at most 2^i p points (or nothing), each
// with its weak deletes (sorted ids), plus the buffer T0 of recently inserted points. Queries
// hold a shared_ptr to the version they started on; writers publish new versions.
//
// The frame state file frames/<frame>.fst stores a version (tree sequence numbers, dead ids,
// T0 points and the last log sequence number applied). See docs/FORMAT.md.
#ifndef HVDB_STORAGE_FRAME_STATE_H_
#define HVDB_STORAGE_FRAME_STATE_H_

#include <algorithm>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "storage/kdtree_reader.h"
#include "storage/point.h"

namespace hvdb {

struct TreeSlot {
  std::shared_ptr<KdTree> tree;  // null: empty slot
  std::shared_ptr<const std::vector<uint64_t>> dead;  // sorted ids deleted from this tree

  bool IsDead(uint64_t id) const {
    return dead && std::binary_search(dead->begin(), dead->end(), id);
  }
  uint64_t live() const { return tree ? tree->header().point_count - (dead ? dead->size() : 0) : 0; }
};

struct FrameVersion {
  uint32_t frame = 0;
  uint64_t applied_lsn = 0;  // last log record applied to this frame
  std::vector<TreeSlot> slots;
  std::shared_ptr<const std::vector<Point>> t0 = std::make_shared<std::vector<Point>>();

  uint64_t PointCount() const;
  // Box of all points (trees' boxes and T0); empty frame: lo > hi.
  Box3 Bounds() const;
  bool empty() const { return PointCount() == 0 && t0->empty(); }
};

std::string TreeFileName(uint32_t frame, uint64_t seq);  // "00000012-000000000000002a.kdt"
// Parses a tree file name; false if it is not one.
bool ParseTreeFileName(const std::string& name, uint32_t* frame, uint64_t* seq);
std::string FrameStateFileName(uint32_t frame);  // "00000012.fst"

// The decoded file: tree sequence numbers instead of open trees.
struct FrameStateRecord {
  uint32_t frame = 0;
  uint64_t applied_lsn = 0;
  uint64_t next_id = 1;  // the dataset's id counter when written: ids below it were issued
  std::vector<uint64_t> tree_seqs;  // 0: empty slot
  std::vector<std::vector<uint64_t>> dead;
  std::vector<Point> t0;
};

std::string EncodeFrameState(const FrameVersion& v, uint64_t next_id);
Result<FrameStateRecord> DecodeFrameState(const std::string& data, const std::string& what);

}  // namespace hvdb

#endif  // HVDB_STORAGE_FRAME_STATE_H_
