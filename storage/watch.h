// Watches: a dataset's changes as they are published (Dataset::Watch), in LSN order, replayed
// from the log first when a watcher resumes from an LSN. The writer publishes each commit,
// revert and bulk load once it is durable; a follower publishes the writer's as it reads them.
#ifndef HVDB_STORAGE_WATCH_H_
#define HVDB_STORAGE_WATCH_H_

#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

namespace hvdb {

struct TxnRecord;

// One published change. Names of kinds (ChangeKindName) are the wire's and the CLI's.
struct ChangeEvent {
  enum class Kind : uint8_t {
    kCommit = 0,   // a transaction (Dataset::Commit)
    kRevert = 1,   // a transaction that undid transaction `reverts`
    kBulk = 2,     // a bulk load of frames[0]
    kDropped = 3,  // the dataset was dropped: the watch ends
    kLive = 4,     // a watch's replay is over: lsn is the last it covered; live events follow
    // Never published: a consumer's queue (a server connection's, Python's) overflowed and
    // the watch ended; resume from lsn.
    kLagged = 5,
  };
  Kind kind = Kind::kCommit;
  std::string dataset;
  uint64_t lsn = 0;
  std::vector<uint32_t> frames;  // touched, ascending
  uint64_t points = 0;           // points added
  uint64_t removed = 0;          // points removed
  uint64_t reverts = 0;          // kRevert: the transaction undone
  // A commit or revert that only flipped label bits (every step a relabel): no point was added,
  // removed or moved, so what depends on the points but not on their labels (a graph cut's
  // graph) still holds. label_bits: the bits it flipped (of relabel steps; 0 otherwise).
  bool labels_only = false;
  uint32_t label_bits = 0;
  // Read from the log by a watch that resumed from an LSN, on the thread that asked for the
  // watch and outside every lock: the only events a subscriber may wait on (to pace a replay).
  bool replayed = false;
};
const char* ChangeKindName(ChangeEvent::Kind kind);
// The event of a log record (a transaction, a revert, or a bulk-load marker).
ChangeEvent EventOfRecord(const std::string& dataset, const TxnRecord& rec);

using ChangeFn = std::function<void(const ChangeEvent&)>;

// Subscribers of one dataset (or of a whole database). Publish calls each subscriber's function
// under the hub's lock, so that every subscriber sees events one at a time and in order, and
// none is called after its Watch is destroyed: a function must be quick (hand the event to a
// queue or another thread) and must not subscribe or unsubscribe.
class WatchHub : public std::enable_shared_from_this<WatchHub> {
 public:
  class Subscription;
  // A subscriber that holds what is published until Go(): a watch replaying the log first.
  std::unique_ptr<Subscription> Subscribe(ChangeFn fn, bool hold);
  void Publish(const ChangeEvent& ev);
  // Sends `last` (a kDropped event) to every subscriber and forgets them all.
  void EndAll(const ChangeEvent& last);
  size_t size() const;

 private:
  struct Entry {
    ChangeFn fn;
    bool hold = false;
    std::deque<ChangeEvent> held;
    bool ended = false;
  };
  static void Deliver(Entry& e, const ChangeEvent& ev);  // under mu_
  mutable std::mutex mu_;
  std::vector<std::shared_ptr<Entry>> subs_;
  friend class Subscription;
};

// A live subscription: destroying it unsubscribes (after that its function is never called).
class WatchHub::Subscription {
 public:
  Subscription(std::shared_ptr<WatchHub> hub, std::shared_ptr<Entry> e)
      : hub_(std::move(hub)), e_(std::move(e)) {}
  ~Subscription();
  // Sends a kLive event (lsn `after`), delivers what was held with an LSN above `after` (a
  // replay covered the rest), then goes live.
  void Go(uint64_t after, const std::string& dataset);
  bool ended() const;

 private:
  std::shared_ptr<WatchHub> hub_;
  std::shared_ptr<Entry> e_;
};

// What Dataset::Watch returns: destroy it to stop watching.
using WatchHandle = WatchHub::Subscription;

}  // namespace hvdb

#endif  // HVDB_STORAGE_WATCH_H_
