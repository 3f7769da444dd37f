#include <algorithm>

#include "server/requests.h"
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
  if (q.lod() > 64) {
    ops_.erase(op->id);
    return SendError(op->id, Status::InvalidArgument("query.lod: " + std::to_string(q.lod()) +
                                                     " is out of range"));
  }
  QueryOptions o;
  o.lod = static_cast<int>(q.lod());
  o.progressive = q.progressive();
  o.temporal_lod = !q.no_temporal_lod();
  o.label_mask = q.label_mask();
  o.batch_points = q.batch_points() == 0 ? 16384u : std::min(q.batch_points(), wire::kMaxBatchPoints);
  op->encoding = q.encoding();
  op->shm = op->encoding == wire::RECORDS && ring_ != nullptr;
  // A batch may overrun batch_points by up to one bucket level; keep it under 1 MiB. (Into a
  // ring slot the cursor never overruns: it ends the batch early instead.)
  if (!op->shm) o.batch_points = std::min<size_t>(o.batch_points, wire::kMaxBatchPoints - 2048);
  // The first batch is made by the same worker task that opens the cursor, with a ring slot
  // (or a record buffer) taken here on the strand.
  const int slot = op->shm ? AcquireSlot() : -1;
  std::vector<Point> buf = op->encoding == wire::RECORDS && !op->shm ? TakeSpare()
                                                                       : std::vector<Point>();
  auto self = shared_from_this();
  Server* s = server_;
  asio::post(server_->workers(), [self, op, s, name = q.dataset(), r = *region, o, slot,
                                  buf = std::move(buf), ring = ring_]() mutable {
    auto ds = FindDataset(s, name);
    Result<std::unique_ptr<Cursor>> cursor =
        ds.ok() ? (*ds)->Query(r, o) : Result<std::unique_ptr<Cursor>>(ds.status());
    if (!cursor.ok()) {
      wire::Response resp = ds.ok() ? ErrorResponse(op->id, cursor.status())
                                    : DatasetError(op->id, ds.status());
      asio::post(self->strand_, [self, op, resp, slot] {
        if (slot >= 0) self->free_slots_.push_back(slot);
        self->Send(resp);
        self->Finish(op->id);
      });
      return;
    }
    {
      std::lock_guard<std::mutex> l(op->mu);
      op->cursor = std::move(cursor).value();
      if (op->cancelled) op->cursor->Cancel();
    }
    if (op->shm && slot < 0) {
      // Every slot is with the client: wait on the strand for a release.
      asio::post(self->strand_, [self, op] { self->Schedule(op); });
      return;
    }
    self->Pump(op, slot, std::move(buf), std::move(ring));
  });
}

void Session::Schedule(std::shared_ptr<Op> op) {
  if (closed_) return;
  if (bytes_queued_ >= server_->config().outbound_high_water) {
    op->paused = true;  // resumed by WriteNext when the queue drains
    return;
  }
  int slot = -1;
  if (op->shm) {
    slot = AcquireSlot();
    if (slot < 0) {
      op->paused = true;  // resumed by OnRelease
      return;
    }
  }
  std::vector<Point> buf = op->encoding == wire::RECORDS && !op->shm ? TakeSpare()
                                                                       : std::vector<Point>();
  auto self = shared_from_this();
  asio::post(server_->workers(), [self, op, slot, buf = std::move(buf), ring = ring_]() mutable {
    self->Pump(op, slot, std::move(buf), std::move(ring));
  });
}

void Session::Pump(std::shared_ptr<Op> op, int slot, std::vector<Point> buf,
                   std::shared_ptr<wire::ShmRing> ring) {
  // On a worker: produce one batch.
  auto self = shared_from_this();
  wire::Response resp;
  resp.set_id(op->id);
  bool last = false;
  Batch batch;
  batch.points = std::move(buf);
  size_t in_slot = 0;
  Result<bool> more = Status::OK();
  if (op->cancelled) {
    more = Status::Cancelled("query cancelled");
  } else if (slot >= 0) {
    more = op->cursor->NextInto(reinterpret_cast<Point*>(ring->slot(static_cast<uint32_t>(slot))),
                                ring->slot_bytes() / sizeof(Point), &in_slot, &batch);
  } else {
    more = op->cursor->Next(&batch);
  }
  bool used_slot = false;
  std::vector<Point> records;
  if (!more.ok()) {
    resp = ErrorResponse(op->id, more.status());
    last = true;
  } else if (!*more) {
    auto* d = resp.mutable_done();
    d->set_points(op->points);
    for (uint32_t f : op->cursor->frames()) d->add_frames(f);
    d->set_clipped(op->cursor->clipped());
    last = true;
  } else {
    auto* b = resp.mutable_batch();
    b->set_level(static_cast<uint32_t>(batch.level));
    b->set_level_done(batch.level_done);
    b->set_splat_scale(batch.splat_scale);
    b->set_encoding(op->encoding);
    if (slot >= 0) {
      op->points += in_slot;
      b->set_record_count(static_cast<uint32_t>(in_slot));
      b->set_shm_slot(static_cast<uint32_t>(slot) + 1);
      used_slot = true;
    } else if (op->encoding == wire::RECORDS) {
      op->points += batch.points.size();
      b->set_record_count(static_cast<uint32_t>(batch.points.size()));
      records = std::move(batch.points);
    } else if (op->encoding == wire::DRACO) {
      op->points += batch.points.size();
      Status st = wire::EncodeDraco(batch.points, 16, b->mutable_draco());
      if (!st.ok()) {
        resp = ErrorResponse(op->id, st);
        last = true;
      }
    } else {
      op->points += batch.points.size();
      wire::EncodeColumns(batch.points, b->mutable_columns());
    }
  }
  asio::post(strand_, [self, op, resp = std::move(resp), last, slot, used_slot,
                       records = std::move(records)]() mutable {
    if (self->closed_) return;
    if (slot >= 0) {
      if (used_slot) {
        self->slot_held_[static_cast<size_t>(slot)] = 1;
      } else {
        self->free_slots_.push_back(slot);
      }
    }
    if (resp.has_batch() && resp.batch().encoding() == wire::RECORDS && slot < 0) {
      self->SendRecords(resp, std::move(records));
    } else {
      self->Send(resp);
    }
    if (last) {
      self->Finish(op->id);
      return;
    }
    self->Schedule(op);
  });
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
    free_slots_.push_back(static_cast<int>(s));
  }
  ResumePaused();
}

std::vector<Point> Session::TakeSpare() {
  if (spare_.empty()) return {};
  std::vector<Point> v = std::move(spare_.back());
  spare_.pop_back();
  return v;
}

void Session::ResumePaused() {
  auto self = shared_from_this();
  for (auto& [id, op] : ops_) {
    if (!op->paused) continue;
    op->paused = false;
    if (op->is_render) {
      asio::post(server_->workers(), [self, op = op] { self->RenderNext(op); });
    } else {
      Schedule(op);
    }
  }
}

void Session::HandleRender(std::shared_ptr<Op> op, const wire::Render& request) {
  // An unknown renderer value is refused by RenderJob::Create; until then it counts as auto.
  render::RendererKind kind = render::RendererKind::kAuto;
  if (request.renderer() == wire::RENDERER_EGL) kind = render::RendererKind::kEgl;
  if (request.renderer() == wire::RENDERER_CPU) kind = render::RendererKind::kCpu;
  // A bounded number of renders run at once, server-wide; the rest are refused at once
  // (OVERLOADED) rather than queued on the workers behind seconds of rendering.
  auto lease = server_->renders().TryAcquire(kind);
  if (!lease.ok()) {
    ops_.erase(op->id);
    return SendError(op->id, lease.status());
  }
  op->render_lease.emplace(std::move(lease).value());
  op->is_render = true;
  auto self = shared_from_this();
  Server* s = server_;
  asio::post(server_->workers(), [self, op, s, request] {
    wire::Response err;
    try {
      auto ds = FindDataset(s, request.dataset());
      if (!ds.ok()) {
        err = DatasetError(op->id, ds.status());
      } else {
        render::RenderLimits limits;
        limits.max_points = s->config().max_render_points;
        auto job = render::RenderJob::Create(*ds, request, limits);
        if (job.ok()) {
          op->render_job = std::move(job).value();
          return self->RenderNext(op);
        }
        err = ErrorResponse(op->id, job.status());
      }
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
    Result<wire::RenderReply> reply =
        !renderer.ok() ? Result<wire::RenderReply>(renderer.status())
        : op->cancelled ? Result<wire::RenderReply>(Status::Cancelled("render cancelled"))
                        : op->render_job->Render(op->next_image, **renderer, &op->cancelled);
    if (reply.ok()) {
      last = reply->last();
      reply->set_fallback(op->render_lease->fallback());
      *resp.mutable_render() = std::move(reply).value();
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
    if (self->bytes_queued_ < self->server_->config().outbound_high_water) {
      asio::post(self->server_->workers(), [self, op] { self->RenderNext(op); });
    } else {
      op->paused = true;  // resumed by WriteNext when the queue drains
    }
  });
}

}  // namespace hvdb::server
