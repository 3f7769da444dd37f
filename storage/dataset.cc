#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <unordered_set>

#include "storage/coding.h"
#include "storage/affine.h"
#include "storage/crc32c.h"
#include "storage/dataset_impl.h"
#include "storage/file.h"
#include "storage/kdtree_builder.h"
#include "storage/lod.h"

namespace hvdb {

namespace {

constexpr char kManifestMagic[8] = {'H', 'V', 'D', 'B', 'M', 'A', 'N', '\0'};
constexpr uint32_t kManifestVersion = 1;
constexpr uint32_t kMaxFrame = 100'000'000;  // ~38 days at 30 fps

using FrameMap = std::map<uint32_t, std::shared_ptr<const FrameVersion>>;

std::string EncodeManifest(const DatasetInfo& info, const Options& opts) {
  Writer w;
  w.PutBytes(kManifestMagic, 8);
  w.Put<uint32_t>(kManifestVersion);
  w.PutString(info.name);
  w.Put<double>(info.fps);
  w.Put<double>(info.space_time_scale);
  w.Put<uint32_t>(info.frame_count);
  w.Put<uint32_t>(opts.block_size);
  w.Put<uint32_t>(static_cast<uint32_t>(opts.lod_levels));
  w.Put<uint32_t>(static_cast<uint32_t>(info.cameras.size()));
  for (const CameraInfo& c : info.cameras) {
    w.Put<uint16_t>(c.id);
    w.PutString(c.name);
    w.Put<uint32_t>(c.width);
    w.Put<uint32_t>(c.height);
    for (double v : {c.fx, c.fy, c.cx, c.cy}) w.Put<double>(v);
    for (double v : c.distortion) w.Put<double>(v);
    for (double v : c.world_from_camera) w.Put<double>(v);
  }
  w.Put<uint32_t>(crc32c::Mask(crc32c::Value(w.data().data(), w.data().size())));
  return std::move(w.data());
}

struct ManifestContents {
  DatasetInfo info;
  uint32_t block_size = 0;
  int lod_levels = 0;
};

Result<ManifestContents> DecodeManifest(const std::string& data, const std::string& what) {
  auto corrupt = [&](const std::string& m) { return Status::Corruption(what + ": " + m); };
  if (data.size() < 16) return corrupt("truncated");
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (crc32c::Unmask(DecodeLE<uint32_t>(p + data.size() - 4)) !=
      crc32c::Value(p, data.size() - 4)) {
    return corrupt("checksum mismatch");
  }
  Reader r(p, data.size() - 4);
  char magic[8];
  uint32_t version = 0, bs = 0, levels = 0, ncam = 0;
  ManifestContents m;
  if (!r.GetBytes(magic, 8) || std::memcmp(magic, kManifestMagic, 8) != 0) {
    return corrupt("bad magic");
  }
  if (!r.Get(&version) || version != kManifestVersion) {
    return corrupt("unsupported version " + std::to_string(version));
  }
  if (!r.GetString(&m.info.name) || !r.Get(&m.info.fps) || !r.Get(&m.info.space_time_scale) ||
      !r.Get(&m.info.frame_count) || !r.Get(&bs) || !r.Get(&levels) || !r.Get(&ncam) ||
      ncam > 65535) {
    return corrupt("bad header");
  }
  for (uint32_t i = 0; i < ncam; ++i) {
    CameraInfo c;
    bool ok = r.Get(&c.id) && r.GetString(&c.name) && r.Get(&c.width) && r.Get(&c.height) &&
              r.Get(&c.fx) && r.Get(&c.fy) && r.Get(&c.cx) && r.Get(&c.cy);
    for (double& v : c.distortion) ok = ok && r.Get(&v);
    for (double& v : c.world_from_camera) ok = ok && r.Get(&v);
    if (!ok) return corrupt("bad camera " + std::to_string(i));
    m.info.cameras.push_back(std::move(c));
  }
  m.block_size = bs;
  m.lod_levels = static_cast<int>(levels);
  return m;
}

Status ValidatePoint(const Point& p) {
  if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
    return Status::InvalidArgument("point " + std::to_string(p.id) +
                                   " has a NaN or infinite coordinate");
  }
  for (float c : p.cov) {
    if (!std::isfinite(c)) {
      return Status::InvalidArgument("point " + std::to_string(p.id) + " has a non-finite covariance");
    }
  }
  if (p.frame >= kMaxFrame) {
    return Status::InvalidArgument("frame " + std::to_string(p.frame) + " out of range (max " +
                                   std::to_string(kMaxFrame - 1) + ")");
  }
  return Status::OK();
}

bool SamePoint(const Point& a, const Point& b) {
  return a.id == b.id && a.x == b.x && a.y == b.y && a.z == b.z;
}

// Where a point lives in a frame version: -1 = T0, >= 0 = tree slot, -2 = nowhere.
struct Holder {
  int slot = -2;
  Point stored;
};

Result<Holder> Locate(const FrameVersion& v, const Point& target,
                      const std::vector<std::vector<uint64_t>>* pending_dead = nullptr) {
  for (const Point& p : *v.t0) {
    if (SamePoint(p, target)) return Holder{-1, p};
  }
  const Box3 probe{{target.x, target.y, target.z}, {target.x, target.y, target.z}};
  BoxTest test = [&probe](const Box3& b) {
    for (int a = 0; a < 3; ++a) {
      if (probe.lo[a] < b.lo[a] || probe.lo[a] > b.hi[a]) return Relation::kOutside;
    }
    return Relation::kCrosses;
  };
  for (size_t s = 0; s < v.slots.size(); ++s) {
    const TreeSlot& slot = v.slots[s];
    if (!slot.tree || slot.IsDead(target.id)) continue;
    if (pending_dead != nullptr && s < pending_dead->size() &&
        std::find((*pending_dead)[s].begin(), (*pending_dead)[s].end(), target.id) !=
            (*pending_dead)[s].end()) {
      continue;
    }
    std::vector<KdTree::BucketHit> hits;
    HVDB_RETURN_IF_ERROR(slot.tree->FindBuckets(test, &hits));
    for (const auto& hit : hits) {
      std::optional<Point> found;
      for (uint32_t k = 0; k < slot.tree->header().levels && !found; ++k) {
        HVDB_RETURN_IF_ERROR(slot.tree->ReadRange(
            static_cast<int>(k), hit.entry.start[k], hit.entry.count[k],
            [&](const uint8_t* rec, size_t n) {
              for (size_t j = 0; j < n && !found; ++j) {
                if (DecodeLE<uint64_t>(rec + j * kPointRecordSize) != target.id) continue;
                Point p = DecodePoint(rec + j * kPointRecordSize);
                if (SamePoint(p, target)) found = p;
              }
            }));
      }
      if (found) return Holder{static_cast<int>(s), *found};
    }
  }
  return Holder{};
}

// Applies one step to a copy of `old`; each removal is found by id and position.
Result<std::shared_ptr<FrameVersion>> ApplyStep(const FrameVersion& old, const FrameEffect& step,
                                                uint64_t lsn) {
  auto v = std::make_shared<FrameVersion>(old);
  v->frame = step.frame;
  v->applied_lsn = std::max(v->applied_lsn, lsn);
  std::vector<Point> t0 = *old.t0;
  std::vector<std::vector<uint64_t>> new_dead(v->slots.size());
  for (const Point& target : step.removed) {
    auto it = std::find_if(t0.begin(), t0.end(),
                           [&](const Point& p) { return SamePoint(p, target); });
    if (it != t0.end()) {
      t0.erase(it);
      continue;
    }
    // T0 was checked above against the current copy; search only the trees.
    FrameVersion probe;
    probe.slots = v->slots;
    HVDB_ASSIGN_OR_RETURN(Holder h, Locate(probe, target, &new_dead));
    if (h.slot < 0) {
      return Status::NotFound("point " + std::to_string(target.id) + " at (" +
                              std::to_string(target.x) + ", " + std::to_string(target.y) + ", " +
                              std::to_string(target.z) + ") not found in frame " +
                              std::to_string(step.frame));
    }
    new_dead[static_cast<size_t>(h.slot)].push_back(target.id);
  }
  for (size_t s = 0; s < new_dead.size(); ++s) {
    if (new_dead[s].empty()) continue;
    std::vector<uint64_t> dead = v->slots[s].dead ? *v->slots[s].dead : std::vector<uint64_t>{};
    dead.insert(dead.end(), new_dead[s].begin(), new_dead[s].end());
    std::sort(dead.begin(), dead.end());
    v->slots[s].dead = std::make_shared<const std::vector<uint64_t>>(std::move(dead));
  }
  t0.insert(t0.end(), step.added.begin(), step.added.end());
  v->t0 = std::make_shared<const std::vector<Point>>(std::move(t0));
  return v;
}

// Calls fn(point) for every live point of `v` in the region (nullptr: all), label-filtered.
Status ScanVersion(const FrameVersion& v, const RegionPlan* plan, uint32_t label_mask,
                   const std::function<void(const Point&)>& fn) {
  auto accept = [&](const Point& p) {
    if (label_mask != 0 && (p.label & label_mask) == 0) return false;
    return plan == nullptr || plan->Contains(p);
  };
  for (const Point& p : *v.t0) {
    if (accept(p)) fn(p);
  }
  for (const TreeSlot& slot : v.slots) {
    if (!slot.tree) continue;
    BoxTest test = [&](const Box3& b) {
      return plan == nullptr ? Relation::kInside : plan->Classify(b, v.frame);
    };
    std::vector<KdTree::BucketHit> hits;
    HVDB_RETURN_IF_ERROR(slot.tree->FindBuckets(test, &hits));
    for (const auto& hit : hits) {
      for (uint32_t k = 0; k < slot.tree->header().levels; ++k) {
        HVDB_RETURN_IF_ERROR(slot.tree->ReadRange(
            static_cast<int>(k), hit.entry.start[k], hit.entry.count[k],
            [&](const uint8_t* rec, size_t n) {
              for (size_t j = 0; j < n; ++j) {
                Point p = DecodePoint(rec + j * kPointRecordSize);
                if (slot.IsDead(p.id)) continue;
                if (label_mask != 0 && (p.label & label_mask) == 0) continue;
                if (!hit.inside && plan != nullptr && !plan->Contains(p)) continue;
                fn(p);
              }
            }));
      }
    }
  }
  return Status::OK();
}

Result<RegionPlan> PlanRegion(const Region& region, int lod, bool temporal_lod,
                              const FrameMap& frames, const DatasetInfo& info,
                              const Options& opts) {
  RegionPlan plan;
  plan.fps = info.fps;
  if (lod < 0 || lod > opts.lod_levels) {
    return Status::InvalidArgument("level of detail " + std::to_string(lod) + " out of range 0.." +
                                   std::to_string(opts.lod_levels));
  }
  uint32_t max_frames = 0;
  bool clip_on_limit = false;
  if (const auto* w = std::get_if<Window>(&region)) {
    HVDB_RETURN_IF_ERROR(ValidateWindow(*w));
    plan.window = *w;
    double f0 = std::floor(std::max(0.0, w->lo[3] * info.fps) - 1);
    for (auto it = frames.lower_bound(static_cast<uint32_t>(std::min(f0 < 0 ? 0.0 : f0, 4e9)));
         it != frames.end(); ++it) {
      double t = it->first / info.fps;
      if (t > w->hi[3]) break;
      if (t >= w->lo[3]) plan.frames.push_back(it->first);
    }
  } else {
    const Slice& s = std::get<Slice>(region);
    HVDB_ASSIGN_OR_RETURN(SliceGeometry g, SliceGeometry::Make(s, info.space_time_scale));
    plan.slice = g;
    plan.slice_clip = s.clip;
    max_frames = s.max_frames != 0 ? s.max_frames : opts.max_slice_frames;
    clip_on_limit = s.on_too_many_frames == Slice::FrameBound::kClip;
    for (const auto& [f, v] : frames) {
      double t = f / info.fps;
      if (s.clip && (t < s.clip->lo[3] || t > s.clip->hi[3])) continue;
      Box3 b = v->Bounds();
      if (b.lo[0] > b.hi[0]) continue;  // empty frame
      if (plan.Classify(b, f) == Relation::kOutside) continue;
      plan.frames.push_back(f);
    }
  }
  if (temporal_lod && lod > 0 && plan.frames.size() > 1) {
    uint32_t stride = 1u << lod;
    std::erase_if(plan.frames, [stride](uint32_t f) { return f % stride != 0; });
  }
  if (max_frames != 0 && plan.frames.size() > max_frames) {
    if (!clip_on_limit) {
      return Status::LimitExceeded(
          "slice touches " + std::to_string(plan.frames.size()) + " frames, more than the bound " +
          std::to_string(max_frames) +
          "; make it thinner or more orthogonal to t, raise max_frames, or ask for a clipped "
          "result");
    }
    plan.frames.resize(max_frames);
    plan.clipped = true;
  }
  for (uint32_t f : plan.frames) plan.versions.push_back(frames.at(f));
  return plan;
}

}  // namespace

Relation RegionPlan::Classify(const Box3& box, uint32_t frame) const {
  if (window) return ClassifyWindow(*window, box);
  Relation r = slice->Classify(box, FrameTime(frame));
  if (r == Relation::kOutside || !slice_clip) return r;
  Relation c = ClassifyWindow(*slice_clip, box);
  if (c == Relation::kOutside) return c;
  return (r == Relation::kInside && c == Relation::kInside) ? Relation::kInside
                                                            : Relation::kCrosses;
}

bool RegionPlan::Contains(const Point& p) const {
  if (window) return WindowContains(*window, p.x, p.y, p.z);
  if (!slice->Selects(p.x, p.y, p.z, FrameTime(p.frame))) return false;
  return !slice_clip || WindowContains(*slice_clip, p.x, p.y, p.z);
}

// ---------------------------------------------------------------------------------------------
// Opening

struct DatasetImpl::WriteRequest {
  enum class Kind { kTxn, kRevert, kBulk, kCheckpoint } kind = Kind::kTxn;
  const Transaction* txn = nullptr;
  uint64_t revert_lsn = 0;
  uint32_t frame = 0;
  std::vector<Point>* points = nullptr;
  bool done = false;
  Status status;
  CommitInfo info;
};

// The leader's view while applying a group: published versions overlaid with new ones.
class DatasetImpl::Working {
 public:
  explicit Working(FrameMap base) : map_(std::move(base)) {}
  std::shared_ptr<const FrameVersion> Get(uint32_t f) const {
    auto it = map_.find(f);
    return it == map_.end() ? nullptr : it->second;
  }
  void Set(uint32_t f, std::shared_ptr<const FrameVersion> v) {
    map_[f] = std::move(v);
    changed_.insert(f);
  }
  const FrameMap& map() const { return map_; }
  const std::set<uint32_t>& changed() const { return changed_; }

 private:
  FrameMap map_;
  std::set<uint32_t> changed_;
};

DatasetImpl::DatasetImpl(std::string dir, Options opts, BufferPool* pool, DatasetInfo info)
    : dir_(std::move(dir)), opts_(opts), pool_(pool),
      p_(opts.block_size / static_cast<uint32_t>(kPointRecordSize)), info_(std::move(info)) {}

DatasetImpl::~DatasetImpl() {
  // A clean close leaves nothing to replay; a failure here only means a longer next open.
  if (wal_ != nullptr) (void)CheckpointLocked();
}

std::string DatasetImpl::TreePath(uint32_t frame, uint64_t seq) const {
  return dir_ + "/trees/" + TreeFileName(frame, seq);
}

Status DatasetImpl::WriteManifest() const {
  return WriteFileAtomic(dir_ + "/MANIFEST", EncodeManifest(info_, opts_));
}

Result<std::unique_ptr<DatasetImpl>> DatasetImpl::Create(const std::string& dir,
                                                         const DatasetInfo& info,
                                                         const Options& opts, BufferPool* pool) {
  if (!(info.fps > 0) || !std::isfinite(info.fps) || info.fps > 10000) {
    return Status::InvalidArgument("fps must be in (0, 10000], got " + std::to_string(info.fps));
  }
  if (!(info.space_time_scale > 0) || !std::isfinite(info.space_time_scale)) {
    return Status::InvalidArgument("space/time scale must be > 0");
  }
  if (FileExists(dir)) return Status::AlreadyExists("dataset '" + info.name + "' already exists");
  // Build in a temporary directory and rename it into place: a crash leaves no half dataset.
  std::string tmp = dir + ".creating";
  HVDB_RETURN_IF_ERROR(RemoveTree(tmp));
  HVDB_RETURN_IF_ERROR(CreateDirs(tmp + "/frames"));
  HVDB_RETURN_IF_ERROR(CreateDirs(tmp + "/trees"));
  DatasetInfo stored = info;
  stored.point_count = 0;
  stored.last_lsn = 0;
  HVDB_RETURN_IF_ERROR(WriteFileAtomic(tmp + "/MANIFEST", EncodeManifest(stored, opts)));
  if (std::rename(tmp.c_str(), dir.c_str()) != 0) {
    return Status::FromErrno("rename " + tmp, errno);
  }
  std::string parent = dir.substr(0, dir.find_last_of('/'));
  HVDB_RETURN_IF_ERROR(SyncDir(parent.empty() ? "." : parent));
  return Open(dir, opts, pool);
}

Result<std::unique_ptr<DatasetImpl>> DatasetImpl::Open(const std::string& dir,
                                                       const Options& opts, BufferPool* pool) {
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(dir + "/MANIFEST"));
  HVDB_ASSIGN_OR_RETURN(ManifestContents m, DecodeManifest(data, dir + "/MANIFEST"));
  if (m.block_size != opts.block_size) {
    return Status::InvalidArgument(dir + ": dataset uses " + std::to_string(m.block_size) +
                                   "-byte blocks, the database is open with " +
                                   std::to_string(opts.block_size));
  }
  Options o = opts;
  o.lod_levels = m.lod_levels;  // a dataset keeps the level count it was built with
  std::unique_ptr<DatasetImpl> ds(new DatasetImpl(dir, o, pool, m.info));
  HVDB_RETURN_IF_ERROR(ds->Recover());
  return ds;
}

Status DatasetImpl::Recover() {
  const std::string frames_dir = dir_ + "/frames", trees_dir = dir_ + "/trees";
  HVDB_ASSIGN_OR_RETURN(auto tree_files, ListDir(trees_dir));
  HVDB_ASSIGN_OR_RETURN(auto frame_files, ListDir(frames_dir));
  uint64_t max_seq = 0, max_id = 0, max_applied = 0;
  std::set<std::string> referenced;
  std::map<uint32_t, uint64_t> persisted_lsn;
  for (const std::string& name : frame_files) {
    std::string path = frames_dir + "/" + name;
    if (name.ends_with(".tmp")) {
      HVDB_RETURN_IF_ERROR(RemoveFile(path));  // a state write cut short by a crash
      continue;
    }
    if (!name.ends_with(".fst")) continue;
    HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(path));
    HVDB_ASSIGN_OR_RETURN(FrameStateRecord rec, DecodeFrameState(data, path));
    auto v = std::make_shared<FrameVersion>();
    v->frame = rec.frame;
    v->applied_lsn = rec.applied_lsn;
    for (size_t s = 0; s < rec.tree_seqs.size(); ++s) {
      TreeSlot slot;
      if (rec.tree_seqs[s] != 0) {
        std::string tname = TreeFileName(rec.frame, rec.tree_seqs[s]);
        HVDB_ASSIGN_OR_RETURN(slot.tree, KdTree::Open(trees_dir + "/" + tname, pool_));
        referenced.insert(tname);
        max_id = std::max(max_id, slot.tree->header().max_id);
        max_seq = std::max(max_seq, rec.tree_seqs[s]);
        if (!rec.dead[s].empty()) {
          slot.dead = std::make_shared<const std::vector<uint64_t>>(std::move(rec.dead[s]));
        }
      }
      v->slots.push_back(std::move(slot));
    }
    for (const Point& p : rec.t0) max_id = std::max(max_id, p.id);
    // Ids of points deleted since are never issued again.
    if (rec.next_id > 0) max_id = std::max(max_id, rec.next_id - 1);
    v->t0 = std::make_shared<const std::vector<Point>>(std::move(rec.t0));
    persisted_lsn[v->frame] = v->applied_lsn;
    max_applied = std::max(max_applied, v->applied_lsn);
    frames_[v->frame] = std::move(v);
  }
  // Tree files no frame lists: outputs of rebuilds cut short, or inputs of finished ones.
  for (const std::string& name : tree_files) {
    uint32_t f;
    uint64_t seq;
    bool is_tree = ParseTreeFileName(name, &f, &seq);
    if (is_tree) max_seq = std::max(max_seq, seq);
    if ((is_tree && !referenced.count(name)) || name.ends_with(".tmp")) {
      HVDB_RETURN_IF_ERROR(RemoveFile(trees_dir + "/" + name));
    }
  }
  next_seq_ = max_seq + 1;

  // Redo the log.
  const std::string wal_path = dir_ + "/wal.log";
  bool exists = FileExists(wal_path);
  WalContents wal;
  if (exists) {
    HVDB_ASSIGN_OR_RETURN(wal, ReadWal(wal_path));
  }
  uint64_t last = max_applied;
  if (exists) last = std::max(last, wal.start_lsn - 1);
  HVDB_ASSIGN_OR_RETURN(auto all_files, ListDir(dir_));
  for (const std::string& name : all_files) {
    // Archived segments: wal-<start lsn>.log; their records are all in the frame states.
    if (name.starts_with("wal-") && name.ends_with(".log")) {
      HVDB_ASSIGN_OR_RETURN(WalContents old, ReadWal(dir_ + "/" + name));
      if (!old.records.empty()) last = std::max(last, old.records.back().lsn);
    }
  }
  for (const TxnRecord& rec : wal.records) {
    for (const FrameEffect& step : rec.frames) {
      auto pl = persisted_lsn.find(step.frame);
      if (pl != persisted_lsn.end() && rec.lsn <= pl->second) continue;
      auto it = frames_.find(step.frame);
      FrameVersion empty;
      empty.frame = step.frame;
      const FrameVersion& base = it == frames_.end() ? empty : *it->second;
      auto applied = ApplyStep(base, step, rec.lsn);
      if (!applied.ok()) {
        return Status::Corruption(wal_path + ": redo of record " + std::to_string(rec.lsn) +
                                  " failed: " + applied.status().message());
      }
      frames_[step.frame] = std::move(applied).value();
      dirty_.insert(step.frame);
      for (const Point& p : step.added) max_id = std::max(max_id, p.id);
    }
    for (const FrameEffect& step : rec.frames) {
      for (const Point& p : step.removed) max_id = std::max(max_id, p.id);
      for (const Point& p : step.added) max_id = std::max(max_id, p.id);
    }
    last = std::max(last, rec.lsn);
  }
  last_lsn_ = last;
  next_id_ = max_id + 1;
  wal_start_lsn_ = exists ? wal.start_lsn : last + 1;
  HVDB_ASSIGN_OR_RETURN(wal_, WalWriter::Open(wal_path, wal_start_lsn_, wal.valid_bytes, exists));
  // Frames whose buffer overflowed (during redo, or a rebuild that failed) get their trees now.
  std::vector<uint32_t> all_frames;
  for (const auto& [f, v] : frames_) all_frames.push_back(f);
  for (uint32_t f : all_frames) {
    if (frames_[f]->t0->size() <= p_) continue;
    FrameVersion v = *frames_[f];
    HVDB_RETURN_IF_ERROR(Rebuild(&v, {}));
  }
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------
// Reading

DatasetInfo DatasetImpl::Info() const {
  DatasetInfo info = info_;
  std::lock_guard<std::mutex> l(mu_);
  bool any = false;
  Box3 all;
  for (const auto& [f, v] : frames_) {
    uint64_t n = v->PointCount();
    if (n == 0) continue;
    info.point_count += n;
    info.frame_count = std::max(info.frame_count, f + 1);
    Box3 b = v->Bounds();
    if (!any) {
      all = b;
      any = true;
    }
    for (int a = 0; a < 3; ++a) {
      all.lo[a] = std::min(all.lo[a], b.lo[a]);
      all.hi[a] = std::max(all.hi[a], b.hi[a]);
    }
  }
  if (any) {
    info.bounds_min = all.lo;
    info.bounds_max = all.hi;
  }
  info.last_lsn = last_lsn_;
  return info;
}

std::shared_ptr<const FrameVersion> DatasetImpl::Snapshot(uint32_t frame) const {
  std::lock_guard<std::mutex> l(mu_);
  auto it = frames_.find(frame);
  return it == frames_.end() ? nullptr : it->second;
}

Result<RegionPlan> DatasetImpl::Plan(const Region& region, int lod, bool temporal_lod) const {
  FrameMap snap;
  {
    std::lock_guard<std::mutex> l(mu_);
    snap = frames_;
  }
  return PlanRegion(region, lod, temporal_lod, snap, info_, opts_);
}

// ---------------------------------------------------------------------------------------------
// Writing

Result<CommitInfo> DatasetImpl::Commit(const Transaction& txn) {
  WriteRequest w;
  w.kind = WriteRequest::Kind::kTxn;
  w.txn = &txn;
  return Submit(&w);
}

Result<CommitInfo> DatasetImpl::Revert(uint64_t lsn) {
  WriteRequest w;
  w.kind = WriteRequest::Kind::kRevert;
  w.revert_lsn = lsn;
  return Submit(&w);
}

Result<uint64_t> DatasetImpl::BulkLoad(uint32_t frame, std::vector<Point> points) {
  if (frame >= kMaxFrame) {
    return Status::InvalidArgument("frame " + std::to_string(frame) + " out of range");
  }
  for (Point& p : points) {
    p.frame = frame;
    HVDB_RETURN_IF_ERROR(ValidatePoint(p));
  }
  WriteRequest w;
  w.kind = WriteRequest::Kind::kBulk;
  w.frame = frame;
  w.points = &points;
  HVDB_ASSIGN_OR_RETURN(CommitInfo info, Submit(&w));
  return info.inserted;
}

Status DatasetImpl::Checkpoint() {
  WriteRequest w;
  w.kind = WriteRequest::Kind::kCheckpoint;
  return Submit(&w).status();
}

Result<CommitInfo> DatasetImpl::Submit(WriteRequest* w) {
  std::unique_lock<std::mutex> l(write_mu_);
  writers_.push_back(w);
  write_cv_.wait(l, [&] { return w->done || writers_.front() == w; });
  if (w->done) {
    if (!w->status.ok()) return w->status;
    return w->info;
  }
  // Leader: take every transaction queued now (bulk loads and checkpoints go alone).
  std::vector<WriteRequest*> group{w};
  if (w->kind == WriteRequest::Kind::kTxn || w->kind == WriteRequest::Kind::kRevert) {
    for (size_t i = 1; i < writers_.size(); ++i) {
      auto k = writers_[i]->kind;
      if (k != WriteRequest::Kind::kTxn && k != WriteRequest::Kind::kRevert) break;
      group.push_back(writers_[i]);
    }
  }
  l.unlock();
  LeadGroup(group);
  l.lock();
  for (size_t i = 0; i < group.size(); ++i) {
    writers_.front()->done = true;
    writers_.pop_front();
  }
  write_cv_.notify_all();
  if (!w->status.ok()) return w->status;
  return w->info;
}

namespace {

struct Selected {
  std::map<uint32_t, std::vector<Point>> by_frame;
};

}  // namespace

Status DatasetImpl::Resolve(const Transaction& txn, Working* ws, TxnRecord* rec,
                            CommitInfo* info) {
  auto apply = [&](const FrameEffect& step) -> Status {
    auto base = ws->Get(step.frame);
    FrameVersion empty;
    empty.frame = step.frame;
    HVDB_ASSIGN_OR_RETURN(auto v, ApplyStep(base ? *base : empty, step, rec->lsn));
    ws->Set(step.frame, std::move(v));
    rec->frames.push_back(step);
    return Status::OK();
  };
  auto select = [&](const Selection& sel) -> Result<Selected> {
    Selected out;
    std::set<std::pair<uint32_t, uint64_t>> seen;
    auto add = [&](const Point& p) {
      if (seen.insert({p.frame, p.id}).second) out.by_frame[p.frame].push_back(p);
    };
    if (sel.region) {
      HVDB_ASSIGN_OR_RETURN(RegionPlan plan,
                            PlanRegion(*sel.region, 0, false, ws->map(), info_, opts_));
      for (uint32_t f : plan.frames) {
        HVDB_RETURN_IF_ERROR(ScanVersion(*ws->Get(f), &plan, sel.label_mask, add));
      }
    } else if (sel.ids.empty()) {
      for (const auto& [f, v] : ws->map()) {
        HVDB_RETURN_IF_ERROR(ScanVersion(*v, nullptr, sel.label_mask, add));
      }
    }
    std::map<uint32_t, std::unordered_set<uint64_t>> wanted;
    for (auto [f, id] : sel.ids) wanted[f].insert(id);
    for (const auto& entry : wanted) {
      const uint32_t f = entry.first;
      const std::unordered_set<uint64_t>& ids = entry.second;  // (clang 14: no lambda capture
                                                                 // of structured bindings)
      auto v = ws->Get(f);
      if (!v) return Status::NotFound("frame " + std::to_string(f) + " has no points");
      size_t found = 0;
      HVDB_RETURN_IF_ERROR(ScanVersion(*v, nullptr, sel.label_mask, [&](const Point& p) {
        if (ids.count(p.id)) {
          add(p);
          ++found;
        }
      }));
      if (found < ids.size()) {
        return Status::NotFound(std::to_string(ids.size() - found) + " selected id(s) not found in frame " +
                                std::to_string(f));
      }
    }
    return out;
  };

  for (const Transaction::Op& op : txn.ops()) {
    if (const auto* ins = std::get_if<Transaction::InsertOp>(&op)) {
      std::map<uint32_t, FrameEffect> steps;
      for (Point p : ins->points) {
        HVDB_RETURN_IF_ERROR(ValidatePoint(p));
        if (p.id == 0) {
          p.id = next_id_++;
          info->assigned_ids.push_back(p.id);
        }
        steps[p.frame].frame = p.frame;
        steps[p.frame].added.push_back(p);
      }
      for (auto& [f, step] : steps) {
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(step));
      }
    } else if (const auto* del = std::get_if<Transaction::DeleteOp>(&op)) {
      auto v = ws->Get(del->frame);
      Point target;
      target.id = del->id;
      target.x = del->pos[0];
      target.y = del->pos[1];
      target.z = del->pos[2];
      Holder h;
      if (v) {
        HVDB_ASSIGN_OR_RETURN(h, Locate(*v, target));
      }
      if (h.slot == -2) {
        return Status::NotFound("delete: point " + std::to_string(del->id) + " not found in frame " +
                                std::to_string(del->frame) + " at the given position");
      }
      FrameEffect step;
      step.frame = del->frame;
      step.removed.push_back(h.stored);
      ++info->removed;
      HVDB_RETURN_IF_ERROR(apply(step));
    } else if (const auto* ds = std::get_if<Transaction::DeleteSelOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(ds->sel));
      for (auto& [f, pts] : sel.by_frame) {
        FrameEffect step;
        step.frame = f;
        step.removed = std::move(pts);
        info->removed += step.removed.size();
        HVDB_RETURN_IF_ERROR(apply(step));
      }
    } else if (const auto* lab = std::get_if<Transaction::LabelOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(lab->sel));
      for (auto& [f, pts] : sel.by_frame) {
        FrameEffect step;
        step.frame = f;
        for (const Point& p : pts) {
          Point q = p;
          q.label = lab->set ? (p.label | lab->bits) : (p.label & ~lab->bits);
          if (q.label == p.label) continue;
          step.removed.push_back(p);
          step.added.push_back(q);
        }
        if (step.removed.empty()) continue;
        info->removed += step.removed.size();
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(step));
      }
    } else if (const auto* tr = std::get_if<Transaction::TransformOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(AffineMap map, AffineMap::Make(tr->map, info_.fps));
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(tr->sel));
      std::map<uint32_t, FrameEffect> removes, adds;
      for (auto& [f, pts] : sel.by_frame) {
        for (const Point& p : pts) {
          HVDB_ASSIGN_OR_RETURN(Point q, map.Apply(p));
          HVDB_RETURN_IF_ERROR(ValidatePoint(q));
          removes[p.frame].frame = p.frame;
          removes[p.frame].removed.push_back(p);
          adds[q.frame].frame = q.frame;
          adds[q.frame].added.push_back(q);
        }
      }
      for (auto& [f, step] : removes) {
        info->removed += step.removed.size();
        HVDB_RETURN_IF_ERROR(apply(step));
      }
      for (auto& [f, step] : adds) {
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(step));
      }
    }
  }
  return Status::OK();
}

Result<TxnRecord> DatasetImpl::FindRecord(uint64_t lsn) const {
  HVDB_ASSIGN_OR_RETURN(auto names, ListDir(dir_));
  std::vector<std::string> logs;
  for (const std::string& n : names) {
    if (n == "wal.log" || (n.starts_with("wal-") && n.ends_with(".log"))) logs.push_back(n);
  }
  for (const std::string& n : logs) {
    HVDB_ASSIGN_OR_RETURN(WalContents c, ReadWal(dir_ + "/" + n));
    for (TxnRecord& r : c.records) {
      if (r.lsn == lsn) return std::move(r);
    }
  }
  return Status::NotFound("transaction " + std::to_string(lsn) +
                          " is not in the log (bulk loads are not transactions and cannot be "
                          "reverted)");
}

void DatasetImpl::LeadGroup(std::vector<WriteRequest*>& group) {
  using Kind = WriteRequest::Kind;
  WriteRequest* first = group.front();
  if (first->kind == Kind::kCheckpoint) {
    first->status = CheckpointLocked();
    return;
  }
  FrameMap base;
  {
    std::lock_guard<std::mutex> l(mu_);
    base = frames_;
  }
  if (first->kind == Kind::kBulk) {
    auto cur = base.count(first->frame) ? base[first->frame] : nullptr;
    FrameVersion v;
    if (cur) v = *cur;
    v.frame = first->frame;
    for (Point& p : *first->points) {
      if (p.id == 0) p.id = next_id_++;
    }
    first->info.inserted = first->points->size();
    first->status = Rebuild(&v, std::move(*first->points));
    return;
  }

  Working ws(base);
  std::vector<TxnRecord> records;
  std::vector<WriteRequest*> committed;
  uint64_t lsn = last_lsn_;
  for (WriteRequest* w : group) {
    Working attempt = ws;
    TxnRecord rec;
    rec.lsn = lsn + 1;
    CommitInfo info;
    Status st;
    if (w->kind == Kind::kRevert) {
      auto orig = FindRecord(w->revert_lsn);
      if (!orig.ok()) {
        st = orig.status();
      } else {
        rec.reverts = w->revert_lsn;
        // The inverse: steps in reverse order, removed and added swapped.
        for (auto it = orig->frames.rbegin(); it != orig->frames.rend() && st.ok(); ++it) {
          FrameEffect inv{it->frame, it->added, it->removed};
          auto basev = attempt.Get(inv.frame);
          FrameVersion empty;
          empty.frame = inv.frame;
          auto applied = ApplyStep(basev ? *basev : empty, inv, rec.lsn);
          if (!applied.ok()) {
            st = Status::InvalidArgument(
                "cannot revert transaction " + std::to_string(w->revert_lsn) +
                ": a later transaction changed its points (" + applied.status().message() +
                "); revert the later one first");
            break;
          }
          attempt.Set(inv.frame, std::move(applied).value());
          info.inserted += inv.added.size();
          info.removed += inv.removed.size();
          rec.frames.push_back(std::move(inv));
        }
      }
    } else {
      st = Resolve(*w->txn, &attempt, &rec, &info);
    }
    if (!st.ok()) {
      w->status = st;
      continue;
    }
    if (rec.frames.empty() && w->kind == Kind::kTxn && w->txn->empty()) {
      w->status = Status::InvalidArgument("empty transaction");
      continue;
    }
    ++lsn;
    info.lsn = lsn;
    w->info = std::move(info);
    records.push_back(std::move(rec));
    committed.push_back(w);
    ws = std::move(attempt);
  }
  if (records.empty()) return;
  // One log write and one fsync for the whole group.
  uint64_t before = wal_->size();
  Status st;
  for (const TxnRecord& r : records) {
    st = wal_->Append(r);
    if (!st.ok()) break;
  }
  if (st.ok() && opts_.sync) st = wal_->Sync();
  if (!st.ok()) {
    // Nothing of the group may survive: cut the log back to where it was.
    auto reopened = WalWriter::Open(dir_ + "/wal.log", wal_start_lsn_, before, true);
    if (reopened.ok()) wal_ = std::move(reopened).value();
    for (WriteRequest* w : committed) {
      w->status = st;
      w->info = {};
    }
    return;
  }
  {
    std::lock_guard<std::mutex> l(mu_);
    for (uint32_t f : ws.changed()) frames_[f] = ws.Get(f);
    last_lsn_ = lsn;
  }
  for (uint32_t f : ws.changed()) dirty_.insert(f);
  // Logarithmic method: frames whose buffer overflowed become trees. The commits above are
  // already durable; a failure here only leaves the buffer big until the next try.
  for (uint32_t f : ws.changed()) {
    auto v = ws.Get(f);
    if (v->t0->size() <= p_) continue;
    FrameVersion copy = *v;
    Status rs = Rebuild(&copy, {});
    if (!rs.ok()) std::fprintf(stderr, "hvdb: rebuild of frame %u deferred: %s\n", f, rs.ToString().c_str());
  }
  if (wal_->size() > opts_.wal_checkpoint_bytes) {
    Status cs = CheckpointLocked();
    if (!cs.ok()) std::fprintf(stderr, "hvdb: checkpoint deferred: %s\n", cs.ToString().c_str());
  }
}

Status DatasetImpl::Rebuild(FrameVersion* v, std::vector<Point> extra) {
  // Smallest slot i that is empty and can hold T0, the extra points and slots 0..i-1.
  std::vector<Point> pts = std::move(extra);
  pts.insert(pts.end(), v->t0->begin(), v->t0->end());
  uint64_t total = pts.size();
  size_t i = 0;
  while (i < v->slots.size() &&
         (v->slots[i].tree || total > (uint64_t{p_} << i))) {
    total += v->slots[i].live();
    ++i;
  }
  if (total == 0) return PersistFrame(*v);
  std::vector<std::shared_ptr<KdTree>> merged;
  for (size_t j = 0; j < i && j < v->slots.size(); ++j) {
    const TreeSlot& s = v->slots[j];
    if (!s.tree) continue;
    std::vector<Point> all;
    HVDB_RETURN_IF_ERROR(s.tree->ReadAll(&all));
    for (const Point& p : all) {
      if (!s.IsDead(p.id)) pts.push_back(p);
    }
    merged.push_back(s.tree);
  }
  while (v->slots.size() <= i) v->slots.emplace_back();
  // Capacity may still be short when everything merged is large: move up until it fits.
  while ((uint64_t{p_} << i) < pts.size()) {
    ++i;
    if (i >= v->slots.size()) v->slots.emplace_back();
  }
  uint64_t seq = next_seq_++;
  TreeBuildParams params;
  params.block_size = opts_.block_size;
  params.lod_levels = opts_.lod_levels;
  params.frame = v->frame;
  params.tree_seq = seq;
  std::string path = TreePath(v->frame, seq);
  HVDB_RETURN_IF_ERROR(BuildTreeFile(path, pts, params));
  auto opened = KdTree::Open(path, pool_);
  if (!opened.ok()) {
    (void)RemoveFile(path);
    return opened.status();
  }
  FrameVersion nv = *v;
  for (size_t j = 0; j < i && j < nv.slots.size(); ++j) nv.slots[j] = TreeSlot{};
  nv.slots[i] = TreeSlot{std::move(opened).value(), nullptr};
  nv.t0 = std::make_shared<const std::vector<Point>>();
  Status st = PersistFrame(nv);
  if (!st.ok()) {
    nv.slots[i].tree->MarkObsolete();  // never referenced by a state file
    return st;
  }
  for (auto& t : merged) t->MarkObsolete();  // deleted when the last reader lets go
  *v = nv;
  return Status::OK();
}

Status DatasetImpl::PersistFrame(const FrameVersion& v) {
  HVDB_RETURN_IF_ERROR(
      WriteFileAtomic(dir_ + "/frames/" + FrameStateFileName(v.frame),
                      EncodeFrameState(v, next_id_.load())));
  {
    std::lock_guard<std::mutex> l(mu_);
    frames_[v.frame] = std::make_shared<const FrameVersion>(v);
  }
  dirty_.erase(v.frame);
  return Status::OK();
}

Status DatasetImpl::CheckpointLocked() {
  std::vector<uint32_t> dirty(dirty_.begin(), dirty_.end());
  for (uint32_t f : dirty) {
    auto v = Snapshot(f);
    if (v) HVDB_RETURN_IF_ERROR(PersistFrame(*v));
  }
  if (wal_->size() <= kWalHeaderSize) return Status::OK();
  // Keep the old segment for Revert; the frames no longer need it for recovery.
  char name[64];
  std::snprintf(name, sizeof(name), "/wal-%016" PRIx64 ".log", wal_start_lsn_);
  std::string from = dir_ + "/wal.log", to = dir_ + name;
  if (std::rename(from.c_str(), to.c_str()) != 0) return Status::FromErrno("rename " + from, errno);
  uint64_t start;
  {
    std::lock_guard<std::mutex> l(mu_);
    start = last_lsn_ + 1;
  }
  wal_start_lsn_ = start;
  HVDB_ASSIGN_OR_RETURN(wal_, WalWriter::Open(from, start, 0, false));
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------
// Introspection

DatasetStats DatasetImpl::Stats() const {
  DatasetStats s;
  uint64_t leaf_blocks = 0, leaf_points = 0, b = p_;
  std::lock_guard<std::mutex> l(mu_);
  for (const auto& [f, v] : frames_) {
    uint64_t n = v->PointCount();
    if (n > 0) ++s.frames_with_data;
    s.points += n;
    s.buffered_points += v->t0->size();
    for (const TreeSlot& slot : v->slots) {
      if (!slot.tree) continue;
      const TreeHeader& h = slot.tree->header();
      ++s.trees;
      s.tree_bytes += slot.tree->file_bytes();
      s.tombstones += slot.dead ? slot.dead->size() : 0;
      for (uint32_t k = 0; k < h.levels; ++k) leaf_blocks += (h.level_count[k] + b - 1) / b;
      leaf_points += h.point_count;
    }
  }
  s.wal_bytes = wal_ ? wal_->size() : 0;
  s.leaf_utilisation = leaf_blocks ? static_cast<double>(leaf_points) / (leaf_blocks * b) : 0;
  return s;
}

std::vector<std::string> DatasetImpl::Check() const {
  std::vector<std::string> problems;
  auto add = [&](const std::vector<std::string>& more) {
    problems.insert(problems.end(), more.begin(), more.end());
  };
  FrameMap snap;
  {
    std::lock_guard<std::mutex> l(mu_);
    snap = frames_;
  }
  // Frame state files as stored (the in-memory versions may be newer: those are in the log).
  auto names = ListDir(dir_ + "/frames");
  if (!names.ok()) {
    problems.push_back(names.status().ToString());
  } else {
    for (const std::string& n : *names) {
      if (!n.ends_with(".fst")) continue;
      auto data = ReadWholeFile(dir_ + "/frames/" + n);
      if (!data.ok()) {
        problems.push_back(data.status().ToString());
        continue;
      }
      auto rec = DecodeFrameState(*data, dir_ + "/frames/" + n);
      if (!rec.ok()) {
        problems.push_back(rec.status().ToString());
        continue;
      }
      for (uint64_t seq : rec->tree_seqs) {
        if (seq != 0 && !FileExists(TreePath(rec->frame, seq))) {
          problems.push_back(dir_ + "/frames/" + n + ": lists missing tree " +
                             TreeFileName(rec->frame, seq));
        }
      }
    }
  }
  for (const auto& [f, v] : snap) {
    for (size_t i = 0; i < v->slots.size(); ++i) {
      const TreeSlot& s = v->slots[i];
      if (!s.tree) continue;
      add(s.tree->Verify());
      const TreeHeader& h = s.tree->header();
      if (h.frame != f) problems.push_back(s.tree->path() + ": holds frame " + std::to_string(h.frame));
      if (h.point_count > (uint64_t{p_} << i)) {
        problems.push_back(s.tree->path() + ": " + std::to_string(h.point_count) +
                           " points exceed slot " + std::to_string(i) + "'s capacity");
      }
    }
  }
  auto logs = ListDir(dir_);
  if (logs.ok()) {
    for (const std::string& n : *logs) {
      if (n == "wal.log" || (n.starts_with("wal-") && n.ends_with(".log"))) {
        auto c = ReadWal(dir_ + "/" + n);
        if (!c.ok()) problems.push_back(c.status().ToString());
      }
    }
  }
  auto m = ReadWholeFile(dir_ + "/MANIFEST");
  if (!m.ok()) {
    problems.push_back(m.status().ToString());
  } else if (auto d = DecodeManifest(*m, dir_ + "/MANIFEST"); !d.ok()) {
    problems.push_back(d.status().ToString());
  }
  return problems;
}

}  // namespace hvdb
