#include "client/client.h"

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "storage/coding.h"

namespace hvdb::client {

namespace asio = boost::asio;
using asio::ip::tcp;

Status ParseAddress(const std::string& address, Options* options) {
  auto colon = address.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == address.size()) {
    return Status::InvalidArgument("--server: expected HOST:PORT, got '" + address + "'");
  }
  std::string host = address.substr(0, colon);
  if (host.size() > 2 && host.front() == '[' && host.back() == ']') {  // [::1]:7878
    host = host.substr(1, host.size() - 2);
  }
  // All digits: std::stoi alone would take "80x" for port 80.
  std::string port = address.substr(colon + 1);
  if (port.size() > 5 || port.find_first_not_of("0123456789") != std::string::npos ||
      std::stoi(port) <= 0 || std::stoi(port) > 65535) {
    return Status::InvalidArgument("--server: bad port in '" + address + "' (1..65535)");
  }
  options->host = std::move(host);
  options->port = static_cast<uint16_t>(std::stoi(port));
  return Status::OK();
}

struct Connection::Impl {
  asio::io_context io;
  tcp::socket sock{io};
  Options opts;

  // Runs the pending operation until it completes or the timeout passes (then it is aborted).
  Status Wait(bool* done, boost::system::error_code* ec, std::chrono::milliseconds timeout,
              const char* what) {
    io.restart();
    io.run_for(timeout);
    if (!*done) {
      boost::system::error_code ignored;
      sock.close(ignored);
      io.restart();
      io.run();
      return Status::IOError(std::string(what) + ": timed out after " +
                             std::to_string(timeout.count()) + " ms");
    }
    if (*ec) return Status::IOError(std::string(what) + ": " + ec->message());
    return Status::OK();
  }

  Status Write(const std::string& data) {
    bool done = false;
    boost::system::error_code ec;
    asio::async_write(sock, asio::buffer(data), [&](boost::system::error_code e, size_t) {
      ec = e;
      done = true;
    });
    return Wait(&done, &ec, opts.request_timeout, "send to hvdb-server");
  }

  Status ReadFrame(std::string* payload) {
    uint8_t header[wire::kFrameHeaderSize];
    bool done = false;
    boost::system::error_code ec;
    asio::async_read(sock, asio::buffer(header), [&](boost::system::error_code e, size_t) {
      ec = e;
      done = true;
    });
    HVDB_RETURN_IF_ERROR(Wait(&done, &ec, opts.request_timeout, "receive from hvdb-server"));
    uint32_t len = DecodeLE<uint32_t>(header);
    if (len > (256u << 20)) return Status::IOError("hvdb-server sent a frame of " + std::to_string(len) + " bytes");
    payload->resize(len);
    done = false;
    asio::async_read(sock, asio::buffer(*payload), [&](boost::system::error_code e, size_t) {
      ec = e;
      done = true;
    });
    return Wait(&done, &ec, opts.request_timeout, "receive from hvdb-server");
  }
};

Connection::Connection(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Connection::~Connection() {
  boost::system::error_code ignored;
  impl_->sock.close(ignored);
}

Result<std::unique_ptr<Connection>> Connection::Connect(const Options& options) {
  auto impl = std::make_unique<Impl>();
  impl->opts = options;
  boost::system::error_code ec;
  tcp::resolver resolver(impl->io);
  auto endpoints = resolver.resolve(options.host, std::to_string(options.port), ec);
  if (ec) return Status::IOError("resolve " + options.host + ": " + ec.message());
  bool done = false;
  asio::async_connect(impl->sock, endpoints, [&](boost::system::error_code e, const tcp::endpoint&) {
    ec = e;
    done = true;
  });
  std::string where = options.host + ":" + std::to_string(options.port);
  Status st = impl->Wait(&done, &ec, options.connect_timeout, ("connect to " + where).c_str());
  if (!st.ok()) {
    return Status::IOError(st.message() + " (is hvdb-server running there?)");
  }
  impl->sock.set_option(tcp::no_delay(true));
  wire::Hello hello;
  hello.set_protocol_version(wire::kProtocolVersion);
  hello.set_token(options.token);
  hello.set_client_name("hvdb-client 0.1");
  if (options.draco) hello.add_capabilities("draco");
  HVDB_RETURN_IF_ERROR(impl->Write(wire::Frame(hello)));
  std::string payload;
  HVDB_RETURN_IF_ERROR(impl->ReadFrame(&payload));
  wire::HelloReply reply;
  if (!reply.ParseFromString(payload) || reply.protocol_version() == 0) {
    // A refusal is an error Response with id 0.
    wire::Response r;
    if (r.ParseFromString(payload) && r.has_error()) return wire::FromWire(r.error());
    return Status::IOError(where + " did not answer the handshake like hvdb-server");
  }
  std::unique_ptr<Connection> c(new Connection(std::move(impl)));
  c->role_ = reply.role();
  return c;
}

Result<uint64_t> Connection::Send(wire::Request* req) {
  if (broken_) return Status::IOError("connection to hvdb-server is broken; reconnect");
  req->set_id(next_id_++);
  Status st = impl_->Write(wire::Frame(*req));
  if (!st.ok()) {
    broken_ = true;
    return st;
  }
  return req->id();
}

Result<wire::Response> Connection::Receive(uint64_t id) {
  auto it = pending_.find(id);
  if (it != pending_.end() && !it->second.empty()) {
    wire::Response r = std::move(it->second.front());
    it->second.pop_front();
    if (it->second.empty()) pending_.erase(it);
    return r;
  }
  for (;;) {
    if (broken_) return Status::IOError("connection to hvdb-server is broken; reconnect");
    std::string payload;
    Status st = impl_->ReadFrame(&payload);
    if (!st.ok()) {
      broken_ = true;
      return st;
    }
    wire::Response r;
    if (!r.ParseFromString(payload)) {
      broken_ = true;
      return Status::IOError("hvdb-server sent an undecodable response");
    }
    if (r.id() == id) return r;
    if (r.id() == 0 && r.has_error()) {  // connection-level: the server is closing
      broken_ = true;
      return wire::FromWire(r.error());
    }
    pending_[r.id()].push_back(std::move(r));
  }
}

Result<wire::Response> Connection::Call(wire::Request* req) {
  HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(req));
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Receive(id));
  if (r.has_error()) return wire::FromWire(r.error());
  return r;
}

Status Connection::Ping() {
  wire::Request req;
  req.mutable_ping()->set_payload("hvdb");
  return Call(&req).status();
}

Result<std::vector<std::string>> Connection::ListDatasets() {
  wire::Request req;
  req.mutable_list();
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return std::vector<std::string>(r.datasets().names().begin(), r.datasets().names().end());
}

Result<DatasetInfo> Connection::CreateDataset(const DatasetInfo& info) {
  wire::Request req;
  auto* c = req.mutable_create();
  c->set_name(info.name);
  c->set_fps(info.fps);
  c->set_space_time_scale(info.space_time_scale);
  c->set_frame_count(info.frame_count);
  for (const CameraInfo& cam : info.cameras) wire::ToWire(cam, c->add_cameras());
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return wire::FromWire(r.info());
}

Status Connection::DropDataset(const std::string& name) {
  wire::Request req;
  req.mutable_drop()->set_name(name);
  return Call(&req).status();
}

Result<DatasetInfo> Connection::Describe(const std::string& dataset) {
  wire::Request req;
  req.mutable_describe()->set_dataset(dataset);
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return wire::FromWire(r.info());
}

Result<std::unique_ptr<QueryStream>> Connection::Query(const std::string& dataset,
                                                       const Region& region,
                                                       const QueryOptions& opts) {
  wire::Request req;
  auto* q = req.mutable_query();
  q->set_dataset(dataset);
  wire::ToWire(region, q->mutable_region());
  q->set_lod(static_cast<uint32_t>(std::max(0, opts.lod)));
  q->set_progressive(opts.progressive);
  q->set_no_temporal_lod(!opts.temporal_lod);
  q->set_batch_points(static_cast<uint32_t>(std::min<size_t>(opts.batch_points, UINT32_MAX)));
  q->set_label_mask(opts.label_mask);
  q->set_encoding(impl_->opts.draco ? wire::DRACO : wire::COLUMNS);
  HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(&req));
  return std::unique_ptr<QueryStream>(new QueryStream(this, id));
}

QueryStream::~QueryStream() {
  if (done_ || conn_->broken()) return;
  // Stop the server's work and drain what is already on its way.
  if (!Cancel().ok()) return;
  Batch b;
  while (true) {
    auto r = Next(&b);
    if (!r.ok() || !*r) break;
  }
}

Result<bool> QueryStream::Next(Batch* batch) {
  if (done_) return false;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, conn_->Receive(id_));
  if (r.has_error()) {
    done_ = true;
    return wire::FromWire(r.error());
  }
  if (r.has_done()) {
    done_ = true;
    frames_.assign(r.done().frames().begin(), r.done().frames().end());
    clipped_ = r.done().clipped();
    return false;
  }
  if (!r.has_batch()) {
    done_ = true;
    return Status::IOError("hvdb-server answered a query with an unexpected message");
  }
  const wire::PointBatch& b = r.batch();
  batch->level = static_cast<int>(b.level());
  batch->level_done = b.level_done();
  batch->splat_scale = b.splat_scale();
  batch->points.clear();
  Status st = b.encoding() == wire::DRACO ? wire::DecodeDraco(b.draco(), &batch->points)
                                          : wire::DecodeColumns(b.columns(), &batch->points);
  if (!st.ok()) return Status::IOError("bad batch from hvdb-server: " + st.message());
  return true;
}

Status QueryStream::Cancel() {
  if (done_) return Status::OK();
  wire::Request req;
  req.mutable_cancel()->set_target(id_);
  HVDB_ASSIGN_OR_RETURN(uint64_t cid, conn_->Send(&req));
  // The ack is kept aside by Receive until someone asks for it; collect it now.
  HVDB_ASSIGN_OR_RETURN(wire::Response ack, conn_->Receive(cid));
  (void)ack;
  return Status::OK();
}

Result<CommitInfo> Connection::Commit(const std::string& dataset, const Transaction& txn) {
  wire::Request req;
  req.mutable_edit()->set_dataset(dataset);
  wire::ToWire(txn, req.mutable_edit());
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  CommitInfo info;
  info.lsn = r.commit().lsn();
  info.inserted = r.commit().inserted();
  info.removed = r.commit().removed();
  info.assigned_ids.assign(r.commit().assigned_ids().begin(), r.commit().assigned_ids().end());
  return info;
}

Result<CommitInfo> Connection::Revert(const std::string& dataset, uint64_t lsn) {
  wire::Request req;
  req.mutable_revert()->set_dataset(dataset);
  req.mutable_revert()->set_lsn(lsn);
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  CommitInfo info;
  info.lsn = r.commit().lsn();
  info.inserted = r.commit().inserted();
  info.removed = r.commit().removed();
  return info;
}

Result<uint64_t> Connection::Ingest(const std::string& dataset, uint32_t frame,
                                    std::span<const Point> pts) {
  const size_t chunk = wire::kMaxBatchPoints;
  // Chunks are pipelined: sent back to back, acknowledged in order.
  std::vector<uint64_t> ids;
  size_t at = 0;
  do {
    size_t n = std::min(chunk, pts.size() - at);
    wire::Request req;
    auto* ing = req.mutable_ingest();
    ing->set_dataset(dataset);
    ing->set_frame(frame);
    wire::EncodeColumns(pts.subspan(at, n), ing->mutable_points());
    at += n;
    ing->set_last(at == pts.size());
    HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(&req));
    ids.push_back(id);
  } while (at < pts.size());
  uint64_t loaded = 0;
  Status first_error;
  for (uint64_t id : ids) {
    HVDB_ASSIGN_OR_RETURN(wire::Response r, Receive(id));
    if (r.has_error() && first_error.ok()) first_error = wire::FromWire(r.error());
    if (r.has_ack()) loaded = r.ack().value();
  }
  if (!first_error.ok()) return first_error;
  return loaded;
}

Result<wire::StatsReply> Connection::Stats(const std::string& dataset) {
  wire::Request req;
  req.mutable_stats()->set_dataset(dataset);
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return r.stats();
}

Result<wire::RenderReply> Connection::Render(const wire::Render& render) {
  if (render.path_size() > 1) {
    return Status::InvalidArgument("render: a request with a path is a sequence; use "
                                   "RenderSequence");
  }
  wire::Request req;
  *req.mutable_render() = render;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  if (!r.has_render()) {
    return Status::IOError("hvdb-server answered a render with another message");
  }
  return std::move(*r.mutable_render());
}

Status Connection::RenderSequence(
    const wire::Render& render, const std::function<Status(const wire::RenderReply&)>& on_image) {
  wire::Request req;
  *req.mutable_render() = render;
  HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(&req));
  Status stopped;
  for (;;) {
    HVDB_ASSIGN_OR_RETURN(wire::Response r, Receive(id));
    if (r.has_error()) {
      Status st = wire::FromWire(r.error());
      // Our own cancellation ends the stream with CANCELLED: report why we stopped instead.
      return stopped.ok() ? st : stopped;
    }
    if (!r.has_render()) {
    return Status::IOError("hvdb-server answered a render with another message");
  }
    if (stopped.ok()) {
      stopped = on_image(r.render());
      if (!stopped.ok() && !r.render().last()) {
        wire::Request cancel;
        cancel.mutable_cancel()->set_target(id);
        HVDB_ASSIGN_OR_RETURN(uint64_t cid, Send(&cancel));
        HVDB_ASSIGN_OR_RETURN(wire::Response ack, Receive(cid));
        (void)ack;
      }
    }
    if (r.render().last()) return stopped;
  }
}

namespace {
CommitInfo CommitFromWire(const wire::CommitReply& c) {
  CommitInfo info;
  info.lsn = c.lsn();
  info.inserted = c.inserted();
  info.removed = c.removed();
  info.assigned_ids.assign(c.assigned_ids().begin(), c.assigned_ids().end());
  return info;
}
}  // namespace

Result<wire::SelectReply> Connection::Select(const wire::SelectRequest& q) {
  wire::Request req;
  *req.mutable_select() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return r.selected();
}

Result<wire::GraphCutReply> Connection::GraphCut(const wire::GraphCutRequest& q) {
  wire::Request req;
  *req.mutable_graph_cut() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return r.graph_cut();
}

Result<wire::CopyReply> Connection::Copy(const wire::CopyRequest& q) {
  wire::Request req;
  *req.mutable_copy() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return r.copied();
}

Result<CommitInfo> Connection::Paste(const wire::PasteRequest& q) {
  wire::Request req;
  *req.mutable_paste() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return CommitFromWire(r.commit());
}

Result<CommitInfo> Connection::Composite(const wire::CompositeRequest& q) {
  wire::Request req;
  *req.mutable_composite() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return CommitFromWire(r.commit());
}

Status Client::EnsureConnected() {
  if (conn_ && !conn_->broken()) return Status::OK();
  HVDB_ASSIGN_OR_RETURN(conn_, Connection::Connect(options_));
  return Status::OK();
}

}  // namespace hvdb::client
