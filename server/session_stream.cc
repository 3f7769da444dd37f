#include <algorithm>

#include "protocol/convert.h"
#include "protocol/render_convert.h"
#include "server/session.h"

namespace hvdb::server {

namespace asio = boost::asio;

void Session::HandleQuery(std::shared_ptr<Op> op, const wire::Query& q) {
  auto region = wire::FromWire(q.region());
  if (!region.ok()) {
    ops_.erase(op->id);
    return SendError(op->id, region.status());
  }
  if (!wire::PointEncoding_IsValid(q.encoding())) {
    ops_.erase(op->id);
    return SendError(op->id, Status::InvalidArgument("query.encoding: unknown value " +
                                                     std::to_string(q.encoding())));
  }
  if (q.encoding() == wire::HVDB7) {
    Status st = wire::CheckHvdb7Params(q.codec());
    if (!st.ok()) {
      ops_.erase(op->id);
      return SendError(op->id, st);
    }
  }
  auto opts = wire::QueryOptionsFromWire(q);
  if (!opts.ok()) {
    ops_.erase(op->id);
    return SendError(op->id, opts.status());
  }
  QueryOptions o = *opts;
  o.batch_points = std::min<size_t>(o.batch_points, wire::kMaxBatchPoints);
  op->encoding = q.encoding();
  op->codec = q.codec();
  op->shm = op->encoding == wire::RECORDS && ring_ != nullptr;
  // Encoded batches may overrun batch_points by up to one bucket level; keep them under 1 MiB.
  // (Records go into a fixed buffer or ring slot, and the cursor ends a batch early instead.)
  if (op->encoding != wire::RECORDS) {
    o.batch_points = std::min<size_t>(o.batch_points, wire::kMaxBatchPoints - 2048);
  }
  // The cursor is opened and the first batches made right here on the strand: a small query
  // (a window, a slice of one frame) is answered without a hand-off between threads. The work
  // is bounded like every task's (two batches, or the granted ring slots).
  Result<service::OpenQuery> open = server_->service().Query(q.dataset(), *region, o);
  if (!open.ok()) {
    Send(ErrorResponse(op->id, open.status()));
    return Finish(op->id);
  }
  {
    std::lock_guard<std::mutex> l(op->mu);
    op->cursor = std::move(open->cursor);
  }
  // Pipelined queries of a client that does not read wait here: each grant counts against the
  // connection's buffer (a whole task's worth, reserved until delivered).
  if (!MayProduce()) {
    op->paused = true;
    return;
  }
  Grant g = MakeGrant(op);
  if (g.batches == 0) return Schedule(op);
  Deliver(op, Produce(op.get(), std::move(g)));
}

Session::Grant Session::MakeGrant(const std::shared_ptr<Op>& op) {
  Grant g;
  if (op->shm) {
    // Several slots at once: the task fills them back to back while the client empties the
    // ones before (no hop through the strand between batches).
    while (g.slots.size() < kSlotsPerTask) {
      int slot = AcquireSlot();
      if (slot < 0) break;
      g.slots.push_back(slot);
      slot_owner_[static_cast<size_t>(slot)] = op;
      ++op->slots_held;
    }
    g.batches = g.slots.size();
    g.ring = ring_;
    // A query holding slots waits for the client to release them (flow control). One holding
    // none, with every slot held for other queries of this connection, sends its records
    // through the socket instead: a client reading its queries in any order never waits on a
    // query that cannot get a slot.
    if (!g.slots.empty() || op->slots_held > 0) return g;
  }
  // Two batches a task: a small query's batch and its QueryDone go out together. Bounded: the
  // strand admits a task only under the high-water mark, and counts the task's batches as
  // buffered until they are delivered. When the server is crowded a connection gets one batch
  // at a time, and only while it holds nothing.
  g.batches = server_->Crowded() || !read_results_ ? 1 : kBatchesPerTask;
  g.reserved = g.batches * wire::kMaxBatchBytes;
  Reserve(static_cast<int64_t>(g.reserved));
  if (op->encoding == wire::RECORDS) {
    // Fixed 1 MiB buffers the cursor fills like a ring slot, recycled once written (sized
    // once: no zeroing per batch).
    while (g.bufs.size() < g.batches) {
      std::vector<Point> b = TakeSpare();
      if (b.size() != wire::kMaxBatchPoints) b.resize(wire::kMaxBatchPoints);
      g.bufs.push_back(std::move(b));
    }
  }
  return g;
}

bool Session::MayProduce() const {
  if (Buffered() >= server_->config().outbound_high_water) return false;
  // A client whose queued results have not moved for a while is not reading: it gets no more
  // work until they do (its write completing resumes it), which keeps the server's threads for
  // clients that read.
  if (bytes_queued_ > 0 && Clock::now() - last_drain_ >= kNotReading) return false;
  // Until a first write of results has completed, one batch at a time: a connection that asks
  // and never reads costs the server one batch of work, not a connection's worth.
  if (bytes_queued_ > 0 && !read_results_) return false;
  return Buffered() == 0 ? !server_->OverBudget() : !server_->Crowded();
}

void Session::Schedule(std::shared_ptr<Op> op) {
  if (closed_) return;
  // A cancelled query only has its CANCELLED to send: it never waits for room.
  if (!op->cancelled && !MayProduce()) {
    op->paused = true;  // resumed by WriteNext when the queue drains
    return;
  }
  Grant g = MakeGrant(op);
  if (g.batches == 0) {
    op->paused = true;  // its ring slots are with the client: resumed by OnRelease
    return;
  }
  auto self = shared_from_this();
  asio::post(server_->io(), [self, op, g = std::move(g)]() mutable {
    self->Pump(op, std::move(g));
  });
}

void Session::Pump(std::shared_ptr<Op> op, Grant g) {
  // On a network thread, off the strand: the batches, then one post to the strand with all of
  // them (one wake-up per task, not per batch).
  auto self = shared_from_this();
  Produced out = Produce(op.get(), std::move(g));
  asio::post(strand_, [self, op, out = std::move(out)]() mutable {
    self->Deliver(op, std::move(out));
  });
}

Session::Produced Session::Produce(Op* op, Grant g) {
  Produced out;
  out.reserved = g.reserved;
  for (size_t i = 0; i < g.batches && !out.finished; ++i) {
    const int slot = i < g.slots.size() ? g.slots[i] : -1;
    Made m;
    wire::Response& resp = m.resp;
    resp.set_id(op->id);
    Batch batch;
    if (i < g.bufs.size()) batch.points = std::move(g.bufs[i]);
    size_t in_slot = 0;
    Result<bool> more = false;
    if (op->cancelled) {
      more = Status::Cancelled("query cancelled");
    } else if (slot >= 0) {
      more = op->cursor->NextInto(reinterpret_cast<Point*>(g.ring->slot(static_cast<uint32_t>(slot))),
                                  g.ring->slot_bytes() / sizeof(Point), &in_slot, &batch);
    } else if (op->encoding == wire::RECORDS) {
      more = op->cursor->NextInto(batch.points.data(), batch.points.size(), &in_slot, &batch);
    } else {
      more = op->cursor->Next(&batch);
    }
    if (!more.ok()) {
      resp = ErrorResponse(op->id, more.status());
      out.finished = true;
    } else if (!*more) {
      auto* d = resp.mutable_done();
      d->set_points(op->points);
      for (uint32_t f : op->cursor->frames()) d->add_frames(f);
      d->set_clipped(op->cursor->clipped());
      out.finished = true;
    } else {
      auto* b = resp.mutable_batch();
      b->set_level(static_cast<uint32_t>(batch.level));
      b->set_level_done(batch.level_done);
      b->set_splat_scale(batch.splat_scale);
      b->set_encoding(op->encoding);
      const bool records = op->encoding == wire::RECORDS;
      op->points += records ? in_slot : batch.points.size();
      if (records) b->set_record_count(static_cast<uint32_t>(in_slot));
      if (slot >= 0) {
        b->set_shm_slot(static_cast<uint32_t>(slot) + 1);
        m.held_slot = slot;
      } else if (records) {
        m.records = std::move(batch.points);
        m.count = in_slot;
      } else if (op->encoding == wire::DRACO || op->encoding == wire::HVDB7) {
        Status st = op->encoding == wire::DRACO
                        ? wire::EncodeDraco(batch.points, 16, b->mutable_draco())
                        : wire::EncodeHvdb7(batch.points, op->codec, b->mutable_hvdb7());
        if (!st.ok()) {
          resp = ErrorResponse(op->id, st);
          out.finished = true;
        }
      } else {
        wire::EncodeColumns(batch.points, b->mutable_columns());
      }
    }
    // A record buffer that carried no batch goes back to the session for the next task.
    if (m.records.empty() && batch.points.size() == wire::kMaxBatchPoints) {
      out.back.push_back(std::move(batch.points));
    }
    out.made.push_back(std::move(m));
  }
  for (size_t i = out.made.size(); i < g.bufs.size(); ++i) out.back.push_back(std::move(g.bufs[i]));
  // Slots not filled go back.
  for (size_t k = 0; k < g.slots.size(); ++k) {
    if (k >= out.made.size() || out.made[k].held_slot < 0) out.unused.push_back(g.slots[k]);
  }
  return out;
}

void Session::Deliver(std::shared_ptr<Op> op, Produced out) {
  Reserve(-static_cast<int64_t>(out.reserved));
  for (int slot : out.unused) ReturnSlot(slot);
  if (closed_) return;  // its buffers go with the task (the close took spare_ out of the budget)
  for (auto& b : out.back) KeepSpare(std::move(b));
  corked_ = true;
  results_queued_ = true;
  for (Made& m : out.made) {
    if (m.held_slot >= 0) slot_held_[static_cast<size_t>(m.held_slot)] = 1;
    if (m.records.empty()) {
      Send(m.resp);
    } else {
      SendRecords(m.resp, std::move(m.records), m.count);
    }
  }
  corked_ = false;
  WriteNext();
  // A query not finished asks for its next grant.
  if (out.finished) return Finish(op->id);
  Schedule(op);
}

void Session::ReturnSlot(int slot) {
  free_slots_.push_back(slot);
  if (auto op = slot_owner_[static_cast<size_t>(slot)].lock()) {
    if (op->slots_held > 0) --op->slots_held;
  }
  slot_owner_[static_cast<size_t>(slot)].reset();
}

int Session::AcquireSlot() {
  if (free_slots_.empty()) return -1;
  int s = free_slots_.back();
  free_slots_.pop_back();
  return s;
}

void Session::OnRelease(const wire::ReleaseSlots& r) {
  for (uint32_t s : r.slots()) {
    if (!ring_ || s >= slot_held_.size() || !slot_held_[s]) {
      // Releasing a slot it does not hold would let the server overwrite a batch the client
      // may still be reading: a protocol violation, so the connection ends.
      close_after_write_ = true;
      return SendError(0, Status::InvalidArgument("release of ring slot " + std::to_string(s) +
                                                  ", which this client does not hold"),
                       wire::MALFORMED);
    }
    slot_held_[s] = 0;
    ReturnSlot(static_cast<int>(s));
  }
  ResumePaused();
}

std::vector<Point> Session::TakeSpare() {
  if (spare_.empty()) return {};
  std::vector<Point> v = std::move(spare_.back());
  spare_.pop_back();
  server_->AddBuffered(-static_cast<int64_t>(kSpareBytes));
  return v;
}

void Session::ResumePaused() {
  auto self = shared_from_this();
  for (auto& [id, op] : ops_) {
    if (!op->paused) continue;
    if (op->is_render && !op->cancelled && !MayProduce()) continue;  // still no room
    op->paused = false;
    if (op->is_render) {
      asio::post(server_->workers(), [self, op = op] { self->RenderNext(op); });
    } else {
      Schedule(op);
    }
  }
}

void Session::HandleRender(std::shared_ptr<Op> op, const wire::Render& message) {
  // The wire message becomes the render job's request here, at the edge: its shape (known
  // enum values, counts) is checked by FromWire, the rest by the job.
  Result<render::RenderRequest> decoded = wire::FromWire(message);
  if (!decoded.ok()) {
    ops_.erase(op->id);
    return SendError(op->id, decoded.status());
  }
  render::RenderRequest request = std::move(decoded).value();
  // A bounded number of renders run at once, server-wide; the rest are refused at once
  // (OVERLOADED) rather than queued on the workers behind seconds of rendering.
  // Gaussian mode draws with the 3DGS rasteriser of the leased renderer's kind (render/job.h):
  // the GPU's where the pool's renderers are EGL ones, else the CPU's.
  auto lease = server_->renders().TryAcquire(request.renderer);
  if (!lease.ok()) {
    ops_.erase(op->id);
    return SendError(op->id, lease.status());
  }
  op->render_lease.emplace(std::move(lease).value());
  op->is_render = true;
  auto self = shared_from_this();
  Server* s = server_;
  asio::post(server_->workers(), [self, op, s, request = std::move(request)] {
    wire::Response err;
    try {
      render::RenderLimits limits;
      limits.max_points = s->config().max_render_points;
      auto job = s->service().Render(request, limits);
      if (job.ok()) {
        op->render_job = std::move(job).value();
        return self->RenderNext(op);
      }
      err = ErrorResponse(op->id, job.status());
    } catch (const std::exception& e) {
      err = ErrorResponse(op->id, Status::Internal(e.what()));
    }
    asio::post(self->strand_, [self, op, err = std::move(err)] {
      op->render_lease.reset();
      self->Send(err);
      self->Finish(op->id);
    });
  });
}

void Session::RenderNext(std::shared_ptr<Op> op) {
  // On a worker: one image of the request.
  auto self = shared_from_this();
  wire::Response resp;
  resp.set_id(op->id);
  bool last = true;
  try {
    Result<render::Renderer*> renderer = op->render_lease->Get();
    Result<render::RenderReply> reply =
        !renderer.ok() ? Result<render::RenderReply>(renderer.status())
        : op->cancelled ? Result<render::RenderReply>(Status::Cancelled("render cancelled"))
                        : op->render_job->Render(op->next_image, **renderer, &op->cancelled);
    if (reply.ok()) {
      last = reply->last;
      reply->fallback = op->render_lease->fallback();
      if (reply->renderer_choice.empty()) reply->renderer_choice = op->render_lease->why();
      wire::ToWire(std::move(reply).value(), resp.mutable_render());
    } else {
      resp = ErrorResponse(op->id, reply.status());
    }
  } catch (const std::exception& e) {  // e.g. std::bad_alloc for a huge image
    resp = ErrorResponse(op->id, Status::Internal(e.what()));
  }
  asio::post(strand_, [self, op, resp = std::move(resp), last] {
    if (self->closed_) return;
    self->Send(resp);
    if (last) {
      op->render_lease.reset();  // the slot is free for the next request
      self->Finish(op->id);
      return;
    }
    ++op->next_image;
    // Sequences obey the same flow control as queries: the next image is made only while
    // the connection has room.
    if (self->MayProduce()) {
      asio::post(self->server_->workers(), [self, op] { self->RenderNext(op); });
    } else {
      op->paused = true;  // resumed by WriteNext when the queue drains
    }
  });
}

}  // namespace hvdb::server
