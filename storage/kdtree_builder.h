// Builds a tree file from the points of one frame, in core (8.3.3: a frame fits in memory).
//
// The kd-tree is split so that the left child of q points gets c * 2^floor(log2(q/c - 1))
// points, c = 2b the bucket size (8.3.1, 8.4): every bucket but the rightmost is full, so
// level 0 of each bucket fills exactly one block. Split axis: widest extent. Inner nodes are
// packed depth-first into node blocks (fig. 8.7).
#ifndef HVDB_STORAGE_KDTREE_BUILDER_H_
#define HVDB_STORAGE_KDTREE_BUILDER_H_

#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "storage/env.h"
#include "storage/kdtree_format.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb {

struct TreeBuildParams {
  uint32_t block_size = 64u << 10;
  int lod_levels = 5;  // l
  uint32_t frame = 0;
  uint64_t tree_seq = 0;
  // Write the compressed format of the cold tier (storage/cold_tree.h) instead of raw blocks.
  bool compressed = false;
  // Per-bucket label summaries (docs/FORMAT.md); false writes the layout of files from before
  // them, which readers must keep reading (tests).
  bool label_summaries = true;
};

// A tree file's bytes in memory, as BuildTreeFile writes them in the raw format.
struct TreeImage {
  struct Free {
    void operator()(uint8_t* p) const { std::free(p); }
  };
  TreeHeader header;
  std::unique_ptr<uint8_t, Free> data;  // 4 KiB-aligned
  size_t bytes = 0;
  // The 4 KiB pages that can hold non-zero bytes (ascending): the rest of each block is zero,
  // and the raw file is written sparse (Env::WriteNewSparseFile).
  std::vector<FileExtent> used;
};

// Points in the left child of a node holding q points, with bucket capacity c.
uint64_t LeftChildSize(uint64_t q, uint64_t c);

// Writes the tree to `path`. sync: via path.tmp, sync, rename (durable and all or nothing when
// it returns); else straight to `path`, unsynced (the caller syncs it before any frame state
// lists it, and recovery deletes unlisted tree files). `points` is reordered.
// REQUIRES: !points.empty().
// The raw file image of the points' tree. `points` is reordered. REQUIRES: !points.empty().
Status BuildTreeImage(std::vector<Point>& points, const TreeBuildParams& params,
                      TreeImage* out);
Status BuildTreeFile(Env* env, const std::string& path, std::vector<Point>& points,
                     const TreeBuildParams& params, bool sync);

}  // namespace hvdb

#endif  // HVDB_STORAGE_KDTREE_BUILDER_H_
