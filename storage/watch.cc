#include "storage/watch.h"

#include <algorithm>

#include "storage/wal.h"

namespace hvdb {

const char* ChangeKindName(ChangeEvent::Kind kind) {
  switch (kind) {
    case ChangeEvent::Kind::kCommit: return "commit";
    case ChangeEvent::Kind::kRevert: return "revert";
    case ChangeEvent::Kind::kBulk: return "bulk";
    case ChangeEvent::Kind::kDropped: return "dropped";
    case ChangeEvent::Kind::kLive: return "live";
    case ChangeEvent::Kind::kLagged: return "lagged";
  }
  return "unknown";
}

ChangeEvent EventOfRecord(const std::string& dataset, const TxnRecord& rec) {
  ChangeEvent ev;
  ev.dataset = dataset;
  ev.lsn = rec.lsn;
  ev.kind = rec.bulk ? ChangeEvent::Kind::kBulk
                     : rec.reverts ? ChangeEvent::Kind::kRevert : ChangeEvent::Kind::kCommit;
  ev.reverts = rec.reverts;
  ev.labels_only = !rec.bulk && !rec.frames.empty();
  for (const FrameEffect& f : rec.frames) {
    ev.labels_only = ev.labels_only && !f.relabels.empty();
    for (const Relabel& r : f.relabels) ev.label_bits |= r.flip;
    ev.frames.push_back(f.frame);
    ev.points += EffectAdded(f);
    ev.removed += EffectRemoved(f);
  }
  if (rec.bulk) ev.points = rec.bulk_points;
  std::sort(ev.frames.begin(), ev.frames.end());
  ev.frames.erase(std::unique(ev.frames.begin(), ev.frames.end()), ev.frames.end());
  return ev;
}

std::unique_ptr<WatchHub::Subscription> WatchHub::Subscribe(ChangeFn fn, bool hold) {
  auto e = std::make_shared<Entry>();
  e->fn = std::move(fn);
  e->hold = hold;
  std::lock_guard<std::mutex> l(mu_);
  subs_.push_back(e);
  return std::make_unique<Subscription>(shared_from_this(), std::move(e));
}

// A subscriber still replaying holds the event for Go(); a live one gets it now.
void WatchHub::Deliver(Entry& e, const ChangeEvent& ev) {
  if (e.hold) {
    e.held.push_back(ev);
  } else {
    e.fn(ev);
  }
}

void WatchHub::Publish(const ChangeEvent& ev) {
  std::lock_guard<std::mutex> l(mu_);
  for (const auto& e : subs_) Deliver(*e, ev);
}

void WatchHub::EndAll(const ChangeEvent& last) {
  std::lock_guard<std::mutex> l(mu_);
  for (const auto& e : subs_) {
    Deliver(*e, last);  // after what a replaying subscriber held: the end comes last
    e->ended = true;
  }
  std::erase_if(subs_, [](const auto& e) { return !e->hold; });  // Go() ends the others
}

size_t WatchHub::size() const {
  std::lock_guard<std::mutex> l(mu_);
  return subs_.size();
}

WatchHub::Subscription::~Subscription() {
  std::lock_guard<std::mutex> l(hub_->mu_);
  std::erase(hub_->subs_, e_);
}

void WatchHub::Subscription::Go(uint64_t after, const std::string& dataset) {
  std::lock_guard<std::mutex> l(hub_->mu_);
  if (!e_->hold) return;
  ChangeEvent live;
  live.kind = ChangeEvent::Kind::kLive;
  live.dataset = dataset;
  live.lsn = after;
  e_->fn(live);
  for (const ChangeEvent& ev : e_->held) {
    if (ev.kind == ChangeEvent::Kind::kDropped || ev.lsn > after) e_->fn(ev);
  }
  e_->held.clear();
  e_->hold = false;
  if (e_->ended) std::erase(hub_->subs_, e_);
}

bool WatchHub::Subscription::ended() const {
  std::lock_guard<std::mutex> l(hub_->mu_);
  return e_->ended;
}

}  // namespace hvdb
