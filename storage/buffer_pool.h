// BufferPool: the one fixed-size block cache shared by every frame, tree and query (8.3.3).
//
// Blocks are identified by (file id, block number). Tree files are immutable, so every
// cached block is clean and eviction never writes: CLOCK (second chance) over unpinned
// blocks. A block stays pinned while a PageRef to it lives. Memory is the capacity given at
// construction, allocated once, plus a hash index of one entry per resident block.
//
// Thread safety: all methods are safe for concurrent use. Loads run outside the lock; a
// second thread asking for a block being loaded waits for that load instead of repeating it.
//
// Loads come one block at a time (Fetch, on a miss) or in batches (Prefetch): a query that knows
// which blocks it will read claims their slots, and one of the pool's loader threads reads them
// all in one batch (the device serves them in parallel) while the query goes on; its Fetch of a
// block still in flight waits for that block.
#ifndef HVDB_STORAGE_BUFFER_POOL_H_
#define HVDB_STORAGE_BUFFER_POOL_H_

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <thread>
#include <unordered_map>
#include <vector>

#include "storage/database.h"
#include "storage/status.h"

namespace hvdb {

class BufferPool;

// A pinned block; unpins on destruction. Movable, not copyable.
class PageRef {
 public:
  PageRef() = default;
  PageRef(BufferPool* pool, uint32_t slot, const uint8_t* data)
      : pool_(pool), slot_(slot), data_(data) {}
  PageRef(PageRef&& o) noexcept { *this = std::move(o); }
  PageRef& operator=(PageRef&& o) noexcept;
  PageRef(const PageRef&) = delete;
  PageRef& operator=(const PageRef&) = delete;
  ~PageRef() { Release(); }
  const uint8_t* data() const { return data_; }
  bool valid() const { return data_ != nullptr; }
  void Release();

 private:
  BufferPool* pool_ = nullptr;
  uint32_t slot_ = 0;
  const uint8_t* data_ = nullptr;
};

class BufferPool {
 public:
  // Fills `dst` (block_size bytes) with block `block` of the file, verifying its checksum.
  using Loader = std::function<Status(uint8_t* dst)>;
  // One block of a batch load: the loader fills `dst` and sets `ok` once it is verified.
  struct BlockLoad {
    uint32_t block = 0;
    uint8_t* dst = nullptr;
    bool ok = false;
    uint32_t slot = 0;  // the pool's
  };
  using BatchLoader = std::function<void(std::span<BlockLoad> loads)>;

  // REQUIRES: capacity_bytes >= 2 * block_size.
  BufferPool(size_t capacity_bytes, uint32_t block_size);
  ~BufferPool();
  BufferPool(const BufferPool&) = delete;
  BufferPool& operator=(const BufferPool&) = delete;

  // A fresh id for a file whose blocks will be cached.
  uint64_t NewFileId();
  // Returns the block pinned, loading it with `load` on a miss. Fails with the loader's error
  // (the block is then not cached) or LimitExceeded when every block is pinned.
  Result<PageRef> Fetch(uint64_t file_id, uint32_t block, const Loader& load);
  // Loads the blocks (ascending) of the file that are not resident in the background, in
  // batches of at most `batch` blocks, each one call of `load` on a loader thread. Claims at
  // most a quarter of the pool; blocks beyond are left to Fetch. Returns the blocks claimed.
  size_t Prefetch(uint64_t file_id, std::span<const uint32_t> blocks, size_t batch,
                  BatchLoader load);
  // Forgets every unpinned block of the file (when a tree file is deleted).
  void Forget(uint64_t file_id);

  uint32_t block_size() const { return block_size_; }
  CacheStats Stats() const;

 private:
  friend class PageRef;
  struct Key {
    uint64_t file;
    uint32_t block;
    bool operator==(const Key&) const = default;
  };
  struct KeyHash {
    size_t operator()(const Key& k) const {
      return std::hash<uint64_t>()(k.file * 0x9E3779B97F4A7C15ull ^ k.block);
    }
  };
  enum class SlotState : uint8_t { kFree, kLoading, kReady };
  struct Slot {
    Key key{};
    SlotState state = SlotState::kFree;
    bool referenced = false;
    uint32_t pins = 0;
  };
  void Unpin(uint32_t slot);
  void LoaderLoop();
  // REQUIRES: mu_ held. Slot `slot` is handed out for the first time: keep the pages of the
  // next slots faulted in ahead of it (a loader does it).
  void PopulateAheadLocked(uint32_t slot);
  // REQUIRES: mu_ held. Returns a free or evicted slot, or -1 when all are pinned.
  int64_t FindVictimLocked();

  const uint32_t block_size_;
  const uint32_t nslots_;
  std::unique_ptr<uint8_t[]> memory_;
  mutable std::mutex mu_;
  std::condition_variable loaded_;
  std::vector<Slot> slots_;
  std::unordered_map<Key, uint32_t, KeyHash> index_;
  uint32_t hand_ = 0;
  uint64_t next_file_id_ = 1;
  uint64_t hits_ = 0, misses_ = 0, evictions_ = 0, prefetched_ = 0;
  uint32_t loading_ = 0;  // slots claimed by Prefetch and not yet loaded
  // Batch loads waiting for a loader thread.
  struct Job {
    std::vector<BlockLoad> loads;
    BatchLoader load;
  };
  std::deque<Job> jobs_;
  std::condition_variable job_cv_;
  // Slots [0, populated_) have their pages faulted in (or are being); populate_want_ is how far
  // the loaders are asked to go. A fresh slot's first load would otherwise take a page fault per
  // 4 KiB on the query's path (~1 000 for a cold window), which costs ~2 us each on a VM here
  // and far more on a fresh one (bench/README.md, issue 35).
  uint32_t populated_ = 0, populate_want_ = 0;
  bool stop_ = false;
  std::vector<std::thread> loaders_;
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_BUFFER_POOL_H_
