#include "server/session.h"

#include <nlohmann/json.hpp>
#include <optional>

#include "edit/operators.h"
#include "render/job.h"

namespace hvdb::server {

namespace asio = boost::asio;
using asio::ip::tcp;

struct Session::Op {
  uint64_t id = 0;
  std::string kind;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
  std::atomic<bool> cancelled{false};
  // Queries: the cursor is set on a worker and cancelled from the strand.
  std::mutex mu;
  std::unique_ptr<Cursor> cursor;
  void Cancel() {
    cancelled = true;
    std::lock_guard<std::mutex> l(mu);
    if (cursor) cursor->Cancel();
  }
  wire::PointEncoding encoding = wire::COLUMNS;
  uint64_t points = 0;
  bool paused = false;
  // Renders: the job (set on a worker), its slot of the server's renderer pool, and the next
  // image of a sequence (advanced on the strand).
  bool is_render = false;
  std::unique_ptr<render::RenderJob> render_job;
  std::optional<render::RendererPool::Lease> render_lease;
  size_t next_image = 0;
};

namespace {

const char* KindOf(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kPing: return "ping";
    case wire::Request::kList: return "list";
    case wire::Request::kCreate: return "create";
    case wire::Request::kDrop: return "drop";
    case wire::Request::kDescribe: return "describe";
    case wire::Request::kQuery: return "query";
    case wire::Request::kCancel: return "cancel";
    case wire::Request::kEdit: return "edit";
    case wire::Request::kRevert: return "revert";
    case wire::Request::kIngest: return "ingest";
    case wire::Request::kStats: return "stats";
    case wire::Request::kRender: return "render";
    case wire::Request::kSelect: return "select";
    case wire::Request::kGraphCut: return "graph_cut";
    case wire::Request::kCopy: return "copy";
    case wire::Request::kPaste: return "paste";
    case wire::Request::kComposite: return "composite";
    default: return "unknown";
  }
}

bool Writes(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kCreate:
    case wire::Request::kDrop:
    case wire::Request::kEdit:
    case wire::Request::kRevert:
    case wire::Request::kIngest:
    case wire::Request::kSelect:
    case wire::Request::kGraphCut:
    case wire::Request::kCopy:
    case wire::Request::kPaste:
    case wire::Request::kComposite: return true;
    default: return false;
  }
}

wire::Response ErrorResponse(uint64_t id, const Status& st,
                             wire::ErrorCode code = wire::ERROR_UNSPECIFIED) {
  wire::Response r;
  r.set_id(id);
  wire::ToWire(st, r.mutable_error());
  if (code != wire::ERROR_UNSPECIFIED) r.mutable_error()->set_code(code);
  return r;
}

// A dataset lookup failure is UNKNOWN_DATASET, not a generic NOT_FOUND.
Result<std::shared_ptr<Dataset>> FindDataset(Server* s, const std::string& name) {
  auto ds = s->db().GetDataset(name);
  // The engine's message names the data directory: not the client's business.
  if (!ds.ok() && ds.status().IsNotFound()) {
    return Status::NotFound("no dataset '" + name + "' on this server (list them with the "
                            "ListDatasets request, `hvdb --server ... datasets`)");
  }
  return ds;
}

wire::Response DatasetError(uint64_t id, const Status& st) {
  return ErrorResponse(id, st, st.IsNotFound() ? wire::UNKNOWN_DATASET : wire::ERROR_UNSPECIFIED);
}

wire::Response CommitResponse(uint64_t id, const CommitInfo& c) {
  wire::Response r;
  r.set_id(id);
  auto* cr = r.mutable_commit();
  cr->set_lsn(c.lsn);
  cr->set_inserted(c.inserted);
  cr->set_removed(c.removed);
  for (uint64_t a : c.assigned_ids) cr->add_assigned_ids(a);
  return r;
}

Result<Affine4> AffineFromWire(const google::protobuf::RepeatedField<double>& m,
                               const google::protobuf::RepeatedField<double>& c) {
  Affine4 a;
  if (!m.empty()) {
    if (m.size() != 16) return Status::InvalidArgument("matrix: needs 16 values");
    for (int i = 0; i < 16; ++i) a.a[static_cast<size_t>(i)] = m[i];
  }
  if (!c.empty()) {
    if (c.size() != 4) return Status::InvalidArgument("offset: needs 4 values");
    for (int i = 0; i < 4; ++i) a.c[static_cast<size_t>(i)] = c[i];
  }
  return a;
}

// The editing operators of edit/operators.h, on a worker.
wire::Response RunEditOperator(Server* s, uint64_t id, const wire::Request& req) {
  std::string name;
  switch (req.body_case()) {
    case wire::Request::kSelect: name = req.select().dataset(); break;
    case wire::Request::kGraphCut: name = req.graph_cut().dataset(); break;
    case wire::Request::kCopy: name = req.copy().dataset(); break;
    case wire::Request::kPaste: name = req.paste().dataset(); break;
    default: name = req.composite().dataset(); break;
  }
  auto ds = FindDataset(s, name);
  if (!ds.ok()) return DatasetError(id, ds.status());
  Dataset& d = **ds;
  wire::Response r;
  r.set_id(id);
  edit::ClipboardStore clipboards(s->config().data_dir);
  if (req.has_select()) {
    const wire::SelectRequest& q = req.select();
    edit::SelectRequest sr;
    auto region = wire::FromWire(q.region());
    if (!region.ok()) return ErrorResponse(id, region.status());
    sr.region = *region;
    sr.bit = static_cast<int>(std::min<uint32_t>(q.bit(), 999));
    if (!wire::SelectMode_IsValid(q.mode())) {
      return ErrorResponse(id, Status::InvalidArgument("select.mode: unknown value"));
    }
    sr.mode = static_cast<edit::SelectMode>(q.mode());
    if (q.has_lasso()) {
      edit::Lasso l;
      auto cam = wire::FromWire(q.lasso().camera());
      if (!cam.ok()) return ErrorResponse(id, cam.status());
      l.camera = *cam;
      if (q.lasso().polygon_size() % 2) {
        return ErrorResponse(id, Status::InvalidArgument("lasso.polygon: needs x y pairs"));
      }
      for (int i = 0; i + 1 < q.lasso().polygon_size(); i += 2) {
        l.polygon.push_back({q.lasso().polygon(i), q.lasso().polygon(i + 1)});
      }
      sr.shape = l;
    } else if (q.has_brush()) {
      edit::Brush b;
      auto cam = wire::FromWire(q.brush().camera());
      if (!cam.ok()) return ErrorResponse(id, cam.status());
      b.camera = *cam;
      b.u = q.brush().u();
      b.v = q.brush().v();
      b.pixel_radius = q.brush().pixel_radius();
      b.radius = q.brush().radius();
      b.depth = q.brush().nearest() ? edit::Brush::Depth::kNearest : edit::Brush::Depth::kMedian;
      sr.shape = b;
    }
    auto res = edit::Select(d, sr);
    if (!res.ok()) return ErrorResponse(id, res.status());
    auto* o = r.mutable_selected();
    o->set_matched(res->matched);
    o->set_selected(res->selected);
    o->set_lsn(res->lsn);
    if (res->brush_center) {
      for (double v : *res->brush_center) o->add_brush_center(v);
    }
  } else if (req.has_graph_cut()) {
    const wire::GraphCutRequest& q = req.graph_cut();
    edit::GraphCutRequest g;
    auto roi = wire::FromWire(q.roi());
    if (!roi.ok()) return ErrorResponse(id, roi.status());
    g.roi = *roi;
    g.foreground_bit = static_cast<int>(std::min<uint32_t>(q.foreground_bit(), 999));
    g.background_bit = static_cast<int>(std::min<uint32_t>(q.background_bit(), 999));
    g.out_bit = static_cast<int>(std::min<uint32_t>(q.out_bit(), 999));
    if (q.k() != 0) g.params.k = static_cast<int>(std::min<uint32_t>(q.k(), 64));
    if (q.intra_radius() != 0) g.params.intra_radius = q.intra_radius();
    if (q.inter_radius() != 0) g.params.inter_radius = q.inter_radius();
    g.params.use_normals = !q.colour_only();
    auto res = edit::GraphCutSelect(d, g);
    if (!res.ok()) return ErrorResponse(id, res.status());
    auto* o = r.mutable_graph_cut();
    o->set_roi_points(res->roi_points);
    o->set_selected(res->selected);
    o->set_lsn(res->lsn);
    o->set_energy(res->cut.energy);
    o->set_intra_edges(res->cut.intra_edges);
    o->set_inter_edges(res->cut.inter_edges);
    o->set_load_ms(res->load_ms);
    o->set_neighbours_ms(res->cut.neighbours_ms);
    o->set_gmm_ms(res->cut.gmm_ms);
    o->set_graph_ms(res->cut.graph_ms);
    o->set_maxflow_ms(res->cut.maxflow_ms);
    o->set_commit_ms(res->commit_ms);
  } else if (req.has_copy()) {
    const wire::CopyRequest& q = req.copy();
    std::optional<hvdb::Region> region;
    if (q.has_region()) {
      auto rr = wire::FromWire(q.region());
      if (!rr.ok()) return ErrorResponse(id, rr.status());
      region = *rr;
    }
    auto res = edit::Copy(d, static_cast<int>(std::min<uint32_t>(q.bit(), 999)), region,
                          clipboards, q.clipboard(), q.cut());
    if (!res.ok()) return ErrorResponse(id, res.status());
    r.mutable_copied()->set_points(res->points);
    r.mutable_copied()->set_lsn(res->lsn);
  } else if (req.has_paste()) {
    const wire::PasteRequest& q = req.paste();
    auto map = AffineFromWire(q.matrix(), q.offset());
    if (!map.ok()) return ErrorResponse(id, map.status());
    auto clip = clipboards.Get(q.clipboard());
    if (!clip.ok()) return ErrorResponse(id, clip.status());
    auto c = edit::Paste(d, *clip, *map);
    if (!c.ok()) return ErrorResponse(id, c.status());
    return CommitResponse(id, *c);
  } else {
    const wire::CompositeRequest& q = req.composite();
    std::vector<Point> object;
    Status st = wire::DecodeColumns(q.object(), &object);
    if (!st.ok()) return ErrorResponse(id, st);
    if (q.trajectory_size() % 3) {
      return ErrorResponse(id, Status::InvalidArgument("composite.trajectory: needs x y z per frame"));
    }
    std::vector<std::array<double, 3>> path;
    for (int i = 0; i + 2 < q.trajectory_size(); i += 3) {
      path.push_back({q.trajectory(i), q.trajectory(i + 1), q.trajectory(i + 2)});
    }
    auto c = edit::Composite(d, object, q.first_frame(), q.frame_count(), path);
    if (!c.ok()) return ErrorResponse(id, c.status());
    return CommitResponse(id, *c);
  }
  return r;
}

}  // namespace

Session::Session(Server* server, tcp::socket socket)
    : server_(server),
      socket_(std::move(socket)),
      strand_(asio::make_strand(static_cast<asio::io_context&>(socket_.get_executor().context()))),
      timer_(strand_) {}

void Session::Start() {
  server_->stats().connections_open++;
  server_->stats().connections_total++;
  socket_.set_option(tcp::no_delay(true));
  deadline_ = Clock::now() + std::chrono::seconds(std::min(server_->config().handshake_timeout_s,
                                                           server_->config().idle_timeout_s));
  auto self = shared_from_this();
  asio::dispatch(strand_, [self] {
    self->ArmTimer();
    self->ReadHeader();
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
    if (ec != asio::error::operation_aborted || !self->closed_) self->ArmTimer();
  });
}

void Session::ReadHeader() {
  auto self = shared_from_this();
  asio::async_read(socket_, asio::buffer(header_),
                   asio::bind_executor(strand_, [self](boost::system::error_code ec, size_t) {
                     if (ec || self->closed_) return self->CloseOnStrand();
                     uint32_t len;
                     if (!wire::ParseFrameHeader(self->header_,
                                                 self->server_->config().max_frame_bytes, &len)) {
                       self->close_after_write_ = true;
                       self->SendError(0, Status::InvalidArgument(
                                              "frame of " + std::to_string(len) +
                                              " bytes exceeds the limit of " +
                                              std::to_string(self->server_->config().max_frame_bytes)),
                                       wire::MALFORMED);
                       return;
                     }
                     self->ReadBody(len);
                   }));
}

void Session::ReadBody(uint32_t len) {
  body_.resize(len);
  auto self = shared_from_this();
  asio::async_read(socket_, asio::buffer(body_),
                   asio::bind_executor(strand_, [self](boost::system::error_code ec, size_t n) {
                     if (ec || self->closed_) return self->CloseOnStrand();
                     self->server_->stats().bytes_in += n + wire::kFrameHeaderSize;
                     self->deadline_ = Clock::now() + std::chrono::seconds(
                                                          self->server_->config().idle_timeout_s);
                     self->OnFrame();
                     if (!self->closed_ && !self->close_after_write_) self->ReadHeader();
                   }));
}

void Session::OnFrame() {
  if (!hello_done_) return OnHello(body_);
  wire::Request req;
  if (!req.ParseFromString(body_)) {
    close_after_write_ = true;
    SendError(0, Status::InvalidArgument("request frame is not a valid Request message"),
              wire::MALFORMED);
    return;
  }
  Dispatch(std::move(req));
}

void Session::OnHello(const std::string& payload) {
  wire::Hello hello;
  wire::Response err;
  if (!hello.ParseFromString(payload)) {
    close_after_write_ = true;
    return SendError(0, Status::InvalidArgument("the first frame must be a Hello message"),
                     wire::MALFORMED);
  }
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
  hello_done_ = true;
  wire::HelloReply reply;
  reply.set_protocol_version(wire::kProtocolVersion);
  reply.add_capabilities("draco");
  reply.add_capabilities("progressive");
  reply.add_capabilities("pipelining");
  reply.set_server_name("hvdb-server 0.1");
  reply.set_role(role_ == Role::kReadWrite ? wire::ROLE_READ_WRITE : wire::ROLE_READ_ONLY);
  std::string frame = wire::Frame(reply);
  bytes_queued_ += frame.size();
  out_.push_back(std::move(frame));
  WriteNext();
}

void Session::Dispatch(wire::Request req) {
  const uint64_t id = req.id();
  if (req.body_case() == wire::Request::BODY_NOT_SET) {
    return SendError(id, Status::InvalidArgument("request: empty or unknown request kind"),
                     wire::MALFORMED);
  }
  if (req.body_case() == wire::Request::kCancel) {
    auto it = ops_.find(req.cancel().target());
    if (it != ops_.end()) it->second->Cancel();
    wire::Response r;
    r.set_id(id);
    r.mutable_ack()->set_value(it != ops_.end() ? 1 : 0);
    return Send(r);
  }
  if (req.body_case() == wire::Request::kPing) {
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
  if (Writes(req) && role_ != Role::kReadWrite) {
    return SendError(id, Status::PermissionDenied(std::string(KindOf(req)) +
                                                  " needs a read-write token"));
  }
  auto op = std::make_shared<Op>();
  op->id = id;
  op->kind = KindOf(req);
  ops_[id] = op;
  Server* s = server_;
  switch (req.body_case()) {
    case wire::Request::kList:
      return RunOnWorker(id, [s, id] {
        wire::Response r;
        r.set_id(id);
        for (const auto& n : s->db().ListDatasets()) r.mutable_datasets()->add_names(n);
        return r;
      });
    case wire::Request::kCreate:
      return RunOnWorker(id, [s, id, c = req.create()] {
        DatasetInfo info;
        info.name = c.name();
        info.fps = c.fps();
        info.space_time_scale = c.space_time_scale() == 0 ? 1.0 : c.space_time_scale();
        info.frame_count = c.frame_count();
        for (const auto& cam : c.cameras()) {
          auto ci = wire::FromWire(cam);
          if (!ci.ok()) return ErrorResponse(id, ci.status());
          info.cameras.push_back(*ci);
        }
        auto ds = s->db().CreateDataset(info);
        if (!ds.ok()) return ErrorResponse(id, ds.status());
        wire::Response r;
        r.set_id(id);
        wire::ToWire((*ds)->Info(), r.mutable_info());
        return r;
      });
    case wire::Request::kDrop:
      return RunOnWorker(id, [s, id, name = req.drop().name()] {
        Status st = s->db().DropDataset(name);
        if (!st.ok()) return DatasetError(id, st);
        wire::Response r;
        r.set_id(id);
        r.mutable_ack();
        return r;
      });
    case wire::Request::kDescribe:
      return RunOnWorker(id, [s, id, name = req.describe().dataset()] {
        auto ds = FindDataset(s, name);
        if (!ds.ok()) return DatasetError(id, ds.status());
        wire::Response r;
        r.set_id(id);
        wire::ToWire((*ds)->Info(), r.mutable_info());
        return r;
      });
    case wire::Request::kEdit:
      return RunOnWorker(id, [s, id, e = req.edit()] {
        auto ds = FindDataset(s, e.dataset());
        if (!ds.ok()) return DatasetError(id, ds.status());
        auto txn = wire::FromWire(e);
        if (!txn.ok()) return ErrorResponse(id, txn.status());
        auto c = (*ds)->Commit(*txn);
        if (!c.ok()) return ErrorResponse(id, c.status());
        wire::Response r;
        r.set_id(id);
        auto* cr = r.mutable_commit();
        cr->set_lsn(c->lsn);
        cr->set_inserted(c->inserted);
        cr->set_removed(c->removed);
        for (uint64_t a : c->assigned_ids) cr->add_assigned_ids(a);
        return r;
      });
    case wire::Request::kRevert:
      return RunOnWorker(id, [s, id, rv = req.revert()] {
        auto ds = FindDataset(s, rv.dataset());
        if (!ds.ok()) return DatasetError(id, ds.status());
        auto c = (*ds)->Revert(rv.lsn());
        if (!c.ok()) return ErrorResponse(id, c.status());
        wire::Response r;
        r.set_id(id);
        r.mutable_commit()->set_lsn(c->lsn);
        r.mutable_commit()->set_inserted(c->inserted);
        r.mutable_commit()->set_removed(c->removed);
        return r;
      });
    case wire::Request::kStats:
      return RunOnWorker(id, [s, id, name = req.stats().dataset()] {
        wire::Response r;
        r.set_id(id);
        auto* st = r.mutable_stats();
        st->set_connections_open(s->stats().connections_open);
        st->set_connections_total(s->stats().connections_total);
        st->set_bytes_in(s->stats().bytes_in);
        st->set_bytes_out(s->stats().bytes_out);
        CacheStats c = s->db().Cache();
        st->set_cache_capacity_bytes(c.capacity_bytes);
        uint64_t lookups = c.hits + c.misses;
        st->set_cache_hit_rate(lookups ? static_cast<double>(c.hits) / lookups : 0);
        for (const auto& sum : s->stats().Summaries()) {
          auto* l = st->add_requests();
          l->set_kind(sum.kind);
          l->set_count(sum.count);
          l->set_p50_ms(sum.p50_ms);
          l->set_p95_ms(sum.p95_ms);
          l->set_p99_ms(sum.p99_ms);
        }
        if (!name.empty()) {
          auto ds = FindDataset(s, name);
          if (!ds.ok()) return DatasetError(id, ds.status());
          DatasetStats d = (*ds)->Stats();
          st->set_last_lsn((*ds)->Info().last_lsn);
          nlohmann::json j = {{"frames_with_data", d.frames_with_data}, {"points", d.points},
                              {"tombstones", d.tombstones}, {"buffered_points", d.buffered_points},
                              {"trees", d.trees}, {"tree_bytes", d.tree_bytes},
                              {"wal_bytes", d.wal_bytes}, {"leaf_utilisation", d.leaf_utilisation}};
          st->set_dataset_json(j.dump());
        }
        return r;
      });
    case wire::Request::kRender:
      return HandleRender(op, req.render());
    case wire::Request::kIngest:
      return HandleIngest(id, req.ingest());
    case wire::Request::kSelect:
    case wire::Request::kGraphCut:
    case wire::Request::kCopy:
    case wire::Request::kPaste:
    case wire::Request::kComposite:
      return RunOnWorker(id, [s, id, req] { return RunEditOperator(s, id, req); });
    case wire::Request::kQuery: {
      const wire::Query& q = req.query();
      auto region = wire::FromWire(q.region());
      if (!region.ok()) {
        ops_.erase(id);
        return SendError(id, region.status());
      }
      if (!wire::PointEncoding_IsValid(q.encoding())) {
        ops_.erase(id);
        return SendError(id, Status::InvalidArgument("query.encoding: unknown value " +
                                                     std::to_string(q.encoding())));
      }
      if (q.lod() > 64) {
        ops_.erase(id);
        return SendError(id, Status::InvalidArgument("query.lod: " + std::to_string(q.lod()) +
                                                     " is out of range"));
      }
      QueryOptions o;
      o.lod = static_cast<int>(q.lod());
      o.progressive = q.progressive();
      o.temporal_lod = !q.no_temporal_lod();
      o.label_mask = q.label_mask();
      o.batch_points = q.batch_points() == 0 ? 16384u : std::min(q.batch_points(), wire::kMaxBatchPoints);
      // A batch may overrun batch_points by up to one bucket level; keep it under 1 MiB.
      o.batch_points = std::min<size_t>(o.batch_points, wire::kMaxBatchPoints - 2048);
      op->encoding = q.encoding();
      auto self = shared_from_this();
      asio::post(server_->workers(), [self, op, s, name = q.dataset(), r = *region, o] {
        auto ds = FindDataset(s, name);
        Result<std::unique_ptr<Cursor>> cursor =
            ds.ok() ? (*ds)->Query(r, o) : Result<std::unique_ptr<Cursor>>(ds.status());
        if (!cursor.ok()) {
          wire::Response resp = ds.ok() ? ErrorResponse(op->id, cursor.status())
                                        : DatasetError(op->id, ds.status());
          asio::post(self->strand_, [self, op, resp] {
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
        self->Pump(op);
      });
      return;
    }
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

void Session::Pump(std::shared_ptr<Op> op) {
  // On a worker: produce one batch.
  auto self = shared_from_this();
  wire::Response resp;
  resp.set_id(op->id);
  bool last = false;
  Batch batch;
  Result<bool> more = op->cancelled ? Result<bool>(Status::Cancelled("query cancelled"))
                                    : op->cursor->Next(&batch);
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
    op->points += batch.points.size();
    auto* b = resp.mutable_batch();
    b->set_level(static_cast<uint32_t>(batch.level));
    b->set_level_done(batch.level_done);
    b->set_splat_scale(batch.splat_scale);
    b->set_encoding(op->encoding);
    if (op->encoding == wire::DRACO) {
      Status st = wire::EncodeDraco(batch.points, 16, b->mutable_draco());
      if (!st.ok()) {
        resp = ErrorResponse(op->id, st);
        last = true;
      }
    } else {
      wire::EncodeColumns(batch.points, b->mutable_columns());
    }
  }
  asio::post(strand_, [self, op, resp = std::move(resp), last] {
    if (self->closed_) return;
    self->Send(resp);
    if (last) {
      self->Finish(op->id);
      return;
    }
    if (self->bytes_queued_ < self->server_->config().outbound_high_water) {
      asio::post(self->server_->workers(), [self, op] { self->Pump(op); });
    } else {
      op->paused = true;  // resumed by WriteNext when the queue drains
    }
  });
}

void Session::ResumePaused() {
  auto self = shared_from_this();
  for (auto& [id, op] : ops_) {
    if (!op->paused) continue;
    op->paused = false;
    if (op->is_render) {
      asio::post(server_->workers(), [self, op = op] { self->RenderNext(op); });
    } else {
      asio::post(server_->workers(), [self, op = op] { self->Pump(op); });
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
  Server* s = server_;
  RunOnWorker(id, [s, id, name = ing.dataset(), frame = ing.frame(), frame_points] {
    auto ds = FindDataset(s, name);
    if (!ds.ok()) return DatasetError(id, ds.status());
    auto n = (*ds)->BulkLoad(frame, std::move(*frame_points));
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

void Session::Send(const wire::Response& r) {
  if (closed_) return;
  std::string frame = wire::Frame(r);
  bytes_queued_ += frame.size();
  out_.push_back(std::move(frame));
  WriteNext();
}

void Session::SendError(uint64_t id, const Status& st, wire::ErrorCode code) {
  Send(ErrorResponse(id, st, code));
}

void Session::WriteNext() {
  if (writing_ || out_.empty() || closed_) return;
  writing_ = true;
  auto self = shared_from_this();
  asio::async_write(socket_, asio::buffer(out_.front()),
                    asio::bind_executor(strand_, [self](boost::system::error_code ec, size_t n) {
                      self->writing_ = false;
                      if (ec) return self->CloseOnStrand();
                      self->server_->stats().bytes_out += n;
                      self->bytes_queued_ -= self->out_.front().size();
                      self->out_.pop_front();
                      // A write finishing is progress too: a slow reader is not idle.
                      self->deadline_ = Clock::now() + std::chrono::seconds(
                                                           self->server_->config().idle_timeout_s);
                      if (self->bytes_queued_ < self->server_->config().outbound_high_water / 2) {
                        self->ResumePaused();
                      }
                      if (self->out_.empty() && self->close_after_write_) {
                        return self->CloseOnStrand();
                      }
                      self->WriteNext();
                    }));
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
  for (auto& [id, op] : ops_) op->Cancel();
  ops_.clear();
  ingest_.clear();
  boost::system::error_code ignored;
  timer_.cancel(ignored);
  socket_.shutdown(tcp::socket::shutdown_both, ignored);
  socket_.close(ignored);
  server_->stats().connections_open--;
  server_->Forget(this);
}

}  // namespace hvdb::server
