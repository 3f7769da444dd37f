#include "client/client.h"

#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>

#include <cerrno>
#include <cstring>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "protocol/convert.h"
#include "protocol/shm.h"
#include "storage/coding.h"

namespace hvdb::client {

namespace asio = boost::asio;
using asio::ip::tcp;

Status ParseAddress(const std::string& address, Options* options) {
  if (address.rfind("unix:", 0) == 0) {
    if (address.size() == 5) return Status::InvalidArgument("--server: unix: needs a PATH");
    options->unix_path = address.substr(5);
    return Status::OK();
  }
  auto colon = address.rfind(':');
  if (colon == std::string::npos || colon == 0 || colon + 1 == address.size()) {
    return Status::InvalidArgument("--server: expected HOST:PORT or unix:PATH, got '" + address +
                                   "'");
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
  options->unix_path.clear();
  return Status::OK();
}

// The socket is used non-blocking with poll() for deadlines: no event loop per call, and
// frames are cut out of one receive buffer, so a small response costs one recv().
struct Connection::Impl {
  asio::io_context io;  // for connecting with a deadline only
  asio::generic::stream_protocol::socket sock{io};
  Options opts;
  std::string where;
  std::unique_ptr<wire::ShmRing> ring;
  std::string rbuf;  // received, not yet consumed: rbuf[rpos..]
  size_t rpos = 0;
  std::vector<uint32_t> releases;  // ring slots to hand back
  Connection* owner = nullptr;

  int fd() { return sock.native_handle(); }

  Status Poll(short events, std::chrono::steady_clock::time_point deadline, const char* what) {
    for (;;) {
      auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          deadline - std::chrono::steady_clock::now());
      if (left.count() <= 0) {
        return Status::IOError(std::string(what) + ": timed out after " +
                               std::to_string(opts.request_timeout.count()) + " ms");
      }
      pollfd p{fd(), events, 0};
      int r = ::poll(&p, 1, static_cast<int>(left.count()));
      if (r > 0) return Status::OK();
      if (r < 0 && errno != EINTR) return Status::IOError(std::string(what) + ": " + std::strerror(errno));
    }
  }

  Status WriteAll(const char* data, size_t n) {
    const auto deadline = std::chrono::steady_clock::now() + opts.request_timeout;
    while (n > 0) {
      ssize_t w = ::send(fd(), data, n, MSG_NOSIGNAL);
      if (w > 0) {
        data += w;
        n -= static_cast<size_t>(w);
      } else if (w < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
        HVDB_RETURN_IF_ERROR(Poll(POLLOUT, deadline, "send to hvdb-server"));
      } else {
        return Status::IOError(std::string("send to hvdb-server: ") + std::strerror(errno));
      }
    }
    return Status::OK();
  }
  Status Write(const std::string& data) { return WriteAll(data.data(), data.size()); }

  // One recv into dst (up to n bytes), waiting if nothing is there. Before waiting, ring slots
  // the caller is done with go back to the server, so that it never waits on us.
  Result<size_t> RecvSome(char* dst, size_t n, std::chrono::steady_clock::time_point deadline) {
    for (;;) {
      ssize_t r = ::recv(fd(), dst, n, 0);
      if (r > 0) return static_cast<size_t>(r);
      if (r == 0) return Status::IOError("hvdb-server closed the connection");
      if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
        return Status::IOError(std::string("receive from hvdb-server: ") + std::strerror(errno));
      }
      HVDB_RETURN_IF_ERROR(owner->FlushReleases());
      HVDB_RETURN_IF_ERROR(Poll(POLLIN, deadline, "receive from hvdb-server"));
    }
  }

  // Exactly n bytes into dst: first what is buffered, then large remainders straight into dst.
  Status ReadExact(char* dst, size_t n, std::chrono::steady_clock::time_point deadline) {
    size_t have = std::min(n, rbuf.size() - rpos);
    if (have > 0) std::memcpy(dst, rbuf.data() + rpos, have);
    rpos += have;
    dst += have;
    n -= have;
    if (rpos == rbuf.size()) {
      rbuf.clear();
      rpos = 0;
    }
    while (n >= (64u << 10)) {
      HVDB_ASSIGN_OR_RETURN(size_t got, RecvSome(dst, n, deadline));
      dst += got;
      n -= got;
    }
    while (n > 0) {
      // Small reads go through the buffer: one recv may bring several frames.
      char tmp[64 << 10];
      HVDB_ASSIGN_OR_RETURN(size_t got, RecvSome(tmp, sizeof(tmp), deadline));
      size_t use = std::min(n, got);
      std::memcpy(dst, tmp, use);
      dst += use;
      n -= use;
      rbuf.append(tmp + use, got - use);
    }
    return Status::OK();
  }
};

Connection::Connection(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {
  impl_->owner = this;
}
Connection::~Connection() {
  boost::system::error_code ignored;
  impl_->sock.close(ignored);
}

std::string Connection::transport() const {
  if (impl_->opts.unix_path.empty()) return "tcp " + impl_->where;
  return "unix " + impl_->opts.unix_path + (impl_->ring ? " + shared memory" : "");
}

Result<std::unique_ptr<Connection>> Connection::Connect(const Options& options) {
  auto impl = std::make_unique<Impl>();
  impl->opts = options;
  boost::system::error_code ec;
  bool done = false;
  auto wait = [&](const std::string& what) -> Status {
    impl->io.restart();
    impl->io.run_for(options.connect_timeout);
    if (!done) {
      boost::system::error_code ignored;
      impl->sock.close(ignored);
      impl->io.restart();
      impl->io.run();
      return Status::IOError(what + ": timed out after " +
                             std::to_string(options.connect_timeout.count()) + " ms");
    }
    if (ec) return Status::IOError(what + ": " + ec.message());
    return Status::OK();
  };
  const bool local = !options.unix_path.empty();
  if (local) {
    impl->where = "unix:" + options.unix_path;
    asio::local::stream_protocol::endpoint ep(options.unix_path);
    impl->sock.async_connect(asio::generic::stream_protocol::endpoint(ep),
                             [&](boost::system::error_code e) {
                               ec = e;
                               done = true;
                             });
    Status st = wait("connect to " + impl->where);
    if (!st.ok()) return Status::IOError(st.message() + " (is hvdb-server listening there?)");
  } else {
    impl->where = options.host + ":" + std::to_string(options.port);
    tcp::resolver resolver(impl->io);
    auto endpoints = resolver.resolve(options.host, std::to_string(options.port), ec);
    if (ec) return Status::IOError("resolve " + options.host + ": " + ec.message());
    Status st = Status::IOError("connect to " + impl->where + ": no address");
    for (const auto& e : endpoints) {
      boost::system::error_code ignored;
      impl->sock.close(ignored);
      done = false;
      impl->sock.async_connect(asio::generic::stream_protocol::endpoint(e.endpoint()),
                               [&](boost::system::error_code err) {
                                 ec = err;
                                 done = true;
                               });
      st = wait("connect to " + impl->where);
      if (st.ok()) break;
    }
    if (!st.ok()) return Status::IOError(st.message() + " (is hvdb-server running there?)");
    int one = 1;
    ::setsockopt(impl->fd(), IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  }
  impl->sock.non_blocking(true, ec);
  if (ec) return Status::IOError("set the socket non-blocking: " + ec.message());
  std::unique_ptr<Connection> c(new Connection(std::move(impl)));
  Impl& im = *c->impl_;
  wire::Hello hello;
  hello.set_protocol_version(wire::kProtocolVersion);
  hello.set_token(options.token);
  hello.set_client_name("hvdb-client 0.2");
  if (options.draco) hello.add_capabilities("draco");
  if (options.hvdb7) hello.add_capabilities("hvdb7");
  if (local && options.shm) hello.add_capabilities("shm");
  HVDB_RETURN_IF_ERROR(im.Write(wire::Frame(hello)));
  // The reply's first bytes may carry the ring's descriptor (SCM_RIGHTS).
  const auto deadline = std::chrono::steady_clock::now() + options.request_timeout;
  uint8_t header[wire::kFrameHeaderSize];
  int ring_fd = -1;
  if (local) {
    HVDB_RETURN_IF_ERROR(wire::RecvWithFd(im.fd(), header, sizeof(header), &ring_fd,
                                          options.request_timeout));
  } else {
    HVDB_RETURN_IF_ERROR(im.ReadExact(reinterpret_cast<char*>(header), sizeof(header), deadline));
  }
  struct FdGuard {
    int& fd;
    ~FdGuard() {
      if (fd >= 0) ::close(fd);
    }
  } guard{ring_fd};
  uint32_t len;
  bool attachment;
  if (!wire::ParseFrameHeader(header, 1u << 20, &len, &attachment) || attachment) {
    return Status::IOError(im.where + " did not answer the handshake like hvdb-server (protocol "
                           "version " + std::to_string(wire::kProtocolVersion) + ")");
  }
  std::string payload(len, '\0');
  HVDB_RETURN_IF_ERROR(im.ReadExact(payload.data(), len, deadline));
  wire::HelloReply reply;
  if (!reply.ParseFromString(payload) || reply.protocol_version() == 0) {
    // A refusal is an error Response with id 0.
    wire::Response r;
    if (r.ParseFromString(payload) && r.has_error()) return wire::FromWire(r.error());
    return Status::IOError(im.where + " did not answer the handshake like hvdb-server");
  }
  c->role_ = reply.role();
  if (reply.shm_slots() > 0) {
    if (ring_fd < 0) return Status::IOError("hvdb-server announced a ring but sent no descriptor");
    if (reply.shm_slot_bytes() % sizeof(Point) != 0 || reply.shm_slot_bytes() == 0 ||
        reply.shm_slot_bytes() > (64u << 20) || reply.shm_slots() > 4096) {
      return Status::IOError("hvdb-server announced a ring of an unexpected shape");
    }
    int fd = ring_fd;
    ring_fd = -1;
    HVDB_ASSIGN_OR_RETURN(im.ring, wire::ShmRing::Map(fd, reply.shm_slots(), reply.shm_slot_bytes()));
  }
  if (!local && options.prefer_local && !reply.local_socket().empty()) {
    // The server is on this machine: take its Unix socket (and ring) instead. If that fails
    // (another mount namespace, permissions), this TCP connection is as good, only slower.
    Options lo = options;
    lo.unix_path = reply.local_socket();
    auto fast = Connect(lo);
    if (fast.ok()) return fast;
  }
  return c;
}

Result<uint64_t> Connection::Send(wire::Request* req) {
  if (broken_) return Status::IOError("connection to hvdb-server is broken; reconnect");
  req->set_id(next_id_++);
  // Ring slots waiting to go back travel in the same write as the request.
  std::string frames;
  if (!impl_->releases.empty()) {
    wire::Request rel;
    for (uint32_t s : impl_->releases) rel.mutable_release()->add_slots(s);
    impl_->releases.clear();
    wire::AppendFrame(rel, &frames);
  }
  wire::AppendFrame(*req, &frames);
  Status st = impl_->Write(frames);
  if (!st.ok()) {
    broken_ = true;
    return st;
  }
  return req->id();
}

void Connection::ReleaseSlot(int slot) {
  impl_->releases.push_back(static_cast<uint32_t>(slot));
  // A quarter of the ring with us: hand it back now rather than when we next wait, so that the
  // server, filling a few slots a task, never runs dry while we are busy copying.
  if (impl_->releases.size() * 4 >= impl_->ring->slots()) (void)FlushReleases();
}

Status Connection::FlushReleases() {
  if (impl_->releases.empty() || broken_) return Status::OK();
  wire::Request req;
  for (uint32_t s : impl_->releases) req.mutable_release()->add_slots(s);
  impl_->releases.clear();
  Status st = impl_->Write(wire::Frame(req));
  if (!st.ok()) broken_ = true;
  return st;
}

Status Connection::ReceiveFull(uint64_t id, Incoming* in, std::vector<Point>* records) {
  auto it = pending_.find(id);
  if (it != pending_.end() && !it->second.empty()) {
    *in = std::move(it->second.front());
    it->second.pop_front();
    if (it->second.empty()) pending_.erase(it);
    if (records) records->swap(in->records);
    return Status::OK();
  }
  Impl& im = *impl_;
  for (;;) {
    if (broken_) return Status::IOError("connection to hvdb-server is broken; reconnect");
    const auto deadline = std::chrono::steady_clock::now() + im.opts.request_timeout;
    auto fail = [&](Status st) {
      broken_ = true;
      return st;
    };
    uint8_t header[wire::kFrameHeaderSize + wire::kAttachmentHeaderSize];
    Status st = im.ReadExact(reinterpret_cast<char*>(header), wire::kFrameHeaderSize, deadline);
    if (!st.ok()) return fail(st);
    uint32_t len, att = 0;
    bool has_att;
    if (!wire::ParseFrameHeader(header, 256u << 20, &len, &has_att)) {
      return fail(Status::IOError("hvdb-server sent a frame of " + std::to_string(len) + " bytes"));
    }
    if (has_att) {
      st = im.ReadExact(reinterpret_cast<char*>(header) + wire::kFrameHeaderSize,
                        wire::kAttachmentHeaderSize, deadline);
      if (!st.ok()) return fail(st);
      att = DecodeLE<uint32_t>(header + wire::kFrameHeaderSize);
      if (att % sizeof(Point) != 0 || att > (256u << 20)) {
        return fail(Status::IOError("hvdb-server sent an attachment of " + std::to_string(att) +
                                    " bytes, not whole point records"));
      }
    }
    std::string payload(len, '\0');
    st = im.ReadExact(payload.data(), len, deadline);
    if (!st.ok()) return fail(st);
    Incoming got;
    if (!got.r.ParseFromString(payload)) {
      return fail(Status::IOError("hvdb-server sent an undecodable response"));
    }
    if (has_att) {
      // Straight into the caller's batch when it is the one waiting; resize keeps the
      // elements it already has (no zeroing of a reused buffer).
      std::vector<Point>* dst = got.r.id() == id && records ? records : &got.records;
      dst->resize(att / sizeof(Point));
      st = im.ReadExact(reinterpret_cast<char*>(dst->data()), att, deadline);
      if (!st.ok()) return fail(st);
    }
    if (got.r.has_batch() && got.r.batch().shm_slot() > 0) {
      const wire::PointBatch& b = got.r.batch();
      if (!im.ring || b.shm_slot() > im.ring->slots() ||
          static_cast<uint64_t>(b.record_count()) * sizeof(Point) > im.ring->slot_bytes()) {
        return fail(Status::IOError("hvdb-server named a ring slot this connection does not have"));
      }
      got.slot = static_cast<int>(b.shm_slot()) - 1;
    }
    if (got.r.id() == 0 && got.r.has_error()) {  // connection-level: the server is closing
      broken_ = true;
      return wire::FromWire(got.r.error());
    }
    if (got.r.id() == id) {
      *in = std::move(got);
      return Status::OK();
    }
    pending_[got.r.id()].push_back(std::move(got));
  }
}

Result<wire::Response> Connection::Receive(uint64_t id) {
  Incoming in;
  HVDB_RETURN_IF_ERROR(ReceiveFull(id, &in, nullptr));
  if (in.slot >= 0) ReleaseSlot(in.slot);  // the caller asked for the message only
  return std::move(in.r);
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
  return Unary<service::op::List>({});
}

Result<DatasetInfo> Connection::CreateDataset(const DatasetInfo& info) {
  return Unary<service::op::Create>(info);
}

Status Connection::DropDataset(const std::string& name) {
  return Unary<service::op::Drop>(name).status();
}

Result<DatasetInfo> Connection::Describe(const std::string& dataset) {
  return Unary<service::op::Describe>(dataset);
}

Result<std::unique_ptr<QueryStream>> Connection::Query(const std::string& dataset,
                                                       const Region& region,
                                                       const QueryOptions& opts) {
  wire::Request req;
  auto* q = req.mutable_query();
  q->set_dataset(dataset);
  wire::ToWire(region, q->mutable_region());
  wire::ToWire(opts, q);
  q->set_encoding(impl_->opts.hvdb7     ? wire::HVDB7
                  : impl_->opts.draco   ? wire::DRACO
                  : impl_->opts.columns ? wire::COLUMNS
                                        : wire::RECORDS);
  if (impl_->opts.hvdb7) {
    q->mutable_codec()->set_position_bits(static_cast<uint32_t>(impl_->opts.hvdb7_position_bits));
    q->mutable_codec()->set_normal_bits(static_cast<uint32_t>(impl_->opts.hvdb7_normal_bits));
  }
  HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(&req));
  return std::unique_ptr<QueryStream>(new QueryStream(this, id));
}

QueryStream::~QueryStream() {
  if (held_slot_ >= 0 && !conn_->broken()) conn_->ReleaseSlot(held_slot_);
  held_slot_ = -1;
  if (done_ || conn_->broken()) return;
  // Stop the server's work and drain what is already on its way.
  if (!Cancel().ok()) return;
  Batch b;
  while (true) {
    auto r = Next(&b);
    if (!r.ok() || !*r) break;
  }
}

Result<bool> QueryStream::Next(Batch* batch) { return Advance(batch, nullptr); }
Result<bool> QueryStream::NextView(BatchView* view) { return Advance(nullptr, view); }

Result<bool> QueryStream::Advance(Batch* batch, BatchView* view) {
  if (held_slot_ >= 0) {
    conn_->ReleaseSlot(held_slot_);
    held_slot_ = -1;
  }
  if (done_) return false;
  std::vector<Point>* dst = batch ? &batch->points : &view_buf_;
  Connection::Incoming in;
  HVDB_RETURN_IF_ERROR(conn_->ReceiveFull(id_, &in, dst));
  const wire::Response& r = in.r;
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
  std::span<const Point> points;
  Status st;
  if (b.encoding() == wire::RECORDS) {
    if (in.slot >= 0) {
      points = {reinterpret_cast<const Point*>(conn_->impl_->ring->slot(static_cast<uint32_t>(in.slot))),
                b.record_count()};
    } else if (dst->size() != b.record_count()) {
      st = Status::InvalidArgument("batch announces " + std::to_string(b.record_count()) +
                                   " records, its attachment holds " + std::to_string(dst->size()));
    } else {
      points = *dst;
    }
  } else {
    dst->clear();
    st = b.encoding() == wire::DRACO   ? wire::DecodeDraco(b.draco(), dst)
         : b.encoding() == wire::HVDB7 ? wire::DecodeHvdb7(b.hvdb7(), dst)
                                       : wire::DecodeColumns(b.columns(), dst);
    points = *dst;
  }
  if (!st.ok()) {
    if (in.slot >= 0) conn_->ReleaseSlot(in.slot);
    return Status::IOError("bad batch from hvdb-server: " + st.message());
  }
  if (batch) {
    batch->level = static_cast<int>(b.level());
    batch->level_done = b.level_done();
    batch->splat_scale = b.splat_scale();
    if (in.slot >= 0) {
      // The one copy of the fast path: out of the ring into the caller's batch.
      batch->points.resize(points.size());
      std::memcpy(static_cast<void*>(batch->points.data()), points.data(), points.size_bytes());
      conn_->ReleaseSlot(in.slot);
    }
  } else {
    view->level = static_cast<int>(b.level());
    view->level_done = b.level_done();
    view->splat_scale = b.splat_scale();
    view->points = points;
    held_slot_ = in.slot;
  }
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

Result<bool> Connection::WaitFor(uint64_t id, std::chrono::milliseconds timeout) {
  if (auto it = pending_.find(id); it != pending_.end() && !it->second.empty()) return true;
  if (impl_->rpos < impl_->rbuf.size()) return true;
  if (broken_) return Status::IOError("connection to hvdb-server is broken; reconnect");
  HVDB_RETURN_IF_ERROR(FlushReleases());
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    pollfd p{impl_->fd(), POLLIN, 0};
    int r = ::poll(&p, 1, static_cast<int>(std::max<int64_t>(0, left.count())));
    if (r > 0) return true;
    if (r == 0) return false;
    if (errno != EINTR) return Status::IOError(std::string("poll: ") + std::strerror(errno));
  }
}

Result<std::unique_ptr<WatchStream>> Connection::Watch(const std::string& dataset,
                                                       std::optional<uint64_t> from_lsn) {
  wire::Request req;
  req.mutable_watch()->set_dataset(dataset);
  if (from_lsn) req.mutable_watch()->set_from_lsn(*from_lsn);
  HVDB_ASSIGN_OR_RETURN(uint64_t id, Send(&req));
  // The first answer is an error, a replayed event or LIVE: it comes at once.
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Receive(id));
  if (r.has_error()) return wire::FromWire(r.error());
  std::unique_ptr<WatchStream> w(new WatchStream(this, id));
  w->first_ = std::move(r);
  return w;
}

WatchStream::~WatchStream() {
  if (done_ || conn_->broken()) return;
  if (!Cancel().ok()) return;
  ChangeEvent ev;
  while (true) {  // what was on its way, then CANCELLED
    auto r = Next(&ev, conn_->impl_->opts.request_timeout);
    if (!r.ok() || !*r) break;
  }
}

Result<bool> WatchStream::Next(ChangeEvent* ev, std::chrono::milliseconds timeout) {
  if (done_) return false;
  wire::Response r;
  if (first_) {
    r = std::move(*first_);
    first_.reset();
  } else {
    HVDB_ASSIGN_OR_RETURN(bool ready, conn_->WaitFor(id_, timeout));
    if (!ready) return false;
    HVDB_ASSIGN_OR_RETURN(r, conn_->Receive(id_));
  }
  if (r.has_error()) {
    done_ = true;
    return wire::FromWire(r.error());
  }
  if (!r.has_event()) {
    done_ = true;
    return Status::IOError("hvdb-server answered a watch with something else than an event");
  }
  HVDB_ASSIGN_OR_RETURN(*ev, wire::FromWire(r.event()));
  if (ev->kind == ChangeEvent::Kind::kDropped || ev->kind == ChangeEvent::Kind::kLagged) {
    done_ = true;
  }
  return true;
}

Status WatchStream::Cancel() {
  if (done_) return Status::OK();
  wire::Request req;
  req.mutable_cancel()->set_target(id_);
  HVDB_ASSIGN_OR_RETURN(uint64_t cid, conn_->Send(&req));
  HVDB_ASSIGN_OR_RETURN(wire::Response ack, conn_->Receive(cid));
  (void)ack;
  return Status::OK();
}

Result<CommitInfo> Connection::Commit(const std::string& dataset, const Transaction& txn) {
  return Unary<service::op::Edit>({dataset, txn});
}

Result<CommitInfo> Connection::Revert(const std::string& dataset, uint64_t lsn) {
  return Unary<service::op::Revert>({dataset, lsn});
}

Result<CompactInfo> Connection::Compact(const std::string& dataset, uint32_t first,
                                        uint32_t last, bool photos) {
  return Unary<service::op::Compact>({dataset, {first, last, photos}});
}

Status Connection::PutPhoto(const std::string& dataset, uint32_t frame, const Photo& photo) {
  return Unary<service::op::PutPhoto>({dataset, {frame, photo}}).status();
}

Result<uint64_t> Connection::Ingest(const std::string& dataset, uint32_t frame,
                                    std::span<const Point> pts,
                                    const GaussianColumns* gaussians) {
  if (gaussians && gaussians->size() != pts.size()) {
    return Status::InvalidArgument("ingest: " + std::to_string(pts.size()) + " points but " +
                                   std::to_string(gaussians->size()) + " Gaussian records");
  }
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
    if (gaussians) wire::EncodeGaussians(*gaussians, at, n, ing->mutable_gaussians());
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
  if (render.path_size() > 1 || render.progressive()) {
    return Status::InvalidArgument("render: a request with a path or progressive gets several "
                                   "replies; use RenderSequence");
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
  return wire::FromWire(r.commit());
}

Result<CommitInfo> Connection::Composite(const wire::CompositeRequest& q) {
  wire::Request req;
  *req.mutable_composite() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return wire::FromWire(r.commit());
}

Result<CommitInfo> Connection::ImportMedia(const wire::ImportMediaRequest& q) {
  wire::Request req;
  *req.mutable_import_media() = q;
  HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
  return wire::FromWire(r.commit());
}

Status Client::EnsureConnected() {
  if (conn_ && !conn_->broken()) return Status::OK();
  if (conn_) retired_.push_back(std::move(conn_));  // streams may still point at it
  HVDB_ASSIGN_OR_RETURN(conn_, Connection::Connect(options_));
  return Status::OK();
}

}  // namespace hvdb::client
