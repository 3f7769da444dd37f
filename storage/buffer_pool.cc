#include "storage/buffer_pool.h"

#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cassert>
#include <cstdint>

namespace hvdb {

PageRef& PageRef::operator=(PageRef&& o) noexcept {
  if (this != &o) {
    Release();
    pool_ = o.pool_;
    slot_ = o.slot_;
    data_ = o.data_;
    o.pool_ = nullptr;
    o.data_ = nullptr;
  }
  return *this;
}

void PageRef::Release() {
  if (pool_ != nullptr) pool_->Unpin(slot_);
  pool_ = nullptr;
  data_ = nullptr;
}

BufferPool::BufferPool(size_t capacity_bytes, uint32_t block_size)
    : block_size_(block_size),
      nslots_(static_cast<uint32_t>(capacity_bytes / block_size)),
      // Untouched pages of this allocation cost no RSS until a block is loaded into them.
      memory_(new uint8_t[static_cast<size_t>(nslots_) * block_size]),
      slots_(nslots_) {
  assert(nslots_ >= 2);
  index_.reserve(nslots_);
  // Four loaders: batches in flight together keep the device's queue full (bench/README.md
  // has the figures). They spend their time waiting for the device, not on a core.
  for (int i = 0; i < 4; ++i) loaders_.emplace_back([this] { LoaderLoop(); });
  std::lock_guard<std::mutex> l(mu_);
  PopulateAheadLocked(0);
}

namespace {

// Pool slots populated ahead of the first use of a slot: 16 MiB, a few cold windows' blocks.
constexpr size_t kPopulateAheadBytes = 16u << 20;

// Faults in the pages of [p, p + n) writable without touching their bytes (a slot there may be
// loading concurrently). Kernels before 5.14 refuse the advice: the loads then fault as before.
void Populate(uint8_t* p, size_t n) {
  static const auto page = static_cast<uintptr_t>(::sysconf(_SC_PAGESIZE));
  const uintptr_t lo = reinterpret_cast<uintptr_t>(p) / page * page;
  const uintptr_t hi = (reinterpret_cast<uintptr_t>(p) + n + page - 1) / page * page;
  (void)::madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_POPULATE_WRITE);
}

}  // namespace

void BufferPool::PopulateAheadLocked(uint32_t slot) {
  const auto ahead = static_cast<uint32_t>(std::max<size_t>(1, kPopulateAheadBytes / block_size_));
  if (slot + ahead / 2 < populate_want_ || populate_want_ >= nslots_) return;
  populate_want_ = std::min<uint32_t>(nslots_, slot + ahead);
  job_cv_.notify_one();
}

BufferPool::~BufferPool() {
  {
    std::lock_guard<std::mutex> l(mu_);
    stop_ = true;  // the loaders finish the queued jobs first: claimed slots are never left
  }
  job_cv_.notify_all();
  for (auto& t : loaders_) t.join();
}

void BufferPool::LoaderLoop() {
  std::unique_lock<std::mutex> l(mu_);
  for (;;) {
    job_cv_.wait(l, [&] { return stop_ || !jobs_.empty() || populated_ < populate_want_; });
    if (jobs_.empty() && populated_ < populate_want_ && !stop_) {
      const uint32_t from = populated_, to = populate_want_;
      populated_ = to;
      l.unlock();
      Populate(memory_.get() + size_t{from} * block_size_, size_t{to - from} * block_size_);
      l.lock();
      continue;
    }
    if (jobs_.empty()) return;  // stopping, nothing left
    Job job = std::move(jobs_.front());
    jobs_.pop_front();
    l.unlock();
    job.load(job.loads);
    l.lock();
    for (const BlockLoad& b : job.loads) {
      Slot& s = slots_[b.slot];
      if (b.ok) {
        s.state = SlotState::kReady;
      } else {
        // A failed read is not cached: a Fetch waiting for it loads it itself and reports why.
        index_.erase(s.key);
        s.state = SlotState::kFree;
      }
      --loading_;
    }
    loaded_.notify_all();
  }
}

size_t BufferPool::Prefetch(uint64_t file_id, std::span<const uint32_t> blocks, size_t batch,
                            BatchLoader load) {
  std::vector<BlockLoad> claimed;
  {
    std::lock_guard<std::mutex> l(mu_);
    const uint32_t budget = nslots_ / 4;
    for (uint32_t blk : blocks) {
      if (loading_ >= budget) break;
      Key key{file_id, blk};
      if (index_.count(key)) continue;
      int64_t victim = FindVictimLocked();
      if (victim < 0) break;
      auto slot = static_cast<uint32_t>(victim);
      Slot& s = slots_[slot];
      s.key = key;
      s.state = SlotState::kLoading;
      s.pins = 0;
      s.referenced = true;  // a second chance before its query reads it
      index_[key] = slot;
      ++loading_;
      ++prefetched_;
      ++misses_;  // read from the file, ahead of its Fetch
      claimed.push_back({blk, memory_.get() + size_t{slot} * block_size_, false, slot});
    }
    for (size_t i = 0; i < claimed.size(); i += batch) {
      Job job;
      job.loads.assign(claimed.begin() + static_cast<std::ptrdiff_t>(i),
                       claimed.begin() + static_cast<std::ptrdiff_t>(std::min(i + batch, claimed.size())));
      job.load = load;
      jobs_.push_back(std::move(job));
    }
  }
  if (!claimed.empty()) job_cv_.notify_all();
  return claimed.size();
}

uint64_t BufferPool::NewFileId() {
  std::lock_guard<std::mutex> l(mu_);
  return next_file_id_++;
}

int64_t BufferPool::FindVictimLocked() {
  // Two full sweeps give every referenced block its second chance.
  for (uint64_t step = 0; step < 2ull * nslots_ + 1; ++step) {
    uint32_t i = hand_;
    hand_ = (hand_ + 1) % nslots_;
    Slot& s = slots_[i];
    if (s.state == SlotState::kFree) {
      PopulateAheadLocked(i);
      return i;
    }
    if (s.state != SlotState::kReady || s.pins > 0) continue;
    if (s.referenced) {
      s.referenced = false;
      continue;
    }
    index_.erase(s.key);
    s.state = SlotState::kFree;
    ++evictions_;
    return i;
  }
  return -1;
}

Result<PageRef> BufferPool::Fetch(uint64_t file_id, uint32_t block, const Loader& load) {
  Key key{file_id, block};
  std::unique_lock<std::mutex> l(mu_);
  for (;;) {
    auto it = index_.find(key);
    if (it == index_.end()) break;
    Slot& s = slots_[it->second];
    if (s.state == SlotState::kReady) {
      ++s.pins;
      s.referenced = true;
      ++hits_;
      return PageRef(this, it->second, memory_.get() + size_t{it->second} * block_size_);
    }
    loaded_.wait(l);  // another thread is loading it; look again when it is done
  }
  int64_t victim = FindVictimLocked();
  if (victim < 0) {
    return Status::LimitExceeded("buffer pool exhausted: all " + std::to_string(nslots_) +
                                 " blocks are pinned; raise the cache size (--cache-mb)");
  }
  auto slot = static_cast<uint32_t>(victim);
  Slot& s = slots_[slot];
  s.key = key;
  s.state = SlotState::kLoading;
  s.pins = 1;
  s.referenced = true;
  index_[key] = slot;
  ++misses_;
  l.unlock();
  uint8_t* dst = memory_.get() + size_t{slot} * block_size_;
  Status st = load(dst);
  l.lock();
  if (!st.ok()) {
    index_.erase(key);
    s.state = SlotState::kFree;
    s.pins = 0;
    loaded_.notify_all();
    return st;
  }
  s.state = SlotState::kReady;
  loaded_.notify_all();
  return PageRef(this, slot, dst);
}

void BufferPool::Unpin(uint32_t slot) {
  std::lock_guard<std::mutex> l(mu_);
  assert(slots_[slot].pins > 0);
  --slots_[slot].pins;
}

void BufferPool::Forget(uint64_t file_id) {
  std::lock_guard<std::mutex> l(mu_);
  for (uint32_t i = 0; i < nslots_; ++i) {
    Slot& s = slots_[i];
    if (s.state == SlotState::kReady && s.key.file == file_id && s.pins == 0) {
      index_.erase(s.key);
      s.state = SlotState::kFree;
    }
  }
}

CacheStats BufferPool::Stats() const {
  std::lock_guard<std::mutex> l(mu_);
  CacheStats c;
  c.capacity_bytes = uint64_t{nslots_} * block_size_;
  c.block_size = block_size_;
  c.hits = hits_;
  c.misses = misses_;
  c.evictions = evictions_;
  c.prefetched = prefetched_;
  for (const Slot& s : slots_) {
    if (s.state == SlotState::kReady) ++c.resident_blocks;
    if (s.pins > 0) ++c.pinned_blocks;
  }
  return c;
}

}  // namespace hvdb
