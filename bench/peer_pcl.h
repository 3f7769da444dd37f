// PCL's out-of-core octree (pcl::outofcore, Debian libpcl-dev) as a peer: the same points and
// the same windows as hvdb's Figure 8.13 run. Nothing of PCL leaks into this header.
#ifndef HVDB_BENCH_PEER_PCL_H_
#define HVDB_BENCH_PEER_PCL_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "storage/point.h"

namespace hvdb::bench {

class PclOctree {
 public:
  // Builds a disk-backed octree in `dir` (which must not exist) over the unit cube with its
  // level-of-detail subsamples (addPointCloud_and_genLOD, PCL's default 12.5% per level).
  // Depth: leaves of ~2048 points on average, like hvdb's buckets. Points are stored as
  // pcl::PointXYZRGBNormal (position, colour, normal), the closest PCL type to hvdb's record.
  static std::unique_ptr<PclOctree> Build(const std::string& dir, const std::vector<Point>& pts);
  ~PclOctree();

  // Build returns the tree flushed to disk and closed; Reopen loads it (again) from disk.
  void Reopen();
  // Points in the box at full resolution (queryBBIncludes at the tree's depth).
  uint64_t Box(const double lo[3], const double hi[3]);
  // Points in the box at a coarser depth (PCL's level-of-detail query).
  uint64_t BoxAtDepth(const double lo[3], const double hi[3], uint64_t depth);
  uint64_t depth() const { return depth_; }
  const std::string& dir() const { return dir_; }

 private:
  struct Impl;
  PclOctree(std::string dir, uint64_t depth);
  std::string dir_;
  uint64_t depth_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_PEER_PCL_H_
