// The storage engine's public API: a data directory of datasets, each a regular grid of
// frames in time with one multiresolution Bkd-tree per frame (thesis 8.3-8.4).
//
// Thread safety: a Database and its Datasets are safe for concurrent use from many threads.
// Queries read a snapshot of each frame taken when the query starts and never block writers;
// commits are serialised per dataset and grouped (one fsync for all commits waiting at once).
// A commit is durable once its log record is synced; each dataset's merger thread turns the
// in-memory buffers T0 into trees in the background (logarithmic method, 8.3.2).
//
// Errors: functions return Status / Result<T> (storage/status.h) and never throw.
#ifndef HVDB_STORAGE_DATABASE_H_
#define HVDB_STORAGE_DATABASE_H_

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <variant>
#include <vector>

#include "storage/env.h"
#include "storage/point.h"
#include "storage/status.h"
#include "storage/watch.h"

namespace hvdb {

class BufferPool;
class DatasetImpl;
struct GaussianColumns;
class CursorImpl;

struct Options {
  size_t cache_bytes = 256u << 20;  // the shared block cache; >= 8 MiB
  uint32_t block_size = 64u << 10;  // bytes per block: a power of two in [4 KiB, 1 MiB]
  int lod_levels = 5;               // l: levels 0 (finest) .. l (coarsest), 0..8
  bool sync = true;                 // fsync the log on every commit (group commit)
  uint32_t max_slice_frames = 64;   // default bound on frames a slice may read
  uint64_t wal_checkpoint_bytes = 64u << 20;  // checkpoint once the log grows past this
  // Points a frame's in-memory buffer T0 holds before the merger makes a tree of it. Commits
  // wait for the merger when a T0 reaches 8x this. In [64, 4 Mi].
  uint32_t t0_points = 64u << 10;
  // The logarithmic method's fan-out k: level L of a frame's forest holds up to k-1 trees of up
  // to t0_points * k^L points. A point is rebuilt about log_k(n / t0_points) times on its way
  // up, a query visits up to k-1 trees a level: 2 is the thesis's binary method (8.3.2); 4
  // builds a point about 3/4 as often (bench/README.md). In [2, 16]; any value reads any dataset.
  uint32_t merge_fanout = 4;
  Env* env = nullptr;  // all file I/O (storage/env.h); null: the POSIX Env::Default()
  // When another process holds the data directory: open it as a follower (read-only; see
  // Database::Refresh) instead of failing.
  bool follow = false;
  // Tree files a checkpoint or bulk load replaced stay this long before they are deleted, so
  // that followers' queries on the state they last read can finish (0: deleted at once).
  uint32_t retired_grace_ms = 0;
  // The cold tier (docs/FORMAT.md "Compressed tree file"): a frame not written for this many
  // seconds is rewritten by the merger into one compressed tree (lossless, ~1/5 of the bytes;
  // queries decode the blocks they read). A write brings it back to raw trees. 0: never
  // automatically (Dataset::Compact still does it).
  uint32_t cold_after_s = 3600;
};

// One camera of the recording rig, for view-dependent rendering.
struct CameraInfo {
  uint16_t id = 0;
  std::string name;
  uint32_t width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  std::array<double, 5> distortion{};  // k1 k2 p1 p2 k3 (OpenCV order)
  // Row-major 4x4 world-from-camera transform (metres).
  std::array<double, 16> world_from_camera{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
};

// The billboard of a camera's view of a frame (thesis 6.1), kept with its photo (the colour
// map). In the camera's undistorted (pinhole) image: disparity d = scale / z (z: camera-space
// depth in metres) = Pi(x, y) + D(x, y), with the proxy plane Pi(x, y) = plane[0] x +
// plane[1] y + plane[2] and the displacement map D.
struct PhotoBillboard {
  double scale = 0;  // pixels * metres; 0: the photo has no billboard
  std::array<double, 3> plane{};
  std::string displacement;  // PNG, 16-bit grey, the camera's size: (D + 128) * 256; 0: no sample
  std::string alpha;         // PNG, 8-bit grey, the camera's size: alpha * 255
};

// A photo of an acquisition camera for one frame: the camera as it was for that frame (its id
// is the Point::camera of the points it took) and the image file's bytes as recorded (PNG or
// JPEG, 8-bit). The render service textures splats with them (thesis 6.3), and draws the
// billboards of those that have one.
struct Photo {
  CameraInfo camera;
  std::string image;
  PhotoBillboard billboard;
};
// The checks a photo passes before it is stored (Dataset::PutPhoto makes them; render's
// CheckPhoto makes them first, then decodes the images): an image of 1 byte to 1 GiB, a camera
// with a size and positive focal lengths, and a billboard (scale != 0) with a positive scale,
// a finite plane and both maps.
Status ValidatePhoto(const Photo& photo);

// The ranges a dataset's parameters must lie in (checked when it is created).
inline constexpr double kMinFps = 1e-3;   // a frame every 1000 s
inline constexpr double kMaxFps = 10000;
inline constexpr uint32_t kMaxFrames = 100'000'000;  // frames 0..kMaxFrames-1: ~38 days at 30 fps

struct DatasetInfo {
  std::string name;
  double fps = 30.0;
  double space_time_scale = 1.0;  // s: metres per second in hyperslices over (x, y, z, s t)
  std::vector<CameraInfo> cameras;
  // A Gaussian-splat dataset: its points also carry 3DGS attributes (opacity, SH colour, the
  // stored scales and rotation) in the Gaussian column (storage/gaussian_column.h).
  bool gaussians = false;
  // Derived on every read:
  uint32_t frame_count = 0;  // max(declared, highest frame with data + 1)
  std::array<float, 3> bounds_min{}, bounds_max{};  // of all points (empty: all zero)
  uint64_t point_count = 0;
  uint64_t last_lsn = 0;  // sequence number of the last committed transaction
};

// A 4D box; t in seconds (frame f is at t = f / fps). Bounds are inclusive.
struct Window {
  std::array<double, 4> lo{}, hi{};
};

// A hyperslice (thesis 8.2): points with |N . (x, y, z, s t) - b| <= db, projected to 3D.
struct Slice {
  std::array<double, 4> normal{0, 0, 0, 1};  // normalised on use; must be non-zero
  double offset = 0;                         // b
  double thickness = 0;                      // db >= 0
  std::optional<Window> clip;                // optional 4D window that clips the slice
  enum class FrameBound { kError, kClip } on_too_many_frames = FrameBound::kError;
  uint32_t max_frames = 0;  // 0: Options::max_slice_frames
};

using Region = std::variant<Window, Slice>;

struct QueryOptions {
  int lod = 0;               // finest level to return (0 = full resolution)
  bool progressive = false;  // coarse levels first across all frames, each level once
  bool temporal_lod = true;  // multi-frame queries at level i read every 2^i-th frame
  size_t batch_points = 16384;
  uint32_t label_mask = 0;  // non-zero: only points with (label & mask) != 0
};

// A batch of results. For slices, x/y/z and cov hold the projected position and covariance
// (eqs. 8.2, 8.3); for windows, the stored ones.
struct Batch {
  int level = 0;            // the LOD level these points belong to
  bool level_done = false;  // progressive: last batch of `level`
  float splat_scale = 1.f;  // 2^(level/2): how much the renderer should grow splats
  std::vector<Point> points;
};

// A streaming query. Not thread-safe; use from one thread. Holds its snapshot until destroyed.
class Cursor {
 public:
  explicit Cursor(std::unique_ptr<CursorImpl> impl);
  ~Cursor();
  Cursor(const Cursor&) = delete;
  Cursor& operator=(const Cursor&) = delete;
  // Fills `batch` with the next points. Returns false when the query is exhausted.
  Result<bool> Next(Batch* batch);
  // The same, into buf[0..capacity) instead of info->points (left untouched): *n points, never
  // more than capacity (a batch ends early rather than overflow). For a caller that owns the
  // memory the results must land in, e.g. hvdb-server's shared-memory ring.
  Result<bool> NextInto(Point* buf, size_t capacity, size_t* n, Batch* info);
  // Stops the query; Next() then returns Cancelled. Safe to call from another thread.
  void Cancel();
  // Frames the query reads (after bounds and temporal LOD), and whether a slice was clipped.
  const std::vector<uint32_t>& frames() const;
  bool clipped() const;
  // At least as many points as the query returns: the live points of the frames it reads. For
  // a caller that keeps every result, to reserve its memory once (reserved, untouched pages
  // cost nothing).
  uint64_t PointsBound() const;

 private:
  std::unique_ptr<CursorImpl> impl_;
};

// A row-major 4x4 linear map plus translation over (x, y, z, t) with t in seconds:
// X' = A X + c. Points whose new t falls on another frame move there (rounded to the nearest).
struct Affine4 {
  std::array<double, 16> a{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
  std::array<double, 4> c{};
};

// Which points an operation acts on: those in `region` (all points if absent) whose label
// matches `label_mask` (any, if 0), plus the explicitly listed (frame, id) pairs.
struct Selection {
  std::optional<Region> region;
  uint32_t label_mask = 0;
  std::vector<std::pair<uint32_t, uint64_t>> ids;
};

// A batch of operations applied atomically by Dataset::Commit, in order.
class Transaction {
 public:
  // id 0: the engine assigns one. `gaussians`, if set, holds a record for each point (of a
  // Gaussian-splat dataset: pasted splats); such points must be new (id 0). Other datasets
  // keep only the points.
  struct InsertOp {
    std::vector<Point> points;
    std::shared_ptr<const GaussianColumns> gaussians;
  };
  struct DeleteOp { uint64_t id; uint32_t frame; std::array<float, 3> pos; };
  struct DeleteSelOp { Selection sel; };
  struct TransformOp { Selection sel; Affine4 map; };
  struct LabelOp { Selection sel; uint32_t bits; bool set; };
  using Op = std::variant<InsertOp, DeleteOp, DeleteSelOp, TransformOp, LabelOp>;

  void Insert(std::vector<Point> points) { ops_.push_back(InsertOp{std::move(points), nullptr}); }
  void Insert(std::vector<Point> points, std::shared_ptr<const GaussianColumns> gaussians) {
    ops_.push_back(InsertOp{std::move(points), std::move(gaussians)});
  }
  void Delete(uint64_t id, uint32_t frame, std::array<float, 3> pos) {
    ops_.push_back(DeleteOp{id, frame, pos});
  }
  void DeleteSelection(Selection sel) { ops_.push_back(DeleteSelOp{std::move(sel)}); }
  void Transform(Selection sel, Affine4 map) { ops_.push_back(TransformOp{std::move(sel), map}); }
  void SetLabel(Selection sel, uint32_t bits, bool set) {
    ops_.push_back(LabelOp{std::move(sel), bits, set});
  }
  const std::vector<Op>& ops() const { return ops_; }
  bool empty() const { return ops_.empty(); }

 private:
  std::vector<Op> ops_;
};

struct CommitInfo {
  uint64_t lsn = 0;  // commit sequence number; pass to Dataset::Revert to undo
  uint64_t inserted = 0, removed = 0;
  std::vector<uint64_t> assigned_ids;  // ids given to inserted points that had id 0, in order
};

struct DatasetStats {
  uint32_t frames_with_data = 0;
  uint64_t points = 0, tombstones = 0, buffered_points = 0;
  uint64_t trees = 0, tree_bytes = 0, wal_bytes = 0;
  // Of those, in the cold tier: compressed frames (all their points in one compressed tree),
  // compressed trees, their file bytes and points.
  uint32_t cold_frames = 0;
  uint64_t cold_trees = 0, cold_tree_bytes = 0, cold_points = 0;
  uint64_t merges = 0;       // trees built by the merger since open
  uint64_t merged_points = 0;  // points written into those trees (rebuilds: / points inserted)
  uint64_t checkpoints = 0;  // log segments closed since open
  double leaf_utilisation = 0;  // points / (leaf blocks * b) over all trees
  // Gaussian datasets: the Gaussian column's segment files, records and bytes.
  uint64_t gaussian_segments = 0, gaussian_records = 0, gaussian_bytes = 0;
};

// What Dataset::Compact did.
struct CompactInfo {
  uint32_t frames = 0;             // frames rewritten into the cold tier
  uint32_t already = 0;            // frames in the range that were compressed already
  uint64_t points = 0;             // their points
  // Their tree files' bytes (before: with the buffered points' 64-byte records).
  uint64_t bytes_before = 0, bytes_after = 0;
  // The video tier of photos (Dataset::CompactPhotos): runs written (one video per camera and
  // stretch of frames), their pictures, cameras whose photos in the range were one run
  // already, the image bytes before (per-frame images and replaced videos) and after (the
  // videos), and the lowest PSNR of a picture written in Y, Cb or Cr (dB).
  uint32_t photo_runs = 0, photo_pictures = 0, photo_already = 0;
  uint64_t photo_bytes_before = 0, photo_bytes_after = 0;
  double photo_min_psnr = 0;
};

struct CacheStats {
  uint64_t capacity_bytes = 0, block_size = 0, hits = 0, misses = 0, evictions = 0;
  uint64_t resident_blocks = 0, pinned_blocks = 0;
  uint64_t prefetched = 0;  // of the misses, blocks loaded ahead of their query in batches
};

// One dataset. Obtain from Database::Open/CreateDataset; shared by all users.
class Dataset {
 public:
  explicit Dataset(std::unique_ptr<DatasetImpl> impl);
  ~Dataset();
  Dataset(const Dataset&) = delete;
  Dataset& operator=(const Dataset&) = delete;

  DatasetInfo Info() const;
  // The coarsest level of detail a query may ask for (Options::lod_levels when created).
  int lod_levels() const;
  // The one rule for a level of detail, which queries (Query) and render jobs alike follow:
  // 0 .. lod_levels(), else InvalidArgument "lod: N is out of range 0..L for dataset 'NAME'
  // (its coarsest level)".
  Status CheckLod(int64_t lod) const;
  Result<std::unique_ptr<Cursor>> Query(const Region& region, const QueryOptions& opts = {});
  // Adds the points to `frame` with the bulk loader (not logged: durable when it returns, and
  // atomic per frame). Ids of 0 are assigned. Points' frame field is overwritten.
  Result<uint64_t> BulkLoad(uint32_t frame, std::vector<Point> points);
  // Gaussian datasets: BulkLoad of splats, each point with its record in `attrs` (same
  // order; GaussianColumns in storage/gaussian_column.h). The engine issues the ids (points'
  // ids are overwritten) and makes the records durable before the points. InvalidArgument on
  // a dataset made without --gaussians or a count that differs.
  Result<uint64_t> BulkLoadGaussians(uint32_t frame, std::vector<Point> points,
                                     const GaussianColumns& attrs);
  // The Gaussian records of `points` (by id), in their order, at the highest SH degree among
  // them. A point without a stored record (an edit inserted it, or the dataset has no
  // Gaussian column) gets DeriveGaussian's; *derived (optional) counts them.
  Result<GaussianColumns> ReadGaussians(std::span<const Point> points,
                                        uint64_t* derived = nullptr) const;
  // The stored records of `ids` (GaussianColumn::Read): found[i] false where an id has none
  // (DeriveMissing fills those from their points).
  // max_blocks: LimitExceeded rather than read more blocks of records than that (a remote
  // request's bound; each block is 1024 records, read whole).
  Status ReadGaussianRecords(std::span<const uint64_t> ids, GaussianColumns* out,
                             std::vector<bool>* found, size_t max_blocks = SIZE_MAX) const;
  // Applies the transaction atomically and durably (when Options::sync).
  Result<CommitInfo> Commit(const Transaction& txn);
  // Commits the inverse of transaction `lsn`, derived from the log.
  Result<CommitInfo> Revert(uint64_t lsn);
  DatasetStats Stats() const;
  // Verifies every checksum, tree invariant and frame state; returns the problems found.
  std::vector<std::string> Check() const;
  // Writes all buffered frame state and starts a new log segment.
  Status Checkpoint();
  // Rewrites the frames in [first, last] that hold points into the cold tier now (one
  // compressed tree each; Options::cold_after_s does it in the background), durably. Frames
  // written meanwhile are retried, then left hot.
  Result<CompactInfo> Compact(uint32_t first, uint32_t last);
  // The video tier of photos (docs/FORMAT.md "Photo video run"): codes each camera's photos of
  // the frames in [first, last] (widened to the runs it touches) as one video per camera and
  // run, every picture within kPhotoVideoMinPsnr (storage/photo_video.h) of its photo, then
  // removes the per-frame images. Photos() reads them back decoded (as PNG). Needs the process's
  // PhotoVideoCodec (media::InstallPhotoVideoCodec), else Unsupported. Lossy; crash-safe.
  Result<CompactInfo> CompactPhotos(uint32_t first, uint32_t last);
  // Stores the photo of camera photo.camera.id for `frame` (replacing any), durably
  // (docs/FORMAT.md "Photos"). NotLeader on a follower.
  Status PutPhoto(uint32_t frame, const Photo& photo);
  // The photos stored for `frame`, by camera id (none: empty). Corruption names a damaged file.
  Result<std::vector<Photo>> Photos(uint32_t frame) const;
  // Waits until the merger has turned every full buffer T0 into a tree (benchmarks, tests).
  Status WaitForMerges();
  // Calls fn with each change published from now on (commits, reverts, bulk loads, in LSN
  // order; a follower publishes the writer's as it reads them), until the Watch is destroyed or
  // the dataset is dropped (a last kDropped event). With from_lsn: first the changes after it,
  // read from the log (InvalidArgument if it is past the last LSN), then the live ones, none
  // lost or repeated. fn's rules: storage/watch.h.
  Result<std::unique_ptr<WatchHandle>> Watch(std::optional<uint64_t> from_lsn, ChangeFn fn);

  DatasetImpl* impl() { return impl_.get(); }

 private:
  std::unique_ptr<DatasetImpl> impl_;
};

// A data directory. One process writes a directory at a time: it holds the directory's lock
// (a file lock, or a RADOS lock with a lease) and its LEADER file says where it serves. Other
// processes may open it as followers (Options::follow): they read what the writer made durable,
// catch up with its commits on Refresh() and refuse writes with NotLeader; TryPromote() makes
// a follower the writer once the lock is free (the writer died or closed).
class Database {
 public:
  static Result<std::unique_ptr<Database>> Open(const std::string& dir, const Options& opts = {});
  bool follower() const { return follower_.load(); }
  // Follower: reads the writer's new commits, bulk loads and checkpoints (its log, frame states
  // and LEADER file) into the open datasets, each commit whole (snapshot isolation); forgets
  // dropped datasets. A writer: nothing to do.
  Status Refresh();
  // Follower: takes the directory's lock if it is free, recovers every open dataset from the
  // log and becomes the writer (true). False while another process holds it.
  Result<bool> TryPromote();
  // Writer: publishes where clients should send writes (LEADER file), e.g. "10.0.0.5:7878".
  Status SetLeaderAddress(const std::string& address);
  // The writer's published address ("" if none), as last read.
  std::string Leader() const;
  ~Database();
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;

  std::vector<std::string> ListDatasets() const;
  // Every open dataset's changes from now on (no replay), each event naming its dataset, after
  // a kLive event (LSN 0, no dataset).
  std::unique_ptr<WatchHandle> WatchAll(ChangeFn fn);
  Result<std::shared_ptr<Dataset>> CreateDataset(const DatasetInfo& info);
  Result<std::shared_ptr<Dataset>> GetDataset(const std::string& name);
  Status DropDataset(const std::string& name);
  CacheStats Cache() const;
  const Options& options() const { return opts_; }
  const std::string& dir() const { return dir_; }

 private:
  Database(std::string dir, Options opts);
  Status RemoveLeftovers();  // writer, at open: creates and drops a crash cut short
  Status WriteLeader(const std::string& address);
  std::string dir_;
  Options opts_;
  Env* env_;
  std::unique_ptr<FileLock> lock_;
  std::atomic<bool> follower_{false};
  uint64_t epoch_ = 0;   // the LEADER file's epoch: a new one each time a writer opens (mu_)
  std::string leader_;   // its address (mu_)
  std::unique_ptr<BufferPool> pool_;
  mutable std::mutex mu_;
  std::vector<std::pair<std::string, std::shared_ptr<Dataset>>> open_;
  std::shared_ptr<WatchHub> all_ = std::make_shared<WatchHub>();  // WatchAll's subscribers
};

// Checks a dataset name: 1-64 characters of [A-Za-z0-9_.-], not starting with '.'.
Status ValidateDatasetName(const std::string& name);

}  // namespace hvdb

#endif  // HVDB_STORAGE_DATABASE_H_
