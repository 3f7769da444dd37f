// The write path: commits and reverts resolved against the published versions, logged with
// one write and one fsync per group, published; bulk loads and checkpoints led alone.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <unordered_map>
#include <unordered_set>

#include "storage/affine.h"
#include "storage/coding.h"
#include "storage/dataset_impl.h"
#include "storage/frame_apply.h"
#include "storage/lod.h"

namespace hvdb {

namespace {

constexpr uint32_t kMaxFrame = kMaxFrames;

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

// The ids a selection names in one frame, tested once for every record of the frame: a bitmap
// over their range when they are that dense (ids are given out in sequence, so a frame's are
// mostly one run), else a sorted array. A hash set cost ~40 ns a record, most of a graph cut's
// commit of 0.37 M relabels over a 1.2 M-point region.
class IdSet {
 public:
  explicit IdSet(std::vector<uint64_t> ids) : ids_(std::move(ids)) {
    std::sort(ids_.begin(), ids_.end());
    ids_.erase(std::unique(ids_.begin(), ids_.end()), ids_.end());
    if (ids_.empty()) return;
    lo_ = ids_.front();
    const uint64_t words = (ids_.back() - lo_) / 64 + 1;  // no overflow: any ids a client sends
    if (words <= ids_.size() + 1024) {
      bits_.assign(words, 0);
      for (uint64_t id : ids_) bits_[(id - lo_) >> 6] |= uint64_t{1} << ((id - lo_) & 63);
    }
  }
  size_t size() const { return ids_.size(); }
  bool count(uint64_t id) const {
    if (!bits_.empty()) {
      const uint64_t off = id - lo_;  // wraps for ids below lo_: then out of range
      return (off >> 6) < bits_.size() && ((bits_[off >> 6] >> (off & 63)) & 1);
    }
    return std::binary_search(ids_.begin(), ids_.end(), id);
  }

 private:
  std::vector<uint64_t> ids_;
  uint64_t lo_ = 0;
  std::vector<uint64_t> bits_;
};

// Calls fn(point, where) for every live point of `v` in the region (nullptr: all),
// label-filtered; `where` is -1 for T0, else the point's tree slot. With `ids`, only points of
// those ids (checked before a record is decoded).
Status ScanVersion(const FrameVersion& v, const RegionPlan* plan, uint32_t label_mask,
                   const std::function<void(const Point&, int32_t)>& fn,
                   const IdSet* ids = nullptr) {
  auto accept = [&](const Point& p) {
    if (label_mask != 0 && (p.label & label_mask) == 0) return false;
    if (ids != nullptr && !ids->count(p.id)) return false;
    return plan == nullptr || plan->Contains(p);
  };
  v.t0.ForEach([&](const Point& p) {
    if (accept(p)) fn(p, -1);
  });
  for (size_t s = 0; s < v.slots.size(); ++s) {
    const TreeSlot& slot = v.slots[s];
    if (!slot.tree) continue;
    BoxTest test = [&](const Box3& b) {
      return plan == nullptr ? Relation::kInside : plan->Classify(b, v.frame);
    };
    std::vector<KdTree::BucketHit> hits;
    HVDB_RETURN_IF_ERROR(slot.tree->FindBuckets(test, &hits, label_mask));
    HVDB_RETURN_IF_ERROR(ReadHits(*slot.tree, hits, [&](const KdTree::BucketHit& hit,
                                                        const uint8_t* rec, size_t n) {
      for (size_t j = 0; j < n; ++j) {
        const uint8_t* r = rec + j * kPointRecordSize;
        if (ids != nullptr && !ids->count(DecodeLE<uint64_t>(r))) continue;
        Point p = DecodePoint(r);
        if (slot.IsDead(p.id)) continue;
        if (label_mask != 0 && (p.label & label_mask) == 0) continue;
        if (!hit.inside && plan != nullptr && !plan->Contains(p)) continue;
        fn(p, static_cast<int32_t>(s));
      }
    }));
  }
  return Status::OK();
}

}  // namespace

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
  return BulkLoadThen(frame, std::move(points), nullptr);
}

Result<uint64_t> DatasetImpl::BulkLoadThen(uint32_t frame, std::vector<Point> points,
                                           const std::function<Status()>& before_install) {
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
  w.bulk_count = points.size();
  // Into a frame that holds nothing yet (ingest fills new frames) the tree is built here,
  // before the writer queue, so that loads of different frames build their trees at once on
  // their callers' threads; the queue only installs it (BulkLocked). The ids go into the tree,
  // so they are taken first.
  auto cur = Snapshot(frame);
  const bool empty = cur == nullptr || (cur->t0.size() == 0 &&
                                        std::none_of(cur->slots.begin(), cur->slots.end(),
                                                     [](const TreeSlot& t) { return t.tree != nullptr; }));
  if (empty && !follower_.load() && !points.empty()) {
    const uint64_t fresh = static_cast<uint64_t>(
        std::count_if(points.begin(), points.end(), [](const Point& p) { return p.id == 0; }));
    uint64_t id = next_id_.fetch_add(fresh);
    for (Point& p : points)
      if (p.id == 0) p.id = id++;
    FrameVersion none;
    none.frame = frame;
    const SlotChoice to = TargetSlot(none, points.size(), /*keep_lower=*/false);
    w.prebuilt_slot = to.slot;
    HVDB_ASSIGN_OR_RETURN(w.prebuilt, BuildMerged(none, to, std::move(points), /*sync=*/true));
    points.clear();
  }
  if (before_install) {
    Status ready = before_install();
    if (!ready.ok()) {
      if (w.prebuilt) w.prebuilt->MarkObsolete();
      return ready;
    }
  }
  auto submitted = Submit(&w);
  if (!submitted.ok() && w.prebuilt) w.prebuilt->MarkObsolete();
  HVDB_RETURN_IF_ERROR(submitted.status());
  return submitted->inserted;
}

Status DatasetImpl::Checkpoint() {
  WriteRequest w;
  w.kind = WriteRequest::Kind::kCheckpoint;
  return Submit(&w).status();
}

Result<CommitInfo> DatasetImpl::Submit(WriteRequest* w) {
  using Kind = WriteRequest::Kind;
  if (follower_.load()) {
    return Status::NotLeader("dataset '" + info_.name + "' is only read here: another process "
                             "holds its data directory and is the one that writes it");
  }
  if ((w->kind == Kind::kTxn || w->kind == Kind::kRevert) && backlog_.load()) {
    // Back-pressure: while some T0 holds 8x its capacity the merger is behind; wait for it
    // rather than let memory grow without bound. A merger that keeps failing fails the commit.
    std::unique_lock<std::mutex> ml(merge_mu_);
    for (;;) {
      bool over = false;
      {
        std::lock_guard<std::mutex> l(mu_);
        for (const auto& [f, v] : frames_) {
          if (Backlogged(*v)) {
            over = true;
            break;
          }
        }
      }
      if (!over) backlog_ = false;
      if (!over || merge_stop_) break;
      if (!merge_error_.ok()) {
        return Status::IOError("commit refused: the buffers are full and merging them fails (" +
                               merge_error_.ToString() + "); free disk space and retry");
      }
      merge_wake_ = true;
      merge_cv_.notify_one();
      merged_cv_.wait_for(ml, std::chrono::milliseconds(100));
    }
  }
  std::unique_lock<std::mutex> l(write_mu_);
  writers_.push_back(w);
  write_cv_.wait(l, [&] { return w->done || writers_.front() == w; });
  if (w->done) {
    if (!w->status.ok()) return w->status;
    return w->info;
  }
  // Leader: take every transaction queued now (the other kinds go alone).
  std::vector<WriteRequest*> group{w};
  if (w->kind == Kind::kTxn || w->kind == Kind::kRevert) {
    for (size_t i = 1; i < writers_.size(); ++i) {
      auto k = writers_[i]->kind;
      if (k != Kind::kTxn && k != Kind::kRevert) break;
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
  std::map<uint32_t, std::vector<int32_t>> where;  // FrameEffect::found_in of each point
};

}  // namespace

Status DatasetImpl::Resolve(const Transaction& txn, Working* ws, TxnRecord* rec,
                            CommitInfo* info, std::vector<uint64_t>* segments) {
  auto apply = [&](FrameEffect&& step) -> Status {
    auto base = ws->Get(step.frame);
    FrameVersion empty;
    empty.frame = step.frame;
    HVDB_ASSIGN_OR_RETURN(auto v, ApplyStep(base ? *base : empty, step, rec->lsn));
    ws->Set(step.frame, std::move(v));
    rec->frames.push_back(std::move(step));
    return Status::OK();
  };
  auto select = [&](const Selection& sel) -> Result<Selected> {
    Selected out;
    // (frame, id) pairs taken, hashed: a selection can hold a whole frame (tens of thousands
    // of points), and an ordered set took a quarter of the CPU samples of a 52 k-point relabel.
    struct PairHash {
      size_t operator()(const std::pair<uint32_t, uint64_t>& k) const {
        return std::hash<uint64_t>()(k.second * 0x9E3779B97F4A7C15ull ^ k.first);
      }
    };
    std::unordered_set<std::pair<uint32_t, uint64_t>, PairHash> seen;
    // Only a region and ids together can meet a point twice: a scan meets each live point
    // once (it is in T0 or in one tree), and `wanted` holds each id once.
    const bool dedup = sel.region.has_value() && !sel.ids.empty();
    if (dedup) seen.reserve(sel.ids.size() + 1024);
    auto add = [&](const Point& p, int32_t where) {
      if (!dedup || seen.insert({p.frame, p.id}).second) {
        out.by_frame[p.frame].push_back(p);
        out.where[p.frame].push_back(where);
      }
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
    std::map<uint32_t, std::vector<uint64_t>> wanted;
    for (auto [f, id] : sel.ids) wanted[f].push_back(id);
    for (auto& entry : wanted) {
      const uint32_t f = entry.first;  // (clang 14: no lambda capture of structured bindings)
      const IdSet ids(std::move(entry.second));
      auto v = ws->Get(f);
      if (!v) return Status::NotFound("frame " + std::to_string(f) + " has no points");
      out.by_frame[f].reserve(out.by_frame[f].size() + ids.size());
      out.where[f].reserve(out.where[f].size() + ids.size());
      size_t found = 0;
      HVDB_RETURN_IF_ERROR(ScanVersion(*v, nullptr, sel.label_mask, [&](const Point& p, int32_t w) {
        add(p, w);
        ++found;
      }, &ids));
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
      FrameEffect* last = nullptr;  // runs of one frame skip the map lookup
      uint64_t recorded = 0;  // first id of the points' Gaussian records, 0: none
      if (gaussians_ && ins->gaussians && !ins->points.empty()) {
        HVDB_ASSIGN_OR_RETURN(recorded, WriteInsertedGaussians(ins->points, *ins->gaussians,
                                                               segments));
      }
      for (size_t i = 0; i < ins->points.size(); ++i) {
        Point p = ins->points[i];
        HVDB_RETURN_IF_ERROR(ValidatePoint(p));
        if (recorded != 0) {
          p.id = recorded + i;
          p.cov = GaussianCovariance(ins->gaussians->record(i));
          p.flags |= kFlagHasCovariance;
          info->assigned_ids.push_back(p.id);
        } else if (p.id == 0) {
          p.id = next_id_++;
          info->assigned_ids.push_back(p.id);
        }
        if (last == nullptr || last->frame != p.frame) {
          last = &steps[p.frame];
          last->frame = p.frame;
        }
        last->added.push_back(p);
      }
      for (auto& [f, step] : steps) {
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(std::move(step)));
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
      HVDB_RETURN_IF_ERROR(apply(std::move(step)));
    } else if (const auto* ds = std::get_if<Transaction::DeleteSelOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(ds->sel));
      for (auto& [f, pts] : sel.by_frame) {
        FrameEffect step;
        step.frame = f;
        step.removed = std::move(pts);
        step.found_in = std::move(sel.where[f]);
        info->removed += step.removed.size();
        HVDB_RETURN_IF_ERROR(apply(std::move(step)));
      }
    } else if (const auto* lab = std::get_if<Transaction::LabelOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(lab->sel));
      for (auto& [f, pts] : sel.by_frame) {
        const std::vector<int32_t>& where = sel.where[f];
        FrameEffect step;
        step.frame = f;
        step.removed.reserve(pts.size());
        step.added.reserve(pts.size());
        step.found_in.reserve(pts.size());
        // The log keeps the ids in groups by the bits that flip (one group for a whole
        // selection, as a rule); the points before and after are applied here.
        std::map<std::pair<uint32_t, uint32_t>, std::vector<uint64_t>> groups;
        for (size_t i = 0; i < pts.size(); ++i) {
          const Point& p = pts[i];
          Point q = p;
          q.label = lab->set ? (p.label | lab->bits) : (p.label & ~lab->bits);
          if (q.label == p.label) continue;
          step.removed.push_back(p);
          step.added.push_back(q);
          step.found_in.push_back(where[i]);
          const uint32_t flip = p.label ^ q.label;
          groups[{flip, q.label & flip}].push_back(p.id);
        }
        if (step.removed.empty()) continue;
        for (auto& [key, ids] : groups) {
          std::sort(ids.begin(), ids.end());
          if (std::adjacent_find(ids.begin(), ids.end()) != ids.end()) {
            step.relabels.clear();  // one id twice in a frame: logged as whole points
            break;
          }
          step.relabels.push_back(Relabel{key.first, key.second, std::move(ids)});
        }
        info->removed += step.removed.size();
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(std::move(step)));
      }
    } else if (const auto* tr = std::get_if<Transaction::TransformOp>(&op)) {
      HVDB_ASSIGN_OR_RETURN(AffineMap map, AffineMap::Make(tr->map, info_.fps));
      HVDB_ASSIGN_OR_RETURN(Selected sel, select(tr->sel));
      std::vector<Point> selected, moved;
      for (auto& [f, pts] : sel.by_frame) {
        for (const Point& p : pts) {
          HVDB_ASSIGN_OR_RETURN(Point q, map.Apply(p));
          HVDB_RETURN_IF_ERROR(ValidatePoint(q));
          selected.push_back(p);
          moved.push_back(q);
        }
      }
      const std::array<double, 9> linear = {tr->map.a[0], tr->map.a[1], tr->map.a[2],
                                            tr->map.a[4], tr->map.a[5], tr->map.a[6],
                                            tr->map.a[8], tr->map.a[9], tr->map.a[10]};
      if (gaussians_ && !GaussianRecordMap(linear).identity() && !selected.empty()) {
        HVDB_RETURN_IF_ERROR(TurnGaussians(linear, selected, moved, segments));
      }
      std::map<uint32_t, FrameEffect> removes, adds;
      size_t i = 0;
      for (auto& [f, pts] : sel.by_frame) {
        for (size_t j = 0; j < pts.size(); ++j, ++i) {
          const Point& p = selected[i];
          const Point& q = moved[i];
          removes[p.frame].frame = p.frame;
          removes[p.frame].removed.push_back(p);
          removes[p.frame].found_in.push_back(sel.where[f][j]);
          adds[q.frame].frame = q.frame;
          adds[q.frame].added.push_back(q);
        }
      }
      for (auto& [f, step] : removes) {
        info->removed += step.removed.size();
        HVDB_RETURN_IF_ERROR(apply(std::move(step)));
      }
      for (auto& [f, step] : adds) {
        info->inserted += step.added.size();
        HVDB_RETURN_IF_ERROR(apply(std::move(step)));
      }
    }
  }
  return Status::OK();
}

Result<TxnRecord> DatasetImpl::FindRecord(uint64_t lsn) const {
  HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(dir_));
  std::vector<std::string> logs;
  for (const std::string& n : names) {
    if (n == "wal.log" || (n.starts_with("wal-") && n.ends_with(".log"))) logs.push_back(n);
  }
  for (const std::string& n : logs) {
    HVDB_ASSIGN_OR_RETURN(WalContents c, ReadWal(env_, dir_ + "/" + n));
    for (TxnRecord& r : c.records) {
      if (r.lsn == lsn && !r.bulk && !r.tier) return std::move(r);
    }
  }
  return Status::NotFound("transaction " + std::to_string(lsn) +
                          " is not in the log (bulk loads are not transactions and cannot be "
                          "reverted)");
}

void DatasetImpl::LeadGroup(std::vector<WriteRequest*>& group) {
  using Kind = WriteRequest::Kind;
  WriteRequest* first = group.front();
  switch (first->kind) {
    case Kind::kCheckpoint: first->status = CheckpointLocked(); return;
    case Kind::kInstall: first->status = Install(*first->merge); return;
    case Kind::kTier: first->status = InstallTier(*first->tiering); return;
    case Kind::kBulk:
      first->info.inserted = first->bulk_count;
      first->status = BulkLocked(first->frame, first->points, std::move(first->prebuilt),
                                 first->prebuilt_slot);
      return;
    default: LeadCommits(group);
  }
}

void DatasetImpl::LeadCommits(std::vector<WriteRequest*>& group) {
  using Kind = WriteRequest::Kind;
  FrameMap base;
  {
    std::lock_guard<std::mutex> l(mu_);
    base = frames_;
  }
  Working ws(base);
  std::vector<TxnRecord> records;
  std::vector<WriteRequest*> committed;
  uint64_t lsn = last_lsn_;
  // Gaussian segments the group's transforms wrote: removed unless their records are logged.
  std::vector<uint64_t> group_segments;
  auto RemoveSegments = [&](std::vector<uint64_t>& firsts) {
    for (uint64_t first : firsts) (void)gaussians_->Remove(first);
    firsts.clear();
  };
  for (WriteRequest* w : group) {
    std::vector<uint64_t> segments;
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
          FrameEffect inv = InverseEffect(*it);
          auto basev = attempt.Get(inv.frame);
          FrameVersion empty;
          empty.frame = inv.frame;
          if (!inv.relabels.empty()) {
            st = ResolveRelabels(basev ? *basev : empty, &inv);
            if (!st.ok()) {
              st = Status::InvalidArgument("cannot revert transaction " +
                                           std::to_string(w->revert_lsn) + ": " + st.message() +
                                           "; revert the later one first");
              break;
            }
          }
          auto applied = ApplyStep(basev ? *basev : empty, inv, rec.lsn, /*exact=*/true);
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
      st = Resolve(*w->txn, &attempt, &rec, &info, &segments);
    }
    if (!st.ok()) {
      RemoveSegments(segments);
      w->status = st;
      continue;
    }
    if (rec.frames.empty() && w->kind == Kind::kTxn && w->txn->empty()) {
      RemoveSegments(segments);
      w->status = Status::InvalidArgument("empty transaction");
      continue;
    }
    group_segments.insert(group_segments.end(), segments.begin(), segments.end());
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
  Status st = wal_->Append(records);
  if (st.ok() && opts_.sync) st = wal_->Sync();
  if (!st.ok()) {
    // Nothing of the group may survive: cut the log back to where it was.
    RemoveSegments(group_segments);
    auto reopened = WalWriter::Open(env_, dir_ + "/wal.log", wal_start_lsn_, before, true);
    if (reopened.ok()) wal_ = std::move(reopened).value();
    for (WriteRequest* w : committed) {
      w->status = st;
      w->info = {};
    }
    return;
  }
  wal_bytes_ = wal_->size();
  bool merge = wal_->size() > opts_.wal_checkpoint_bytes;
  {
    std::lock_guard<std::mutex> l(mu_);
    for (uint32_t f : ws.changed()) {
      frames_[f] = ws.Get(f);
      merge = merge || NeedsMerge(*frames_[f]);
      if (Backlogged(*frames_[f])) backlog_ = true;  // the next commits wait
    }
    last_lsn_ = lsn;
  }
  std::vector<ChangeEvent> events;
  events.reserve(records.size());
  for (const TxnRecord& r : records) events.push_back(EventOfRecord(info_.name, r));
  Publish(events);
  for (uint32_t f : ws.changed()) dirty_.insert(f);
  {
    std::vector<std::shared_ptr<const FrameVersion>> written;
    for (uint32_t f : ws.changed()) written.push_back(ws.Get(f));
    NoteWrites(written);
  }
  // Trees are the merger's work (logarithmic method), and so are checkpoints: a commit is
  // durable now, with its points in T0 and its record in the log.
  if (merge) {
    std::lock_guard<std::mutex> l(merge_mu_);
    checkpoint_wanted_ = checkpoint_wanted_ || wal_->size() > opts_.wal_checkpoint_bytes;
    merge_wake_ = true;
    merge_cv_.notify_one();
  }
}

}  // namespace hvdb
