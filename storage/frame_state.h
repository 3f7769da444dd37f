// FrameVersion: one frame's Bkd-tree (thesis 8.3.2) as an immutable snapshot, and its file.
//
// A frame is a forest: slot i holds a kd-tree of at most k^(i/(k-1)) p points (or nothing;
// p = Options::t0_points, k = Options::merge_fanout), each with its weak deletes (sorted ids), plus the buffer T0 of recently
// inserted points, in memory and in the log. Queries hold a shared_ptr to the version they
// started on; writers publish new versions; the merger turns a full T0 into a tree.
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

// T0 as a list of shared, immutable chunks. T0 holds tens of thousands of points, and every
// commit makes a new version of it: appending shares all chunks but a small last one, so a
// commit copies what it adds, not the whole buffer.
class PointBuffer {
 public:
  using Chunk = std::shared_ptr<const std::vector<Point>>;
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  const std::vector<Chunk>& chunks() const { return chunks_; }
  template <typename F>
  void ForEach(F&& f) const {
    for (const Chunk& c : chunks_) {
      for (const Point& p : *c) f(p);
    }
  }
  std::vector<Point> ToVector() const;
  void Append(std::vector<Point> pts);
  // Removes the points for which drop(p) is true (called once per point, in order), copying
  // only the chunks that hold one.
  template <typename Pred>
  size_t RemoveIf(Pred&& drop) {
    size_t removed = 0;
    std::vector<Chunk> out;
    for (Chunk& c : chunks_) {
      std::shared_ptr<std::vector<Point>> kept;
      for (size_t i = 0; i < c->size(); ++i) {
        const Point& p = (*c)[i];
        if (drop(p)) {
          if (!kept) kept = std::make_shared<std::vector<Point>>(c->begin(), c->begin() + i);
          ++removed;
        } else if (kept) {
          kept->push_back(p);
        }
      }
      if (!kept) {
        out.push_back(std::move(c));
      } else if (!kept->empty()) {
        out.push_back(std::move(kept));
      }
    }
    chunks_ = std::move(out);
    size_ -= removed;
    return removed;
  }
  // The points after the first `n` (the merger keeps what arrived while it worked).
  PointBuffer Suffix(size_t n) const;

 private:
  std::vector<Chunk> chunks_;
  size_t size_ = 0;
};

struct FrameVersion {
  uint32_t frame = 0;
  uint64_t applied_lsn = 0;  // last log record applied to this frame
  std::vector<TreeSlot> slots;
  PointBuffer t0;

  uint64_t PointCount() const;
  // Box of all points (trees' boxes and T0); empty frame: lo > hi.
  Box3 Bounds() const;
  bool empty() const { return PointCount() == 0 && t0.empty(); }
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
