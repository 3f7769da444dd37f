// The logarithmic method (8.3.2) off the commit path: a merger thread per dataset turns a full
// buffer T0, together with the smaller trees before the first free slot, into one tree.
//
// The merger builds from a snapshot with no lock held and installs the tree as a queued writer
// (so it never races a commit); what changed in the frame meanwhile is carried over: points
// that left T0 or the merged trees become the new tree's dead ids, points that arrived stay in
// T0. A built tree is not synced: its points are still in the log, and recovery deletes tree
// files no frame state lists. Checkpoints (also run by the merger once the log is large) sync
// the trees a frame lists, then write its state; trees the old state listed are deleted after.
#include <algorithm>
#include <cstdio>

#include "storage/dataset_impl.h"
#include "storage/log.h"
#include "storage/kdtree_builder.h"

namespace hvdb {

uint64_t DatasetImpl::SlotCapacity(size_t slot) const {
  const size_t per_level = opts_.merge_fanout - 1;
  uint64_t cap = t0_cap_;
  for (size_t l = slot / per_level; l > 0 && cap < (uint64_t{1} << 62) / opts_.merge_fanout; --l) {
    cap *= opts_.merge_fanout;
  }
  return cap;
}

DatasetImpl::SlotChoice DatasetImpl::TargetSlot(const FrameVersion& v, uint64_t extra,
                                                bool keep_lower) const {
  const size_t per_level = opts_.merge_fanout - 1;
  uint64_t total = v.t0.size() + extra;
  size_t from = 0;
  while (keep_lower && total > SlotCapacity(from)) from += per_level;
  for (size_t first = from;; first += per_level) {
    // Past the last slot every slot is free.
    std::optional<size_t> free;
    for (size_t s = first; s < first + per_level && !free; ++s) {
      if (s >= v.slots.size() || !v.slots[s].tree) free = s;
    }
    if (free && total <= SlotCapacity(first)) return {*free, from, first};
    for (size_t s = first; s < first + per_level && s < v.slots.size(); ++s) {
      total += v.slots[s].live();
    }
  }
}

Status DatasetImpl::LivePoints(const FrameVersion& v, size_t from, size_t to,
                               std::vector<Point>* pts) const {
  uint64_t want = pts->size() + v.t0.size();
  for (size_t j = from; j < to && j < v.slots.size(); ++j) want += v.slots[j].live();
  pts->reserve(want);
  v.t0.ForEach([pts](const Point& p) { pts->push_back(p); });
  for (size_t j = from; j < to && j < v.slots.size(); ++j) {
    const TreeSlot& s = v.slots[j];
    if (!s.tree) continue;
    size_t at = pts->size();
    HVDB_RETURN_IF_ERROR(s.tree->ReadAll(pts));
    if (s.dead) {
      auto first = pts->begin() + static_cast<std::ptrdiff_t>(at);
      pts->erase(std::remove_if(first, pts->end(), [&s](const Point& p) { return s.IsDead(p.id); }),
                 pts->end());
    }
  }
  return Status::OK();
}

TreeBuildParams DatasetImpl::TreeParams(uint32_t frame, uint64_t seq) const {
  TreeBuildParams params;
  params.block_size = opts_.block_size;
  params.lod_levels = opts_.lod_levels;
  params.frame = frame;
  params.tree_seq = seq;
  return params;
}

Result<std::shared_ptr<KdTree>> DatasetImpl::NewTree(
    uint32_t frame, bool sync,
    const std::function<Status(const std::string& path, uint64_t seq)>& write) {
  const uint64_t seq = next_seq_++;
  const std::string path = TreePath(frame, seq);
  Status st = write(path, seq);
  if (!st.ok()) {
    (void)env_->Remove(path);
    return st;
  }
  auto opened = KdTree::Open(env_, path, pool_, /*synced=*/sync);
  if (!opened.ok()) (void)env_->Remove(path);
  return opened;
}

Result<std::shared_ptr<KdTree>> DatasetImpl::BuildMerged(const FrameVersion& v,
                                                         const SlotChoice& c,
                                                         std::vector<Point> extra, bool sync) {
  std::vector<Point> pts = std::move(extra);
  HVDB_RETURN_IF_ERROR(LivePoints(v, c.from, c.to, &pts));
  if (pts.empty()) return std::shared_ptr<KdTree>();  // everything was deleted
  return NewTree(v.frame, sync, [&](const std::string& path, uint64_t seq) {
    return BuildTreeFile(env_, path, pts, TreeParams(v.frame, seq), sync);
  });
}

void DatasetImpl::WakeMerger() {
  std::lock_guard<std::mutex> l(merge_mu_);
  merge_wake_ = true;
  merge_cv_.notify_one();
}

void DatasetImpl::MergerLoop() {
  std::unique_lock<std::mutex> l(merge_mu_);
  for (;;) {
    if (opts_.retired_grace_ms > 0 || opts_.cold_after_s > 0) {
      // Also wakes to delete replaced trees whose grace ran out, and to find idle frames.
      merge_cv_.wait_for(l, std::chrono::milliseconds(500),
                         [&] { return merge_stop_ || merge_wake_; });
      if (merge_stop_) return;
      l.unlock();
      ReleaseBuried(/*all=*/false);
      TierPass();
      l.lock();
      if (!merge_stop_ && !merge_wake_) continue;
    } else {
      merge_cv_.wait(l, [&] { return merge_stop_ || merge_wake_; });
    }
    if (merge_stop_) return;
    merge_wake_ = false;
    const bool checkpoint = checkpoint_wanted_;
    checkpoint_wanted_ = false;
    l.unlock();
    Status err;
    for (;;) {  // the fullest T0 first, until none is over capacity
      uint32_t frame = 0;
      size_t most = 0;
      {
        std::lock_guard<std::mutex> fl(mu_);
        for (const auto& [f, v] : frames_) {
          if (NeedsMerge(*v) && v->t0.size() > most) {
            most = v->t0.size();
            frame = f;
          }
        }
      }
      if (most == 0) break;
      {
        std::lock_guard<std::mutex> sl(merge_mu_);
        if (merge_stop_) break;
      }
      err = MergeOnce(frame);
      if (!err.ok()) break;
    }
    if (err.ok()) TierPass();  // thaws frames that were just written
    if (checkpoint && err.ok()) {
      WriteRequest w;
      w.kind = WriteRequest::Kind::kCheckpoint;
      err = Submit(&w).status();
    }
    l.lock();
    merge_error_ = err;
    ++merge_rounds_;
    merged_cv_.notify_all();
    if (!err.ok()) {
      LogWarning(info_.name + ": merge deferred: " + err.ToString());
      // Retry later (a full disk may be freed); commits go on into T0 up to its bound.
      merge_cv_.wait_for(l, std::chrono::seconds(1), [&] { return merge_stop_ || merge_wake_; });
      merge_wake_ = true;
      checkpoint_wanted_ = checkpoint_wanted_ || checkpoint;
    }
  }
}

Status DatasetImpl::MergeOnce(uint32_t frame) {
  auto v = Snapshot(frame);
  if (!v || !NeedsMerge(*v)) return Status::OK();
  Merge m;
  m.frame = frame;
  m.base = v;
  m.target = TargetSlot(*v, 0, /*keep_lower=*/true);
  HVDB_ASSIGN_OR_RETURN(m.tree, BuildMerged(*v, m.target, {}, /*sync=*/false));
  WriteRequest w;
  w.kind = WriteRequest::Kind::kInstall;
  w.merge = &m;
  Status st = Submit(&w).status();
  if (!st.ok() && m.tree) m.tree->MarkObsolete();
  return st;
}

Status DatasetImpl::Install(const Merge& m) {
  auto cur = Snapshot(m.frame);
  const FrameVersion& base = *m.base;
  // A bulk load may have replaced the trees since the snapshot: then the work is stale.
  const size_t slot = m.target.slot;
  bool fresh = cur != nullptr && (slot >= cur->slots.size() || !cur->slots[slot].tree);
  for (size_t j = m.target.from; fresh && j < m.target.to && j < base.slots.size(); ++j) {
    fresh = j < cur->slots.size() && cur->slots[j].tree == base.slots[j].tree;
  }
  if (!fresh) {
    if (m.tree) m.tree->MarkObsolete();
    return Status::OK();
  }
  // T0 now = the snapshot's T0 less the points removed since, then the points added since:
  // walk both in order; snapshot points not found in turn were removed (so are dead ids).
  std::vector<uint64_t> dead;
  const auto& chunks = cur->t0.chunks();
  size_t ci = 0, pi = 0, kept = 0;
  base.t0.ForEach([&](const Point& p) {
    while (ci < chunks.size() && pi >= chunks[ci]->size()) {
      ++ci;
      pi = 0;
    }
    if (ci < chunks.size() && (*chunks[ci])[pi] == p) {
      ++pi;
      ++kept;
    } else {
      dead.push_back(p.id);
    }
  });
  auto nv = std::make_shared<FrameVersion>(*cur);
  std::vector<std::shared_ptr<KdTree>> merged;
  for (size_t j = m.target.from; j < m.target.to && j < base.slots.size(); ++j) {
    const TreeSlot& was = base.slots[j];
    if (!was.tree) continue;
    // Deleted from the merged tree since the snapshot.
    if (cur->slots[j].dead) {
      std::vector<uint64_t> before = was.dead ? *was.dead : std::vector<uint64_t>{};
      std::set_difference(cur->slots[j].dead->begin(), cur->slots[j].dead->end(), before.begin(),
                          before.end(), std::back_inserter(dead));
    }
    merged.push_back(was.tree);
    nv->slots[j] = TreeSlot{};
  }
  while (nv->slots.size() <= slot) nv->slots.emplace_back();
  std::sort(dead.begin(), dead.end());
  TreeSlot out;
  out.tree = m.tree;
  if (m.tree && !dead.empty()) {
    out.dead = std::make_shared<const std::vector<uint64_t>>(std::move(dead));
  }
  nv->slots[slot] = std::move(out);
  nv->t0 = cur->t0.Suffix(kept);
  {
    std::lock_guard<std::mutex> l(mu_);
    frames_[m.frame] = nv;
  }
  dirty_.insert(m.frame);
  for (auto& t : merged) Retire(m.frame, t);
  ++merges_;
  if (m.tree) merged_points_ += m.tree->header().point_count;
  return Status::OK();
}

void DatasetImpl::Retire(uint32_t frame, const std::shared_ptr<KdTree>& tree) {
  if (tree->durable()) {
    retired_[frame].push_back(tree);  // the state on disk lists it: keep it until replaced
  } else {
    tree->MarkObsolete();  // deleted when the last reader lets go
  }
}

Status DatasetImpl::BulkLocked(uint32_t frame, std::vector<Point>* points,
                               std::shared_ptr<KdTree> prebuilt, size_t slot) {
  // Unsynced commits (Options::sync off) become durable first, so that a power loss keeps a
  // prefix of what was acknowledged.
  if (!opts_.sync) HVDB_RETURN_IF_ERROR(wal_->Sync());
  auto cur = Snapshot(frame);
  FrameVersion v;
  if (cur) v = *cur;
  v.frame = frame;
  std::shared_ptr<KdTree> tree;
  size_t i = 0;
  SlotChoice to;  // nothing merged into a prebuilt tree
  uint64_t loaded = points->size();
  if (prebuilt) {
    // Built for the empty frame: still right if nothing came into the frame meanwhile.
    const bool empty = v.t0.size() == 0 && std::none_of(v.slots.begin(), v.slots.end(),
                                                        [](const TreeSlot& t) { return t.tree != nullptr; });
    loaded = prebuilt->header().point_count;
    if (empty) {
      tree = std::move(prebuilt);
      i = slot;
    } else {
      points->clear();
      Status read = prebuilt->ReadAll(points);
      prebuilt->MarkObsolete();
      HVDB_RETURN_IF_ERROR(read);
    }
  }
  if (!tree) {
    for (Point& p : *points) {
      if (p.id == 0) p.id = next_id_++;
    }
    loaded = points->size();
    to = TargetSlot(v, points->size(), /*keep_lower=*/false);
    i = to.slot;
    HVDB_ASSIGN_OR_RETURN(tree, BuildMerged(v, to, std::move(*points), /*sync=*/true));
  }
  FrameVersion nv = v;
  std::vector<std::shared_ptr<KdTree>> merged;
  for (size_t j = to.from; j < to.to && j < nv.slots.size(); ++j) {
    if (nv.slots[j].tree) merged.push_back(nv.slots[j].tree);
    nv.slots[j] = TreeSlot{};
  }
  while (nv.slots.size() <= i) nv.slots.emplace_back();
  nv.slots[i] = TreeSlot{tree, nullptr};
  nv.t0 = PointBuffer();
  // Durable once the state listing the tree is. A bulk load is no transaction (it cannot be
  // reverted) but takes the next LSN, so that watchers can resume after it: the state's applied
  // LSN, and the log's marker for followers and watchers, which re-read the state it names.
  uint64_t lsn;
  {
    std::lock_guard<std::mutex> l(mu_);
    lsn = last_lsn_ + 1;
  }
  nv.applied_lsn = lsn;
  Status st = PersistFrame(nv);
  if (!st.ok()) {
    if (tree) tree->MarkObsolete();
    return st;
  }
  TxnRecord marker;
  marker.lsn = lsn;
  marker.bulk = true;
  marker.bulk_points = loaded;
  marker.frames.emplace_back();
  marker.frames[0].frame = frame;
  Status logged = wal_->Append({marker});
  if (logged.ok() && opts_.sync) logged = wal_->Sync();
  wal_bytes_ = wal_->size();
  std::shared_ptr<const FrameVersion> loaded_version;
  {
    std::lock_guard<std::mutex> l(mu_);
    frames_[frame] = loaded_version = std::make_shared<const FrameVersion>(std::move(nv));
    last_lsn_ = lsn;
  }
  for (auto& t : merged) Bury(t);  // the durable state no longer lists them
  NoteWrites({loaded_version});
  if (!logged.ok()) {
    // The load is durable: an error would invite a retry that loads the points twice.
    // Followers see it at their next full reload (a checkpoint, or a new writer); a watcher
    // resuming from before it does not (its LSN is missing from the log).
    LogWarning(info_.name + ": frame " + std::to_string(frame) +
               " loaded, but its log marker failed: " + logged.ToString());
  }
  Publish({EventOfRecord(info_.name, marker)});
  return Status::OK();
}

Status DatasetImpl::PersistFrame(const FrameVersion& v) {
  bool synced_any = false;
  for (const TreeSlot& s : v.slots) {
    if (s.tree && !s.tree->durable()) {
      HVDB_RETURN_IF_ERROR(s.tree->Sync());
      synced_any = true;
    }
  }
  if (synced_any) HVDB_RETURN_IF_ERROR(env_->SyncDir(dir_ + "/trees"));
  HVDB_RETURN_IF_ERROR(WriteFileAtomic(env_, dir_ + "/frames/" + FrameStateFileName(v.frame),
                                       EncodeFrameState(v, next_id_.load())));
  for (const TreeSlot& s : v.slots) {
    if (s.tree) s.tree->MarkDurable();
  }
  auto it = retired_.find(v.frame);
  if (it != retired_.end()) {
    for (auto& t : it->second) Bury(t);
    retired_.erase(it);
  }
  dirty_.erase(v.frame);
  return Status::OK();
}

Status DatasetImpl::CheckpointLocked() {
  if (!opts_.sync) HVDB_RETURN_IF_ERROR(wal_->Sync());  // a prefix survives, as in BulkLocked
  std::vector<uint32_t> dirty(dirty_.begin(), dirty_.end());
  for (uint32_t f : dirty) {
    auto v = Snapshot(f);
    if (v) HVDB_RETURN_IF_ERROR(PersistFrame(*v));
  }
  if (wal_->size() <= kWalHeaderSize) return Status::OK();
  // Keep the old segment for Revert; the frames no longer need it for recovery.
  char name[64];
  std::snprintf(name, sizeof(name), "/wal-%016llx.log",
                static_cast<unsigned long long>(wal_start_lsn_));
  std::string from = dir_ + "/wal.log", to = dir_ + name;
  HVDB_RETURN_IF_ERROR(env_->Rename(from, to));
  uint64_t start;
  {
    std::lock_guard<std::mutex> l(mu_);
    start = last_lsn_ + 1;
  }
  wal_start_lsn_ = start;
  HVDB_ASSIGN_OR_RETURN(wal_, WalWriter::Open(env_, from, start, 0, false));
  wal_bytes_ = wal_->size();
  ++checkpoints_;
  return Status::OK();
}

Status DatasetImpl::WaitForMerges() {
  // A failed merge is retried once on our behalf before its error is returned.
  uint64_t retry_after = UINT64_MAX;
  for (;;) {
    bool pending = false;
    {
      std::lock_guard<std::mutex> l(mu_);
      for (const auto& [f, v] : frames_) pending = pending || NeedsMerge(*v);
    }
    std::unique_lock<std::mutex> l(merge_mu_);
    if (!pending) return Status::OK();
    if (merge_stop_) return Status::Cancelled("dataset closing");
    if (!merge_error_.ok()) {
      if (retry_after == UINT64_MAX) {
        retry_after = merge_rounds_;
      } else if (merge_rounds_ > retry_after) {
        return merge_error_;
      }
    }
    merge_wake_ = true;
    merge_cv_.notify_one();
    merged_cv_.wait_for(l, std::chrono::milliseconds(50));
  }
}

}  // namespace hvdb
