// libspatialindex's R*-tree (Debian libspatialindex-dev) as the thesis's Table 8.1 peer: disk
// storage manager, 64 KiB pages, every point stored with its 64-byte record as the entry's data.
#ifndef HVDB_BENCH_PEER_RTREE_H_
#define HVDB_BENCH_PEER_RTREE_H_

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "storage/point.h"

namespace hvdb::bench {

class RTreePeer {
 public:
  // dim 4: (x, y, z, t) with t = frame / fps; dim 3: (x, y, z).
  struct Params {
    uint32_t dim = 3;
    uint32_t page_size = 64u << 10;
    uint32_t buffer_pages = 4096;  // RandomEvictionsBuffer capacity (write-back), in nodes
    double fill_factor = 0.7;
    double fps = 30;
  };
  // A new, empty tree in base.idx / base.dat (removed first if present).
  static std::unique_ptr<RTreePeer> Create(const std::string& base, const Params& p);
  // A new tree bulk-loaded with STR (Sort-Tile-Recursive) from the points.
  static std::unique_ptr<RTreePeer> BulkLoad(const std::string& base, const Params& p,
                                             std::span<const Point> pts);
  ~RTreePeer();

  // Inserts one point at a time (insertData), as an R*-tree grows.
  void Insert(std::span<const Point> pts);
  // Writes every dirty node (buffer flush) and fsyncs both files: the tree is then durable.
  void Sync();
  // Closes the tree (flushing it) and frees its memory; Reopen loads it again from the files
  // (with an empty buffer).
  void Close();
  void Reopen();
  // Points whose box intersects [lo, hi] (dim coordinates each), decoded from their records.
  uint64_t Query(const double* lo, const double* hi, std::vector<Point>* out);
  std::vector<std::string> Files() const;
  // Entries per leaf / inner node chosen so that a node fills one page.
  uint32_t leaf_capacity() const { return leaf_cap_; }
  uint32_t index_capacity() const { return index_cap_; }

 private:
  struct Impl;
  RTreePeer(std::string base, Params p);
  void OpenFresh();
  std::string base_;
  Params p_;
  uint32_t leaf_cap_ = 0, index_cap_ = 0;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_PEER_RTREE_H_
