// nanoflann's in-memory kd-tree (Debian libnanoflann-dev): the upper bound for a window query
// without durability, paging or levels of detail. The points stay in the caller's vector.
#ifndef HVDB_BENCH_PEER_KDTREE_H_
#define HVDB_BENCH_PEER_KDTREE_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "storage/point.h"

namespace hvdb::bench {

class KdTreePeer {
 public:
  // Builds the index over pts (which must outlive the peer). leaf_size: nanoflann's
  // leaf_max_size.
  KdTreePeer(const std::vector<Point>& pts, size_t leaf_size = 16);
  ~KdTreePeer();
  // Appends copies of the points inside the box [lo, hi] to out (the 64-byte records, as hvdb
  // returns them); returns how many.
  uint64_t Box(const double lo[3], const double hi[3], std::vector<Point>* out) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_PEER_KDTREE_H_
