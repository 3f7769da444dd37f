// The searches of a frame version's stored points that the write path (dataset_write.cc)
// shares with the application of a step to a version (frame_apply.cc: ResolveRelabels and
// ApplyStep of dataset_impl.h).
#ifndef HVDB_STORAGE_FRAME_APPLY_H_
#define HVDB_STORAGE_FRAME_APPLY_H_

#include <cstdint>
#include <vector>

#include "storage/dataset_impl.h"

namespace hvdb {

// Where a point lives in a frame version: -1 = T0, >= 0 = tree slot, -2 = nowhere.
struct Holder {
  int slot = -2;
  Point stored;
};

// Finds `target` (by id and position) in `v`: T0 first, then the trees, skipping the points
// `pending_dead` already marks dead in each slot.
Result<Holder> Locate(const FrameVersion& v, const Point& target,
                      const std::vector<std::vector<uint64_t>>* pending_dead = nullptr);

// Calls fn(hit, records, n) for the runs of records of every level of the buckets `hits` of
// `tree` (each stored point once: a point lives at one level).
template <typename Fn>
Status ReadHits(const KdTree& tree, const std::vector<KdTree::BucketHit>& hits, Fn&& fn) {
  for (const auto& hit : hits) {
    for (uint32_t k = 0; k < tree.header().levels; ++k) {
      HVDB_RETURN_IF_ERROR(tree.ReadRange(static_cast<int>(k), hit.entry.start[k],
                                          hit.entry.count[k],
                                          [&](const uint8_t* rec, size_t n) { fn(hit, rec, n); }));
    }
  }
  return Status::OK();
}

}  // namespace hvdb

#endif  // HVDB_STORAGE_FRAME_APPLY_H_
