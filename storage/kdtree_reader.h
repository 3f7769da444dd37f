// KdTree: an open, immutable tree file, read block by block through the buffer pool.
//
// Thread safety: all const methods are safe for concurrent use. The object is shared by the
// frame versions that list it; when the last one lets go of a tree marked obsolete (replaced
// by a rebuild), its file is deleted.
#ifndef HVDB_STORAGE_KDTREE_READER_H_
#define HVDB_STORAGE_KDTREE_READER_H_

#include <atomic>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "storage/buffer_pool.h"
#include "storage/cold_tree.h"
#include "storage/env.h"
#include "storage/kdtree_format.h"
#include "storage/point.h"

namespace hvdb {

class KdTree {
 public:
  // `synced`: the file's contents are known durable (else Sync() makes them so).
  static Result<std::shared_ptr<KdTree>> Open(Env* env, const std::string& path,
                                              BufferPool* pool, bool synced = true);
  ~KdTree();
  KdTree(const KdTree&) = delete;
  KdTree& operator=(const KdTree&) = delete;

  const TreeHeader& header() const { return h_; }
  const std::string& path() const { return file_->path(); }
  uint64_t file_bytes() const { return file_->size(); }
  // A compressed tree file of the cold tier (storage/cold_tree.h).
  bool compressed() const { return cold_ != nullptr; }
  // The file is deleted when the last reference goes.
  void MarkObsolete() { obsolete_ = true; }
  // Makes the file durable (once); a frame state may list the tree only after this.
  Status Sync();
  // Listed by the frame state file on disk: the file must outlive every version that drops
  // it until a newer state is durable.
  bool durable() const { return durable_.load(); }
  void MarkDurable() { durable_ = true; }
  void DropCache() const { file_->DropCache(); }

  struct BucketHit {
    uint32_t bucket;
    bool inside;  // the whole bucket box lies in the query region
    DirEntry entry;
  };
  // Walks the inner nodes and returns the buckets whose boxes are not outside `test`,
  // in depth-first (= storage) order. With a `label_mask`, only buckets whose label summary
  // has one of its bits (docs/FORMAT.md), and none at all, without reading a block, when the
  // tree's summary has none: a masked scan reads only what can hold its points.
  Status FindBuckets(const BoxTest& test, std::vector<BucketHit>* out,
                     uint32_t label_mask = 0) const;
  // Has the buffer pool load, in the background, the blocks of the hits' records at levels
  // [lo, hi] that it lacks: batches of merged requests issued at once, so the device serves
  // them in parallel instead of one 64 KiB read at a time (BufferPool::Prefetch).
  void Prefetch(const std::vector<BucketHit>& hits, int lo, int hi) const;
  // Calls fn(records, n) for consecutive runs of the 64-byte records of level `level`,
  // positions [start, start + count) of that level's segment.
  Status ReadRange(int level, uint32_t start, uint32_t count,
                   const std::function<void(const uint8_t*, size_t)>& fn) const;
  // Every point of every level.
  Status ReadAll(std::vector<Point>* out) const;
  // The raw file image (every block, checked; decoded if compressed), e.g. to transcode it.
  Status ReadImage(TreeImage* out) const;
  // Integrity check from disk (bypassing the cache): checksums of every block, node split
  // invariants, bucket boxes, fullness. Returns one line per problem.
  std::vector<std::string> Verify() const;

 private:
  KdTree(Env* env, std::shared_ptr<RandomAccessFile> file, BufferPool* pool, TreeHeader h,
         std::vector<uint32_t> crcs, std::shared_ptr<const ColdBlockTable> cold);
  Result<PageRef> Block(uint32_t blk) const;
  Status LoadBlock(uint32_t blk, uint8_t* dst) const;
  Result<DirEntry> Dir(uint32_t bucket) const;
  // Loads the blocks (ascending) into the pool in the background, in merged runs.
  void PrefetchBlocks(const std::vector<uint32_t>& blocks) const;
  void PrefetchColdBlocks(const std::vector<uint32_t>& blocks, size_t batch) const;

  Env* const env_;
  std::shared_ptr<RandomAccessFile> file_;
  BufferPool* pool_;
  const TreeHeader h_;
  // Masked CRC-32C of every block (0: not covered); shared with batch loads in flight.
  const std::shared_ptr<const std::vector<uint32_t>> crcs_;
  // Compressed files: where each block's payload lies (null: raw blocks at blk * B).
  const std::shared_ptr<const ColdBlockTable> cold_;
  const uint64_t file_id_;
  std::atomic<bool> obsolete_{false};
  std::atomic<bool> synced_{true}, durable_{false};
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_KDTREE_READER_H_
