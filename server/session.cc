#include "server/session.h"

#include <algorithm>
#include <cmath>
#include <array>

#include "protocol/convert.h"
#include "render/job.h"

namespace hvdb::server {

namespace asio = boost::asio;

Session::Session(Server* server, Strand strand, std::shared_ptr<Transport> transport,
                 bool unix_socket, bool loopback)
    : server_(server),
      unix_socket_(unix_socket),
      loopback_(loopback),
      strand_(std::move(strand)),
      transport_(std::move(transport)),
      timer_(strand_) {}

void Session::Start() {
  server_->stats().connections_open++;
  server_->stats().connections_total++;
  deadline_ = Clock::now() + std::chrono::seconds(std::min(server_->config().handshake_timeout_s,
                                                           server_->config().idle_timeout_s));
  auto self = shared_from_this();
  asio::dispatch(strand_, [self] {
    self->ArmTimer();
    self->ReadNext();
  });
}

void Session::ArmTimer() {
  auto self = shared_from_this();
  // Wake at least once a second: the deadline moves (and may move closer) as frames complete.
  timer_.expires_at(std::min(deadline_, Clock::now() + std::chrono::seconds(1)));
  timer_.async_wait([self](boost::system::error_code ec) {
    if (self->closed_) return;
    if (!ec && Clock::now() >= self->deadline_) {
      Log(LogLevel::kInfo, "closing idle or slow connection");
      self->CloseOnStrand();
      return;
    }
    // When the server's memory budget is crowded, a connection whose results have not drained
    // at all for a while gives its memory back: otherwise clients that never read could hold
    // the budget until their idle timeout and starve everyone else.
    if (!ec && self->bytes_queued_ > 0 && self->server_->Crowded() &&
        Clock::now() - self->last_drain_ >= kStallWhileCrowded) {
      Log(LogLevel::kWarn, "closing a connection that has not read its " +
                               std::to_string(self->bytes_queued_ >> 10) +
                               " KiB of results for " +
                               std::to_string(kStallWhileCrowded.count()) +
                               " s while the server's memory budget is crowded");
      self->CloseOnStrand();
      return;
    }
    // Queries that paused for the server's budget while this connection held nothing have no
    // write of their own to resume them: they look again every second.
    if (!ec && self->Buffered() == 0) self->ResumePaused();
    if (ec != asio::error::operation_aborted || !self->closed_) self->ArmTimer();
  });
}

void Session::ReadNext() {
  auto self = shared_from_this();
  reading_ = true;
  transport_->Read(hello_done_ ? nullptr : &hello_msg_, &request_,
                   [self](boost::system::error_code ec, Status st, size_t n) {
                     self->reading_ = false;
                     if (ec || self->closed_) return self->CloseOnStrand();
                     self->server_->stats().bytes_in += n;
                     if (!st.ok()) {  // undecodable: the stream cannot be trusted any more
                       self->close_after_write_ = true;
                       return self->SendError(0, st, wire::MALFORMED);
                     }
                     self->deadline_ = Clock::now() + std::chrono::seconds(
                                                          self->server_->config().idle_timeout_s);
                     if (!self->hello_done_) {
                       self->OnHello();
                     } else {
                       self->Dispatch(std::move(self->request_));
                     }
                     if (self->closed_ || self->close_after_write_) return;
                     // Back-pressure: a client that does not read what it asked for is not
                     // read from either, until its results drain (WriteNext resumes).
                     if (self->CanRead()) {
                       self->ReadNext();
                     } else {
                       self->read_paused_ = true;
                     }
                   });
}

bool Session::CanRead() const {
  const size_t high = server_->config().outbound_high_water;
  return Buffered() < high && !(server_->Crowded() && Buffered() > 0);
}

void Session::Reserve(int64_t delta) {
  bytes_reserved_ = static_cast<size_t>(static_cast<int64_t>(bytes_reserved_) + delta);
  server_->AddBuffered(delta);
}

void Session::OnHello() {
  const wire::Hello& hello = hello_msg_;
  if (hello.protocol_version() != wire::kProtocolVersion) {
    close_after_write_ = true;
    return SendError(0, Status::Unsupported("protocol version " +
                                            std::to_string(hello.protocol_version()) +
                                            " is not supported; this server speaks version " +
                                            std::to_string(wire::kProtocolVersion)));
  }
  role_ = server_->Authenticate(hello.token());
  if (role_ == Role::kNone) {
    close_after_write_ = true;
    return SendError(0, Status::PermissionDenied("invalid or missing access token"));
  }
  if (!server_->Authenticated(this)) {
    close_after_write_ = true;
    return SendError(0, server_->AtConnectionLimit());
  }
  authenticated_ = true;
  hello_done_ = true;
  wire::HelloReply reply;
  reply.set_protocol_version(wire::kProtocolVersion);
  reply.add_capabilities("draco");
  reply.add_capabilities("hvdb7");
  reply.add_capabilities("records");
  reply.add_capabilities("progressive");
  reply.add_capabilities("pipelining");
  if (unix_socket_) reply.add_capabilities("shm");
  reply.set_server_name("hvdb-server 0.2");
  reply.set_role(role_ == Role::kReadWrite ? wire::ROLE_READ_WRITE : wire::ROLE_READ_ONLY);
  if (loopback_ && !server_->local_socket().empty()) {
    reply.set_local_socket(server_->local_socket());
  }
  const bool wants_shm = std::find(hello.capabilities().begin(), hello.capabilities().end(),
                                   "shm") != hello.capabilities().end();
  if (unix_socket_ && wants_shm && server_->config().shm_slots > 0) {
    // The fast path: a ring of slots the workers write batches into, its descriptor passed
    // with this very frame. Nothing else has been written yet, so a direct sendmsg is safe.
    auto ring = wire::ShmRing::Create(server_->config().shm_slots, wire::kMaxBatchBytes);
    if (ring.ok()) {
      ring_ = std::shared_ptr<wire::ShmRing>(std::move(ring).value());
      reply.set_shm_slots(ring_->slots());
      reply.set_shm_slot_bytes(ring_->slot_bytes());
      slot_held_.assign(ring_->slots(), 0);
      slot_owner_.assign(ring_->slots(), {});
      for (int i = static_cast<int>(ring_->slots()) - 1; i >= 0; --i) free_slots_.push_back(i);
      std::string frame = wire::Frame(reply);
      Status st = wire::SendWithFd(transport_->native_handle(), frame, ring_->fd(),
                                   std::chrono::seconds(server_->config().handshake_timeout_s));
      if (!st.ok()) {
        Log(LogLevel::kWarn, "handshake with shared memory failed: " + st.ToString());
        return CloseOnStrand();
      }
      server_->stats().bytes_out += frame.size();
      return;
    }
    // No memfd (e.g. a sandbox without it): the connection works without the ring, and says so.
    Log(LogLevel::kWarn, "no shared-memory ring for a local client: " + ring.status().ToString());
  }
  Send(reply);
}

void Session::Dispatch(wire::Request req) {
  const uint64_t id = req.id();
  if (req.body_case() == wire::Request::BODY_NOT_SET) {
    // MALFORMED closes the connection (docs/PROTOCOL.md, "Errors"): a client that sends what
    // this server cannot read is out of step with it.
    close_after_write_ = true;
    return SendError(id, Status::InvalidArgument("request: empty or unknown request kind"),
                     wire::MALFORMED);
  }
  if (req.body_case() == wire::Request::kCancel) {
    auto it = ops_.find(req.cancel().target());
    const bool found = it != ops_.end();
    const bool watch = found && it->second->watch_flow != nullptr;
    if (found) it->second->Cancel();
    wire::Response r;
    r.set_id(id);
    r.mutable_ack()->set_value(found ? 1 : 0);
    Send(r);
    if (watch) {  // a watch has nothing in progress to notice the flag: it ends here
      const uint64_t target = req.cancel().target();
      SendError(target, Status::Cancelled("watch cancelled"));
      Finish(target);
    }
    return;
  }
  if (req.body_case() == wire::Request::kRelease) return OnRelease(req.release());
  if (req.body_case() == wire::Request::kPing) {
    if (req.ping().payload().size() > kMaxPingPayload) {
      return SendError(id, Status::InvalidArgument(
                               "ping.payload: " + std::to_string(req.ping().payload().size()) +
                               " bytes; at most " + std::to_string(kMaxPingPayload) +
                               " are echoed"),
                       wire::INVALID_PARAMETER);
    }
    wire::Response r;
    r.set_id(id);
    auto start = std::chrono::steady_clock::now();
    r.mutable_pong()->set_payload(req.ping().payload());
    Send(r);
    server_->stats().Record("ping", std::chrono::duration<double, std::milli>(
                                        std::chrono::steady_clock::now() - start).count());
    return;
  }
  if (ops_.count(id)) {
    return SendError(id, Status::InvalidArgument("request id: " + std::to_string(id) +
                                                 " is already in flight on this connection"));
  }
  if (ops_.size() >= server_->config().max_inflight) {
    return SendError(id, Status::Overloaded("more than " +
                                            std::to_string(server_->config().max_inflight) +
                                            " requests in flight on this connection; wait for "
                                            "some to finish"));
  }
  const service::RequestKind& kind = service::KindOf(req);
  if (kind.writes && role_ != Role::kReadWrite) {
    return SendError(id, Status::PermissionDenied(std::string(kind.name) +
                                                  " needs a read-write token"));
  }
  if (kind.writes && server_->db().follower()) {
    return SendError(id, server_->NotLeader(kind.name));
  }
  auto op = std::make_shared<Op>();
  op->id = id;
  op->kind = kind.name;
  ops_[id] = op;
  Server* s = server_;
  if (kind.flow == service::Flow::kUnary) {
    return RunOnWorker(id, [s, req = std::move(req)] {
      return service::ExecuteUnary(s->service(), req);
    });
  }
  // The streams: the executor's call wrapped in the session's flow control.
  switch (req.body_case()) {
    case wire::Request::kRender:
      return HandleRender(op, req.render());
    case wire::Request::kIngest:
      return HandleIngest(id, req.ingest());
    case wire::Request::kQuery:
      return HandleQuery(op, req.query());
    case wire::Request::kWatch:
      return HandleWatch(op, req.watch());
    default:
      ops_.erase(id);
      return SendError(id, Status::InvalidArgument("request: unknown kind"), wire::MALFORMED);
  }
}

void Session::RunOnWorker(uint64_t id, std::function<wire::Response()> fn) {
  auto self = shared_from_this();
  asio::post(server_->workers(), [self, id, fn = std::move(fn)] {
    wire::Response r;
    try {
      r = fn();
    } catch (const std::exception& e) {  // e.g. std::bad_alloc: this request fails, not the server
      r = ErrorResponse(id, Status::Internal(e.what()));
    }
    asio::post(self->strand_, [self, id, r = std::move(r)] {
      self->Send(r);
      self->Finish(id);
    });
  });
}
void Session::HandleIngest(uint64_t id, const wire::Ingest& ing) {
  // Chunks are collected here, in arrival order; the frame is bulk-loaded on `last`. Once a
  // chunk of a frame fails, the frame's other chunks are refused too, so that no part of a
  // frame is ever loaded.
  auto key = std::make_pair(ing.dataset(), ing.frame());
  auto fail = [&](const Status& st) {
    auto it = ingest_.find(key);
    if (it != ingest_.end()) {
      ingest_bytes_ -= it->second.size() * sizeof(Point);
      ingest_.erase(it);
    }
    auto g = ingest_gaussians_.find(key);
    if (g != ingest_gaussians_.end()) {
      ingest_bytes_ -= g->second.values.size() * sizeof(float);
      ingest_gaussians_.erase(g);
    }
    if (!ing.last()) ingest_failed_.insert(key);
    ops_.erase(id);
    SendError(id, st);
  };
  if (ingest_failed_.count(key)) {
    if (ing.last()) ingest_failed_.erase(key);
    return fail(Status::InvalidArgument("ingest: an earlier chunk of frame " +
                                        std::to_string(ing.frame()) +
                                        " failed; nothing of the frame was loaded"));
  }
  std::vector<Point>& pts = ingest_[key];
  size_t before = pts.size();
  Status st = wire::DecodeColumns(ing.points(), &pts);
  if (!st.ok()) {
    pts.resize(before);
    return fail(st);
  }
  ingest_bytes_ += (pts.size() - before) * sizeof(Point);
  // A Gaussian frame's chunks each carry their points' records; the first chunk says which.
  const bool gaussian_frame = ingest_gaussians_.count(key) > 0 || (before == 0 && ing.has_gaussians());
  if (gaussian_frame != ing.has_gaussians()) {
    return fail(Status::InvalidArgument(
        "ingest: frame " + std::to_string(ing.frame()) +
        ": Gaussian records must come with every chunk of a frame or with none"));
  }
  if (gaussian_frame) {
    GaussianColumns& g = ingest_gaussians_[key];
    const size_t gbefore = g.values.size();
    Status gs = wire::DecodeGaussians(ing.gaussians(), &g);
    if (gs.ok() && ing.gaussians().count() != pts.size() - before) {
      gs = Status::InvalidArgument("ingest: a chunk of " + std::to_string(pts.size() - before) +
                                   " points carries " + std::to_string(ing.gaussians().count()) +
                                   " Gaussian records");
    }
    if (!gs.ok()) {
      g.values.resize(gbefore);
      return fail(gs);
    }
    ingest_bytes_ += (g.values.size() - gbefore) * sizeof(float);
  }
  if (ingest_bytes_ > server_->config().max_ingest_bytes) {
    return fail(Status::LimitExceeded("ingest: more than " +
                                      std::to_string(server_->config().max_ingest_bytes >> 20) +
                                      " MiB buffered on this connection; send `last` for each "
                                      "frame sooner"));
  }
  if (!ing.last()) {
    wire::Response r;
    r.set_id(id);
    r.mutable_ack()->set_value(pts.size());
    Send(r);
    ops_[id]->kind = "ingest_chunk";
    return Finish(id);
  }
  auto frame_points = std::make_shared<std::vector<Point>>(std::move(pts));
  ingest_bytes_ -= frame_points->size() * sizeof(Point);
  ingest_.erase(key);
  std::shared_ptr<GaussianColumns> gaussians;
  if (auto g = ingest_gaussians_.find(key); g != ingest_gaussians_.end()) {
    gaussians = std::make_shared<GaussianColumns>(std::move(g->second));
    ingest_bytes_ -= gaussians->values.size() * sizeof(float);
    ingest_gaussians_.erase(g);
  }
  Server* s = server_;
  RunOnWorker(id, [s, id, name = ing.dataset(), frame = ing.frame(), frame_points, gaussians] {
    auto n = s->service().BulkLoad(name, frame, std::move(*frame_points), gaussians.get());
    if (!n.ok()) return ErrorResponse(id, n.status());
    wire::Response r;
    r.set_id(id);
    r.mutable_ack()->set_value(*n);
    return r;
  });
}

void Session::Finish(uint64_t id) {
  auto it = ops_.find(id);
  if (it == ops_.end()) return;
  double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                        it->second->start)
                  .count();
  server_->stats().Record(it->second->kind, ms);
  ops_.erase(it);
}

void Session::Send(const google::protobuf::Message& m) {
  Enqueue(transport_->Encode(m, {}, 0));
}

void Session::SendRecords(const wire::Response& r, std::vector<Point> records, size_t count) {
  Enqueue(transport_->Encode(r, std::move(records), count));
}

void Session::Enqueue(OutFrame f) {
  if (closed_) return;
  if (out_.empty()) last_drain_ = Clock::now();  // the clock of a stall starts now
  bytes_queued_ += f.bytes();
  server_->AddBuffered(static_cast<int64_t>(f.bytes()));
  out_.push_back(std::move(f));
  WriteNext();
}

void Session::SendError(uint64_t id, const Status& st, wire::ErrorCode code) {
  Send(ErrorResponse(id, st, code));
}

void Session::WriteNext() {
  if (writing_ || corked_ || out_.empty() || closed_) return;
  writing_ = true;
  auto self = shared_from_this();
  transport_->Write(out_, [self](boost::system::error_code ec, size_t frames, size_t n) {
    self->writing_ = false;
    if (self->closed_) return;  // its bytes left the accounting at the close
    if (ec) return self->CloseOnStrand();
    self->server_->stats().bytes_out += n;
    for (size_t k = 0; k < frames; ++k) {
      OutFrame& done = self->out_.front();
      self->bytes_queued_ -= done.bytes();
      if (done.watch != 0) {
        if (auto w = self->ops_.find(done.watch);
            w != self->ops_.end() && w->second->watch_flow != nullptr) {
          w->second->watch_queued -= std::min(w->second->watch_queued, done.bytes());
          w->second->watch_flow->Written(done.watch_cost);
        }
      }
      self->server_->AddBuffered(-static_cast<int64_t>(done.bytes()));
      // The records' buffer serves the next batch (a few, so memory stays
      // bounded by the flow control's high-water mark).
      if (done.records.capacity() != 0) self->KeepSpare(std::move(done.records));
      self->out_.pop_front();
    }
    // A write finishing is progress too: a slow reader is not idle.
    self->deadline_ = Clock::now() + std::chrono::seconds(
                                         self->server_->config().idle_timeout_s);
    self->last_drain_ = Clock::now();
    if (self->results_queued_) self->read_results_ = true;
    if (self->Buffered() < self->server_->config().outbound_high_water / 2 &&
        !self->close_after_write_) {
      self->ResumePaused();
    }
    if (self->out_.empty() && self->close_after_write_) {
      return self->CloseOnStrand();
    }
    if (self->read_paused_ && !self->close_after_write_ && self->CanRead()) {
      self->read_paused_ = false;
      self->ReadNext();
    }
    self->WriteNext();
  });
}

void Session::Refuse(const Status& st) {
  auto self = shared_from_this();
  asio::dispatch(strand_, [self, st] {
    self->close_after_write_ = true;
    self->hello_done_ = true;
    self->SendError(0, st);
  });
}

void Session::Close() {
  auto self = shared_from_this();
  asio::dispatch(strand_, [self] { self->CloseOnStrand(); });
}

void Session::CloseOnStrand() {
  if (closed_) return;
  closed_ = true;
  // What is still queued is freed with the session; the budget forgets it now.
  const size_t freed = bytes_queued_ + spare_.size() * kSpareBytes + ingest_bytes_;
  server_->AddBuffered(-static_cast<int64_t>(bytes_queued_));
  bytes_queued_ = 0;
  for (auto& [id, op] : ops_) op->Cancel();
  ops_.clear();
  ingest_.clear();
  server_->AddBuffered(-static_cast<int64_t>(spare_.size() * kSpareBytes));
  spare_.clear();
  // Workers still making a batch hold their own reference; the ring goes with the last one.
  ring_.reset();
  boost::system::error_code ignored;
  timer_.cancel(ignored);
  transport_->Close();
  server_->stats().connections_open--;
  server_->Forget(this, freed);
}

void Session::KeepSpare(std::vector<Point> buf) {
  // Kept for the next batches only while the server has memory to spare; counted in its budget.
  if (closed_ || spare_.size() >= kMaxSpares || server_->Crowded()) return;
  server_->AddBuffered(static_cast<int64_t>(kSpareBytes));
  spare_.push_back(std::move(buf));
}

}  // namespace hvdb::server
