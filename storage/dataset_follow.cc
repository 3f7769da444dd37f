// Followers: a process that opens a dataset another process writes (database.h). It never
// writes a file. It reads what the writer made durable the way recovery does (frame states,
// then wal.log redone over them) and then tails wal.log: each record appended since its last
// look is applied to its frames, and all records found in one look are published together, so
// a query sees whole commits only (snapshot isolation across processes). It reloads from the
// files instead when the tail does not continue where it stopped: the log was rotated by a
// checkpoint (its first LSN changed), an LSN is missing, a bulk load's state has moved on
// past its marker, or the writer changed (Database::Refresh sees a new LEADER epoch). A bulk
// load is not in the log but leaves a marker record there; the follower re-reads that frame's
// state.
//
// The writer's merges are invisible to followers until a checkpoint lists their trees: a
// follower's T0 holds what was committed since (bounded by Options::wal_checkpoint_bytes). Tree
// files a checkpoint replaces are deleted by the writer only after Options::retired_grace_ms,
// so queries on a follower's older state can finish; on POSIX an open file survives deletion
// anyway, on RADOS it does not.
#include <thread>

#include "storage/dataset_impl.h"

namespace hvdb {

Status DatasetImpl::Refresh(bool full) {
  std::lock_guard<std::mutex> fl(follow_mu_);
  if (!follower_) return Status::OK();
  if (!full) {
    followed_.clear();
    HVDB_ASSIGN_OR_RETURN(bool followed, FollowLog());
    if (followed) {
      Publish(followed_);
      followed_.clear();
      return Status::OK();
    }
  }
  uint64_t before;
  {
    std::lock_guard<std::mutex> l(mu_);
    before = last_lsn_;
  }
  HVDB_RETURN_IF_ERROR(Reload());
  uint64_t after;
  {
    std::lock_guard<std::mutex> l(mu_);
    after = last_lsn_;
  }
  // What the reload brought in, from the log (a change whose record is missing, e.g. a bulk
  // load whose marker failed, has no event).
  if (after > before && (hub_->size() > 0 || (parent_hub_ && parent_hub_->size() > 0))) {
    auto events = EventsBetween(before, after);
    if (!events.ok()) return events.status();
    Publish(*events);
  }
  return Status::OK();
}

Result<bool> DatasetImpl::FollowLog() {
  const std::string path = dir_ + "/wal.log";
  auto file = env_->OpenRead(path);
  if (!file.ok()) {
    // Between a checkpoint's rename and the new log's creation: look again next time.
    if (file.status().IsNotFound()) return true;
    return file.status();
  }
  const uint64_t size = (*file)->size();
  if (size < kWalHeaderSize) return true;  // being created
  uint8_t head[kWalHeaderSize];
  // A read that fails, or a header that is not one, raced a rotation (on RADOS the object can
  // go between its stat and its read): the reload reads the files again, and reports what is
  // really wrong with them.
  if (!(*file)->Read(0, kWalHeaderSize, head).ok()) return false;
  auto start = DecodeWalHeader(head, kWalHeaderSize, path);
  if (!start.ok() || *start != follow_start_ || size < follow_offset_) return false;
  const uint64_t from = std::max<uint64_t>(follow_offset_, kWalHeaderSize);
  if (size == from) return true;
  std::string tail(size - from, '\0');
  // A read that fails here raced a rotation: the reload reads the new files.
  if (!(*file)->Read(from, tail.size(), tail.data()).ok()) return false;
  std::vector<TxnRecord> recs;
  const size_t used = ReadWalTail(reinterpret_cast<const uint8_t*>(tail.data()), tail.size(), &recs);
  if (recs.empty()) return true;  // the next record is not whole yet

  FrameMap snap, changed;
  uint64_t last;
  {
    std::lock_guard<std::mutex> l(mu_);
    snap = frames_;
    last = last_lsn_;
  }
  auto current = [&](uint32_t f) -> std::shared_ptr<const FrameVersion> {
    if (auto it = changed.find(f); it != changed.end()) return it->second;
    if (auto it = snap.find(f); it != snap.end()) return it->second;
    return nullptr;
  };
  for (const TxnRecord& rec : recs) {
    // A gap (or a marker of another time): read the files again. Bulk-load markers take the
    // next LSN; those of older logs repeat the last one.
    if (rec.lsn != last + 1 && !((rec.bulk || rec.tier) && rec.lsn == last)) return false;
    if (rec.tier) {
      // The frame was rewritten into the other tier: the same points in other trees (the old
      // ones are deleted after the writer's grace). Taken if nothing else changed it meanwhile.
      const uint32_t f = rec.frames.at(0).frame;
      HVDB_ASSIGN_OR_RETURN(auto v, LoadFrameState(dir_ + "/frames/" + FrameStateFileName(f), snap));
      auto cur = current(f);
      if (!cur || v->applied_lsn != cur->applied_lsn) return false;  // reload
      changed[f] = std::move(v);
      continue;  // no change to publish
    }
    if (rec.bulk) {
      const uint32_t f = rec.frames.at(0).frame;
      HVDB_ASSIGN_OR_RETURN(auto v, LoadFrameState(dir_ + "/frames/" + FrameStateFileName(f), snap));
      if (v->applied_lsn != rec.lsn) return false;  // replaced again since: reload
      changed[f] = std::move(v);
    } else {
      for (const FrameEffect& step : rec.frames) {
        // Every record here is past what the frames hold (a bulk marker's state included).
        auto base = current(step.frame);
        FrameVersion empty;
        empty.frame = step.frame;
        auto applied = ApplyStep(base ? *base : empty, step, rec.lsn);
        if (!applied.ok()) {
          return Status::Corruption(path + ": following record " + std::to_string(rec.lsn) +
                                    " failed: " + applied.status().message());
        }
        changed[step.frame] = std::move(applied).value();
      }
    }
    last = rec.lsn;
    followed_.push_back(EventOfRecord(info_.name, rec));
  }
  {
    std::lock_guard<std::mutex> l(mu_);
    for (auto& [f, v] : changed) frames_[f] = std::move(v);
    last_lsn_ = last;
  }
  follow_offset_ = from + used;
  wal_bytes_ = follow_offset_;
  return true;
}

Status DatasetImpl::Reload() {
  FrameMap snap;
  {
    std::lock_guard<std::mutex> l(mu_);
    snap = frames_;
  }
  const std::string path = dir_ + "/wal.log";
  // States and log must belong together: a checkpoint that rotates the log between reading
  // the states and reading the log shows as a different first LSN, and the load is repeated.
  // (A checkpoint in progress is harmless: every state records the last LSN it includes.)
  for (int attempt = 0;; ++attempt) {
    uint64_t start_before = 0;
    if (auto f = env_->OpenRead(path); f.ok() && (*f)->size() >= kWalHeaderSize) {
      uint8_t head[kWalHeaderSize];
      if ((*f)->Read(0, kWalHeaderSize, head).ok()) {
        auto s = DecodeWalHeader(head, kWalHeaderSize, path);
        if (s.ok()) start_before = *s;
      }
    }
    Loaded l;
    Status st = Load(/*writer=*/false, snap, &l);
    if (st.ok() && l.wal_exists && l.wal_start == start_before) {
      return Start(std::move(l), /*writer=*/false);
    }
    if (attempt == 4) {
      return st.ok() ? Status::IOError(dir_ + ": the writer rotated its log during five reloads "
                                              "in a row; try again")
                     : st;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20 << attempt));
  }
}

Status DatasetImpl::Promote() {
  std::lock_guard<std::mutex> fl(follow_mu_);
  if (!follower_) return Status::OK();
  FrameMap snap;
  {
    std::lock_guard<std::mutex> l(mu_);
    snap = frames_;
  }
  Loaded l;
  HVDB_RETURN_IF_ERROR(Load(/*writer=*/true, snap, &l));
  HVDB_RETURN_IF_ERROR(Start(std::move(l), /*writer=*/true));
  follower_ = false;
  StartMerger();
  return Status::OK();
}

void DatasetImpl::Bury(const std::shared_ptr<KdTree>& tree) {
  tree->MarkObsolete();  // its file goes when the last reference does
  if (opts_.retired_grace_ms == 0) return;
  std::lock_guard<std::mutex> l(grave_mu_);
  graves_.emplace_back(std::chrono::steady_clock::now() +
                           std::chrono::milliseconds(opts_.retired_grace_ms),
                       tree);
}

void DatasetImpl::ReleaseBuried(bool all) {
  std::vector<std::shared_ptr<KdTree>> due;  // dropped outside the lock: deleting is I/O
  {
    std::lock_guard<std::mutex> l(grave_mu_);
    const auto now = std::chrono::steady_clock::now();
    while (!graves_.empty() && (all || graves_.front().first <= now)) {
      due.push_back(std::move(graves_.front().second));
      graves_.pop_front();
    }
  }
}

}  // namespace hvdb
