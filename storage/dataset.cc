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
#include "storage/env.h"
#include "storage/kdtree_builder.h"
#include "storage/lod.h"

namespace hvdb {

namespace {

std::string FormatNumber(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

constexpr char kManifestMagic[8] = {'H', 'V', 'D', 'B', 'M', 'A', 'N', '\0'};
// Version 2 adds a flags word after the cameras (bit 0: a Gaussian-splat dataset); version 1
// manifests are still read.
constexpr uint32_t kManifestVersion = 2;

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
  w.Put<uint32_t>(info.gaussians ? 1u : 0u);
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
  if (!r.Get(&version) || version < 1 || version > kManifestVersion) {
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
  if (version >= 2) {
    uint32_t flags = 0;
    if (!r.Get(&flags) || (flags & ~1u) != 0) return corrupt("bad flags");
    m.info.gaussians = (flags & 1u) != 0;
  }
  m.block_size = bs;
  m.lod_levels = static_cast<int>(levels);
  return m;
}

}  // namespace

Status CheckLodRange(int64_t lod, int levels, const std::string& dataset) {
  if (lod >= 0 && lod <= levels) return Status::OK();
  return Status::InvalidArgument("lod: " + std::to_string(lod) + " is out of range 0.." +
                                 std::to_string(levels) + " for dataset '" + dataset +
                                 "' (its coarsest level)");
}

Result<RegionPlan> PlanRegion(const Region& region, int lod, bool temporal_lod,
                              const FrameMap& frames, const DatasetInfo& info,
                              const Options& opts) {
  RegionPlan plan;
  plan.fps = info.fps;
  HVDB_RETURN_IF_ERROR(CheckLodRange(lod, opts.lod_levels, info.name));
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

DatasetImpl::DatasetImpl(std::string dir, Options opts, BufferPool* pool, DatasetInfo info)
    : dir_(std::move(dir)), opts_(opts), env_(opts.env ? opts.env : Env::Default()), pool_(pool),
      t0_cap_(opts.t0_points), info_(std::move(info)) {}

DatasetImpl::~DatasetImpl() {
  {
    std::lock_guard<std::mutex> l(merge_mu_);
    merge_stop_ = true;
  }
  merge_cv_.notify_all();
  merged_cv_.notify_all();
  if (merger_.joinable()) merger_.join();
  // A clean close leaves nothing to replay; a failure here only means a longer next open.
  if (wal_ != nullptr) (void)CheckpointLocked();
  ReleaseBuried(/*all=*/true);
}

std::string DatasetImpl::TreePath(uint32_t frame, uint64_t seq) const {
  return dir_ + "/trees/" + TreeFileName(frame, seq);
}

Status DatasetImpl::WriteManifest() const {
  return WriteFileAtomic(env_, dir_ + "/MANIFEST", EncodeManifest(info_, opts_));
}

Result<std::unique_ptr<DatasetImpl>> DatasetImpl::Create(const std::string& dir,
                                                         const DatasetInfo& info,
                                                         const Options& opts, BufferPool* pool) {
  // The ranges of docs/PROTOCOL.md ("CreateDataset"), checked here so that every entry point
  // (the server, the embedded CLI, Python) refuses the same values.
  if (!(info.fps >= kMinFps) || !(info.fps <= kMaxFps)) {
    return Status::InvalidArgument("fps must be in [" + FormatNumber(kMinFps) + ", " +
                                   FormatNumber(kMaxFps) + "], got " + FormatNumber(info.fps));
  }
  if (!(info.space_time_scale >= 1e-9) || !(info.space_time_scale <= 1e9)) {
    return Status::InvalidArgument("space/time scale must be in [1e-09, 1e+09], got " +
                                   FormatNumber(info.space_time_scale));
  }
  if (info.frame_count > kMaxFrames) {
    return Status::InvalidArgument("frame count must be at most " + std::to_string(kMaxFrames) +
                                   " (frames are numbered below it), got " +
                                   std::to_string(info.frame_count));
  }
  Env* env = opts.env ? opts.env : Env::Default();
  const bool atomic = env->AtomicDirRename();
  if (env->Exists(dir)) {
    if (atomic || env->Exists(dir + "/MANIFEST")) {
      return Status::AlreadyExists("dataset '" + info.name + "' already exists");
    }
    HVDB_RETURN_IF_ERROR(env->RemoveTree(dir));  // a create cut short: no MANIFEST yet
  }
  // Build in a temporary directory and rename it into place: a crash leaves no half dataset.
  // Without atomic directory renames (RADOS) it is built in place: its MANIFEST, written last
  // and atomically, is what makes a directory a dataset.
  std::string tmp = atomic ? dir + ".creating" : dir;
  HVDB_RETURN_IF_ERROR(env->RemoveTree(tmp));
  HVDB_RETURN_IF_ERROR(env->CreateDirs(tmp + "/frames"));
  HVDB_RETURN_IF_ERROR(env->CreateDirs(tmp + "/trees"));
  DatasetInfo stored = info;
  stored.point_count = 0;
  stored.last_lsn = 0;
  HVDB_RETURN_IF_ERROR(WriteFileAtomic(env, tmp + "/MANIFEST", EncodeManifest(stored, opts)));
  HVDB_RETURN_IF_ERROR(env->SyncDir(tmp));
  if (atomic) {
    HVDB_RETURN_IF_ERROR(env->Rename(tmp, dir));
    HVDB_RETURN_IF_ERROR(env->SyncDir(ParentDir(dir)));
  }
  return Open(dir, opts, pool);
}

Result<std::unique_ptr<DatasetImpl>> DatasetImpl::Open(const std::string& dir,
                                                       const Options& opts, BufferPool* pool,
                                                       bool follower) {
  Env* env = opts.env ? opts.env : Env::Default();
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env, dir + "/MANIFEST"));
  HVDB_ASSIGN_OR_RETURN(ManifestContents m, DecodeManifest(data, dir + "/MANIFEST"));
  if (m.block_size != opts.block_size) {
    return Status::InvalidArgument(dir + ": dataset uses " + std::to_string(m.block_size) +
                                   "-byte blocks, the database is open with " +
                                   std::to_string(opts.block_size));
  }
  Options o = opts;
  o.lod_levels = m.lod_levels;  // a dataset keeps the level count it was built with
  std::unique_ptr<DatasetImpl> ds(new DatasetImpl(dir, o, pool, m.info));
  ds->follower_ = follower;
  if (follower) {
    HVDB_RETURN_IF_ERROR(ds->Reload());
  } else {
    Loaded l;
    HVDB_RETURN_IF_ERROR(ds->Load(/*writer=*/true, {}, &l));
    HVDB_RETURN_IF_ERROR(ds->Start(std::move(l), /*writer=*/true));
    ds->StartMerger();
  }
  return ds;
}

Status DatasetImpl::Start(Loaded l, bool writer) {
  {
    std::lock_guard<std::mutex> lk(mu_);
    frames_ = std::move(l.frames);
    last_lsn_ = l.last_lsn;
  }
  next_id_ = l.next_id;
  next_seq_ = l.next_seq;
  // The column is opened once: queries may be reading it while a follower reloads (they hold
  // no lock on it); later starts refresh it, and a promotion recovers it as a writer's open.
  if (info_.gaussians && !gaussians_) {
    HVDB_ASSIGN_OR_RETURN(gaussians_, GaussianColumn::Open(env_, dir_, writer, l.next_id));
  } else if (gaussians_) {
    HVDB_RETURN_IF_ERROR(writer ? gaussians_->Recover(l.next_id) : gaussians_->Refresh());
  }
  if (!writer) {
    follow_start_ = l.wal_start;
    follow_offset_ = l.wal_exists ? l.wal_bytes : 0;
    wal_bytes_ = follow_offset_;
    return Status::OK();
  }
  dirty_ = std::move(l.dirty);
  wal_start_lsn_ = l.wal_start;
  HVDB_ASSIGN_OR_RETURN(wal_, WalWriter::Open(env_, dir_ + "/wal.log", wal_start_lsn_,
                                              l.wal_bytes, l.wal_exists));
  wal_bytes_ = wal_->size();
  return Status::OK();
}

void DatasetImpl::StartMerger() {
  merger_ = std::thread([this] { MergerLoop(); });
  WakeMerger();  // frames whose T0 overflowed before the crash
}

Result<std::shared_ptr<FrameVersion>> DatasetImpl::LoadFrameState(const std::string& path,
                                                                  const FrameMap& reuse,
                                                                  uint64_t* next_id_out) {
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env_, path));
  HVDB_ASSIGN_OR_RETURN(FrameStateRecord rec, DecodeFrameState(data, path));
  auto v = std::make_shared<FrameVersion>();
  v->frame = rec.frame;
  v->applied_lsn = rec.applied_lsn;
  auto known = reuse.find(rec.frame);
  for (size_t s = 0; s < rec.tree_seqs.size(); ++s) {
    TreeSlot slot;
    if (rec.tree_seqs[s] != 0) {
      // A follower reloading shares the trees it has open (and their cached blocks).
      if (known != reuse.end()) {
        for (const TreeSlot& o : known->second->slots) {
          if (o.tree && o.tree->header().tree_seq == rec.tree_seqs[s]) slot.tree = o.tree;
        }
      }
      if (!slot.tree) {
        HVDB_ASSIGN_OR_RETURN(slot.tree, KdTree::Open(env_, TreePath(rec.frame, rec.tree_seqs[s]),
                                                      pool_));
        slot.tree->MarkDurable();
      }
      if (!rec.dead[s].empty()) {
        slot.dead = std::make_shared<const std::vector<uint64_t>>(std::move(rec.dead[s]));
      }
    }
    v->slots.push_back(std::move(slot));
  }
  // Ids of points deleted since are never issued again.
  uint64_t next_id = rec.next_id;
  for (const Point& p : rec.t0) next_id = std::max(next_id, p.id + 1);
  v->t0.Append(std::move(rec.t0));
  if (next_id_out) *next_id_out = next_id;
  return v;
}

Status DatasetImpl::Load(bool writer, const FrameMap& reuse, Loaded* out) {
  const std::string frames_dir = dir_ + "/frames", trees_dir = dir_ + "/trees";
  HVDB_ASSIGN_OR_RETURN(auto tree_files, env_->ListDir(trees_dir));
  HVDB_ASSIGN_OR_RETURN(auto frame_files, env_->ListDir(frames_dir));
  uint64_t max_seq = 0, max_id = 0, max_applied = 0;
  std::set<std::string> referenced;
  std::map<uint32_t, uint64_t> persisted_lsn;
  for (const std::string& name : frame_files) {
    std::string path = frames_dir + "/" + name;
    if (name.ends_with(".tmp")) {
      // A state write cut short by a crash (or, to a follower, one in progress).
      if (writer) HVDB_RETURN_IF_ERROR(env_->Remove(path));
      continue;
    }
    if (!name.ends_with(".fst")) continue;
    uint64_t next_id = 0;
    HVDB_ASSIGN_OR_RETURN(auto v, LoadFrameState(path, reuse, &next_id));
    for (const TreeSlot& slot : v->slots) {
      if (!slot.tree) continue;
      referenced.insert(TreeFileName(v->frame, slot.tree->header().tree_seq));
      max_id = std::max(max_id, slot.tree->header().max_id);
      max_seq = std::max(max_seq, slot.tree->header().tree_seq);
    }
    if (next_id > 0) max_id = std::max(max_id, next_id - 1);
    persisted_lsn[v->frame] = v->applied_lsn;
    max_applied = std::max(max_applied, v->applied_lsn);
    out->frames[v->frame] = std::move(v);
  }
  // Tree files no frame lists: outputs of rebuilds cut short, or inputs of finished ones.
  for (const std::string& name : tree_files) {
    uint32_t f;
    uint64_t seq;
    bool is_tree = ParseTreeFileName(name, &f, &seq);
    if (is_tree) max_seq = std::max(max_seq, seq);
    if (writer && ((is_tree && !referenced.count(name)) || name.ends_with(".tmp"))) {
      HVDB_RETURN_IF_ERROR(env_->Remove(trees_dir + "/" + name));
    }
  }
  out->next_seq = max_seq + 1;

  // Redo the log.
  const std::string wal_path = dir_ + "/wal.log";
  const bool exists = env_->Exists(wal_path);
  WalContents wal;
  if (exists) {
    HVDB_ASSIGN_OR_RETURN(wal, ReadWal(env_, wal_path));
  }
  uint64_t last = max_applied;
  if (exists) last = std::max(last, wal.start_lsn - 1);
  if (writer || !exists) {
    HVDB_ASSIGN_OR_RETURN(auto all_files, env_->ListDir(dir_));
    for (const std::string& name : all_files) {
      // Archived segments: wal-<start lsn>.log; their records are all in the frame states.
      if (name.starts_with("wal-") && name.ends_with(".log")) {
        HVDB_ASSIGN_OR_RETURN(WalContents old, ReadWal(env_, dir_ + "/" + name));
        if (!old.records.empty()) last = std::max(last, old.records.back().lsn);
      }
    }
  }
  for (const TxnRecord& rec : wal.records) {
    last = std::max(last, rec.lsn);
    // Its frame state is durable; the marker is for followers.
    if (rec.bulk || rec.tier) continue;
    for (const FrameEffect& step : rec.frames) {
      auto pl = persisted_lsn.find(step.frame);
      if (pl != persisted_lsn.end() && rec.lsn <= pl->second) continue;
      auto it = out->frames.find(step.frame);
      FrameVersion empty;
      empty.frame = step.frame;
      const FrameVersion& base = it == out->frames.end() ? empty : *it->second;
      auto applied = ApplyStep(base, step, rec.lsn);
      if (!applied.ok()) {
        return Status::Corruption(wal_path + ": redo of record " + std::to_string(rec.lsn) +
                                  " failed: " + applied.status().message());
      }
      out->frames[step.frame] = std::move(applied).value();
      out->dirty.insert(step.frame);
    }
    for (const FrameEffect& step : rec.frames) {
      for (const Point& p : step.removed) max_id = std::max(max_id, p.id);
      for (const Point& p : step.added) max_id = std::max(max_id, p.id);
      for (const Relabel& g : step.relabels) max_id = std::max(max_id, g.ids.back());
    }
  }
  out->last_lsn = last;
  out->next_id = max_id + 1;
  out->wal_exists = exists;
  out->wal_start = exists ? wal.start_lsn : last + 1;
  out->wal_bytes = wal.valid_bytes;
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
// Introspection

DatasetStats DatasetImpl::Stats() const {
  DatasetStats s;
  uint64_t leaf_blocks = 0, leaf_points = 0, b = opts_.block_size / kPointRecordSize;
  std::lock_guard<std::mutex> l(mu_);
  for (const auto& [f, v] : frames_) {
    uint64_t n = v->PointCount();
    if (n > 0) ++s.frames_with_data;
    if (n > 0 && IsCold(*v)) ++s.cold_frames;
    s.points += n;
    s.buffered_points += v->t0.size();
    for (const TreeSlot& slot : v->slots) {
      if (!slot.tree) continue;
      const TreeHeader& h = slot.tree->header();
      ++s.trees;
      s.tree_bytes += slot.tree->file_bytes();
      if (slot.tree->compressed()) {
        ++s.cold_trees;
        s.cold_tree_bytes += slot.tree->file_bytes();
        s.cold_points += h.point_count;
      }
      s.tombstones += slot.dead ? slot.dead->size() : 0;
      for (uint32_t k = 0; k < h.levels; ++k) leaf_blocks += (h.level_count[k] + b - 1) / b;
      leaf_points += h.point_count;
    }
  }
  s.wal_bytes = wal_bytes_.load();
  s.merges = merges_.load();
  s.merged_points = merged_points_.load();
  s.checkpoints = checkpoints_.load();
  s.leaf_utilisation = leaf_blocks ? static_cast<double>(leaf_points) / (leaf_blocks * b) : 0;
  if (gaussians_) {
    const GaussianColumn::Totals t = gaussians_->totals();
    s.gaussian_segments = t.segments;
    s.gaussian_records = t.records;
    s.gaussian_bytes = t.bytes;
  }
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
  if (gaussians_) add(gaussians_->Verify());
  // Frame state files as stored (the in-memory versions may be newer: those are in the log).
  auto names = env_->ListDir(dir_ + "/frames");
  if (!names.ok()) {
    problems.push_back(names.status().ToString());
  } else {
    for (const std::string& n : *names) {
      if (!n.ends_with(".fst")) continue;
      auto data = ReadWholeFile(env_, dir_ + "/frames/" + n);
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
        if (seq != 0 && !env_->Exists(TreePath(rec->frame, seq))) {
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
      // Forests made with fan-out 2 (every build before Options::merge_fanout) hold up to
      // p*2^i in slot i, more than a wider fan-out's level of the slot: either is consistent.
      const uint64_t binary = i < 40 ? t0_cap_ << i : UINT64_MAX;
      if (h.point_count > std::max(SlotCapacity(i), binary)) {
        problems.push_back(s.tree->path() + ": " + std::to_string(h.point_count) +
                           " points exceed slot " + std::to_string(i) + "'s capacity");
      }
    }
  }
  auto logs = env_->ListDir(dir_);
  if (logs.ok()) {
    for (const std::string& n : *logs) {
      if (n == "wal.log" || (n.starts_with("wal-") && n.ends_with(".log"))) {
        auto c = ReadWal(env_, dir_ + "/" + n);
        if (!c.ok()) problems.push_back(c.status().ToString());
      }
    }
  }
  auto m = ReadWholeFile(env_, dir_ + "/MANIFEST");
  if (!m.ok()) {
    problems.push_back(m.status().ToString());
  } else if (auto d = DecodeManifest(*m, dir_ + "/MANIFEST"); !d.ok()) {
    problems.push_back(d.status().ToString());
  }
  return problems;
}

}  // namespace hvdb
