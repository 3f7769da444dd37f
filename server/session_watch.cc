// Watch requests (docs/PROTOCOL.md, "Watching"): a subscription to a dataset's changes whose
// events are queued on the connection as they are published; a replay from the log is paced by
// what the client reads. Memory stays bounded for a client that stops reading: with its events
// past the connection's high-water mark and nothing drained for a second, past four times the
// mark, with kMaxWatchInflight events not yet on the strand, or a replay stuck for a second, the
// watch ends with LAGGED, naming the LSN to resume from.
#include "protocol/convert.h"
#include "server/session.h"

namespace hvdb::server {

namespace asio = boost::asio;

void Session::HandleWatch(std::shared_ptr<Op> op, const wire::Watch& w) {
  auto flow = std::make_shared<Op::WatchFlow>();
  op->watch_flow = flow;
  op->watch_dataset = w.dataset();
  std::optional<uint64_t> from;
  if (w.has_from_lsn()) from = w.from_lsn();
  op->watch_sent_lsn = from.value_or(0);
  std::weak_ptr<Session> weak = shared_from_this();
  const uint64_t id = op->id;
  // Runs on the publishing thread (a commit's leader, a follower's refresh), where it only
  // posts; or, for a replay, on the worker that subscribes, outside every lock, where it waits
  // for the client to read what came before (pacing), at most kNotReading.
  ChangeFn fn = [weak, flow, strand = strand_, id](const ChangeEvent& ev) {
    if (flow->overflow.load()) return;
    bool lag = false;
    {
      std::unique_lock<std::mutex> l(flow->mu);
      if (ev.replayed) {
        lag = !flow->cv.wait_for(l, kNotReading, [&] {
          return flow->unwritten < kReplayWindow || flow->closed;
        });
      }
      if (flow->closed) return;
      if (!lag && flow->inflight.load() >= kMaxWatchInflight) lag = true;
      if (!lag) {
        flow->unwritten += WatchCost(ev);
        flow->inflight.fetch_add(1);
      }
    }
    if (lag) {
      flow->overflow = true;
      asio::post(strand, [weak, id] {
        if (auto s = weak.lock()) s->OnWatchEvent(id, nullptr);
      });
      return;
    }
    asio::post(strand, [weak, flow, id, ev] {
      flow->inflight.fetch_sub(1);
      if (auto s = weak.lock()) s->OnWatchEvent(id, &ev);
    });
  };
  auto self = shared_from_this();
  asio::post(server_->workers(), [self, op, name = w.dataset(), from, fn = std::move(fn)] {
    auto handle = self->server_->service().Watch(name, from, fn);
    asio::post(self->strand_, [self, op, handle = std::move(handle)]() mutable {
      auto it = self->ops_.find(op->id);
      if (it == self->ops_.end() || it->second != op) return;  // cancelled, or closed
      if (!handle.ok()) {
        self->Send(ErrorResponse(op->id, handle.status()));
        return self->Finish(op->id);
      }
      op->watch = std::move(handle).value();
    });
  });
}

void Session::OnWatchEvent(uint64_t id, const ChangeEvent* ev) {
  if (closed_) return;
  auto it = ops_.find(id);
  if (it == ops_.end() || it->second->watch_flow == nullptr) return;
  Op& op = *it->second;
  wire::Response r;
  r.set_id(id);
  // Everything up to the replay's end is queued once its LIVE event comes.
  if (ev != nullptr && ev->kind == ChangeEvent::Kind::kLive) op.watch_sent_lsn = ev->lsn;
  // Lagging: the watch's own events past the connection's high-water mark with nothing drained
  // for a while (the client does not read), or past four times the mark whatever it does (a
  // replay burst stays within that). Other requests' results on the connection do not count:
  // their own flow control bounds them.
  const size_t mark = server_->config().outbound_high_water;
  const bool stalled = op.watch_queued >= mark && Clock::now() - last_drain_ >= kNotReading;
  if (ev == nullptr || op.watch_flow->overflow || stalled || op.watch_queued >= 4 * mark) {
    ChangeEvent lag;
    lag.kind = ChangeEvent::Kind::kLagged;
    lag.dataset = op.watch_dataset;
    lag.lsn = op.watch_sent_lsn;
    wire::ToWire(lag, r.mutable_event());
    Send(r);
    it->second->Cancel();  // a replay waiting to send more stops
    return Finish(id);
  }
  wire::ToWire(*ev, r.mutable_event());
  OutFrame f = transport_->Encode(r, {}, 0);
  f.watch = id;
  f.watch_cost = WatchCost(*ev);
  op.watch_queued += f.bytes();
  Enqueue(std::move(f));
  if (ev->kind == ChangeEvent::Kind::kDropped) {
    it->second->Cancel();
    return Finish(id);
  }
  op.watch_sent_lsn = ev->lsn;
}

}  // namespace hvdb::server
