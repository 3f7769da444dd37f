// Watches of one dataset (storage/watch.h): live events come from the writer's commit path
// (dataset_write.cc, dataset_merge.cc) or a follower's Refresh (dataset_follow.cc); a watch
// that resumes from an LSN reads the changes since from the log segments first.
#include <algorithm>
#include <cstdlib>

#include "storage/dataset_impl.h"

namespace hvdb {

void DatasetImpl::Publish(const std::vector<ChangeEvent>& events) {
  for (const ChangeEvent& ev : events) {
    hub_->Publish(ev);
    if (parent_hub_) parent_hub_->Publish(ev);
  }
}

void DatasetImpl::EndWatches() {
  ChangeEvent end;
  end.kind = ChangeEvent::Kind::kDropped;
  end.dataset = info_.name;
  {
    std::lock_guard<std::mutex> l(mu_);
    end.lsn = last_lsn_;
  }
  hub_->EndAll(end);
  if (parent_hub_) parent_hub_->Publish(end);
}

Result<std::unique_ptr<WatchHandle>> DatasetImpl::Watch(std::optional<uint64_t> from_lsn, ChangeFn fn) {
  // Subscribed first, holding what is published: every change past `upto` reaches it, every
  // one up to `upto` is in the log (a change is logged before it is published).
  auto sub = hub_->Subscribe(fn, /*hold=*/true);
  uint64_t upto;
  {
    std::lock_guard<std::mutex> l(mu_);
    upto = last_lsn_;
  }
  const uint64_t after = from_lsn.value_or(upto);
  if (after > upto) {
    return Status::InvalidArgument(
        "from_lsn " + std::to_string(after) + " is past dataset '" + info_.name +
        "''s last LSN " + std::to_string(upto) + " (resume from an LSN it has given)");
  }
  if (after < upto) {
    HVDB_ASSIGN_OR_RETURN(std::vector<ChangeEvent> past, EventsBetween(after, upto));
    for (ChangeEvent& ev : past) {
      ev.replayed = true;
      fn(ev);
    }
  }
  sub->Go(upto, info_.name);
  return sub;
}

Result<std::vector<ChangeEvent>> DatasetImpl::EventsBetween(uint64_t after, uint64_t upto) const {
  // A checkpoint may rotate wal.log between the listing and the reads: list again.
  for (int attempt = 0;; ++attempt) {
    HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(dir_));
    // Segments by first LSN: archived ones are named by it, wal.log's header holds it.
    std::vector<std::pair<uint64_t, std::string>> segs;
    for (const std::string& n : names) {
      if (n.size() == 24 && n.starts_with("wal-") && n.ends_with(".log")) {
        segs.emplace_back(std::strtoull(n.substr(4, 16).c_str(), nullptr, 16), n);
      } else if (n == "wal.log") {
        segs.emplace_back(UINT64_MAX, n);  // the newest; read it last
      }
    }
    std::sort(segs.begin(), segs.end());
    std::vector<ChangeEvent> out;
    bool raced = false;
    for (size_t i = 0; i < segs.size() && !raced; ++i) {
      // A segment ends where the next begins: skip those wholly at or before `after`.
      if (i + 1 < segs.size() && segs[i + 1].first != UINT64_MAX &&
          segs[i + 1].first <= after + 1) {
        continue;
      }
      auto c = ReadWal(env_, dir_ + "/" + segs[i].second);
      if (!c.ok()) {
        if (c.status().IsNotFound()) {
          raced = true;
          break;
        }
        return c.status();
      }
      for (const TxnRecord& r : c->records) {
        if (r.lsn > after && r.lsn <= upto && !r.tier) out.push_back(EventOfRecord(info_.name, r));
      }
    }
    // Markers of older logs repeat an LSN: keep the log's order, which is LSN order.
    std::stable_sort(out.begin(), out.end(),
                     [](const ChangeEvent& a, const ChangeEvent& b) { return a.lsn < b.lsn; });
    // LSNs are dense, so a gap means a checkpoint renamed wal.log after the listing and the
    // name now holds the next segment: list again.
    uint64_t next = after + 1;
    for (const ChangeEvent& ev : out) {
      if (ev.lsn > next) break;
      next = std::max(next, ev.lsn + 1);
    }
    if (!raced && next > upto) return out;
    if (attempt == 4) {
      if (raced) {
        return Status::IOError(dir_ + ": the log was rotated during five reads in a row; try again");
      }
      return Status::NotFound(dir_ + ": the log no longer holds the changes from LSN " +
                              std::to_string(next) + " (resume from a later LSN)");
    }
  }
}

}  // namespace hvdb
