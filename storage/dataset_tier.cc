// The cold tier: frames rewritten into one compressed tree (storage/cold_tree.h), and back.
//
// Compaction reads every live point of a frame (its trees less their dead ids, and T0), builds
// one compressed tree, durably, and installs it as a queued writer only if the frame did not
// change meanwhile: the new frame state (written before the version is published) lists that
// tree alone, with an empty T0 and the same applied LSN, so recovery needs nothing of the log
// for it. A crash before the state is durable leaves an unlisted tree file, which recovery
// deletes; the old trees are deleted only after the new state is durable.
//
// A write to a frame with a compressed tree brings it back to the hot tier: the merger replaces
// the compressed tree by a raw tree of the same points (its dead ids carry over), so edits of a
// frame being worked on pay no decoding. That swap needs only the tree to still be in its slot,
// so it is never starved by a stream of commits.
#include <algorithm>
#include <functional>

#include "storage/dataset_impl.h"
#include "storage/cold_tree.h"
#include "storage/kdtree_builder.h"
#include "storage/log.h"

namespace hvdb {

bool DatasetImpl::IsCold(const FrameVersion& v) {
  if (!v.t0.empty()) return false;
  int trees = 0;
  for (const TreeSlot& s : v.slots) {
    if (!s.tree) continue;
    if (!s.tree->compressed() || (s.dead && !s.dead->empty())) return false;
    ++trees;
  }
  return trees == 1;
}

Status DatasetImpl::CompactFrame(uint32_t frame, CompactInfo* info, bool* stale) {
  *stale = false;
  auto v = Snapshot(frame);
  if (!v || v->PointCount() == 0) return Status::OK();
  if (IsCold(*v)) {
    ++info->already;
    return Status::OK();
  }
  // One raw tree and nothing else: its blocks are transcoded as they are (no rebuild; the
  // tree, and so every level of detail, stays exactly the same).
  std::shared_ptr<KdTree> only;
  int trees = 0;
  for (const TreeSlot& s : v->slots) {
    if (!s.tree) continue;
    ++trees;
    if (!s.dead || s.dead->empty()) only = s.tree;
  }
  if (trees == 1 && only && v->t0.empty()) {
    return InstallCompacted(v, only->header().point_count, only->file_bytes(),
                            [&](const std::string& path, uint64_t seq) {
                              TreeImage image;
                              HVDB_RETURN_IF_ERROR(only->ReadImage(&image));
                              image.header.tree_seq = seq;
                              return WriteCompressedTree(env_, path, image, /*sync=*/true);
                            },
                            info, stale);
  }
  std::vector<Point> pts;
  HVDB_RETURN_IF_ERROR(LivePoints(*v, 0, v->slots.size(), &pts));
  if (pts.empty()) return Status::OK();
  // The buffer's points count as the 64-byte records they are held as (in the buffer T0 and
  // its log): a frame of buffered points only was 0 bytes "before" its compaction.
  uint64_t before = v->t0.size() * kPointRecordSize;
  for (const TreeSlot& s : v->slots) before += s.tree ? s.tree->file_bytes() : 0;
  return InstallCompacted(v, pts.size(), before,
                          [&](const std::string& path, uint64_t seq) {
                            TreeBuildParams params = TreeParams(frame, seq);
                            params.compressed = true;
                            return BuildTreeFile(env_, path, pts, params, /*sync=*/true);
                          },
                          info, stale);
}

Status DatasetImpl::InstallCompacted(
    const std::shared_ptr<const FrameVersion>& v, uint64_t n, uint64_t before,
    const std::function<Status(const std::string& path, uint64_t seq)>& write, CompactInfo* info,
    bool* stale) {
  Tiering t;
  t.frame = v->frame;
  t.compact = true;
  t.base = v;
  t.slot = TargetSlot(FrameVersion{}, n, /*keep_lower=*/false).slot;
  HVDB_ASSIGN_OR_RETURN(t.tree, NewTree(v->frame, /*sync=*/true, write));
  HVDB_RETURN_IF_ERROR(SubmitTier(t));
  *stale = t.stale;
  if (t.stale) return Status::OK();
  ++info->frames;
  info->points += n;
  info->bytes_before += before;
  info->bytes_after += t.tree->file_bytes();
  return Status::OK();
}

Status DatasetImpl::ThawFrame(uint32_t frame) {
  for (;;) {
    auto v = Snapshot(frame);
    if (!v) return Status::OK();
    size_t slot = v->slots.size();
    for (size_t i = 0; i < v->slots.size(); ++i) {
      if (v->slots[i].tree && v->slots[i].tree->compressed()) {
        slot = i;
        break;
      }
    }
    if (slot == v->slots.size()) return Status::OK();
    // Every point of the tree, dead ones included: the slot's dead ids stay as they are.
    std::vector<Point> pts;
    HVDB_RETURN_IF_ERROR(v->slots[slot].tree->ReadAll(&pts));
    Tiering t;
    t.frame = frame;
    t.compact = false;
    t.base = v;
    t.slot = slot;
    // Unsynced, as the merger's trees: the frame's state on disk lists the compressed tree
    // until the next checkpoint, and recovery deletes this file if a crash comes first.
    HVDB_ASSIGN_OR_RETURN(t.tree, NewTree(frame, /*sync=*/false,
                                          [&](const std::string& path, uint64_t seq) {
                                            return BuildTreeFile(env_, path, pts,
                                                                 TreeParams(frame, seq), false);
                                          }));
    HVDB_RETURN_IF_ERROR(SubmitTier(t));
    // Stale (a merge or bulk load moved the tree): look again.
  }
}

Status DatasetImpl::SubmitTier(const Tiering& t) {
  WriteRequest w;
  w.kind = WriteRequest::Kind::kTier;
  w.tiering = &t;
  Status st = Submit(&w).status();
  if (!st.ok() || t.stale) t.tree->MarkObsolete();
  return st;
}

Status DatasetImpl::InstallTier(const Tiering& t) {
  auto cur = Snapshot(t.frame);
  if (t.compact) {
    if (cur != t.base) {
      t.stale = true;
      return Status::OK();
    }
    FrameVersion nv;
    nv.frame = t.frame;
    nv.applied_lsn = cur->applied_lsn;
    nv.slots.resize(t.slot + 1);
    nv.slots[t.slot] = TreeSlot{t.tree, nullptr};
    HVDB_RETURN_IF_ERROR(PersistFrame(nv));
    {
      std::lock_guard<std::mutex> l(mu_);
      frames_[t.frame] = std::make_shared<const FrameVersion>(std::move(nv));
    }
    for (const TreeSlot& s : cur->slots) {
      if (s.tree) Bury(s.tree);  // the durable state no longer lists them
    }
    // For followers: re-read the frame's state (they would otherwise go on reading the old
    // trees until their next full reload). The state is durable already: a failure here
    // only delays them.
    TxnRecord marker;
    {
      std::lock_guard<std::mutex> l(mu_);
      marker.lsn = last_lsn_;
    }
    marker.tier = true;
    marker.frames.emplace_back();
    marker.frames[0].frame = t.frame;
    Status logged = wal_->Append({marker});
    if (logged.ok() && opts_.sync) logged = wal_->Sync();
    wal_bytes_ = wal_->size();
    if (!logged.ok()) {
      LogWarning(info_.name + ": frame " + std::to_string(t.frame) +
                 " compacted, but its log marker failed: " + logged.ToString());
    }
    return Status::OK();
  }
  const std::shared_ptr<KdTree>& was = t.base->slots[t.slot].tree;
  if (!cur || t.slot >= cur->slots.size() || cur->slots[t.slot].tree != was) {
    t.stale = true;
    return Status::OK();
  }
  auto nv = std::make_shared<FrameVersion>(*cur);
  nv->slots[t.slot].tree = t.tree;
  {
    std::lock_guard<std::mutex> l(mu_);
    frames_[t.frame] = nv;
  }
  dirty_.insert(t.frame);
  Retire(t.frame, was);
  return Status::OK();
}

void DatasetImpl::NoteWrites(const std::vector<std::shared_ptr<const FrameVersion>>& written) {
  const auto now = std::chrono::steady_clock::now();
  std::vector<uint32_t> thaw;
  for (const auto& v : written) {
    for (const TreeSlot& s : v->slots) {
      if (s.tree && s.tree->compressed()) {
        thaw.push_back(v->frame);
        break;
      }
    }
  }
  std::lock_guard<std::mutex> l(merge_mu_);
  for (const auto& v : written) last_write_[v->frame] = now;
  if (!thaw.empty()) {
    thaw_.insert(thaw.begin(), thaw.end());
    merge_wake_ = true;
    merge_cv_.notify_one();
  }
}

void DatasetImpl::TierPass() {
  const auto now = std::chrono::steady_clock::now();
  std::set<uint32_t> thaw;
  bool look = false;
  {
    std::lock_guard<std::mutex> l(merge_mu_);
    thaw.swap(thaw_);
    if (opts_.cold_after_s > 0 && now - last_tier_pass_ >= std::chrono::seconds(1)) {
      look = true;
      last_tier_pass_ = now;
    }
  }
  for (uint32_t f : thaw) {
    Status st = ThawFrame(f);
    if (!st.ok()) LogWarning(info_.name + ": frame " + std::to_string(f) + " stays compressed: " + st.ToString());
  }
  if (!look) return;
  const auto cutoff = now - std::chrono::seconds(opts_.cold_after_s);
  std::vector<uint32_t> idle;
  std::map<uint32_t, std::chrono::steady_clock::time_point> last_write;
  {
    std::lock_guard<std::mutex> l(merge_mu_);  // never with mu_: Submit takes them the other way
    last_write = last_write_;
  }
  {
    std::lock_guard<std::mutex> fl(mu_);
    for (const auto& [f, v] : frames_) {
      if (v->PointCount() == 0 || IsCold(*v)) continue;
      auto it = last_write.find(f);
      if ((it == last_write.end() ? opened_ : it->second) <= cutoff) idle.push_back(f);
    }
  }
  for (uint32_t f : idle) {
    {
      std::lock_guard<std::mutex> l(merge_mu_);
      if (merge_stop_) return;
    }
    CompactInfo info;
    bool stale = false;
    Status st = CompactFrame(f, &info, &stale);
    if (!st.ok()) {
      LogWarning(info_.name + ": frame " + std::to_string(f) + " not compacted: " + st.ToString());
      return;  // next pass
    }
  }
}

Status DatasetImpl::CheckCompact(uint32_t first, uint32_t last) const {
  if (first > last) {
    return Status::InvalidArgument("compact: first frame " + std::to_string(first) +
                                   " is after last frame " + std::to_string(last) +
                                   "; give first <= last");
  }
  if (follower_.load()) {
    return Status::NotLeader("dataset '" + info_.name + "' is only read here: compact it on "
                             "the process that writes it");
  }
  return Status::OK();
}

Result<CompactInfo> DatasetImpl::Compact(uint32_t first, uint32_t last) {
  HVDB_RETURN_IF_ERROR(CheckCompact(first, last));
  std::vector<uint32_t> frames;
  {
    std::lock_guard<std::mutex> l(mu_);
    for (auto it = frames_.lower_bound(first); it != frames_.end() && it->first <= last; ++it) {
      frames.push_back(it->first);
    }
  }
  CompactInfo info;
  for (uint32_t f : frames) {
    bool stale = true;
    for (int attempt = 0; attempt < 3 && stale; ++attempt) {
      HVDB_RETURN_IF_ERROR(CompactFrame(f, &info, &stale));
    }
  }
  return info;
}

}  // namespace hvdb
