// DatasetImpl: the engine behind Dataset. Internal header; see database.h for the contract.
//
// Layout of a dataset directory DIR/<name>/ (docs/FORMAT.md):
//   MANIFEST            dataset metadata
//   frames/<f>.fst      each frame's state (its forest, dead ids, buffer T0)
//   trees/<f>-<seq>.kdt immutable tree files
//   wal.log             the log since the last checkpoint; wal-<lsn>.log: older segments
//
// Concurrency: readers take shared_ptr snapshots of frame versions under mu_. Writers
// (commits, bulk loads, checkpoints, the merger's installs) queue on write_mu_; the writer at
// the front of the queue (the leader) applies every queued transaction, writes their log
// records with one write and one fsync (group commit), publishes the new versions, then wakes
// the others. A commit never builds a tree: its points go to T0 (dataset_write.cc). The merger
// thread (dataset_merge.cc) builds trees from snapshots outside every lock and installs them
// as a queued writer; frame states are written at checkpoints (the log covers them until then).
#ifndef HVDB_STORAGE_DATASET_IMPL_H_
#define HVDB_STORAGE_DATASET_IMPL_H_

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include "storage/buffer_pool.h"
#include "storage/database.h"
#include "storage/frame_state.h"
#include "storage/gaussian_column.h"
#include "storage/hyperslice.h"
#include "storage/kdtree_builder.h"
#include "storage/wal.h"

namespace hvdb {

using FrameMap = std::map<uint32_t, std::shared_ptr<const FrameVersion>>;

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

Result<RegionPlan> PlanRegion(const Region& region, int lod, bool temporal_lod,
                              const FrameMap& frames, const DatasetInfo& info,
                              const Options& opts);
// Dataset::CheckLod: `lod` in 0..levels (the coarsest level) of the dataset named `dataset`.
Status CheckLodRange(int64_t lod, int levels, const std::string& dataset);
// Fills step->removed/added from step->relabels: each relabelled point of `v` before and after.
// InvalidArgument if a point's flipped bits are not as the relabel left them (changed later),
// NotFound if a point is gone.
Status ResolveRelabels(const FrameVersion& v, FrameEffect* step);
// A copy of `old` with `step` applied (resolved first if it is relabels read from the log);
// each removed point is found by id and position, and, when
// `exact`, must also hold the very record given (a revert: a point a later transaction changed,
// e.g. relabelled, is an error rather than silently restored to its old value).
Result<std::shared_ptr<FrameVersion>> ApplyStep(const FrameVersion& old, const FrameEffect& step,
                                                uint64_t lsn, bool exact = false);

class DatasetImpl {
 public:
  static Result<std::unique_ptr<DatasetImpl>> Create(const std::string& dir,
                                                     const DatasetInfo& info,
                                                     const Options& opts, BufferPool* pool);
  // follower: read-only, for a directory another process writes (database.h).
  static Result<std::unique_ptr<DatasetImpl>> Open(const std::string& dir, const Options& opts,
                                                   BufferPool* pool, bool follower = false);
  ~DatasetImpl();

  DatasetInfo Info() const;
  Result<std::unique_ptr<Cursor>> Query(const Region& region, const QueryOptions& opts);
  Result<uint64_t> BulkLoad(uint32_t frame, std::vector<Point> points);
  // BulkLoad that calls before_install (when set) after the frame's tree is built and before it
  // is installed; its error fails the load.
  Result<uint64_t> BulkLoadThen(uint32_t frame, std::vector<Point> points,
                                const std::function<Status()>& before_install);
  // storage/dataset_gaussians.cc: the Gaussian column.
  Result<uint64_t> BulkLoadGaussians(uint32_t frame, std::vector<Point> points,
                                     const GaussianColumns& attrs);
  Result<GaussianColumns> ReadGaussians(std::span<const Point> points, uint64_t* derived) const;
  Status ReadGaussianRecords(std::span<const uint64_t> ids, GaussianColumns* out,
                             std::vector<bool>* found, size_t max_blocks = SIZE_MAX) const;
  Result<CommitInfo> Commit(const Transaction& txn);
  Result<CommitInfo> Revert(uint64_t lsn);
  DatasetStats Stats() const;
  std::vector<std::string> Check() const;
  Status Checkpoint();
  // storage/dataset_tier.cc: the cold tier.
  Result<CompactInfo> Compact(uint32_t first, uint32_t last);
  // storage/photos.cc.
  Status PutPhoto(uint32_t frame, const Photo& photo);
  Result<std::vector<Photo>> Photos(uint32_t frame) const;
  // storage/photo_video.cc: the video tier of photos. One camera's photo of a frame (nullopt:
  // none), from its per-frame file or its run.
  Result<std::optional<Photo>> PhotoOf(uint32_t frame, uint16_t camera) const;
  Result<CompactInfo> CompactPhotos(uint32_t first, uint32_t last);
  // The checks both compactions make: first <= last, and this process writes the dataset.
  Status CheckCompact(uint32_t first, uint32_t last) const;
  // Blocks until no frame's T0 is over its capacity (tests and benchmarks); after a failed
  // merge, until a retry fails too.
  Status WaitForMerges();
  // Follower (dataset_follow.cc): applies the writer's log records appended since the last
  // call, or, when `full`, on a checkpoint or a gap, reloads the frame states and the log.
  Status Refresh(bool full);
  // Follower: recovers from the files as a writer opening them would and becomes the writer.
  // The caller holds the directory's lock.
  Status Promote();

  // Dataset::Watch; parent: a hub that gets every event too (Database::WatchAll).
  Result<std::unique_ptr<WatchHandle>> Watch(std::optional<uint64_t> from_lsn, ChangeFn fn);
  void SetParentHub(std::shared_ptr<WatchHub> parent) { parent_hub_ = std::move(parent); }
  // Ends every watch with a kDropped event (the dataset was dropped).
  void EndWatches();

  // Resolves a region to frames (for queries: temporal LOD and the slice frame bound).
  Result<RegionPlan> Plan(const Region& region, int lod, bool temporal_lod) const;
  std::shared_ptr<const FrameVersion> Snapshot(uint32_t frame) const;
  const Options& options() const { return opts_; }
  int levels() const { return opts_.lod_levels; }

 private:
  struct WriteRequest;
  struct Merge;
  struct Tiering;
  class Working;

  // What the files say: frame states with wal.log redone over them.
  struct Loaded {
    FrameMap frames;
    std::set<uint32_t> dirty;  // frames whose state file lags the log
    uint64_t last_lsn = 0, next_id = 1, next_seq = 1;
    bool wal_exists = false;
    uint64_t wal_start = 1, wal_bytes = 0;  // wal.log's first LSN and valid prefix
  };

  DatasetImpl(std::string dir, Options opts, BufferPool* pool, DatasetInfo info);
  // Reads the files into *out. writer: also removes what a crash left (temporary files, tree
  // files no state lists); a follower changes nothing. Open trees in `reuse` are shared.
  Status Load(bool writer, const FrameMap& reuse, Loaded* out);
  Result<std::shared_ptr<FrameVersion>> LoadFrameState(const std::string& path,
                                                       const FrameMap& reuse,
                                                       uint64_t* next_id = nullptr);
  // Publishes `l` and, for a writer, opens wal.log for appending.
  Status Start(Loaded l, bool writer);
  void StartMerger();
  Result<bool> FollowLog();  // false: needs a full reload
  Status Reload();
  void Bury(const std::shared_ptr<KdTree>& tree);  // a replaced tree: deleted after the grace
  void ReleaseBuried(bool all);
  Status WriteManifest() const;
  Result<CommitInfo> Submit(WriteRequest* w);
  void LeadGroup(std::vector<WriteRequest*>& group);
  void LeadCommits(std::vector<WriteRequest*>& group);
  // Resolves a request against the working state into a log record (no change yet).
  // Gaussian records the request's transforms wrote are listed in `segments` (by first id),
  // also on failure: the caller removes them unless the record is logged.
  Status Resolve(const Transaction& txn, Working* ws, TxnRecord* rec, CommitInfo* info,
                 std::vector<uint64_t>* segments);
  // The turned Gaussian records of the points a transform moves (GaussianRecordMap) under fresh
  // ids, written durably as one segment: a splat that turns is a new point (its old record
  // stays, for undo). Sets the ids of `moved` and lists the segment.
  // The records of points an insert brings (new points, id 0) written as one segment under
  // fresh consecutive ids; returns the first (listed in `segments`).
  Result<uint64_t> WriteInsertedGaussians(std::span<const Point> points,
                                          const GaussianColumns& records,
                                          std::vector<uint64_t>* segments);
  Status TurnGaussians(const std::array<double, 9>& linear, std::span<const Point> selected,
                       std::span<Point> moved, std::vector<uint64_t>* segments);
  Result<TxnRecord> FindRecord(uint64_t lsn) const;
  // storage/dataset_watch.cc: the events of the logged changes with LSNs in (after, upto].
  Result<std::vector<ChangeEvent>> EventsBetween(uint64_t after, uint64_t upto) const;
  void Publish(const std::vector<ChangeEvent>& events);
  std::string TreePath(uint32_t frame, uint64_t seq) const;

  // dataset_merge.cc: the logarithmic method.
  // The logarithmic method with fan-out k (Options::merge_fanout): level L is slots
  // L(k-1) .. L(k-1)+k-2, each holding a tree of up to p*k^L points (p: T0's capacity). A
  // merge builds T0 (plus `extra` points) and every tree of the levels from L0 below L into
  // one tree in a free slot of the first level L >= L0 where the total fits; trees of L and
  // above stay. L0 is 0 for a bulk load (the frame's small trees go into the loaded one); for
  // the merger it is the level T0 alone fits in: 1 when T0 just passed p (so level 0 holds
  // bulk loads only), higher when commits ran ahead of the merger, and a T0 grown to several
  // times p then skips the levels below its size instead of taking their trees up with it
  // (rebuilding them for nothing). By induction a level-L tree
  // holds at most p + (k-1)(p + kp + .. + k^(L-1)p) = p*k^L points, and a point is rebuilt
  // once per level it climbs. Slot order carries no meaning: a live point is in one place.
  struct SlotChoice {
    size_t slot = 0;              // the new tree's
    size_t from = 0, to = 0;      // slots [from, to) go into it
  };
  SlotChoice TargetSlot(const FrameVersion& v, uint64_t extra, bool keep_lower) const;
  uint64_t SlotCapacity(size_t slot) const;
  // Builds the tree of slot i from v's T0, `extra` and slots 0..i-1 (no lock held).
  // Appends T0 and the live points of slots [from, to) of `v` to *pts.
  Status LivePoints(const FrameVersion& v, size_t from, size_t to, std::vector<Point>* pts) const;
  TreeBuildParams TreeParams(uint32_t frame, uint64_t seq) const;
  // A new tree file of the frame: `write` makes it at the path of a fresh sequence number,
  // then it is opened (synced: its contents are durable); on failure nothing is left behind.
  Result<std::shared_ptr<KdTree>> NewTree(
      uint32_t frame, bool sync,
      const std::function<Status(const std::string& path, uint64_t seq)>& write);
  // A tree of `extra`, T0 and the live points of the slots `c` merges.
  Result<std::shared_ptr<KdTree>> BuildMerged(const FrameVersion& v, const SlotChoice& c,
                                              std::vector<Point> extra, bool sync);
  void MergerLoop();
  Status MergeOnce(uint32_t frame);
  Status Install(const Merge& m);  // as leader
  void Retire(uint32_t frame, const std::shared_ptr<KdTree>& tree);  // as leader
  // As leader. `prebuilt`: the points' tree built before (BulkLoad), for slot `slot` of an
  // empty frame; used if the frame is still empty, else read back and built again.
  Status BulkLocked(uint32_t frame, std::vector<Point>* points, std::shared_ptr<KdTree> prebuilt,
                    size_t slot);
  Status PersistFrame(const FrameVersion& v);                          // as leader

  // dataset_tier.cc. A frame is cold when all its points are in one compressed tree.
  static bool IsCold(const FrameVersion& v);
  // Rewrites the frame into one compressed tree. *stale: it changed meanwhile (try again).
  Status CompactFrame(uint32_t frame, CompactInfo* info, bool* stale);
  // Replaces a compressed tree of the frame by a raw one of the same points (after a write).
  Status ThawFrame(uint32_t frame);
  // Writes the frame's compressed tree with `write` (n points, replacing `before` bytes of
  // trees) and installs it if `v` is still the frame's version.
  Status InstallCompacted(const std::shared_ptr<const FrameVersion>& v, uint64_t n,
                          uint64_t before,
                          const std::function<Status(const std::string& path, uint64_t seq)>& write,
                          CompactInfo* info, bool* stale);
  // Installs t as a queued writer; a tree that was not installed (stale, or an error) goes.
  Status SubmitTier(const Tiering& t);
  Status InstallTier(const Tiering& t);  // as leader
  // After the leader published writes to these frames: remembers when, and has the merger
  // thaw those with compressed trees.
  void NoteWrites(const std::vector<std::shared_ptr<const FrameVersion>>& written);
  // Merger: thaws written frames, and compacts frames idle for Options::cold_after_s.
  void TierPass();
  Status CheckpointLocked();                                           // as leader
  void WakeMerger();
  bool NeedsMerge(const FrameVersion& v) const { return v.t0.size() > t0_cap_; }
  // So far behind that commits wait for the merger (back-pressure).
  bool Backlogged(const FrameVersion& v) const { return v.t0.size() > 8 * t0_cap_; }

  const std::string dir_;
  const Options opts_;
  Env* const env_;
  BufferPool* const pool_;
  const uint64_t t0_cap_;  // p: T0's capacity, and slot 0's
  DatasetInfo info_;       // static part: name, fps, scale, cameras, declared frame count

  // PutPhoto against CompactPhotos' removal of per-frame files; compactions of photos, one at
  // a time.
  std::mutex photo_mu_, photo_compact_mu_;
  Result<std::optional<Photo>> PhotoFromRun(const std::string& name, uint32_t frame,
                                            bool* gone) const;
  Status WriteRuns(uint16_t camera, const std::map<uint32_t, Photo>& photos,
                   std::set<std::string>* written, CompactInfo* info);
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
  // Trees the state files on disk still list but no version does: deleted once the frame's
  // next state is durable.
  std::map<uint32_t, std::vector<std::shared_ptr<KdTree>>> retired_;
  std::atomic<bool> follower_{false};
  // Gaussian datasets: the column of 3DGS attributes (null otherwise); opened by Start.
  std::unique_ptr<GaussianColumn> gaussians_;
  // A follower's place in wal.log (follow_mu_; Refresh and Promote hold it).
  std::mutex follow_mu_;
  uint64_t follow_start_ = 0, follow_offset_ = 0;
  std::vector<ChangeEvent> followed_;  // what FollowLog applied, for Refresh to publish
  // Watchers (storage/watch.h): this dataset's, and the database's (WatchAll).
  std::shared_ptr<WatchHub> hub_ = std::make_shared<WatchHub>();
  std::shared_ptr<WatchHub> parent_hub_;
  // Replaced trees kept until their deadline (Options::retired_grace_ms).
  std::mutex grave_mu_;
  std::deque<std::pair<std::chrono::steady_clock::time_point, std::shared_ptr<KdTree>>> graves_;
  std::atomic<uint64_t> next_id_{1};
  std::atomic<uint64_t> next_seq_{1};
  std::atomic<uint64_t> merges_{0}, merged_points_{0}, checkpoints_{0};
  std::atomic<uint64_t> wal_bytes_{0};
  // Set by a commit that leaves some T0 above 8x its capacity, cleared by the first writer that
  // finds none: commits look at the frames only while it is set.
  std::atomic<bool> backlog_{false};

  // The merger: one thread per dataset, woken by commits that overfill a T0 or the log.
  std::mutex merge_mu_;  // guards the fields below
  std::condition_variable merge_cv_;   // wakes the merger
  std::condition_variable merged_cv_;  // wakes writers waiting for a merge
  bool merge_stop_ = false, merge_wake_ = false, checkpoint_wanted_ = false;
  Status merge_error_;  // the last failed merge (cleared by a successful one)
  uint64_t merge_rounds_ = 0;  // merger passes finished
  // The cold tier (merge_mu_): when each frame was last written (frames not written since open:
  // the open), frames written while they had a compressed tree, and when the merger last
  // looked for idle frames.
  std::map<uint32_t, std::chrono::steady_clock::time_point> last_write_;
  std::set<uint32_t> thaw_;
  std::chrono::steady_clock::time_point opened_ = std::chrono::steady_clock::now();
  std::chrono::steady_clock::time_point last_tier_pass_{};
  std::thread merger_;
};

// One queued writer. Bulk loads, checkpoints and installs are led alone.
struct DatasetImpl::WriteRequest {
  enum class Kind { kTxn, kRevert, kBulk, kCheckpoint, kInstall, kTier } kind = Kind::kTxn;
  const Transaction* txn = nullptr;
  uint64_t revert_lsn = 0;
  uint32_t frame = 0;
  std::vector<Point>* points = nullptr;
  uint64_t bulk_count = 0;               // kBulk: the points loaded
  std::shared_ptr<KdTree> prebuilt;      // kBulk into an empty frame: its tree, built already
  size_t prebuilt_slot = 0;
  const Merge* merge = nullptr;
  const Tiering* tiering = nullptr;
  bool done = false;
  Status status;
  CommitInfo info;
};

// A tree the merger built from `base` (T0 and slots 0..slot-1), to go into slot `slot`.
struct DatasetImpl::Merge {
  uint32_t frame = 0;
  std::shared_ptr<const FrameVersion> base;
  SlotChoice target;  // the new tree's slot, and base's slots that went into it
  std::shared_ptr<KdTree> tree;
};

// A frame rewritten into the other tier, built from `base`. Compaction: `tree` holds every
// live point of base and replaces all of base's trees and T0 (only if the frame is unchanged).
// Thaw: `tree` holds the points of base's compressed tree in slot `slot` and replaces it
// (only if that slot still holds it; its dead ids carry over).
struct DatasetImpl::Tiering {
  uint32_t frame = 0;
  bool compact = true;
  std::shared_ptr<const FrameVersion> base;
  size_t slot = 0;
  std::shared_ptr<KdTree> tree;
  mutable bool stale = false;  // set by InstallTier: the frame changed, nothing was installed
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_DATASET_IMPL_H_
