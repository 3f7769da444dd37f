// DatasetImpl: the engine behind Dataset. Internal header; see database.h for the contract.
//
// Layout of a dataset directory DIR/<name>/ (docs/FORMAT.md):
//   MANIFEST            dataset metadata
//   frames/<f>.fst      each frame's state (its forest, dead ids, buffer T0)
//   trees/<f>-<seq>.kdt immutable tree files
//   wal.log             the log since the last checkpoint; wal-<lsn>.log: older segments
//
// Concurrency: readers take shared_ptr snapshots of frame versions under mu_. Writers
// (commits, bulk loads, checkpoints) queue on write_mu_; the writer at the front of the queue
// (the leader) applies every queued transaction, writes their log records with one fsync
// (group commit), publishes the new versions, then wakes the others.
#ifndef HVDB_STORAGE_DATASET_IMPL_H_
#define HVDB_STORAGE_DATASET_IMPL_H_

#include <condition_variable>
#include <deque>
#include <map>
#include <mutex>
#include <set>

#include "storage/buffer_pool.h"
#include "storage/database.h"
#include "storage/frame_state.h"
#include "storage/hyperslice.h"
#include "storage/wal.h"

namespace hvdb {

// A region resolved against a dataset: which frames, and the per-frame tests.
struct RegionPlan {
  std::vector<uint32_t> frames;
  std::vector<std::shared_ptr<const FrameVersion>> versions;  // the snapshot of each frame
  bool clipped = false;
  std::optional<Window> window;
  std::optional<SliceGeometry> slice;
  std::optional<Window> slice_clip;
  double fps = 30;
  double FrameTime(uint32_t f) const { return f / fps; }
  Relation Classify(const Box3& box, uint32_t frame) const;
  bool Contains(const Point& p) const;  // p in its own frame
};

class DatasetImpl {
 public:
  static Result<std::unique_ptr<DatasetImpl>> Create(const std::string& dir,
                                                     const DatasetInfo& info,
                                                     const Options& opts, BufferPool* pool);
  static Result<std::unique_ptr<DatasetImpl>> Open(const std::string& dir, const Options& opts,
                                                   BufferPool* pool);
  ~DatasetImpl();

  DatasetInfo Info() const;
  Result<std::unique_ptr<Cursor>> Query(const Region& region, const QueryOptions& opts);
  Result<uint64_t> BulkLoad(uint32_t frame, std::vector<Point> points);
  Result<CommitInfo> Commit(const Transaction& txn);
  Result<CommitInfo> Revert(uint64_t lsn);
  DatasetStats Stats() const;
  std::vector<std::string> Check() const;
  Status Checkpoint();

  // Resolves a region to frames (for queries: temporal LOD and the slice frame bound).
  Result<RegionPlan> Plan(const Region& region, int lod, bool temporal_lod) const;
  std::shared_ptr<const FrameVersion> Snapshot(uint32_t frame) const;
  const Options& options() const { return opts_; }
  int levels() const { return opts_.lod_levels; }

 private:
  struct WriteRequest;
  class Working;

  DatasetImpl(std::string dir, Options opts, BufferPool* pool, DatasetInfo info);
  Status Recover();
  Status WriteManifest() const;
  Result<CommitInfo> Submit(WriteRequest* w);
  void LeadGroup(std::vector<WriteRequest*>& group);
  // Resolves a request against the working state into a log record (no change yet).
  Status Resolve(const Transaction& txn, Working* ws, TxnRecord* rec, CommitInfo* info);
  // Turns the frames whose buffer overflowed into trees (logarithmic method).
  Status Rebuild(FrameVersion* v, std::vector<Point> extra);
  Status PersistFrame(const FrameVersion& v);
  Status CheckpointLocked();
  Result<TxnRecord> FindRecord(uint64_t lsn) const;
  std::string TreePath(uint32_t frame, uint64_t seq) const;

  const std::string dir_;
  const Options opts_;
  BufferPool* const pool_;
  const uint32_t p_;  // T0 capacity: one block of points
  DatasetInfo info_;  // static part: name, fps, scale, cameras, declared frame count

  mutable std::mutex mu_;  // guards frames_, last_lsn_
  std::map<uint32_t, std::shared_ptr<const FrameVersion>> frames_;
  uint64_t last_lsn_ = 0;

  std::mutex write_mu_;  // guards writers_
  std::condition_variable write_cv_;
  std::deque<WriteRequest*> writers_;
  // Owned by the leader (the writer at the front of writers_):
  std::unique_ptr<WalWriter> wal_;
  uint64_t wal_start_lsn_ = 1;
  std::set<uint32_t> dirty_;  // frames whose state file lags the log
  std::atomic<uint64_t> next_id_{1};
  std::atomic<uint64_t> next_seq_{1};
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_DATASET_IMPL_H_
