// The hvdb client library: talks to hvdb-server over the wire protocol (docs/PROTOCOL.md).
//
// Connection is one TCP or Unix-socket connection. Its synchronous calls (Ping, Describe,
// Commit, ...) send a request and wait for its answer; Query returns a QueryStream that yields
// batches as they arrive, so many requests can be in flight on one connection (pipelining:
// Send/Receive). Query results come as the stored 64-byte records: over TCP in the frames'
// attachments, read straight into the caller's batch; over the Unix socket through a
// shared-memory ring (the local fast path), which a loopback TCP connection switches to by
// itself. Every call has a deadline (Options::request_timeout). A Connection is not
// thread-safe: use one per thread. Client adds reconnection with exponential backoff for
// requests that are safe to repeat (everything but Commit, Revert and Ingest, which are
// reported as failed instead).
#ifndef HVDB_CLIENT_CLIENT_H_
#define HVDB_CLIENT_CLIENT_H_

#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <thread>
#include <vector>

#include "protocol/wire.h"
#include "service/requests.h"
#include "storage/database.h"

namespace hvdb::client {

struct Options {
  std::string host = "127.0.0.1";
  uint16_t port = 7878;
  std::string unix_path;  // set: connect to this Unix socket instead of host:port
  // On loopback TCP, move to the Unix socket the server names (the local fast path).
  bool prefer_local = true;
  bool shm = true;        // on a Unix socket, ask for the shared-memory ring
  bool columns = false;   // ask for point columns instead of records (interop, tests)
  std::string token;  // for servers that require one
  std::chrono::milliseconds connect_timeout{5000};
  std::chrono::milliseconds request_timeout{120000};
  bool draco = false;  // ask for Draco-coded batches (positions quantised, colours, ids, frames)
  // Ask for hvdb7-coded batches (codec/: every attribute; positions on a grid of 2^bits over
  // each batch's extent, 0: the server's default of 16; colours and lossless fields exact).
  bool hvdb7 = false;
  int hvdb7_position_bits = 0;
  int hvdb7_normal_bits = 0;  // 0: the server's default of 12
  int max_attempts = 5;                           // Client: tries per idempotent request
  std::chrono::milliseconds backoff{100};         // Client: first retry delay, doubled each time
};

// Parses "HOST:PORT" into options.host/port, or "unix:PATH" into options.unix_path.
Status ParseAddress(const std::string& address, Options* options);

class Connection;

// A batch as it lies in the connection's buffers: valid until the stream's next call.
struct BatchView {
  int level = 0;
  bool level_done = false;
  float splat_scale = 1.f;
  std::span<const Point> points;
};

// The results of one query, batch by batch. Destroying it before the end cancels the query.
class QueryStream {
 public:
  ~QueryStream();
  QueryStream(const QueryStream&) = delete;
  QueryStream& operator=(const QueryStream&) = delete;
  // Next batch; false at the end. Errors from the server come back as their Status.
  Result<bool> Next(Batch* batch);
  // The next batch without a copy: on the fast path the records in the shared-memory ring
  // (the slot goes back to the server at the next call), else the received records.
  Result<bool> NextView(BatchView* view);
  // Asks the server to stop; Next() then reports Cancelled (or the end, if it came first).
  Status Cancel();
  uint64_t id() const { return id_; }
  // Valid after Next() returned false.
  const std::vector<uint32_t>& frames() const { return frames_; }
  bool clipped() const { return clipped_; }

 private:
  friend class Connection;
  QueryStream(Connection* c, uint64_t id) : conn_(c), id_(id) {}
  Result<bool> Advance(Batch* batch, BatchView* view);
  Connection* conn_;
  uint64_t id_;
  bool done_ = false;
  int held_slot_ = -1;            // NextView's ring slot, released at the next call
  std::vector<Point> view_buf_;   // NextView's records off the socket
  std::vector<uint32_t> frames_;
  bool clipped_ = false;
};

// A watch of a dataset's changes (docs/PROTOCOL.md, "Watching"). Destroying it before the
// end cancels it on the server.
class WatchStream {
 public:
  ~WatchStream();
  WatchStream(const WatchStream&) = delete;
  WatchStream& operator=(const WatchStream&) = delete;
  // The next event, waiting at most `timeout` for it: false if none came in time (the watch
  // goes on). The watch has ended after a kDropped or kLagged event (then false at once).
  // Errors from the server come back as their Status.
  Result<bool> Next(ChangeEvent* ev, std::chrono::milliseconds timeout);
  // Ends the watch; Next() then reports Cancelled, after the events already on their way.
  Status Cancel();
  bool ended() const { return done_; }

 private:
  friend class Connection;
  WatchStream(Connection* c, uint64_t id) : conn_(c), id_(id) {}
  Connection* conn_;
  uint64_t id_;
  bool done_ = false;
  std::optional<wire::Response> first_;  // the answer Connection::Watch waited for
};

class Connection {
 public:
  static Result<std::unique_ptr<Connection>> Connect(const Options& options);
  ~Connection();
  Connection(const Connection&) = delete;
  Connection& operator=(const Connection&) = delete;

  Status Ping();
  Result<std::vector<std::string>> ListDatasets();
  Result<DatasetInfo> CreateDataset(const DatasetInfo& info);
  Status DropDataset(const std::string& name);
  Result<DatasetInfo> Describe(const std::string& dataset);
  Result<std::unique_ptr<QueryStream>> Query(const std::string& dataset, const Region& region,
                                             const QueryOptions& opts = {});
  Result<CommitInfo> Commit(const std::string& dataset, const Transaction& txn);
  Result<CommitInfo> Revert(const std::string& dataset, uint64_t lsn);
  // Frames [first, last] into the cold tier now.
  Result<CompactInfo> Compact(const std::string& dataset, uint32_t first, uint32_t last,
                              bool photos = false);
  Status PutPhoto(const std::string& dataset, uint32_t frame, const Photo& photo);
  // Bulk-loads the points into `frame`, sent in chunks of at most 1 MiB.
  // gaussians: a Gaussian-splat dataset's records of pts, sent with each chunk.
  Result<uint64_t> Ingest(const std::string& dataset, uint32_t frame, std::span<const Point> pts,
                          const GaussianColumns* gaussians = nullptr);
  Result<wire::StatsReply> Stats(const std::string& dataset = "");
  // Subscribes to the dataset's changes ("": every dataset's, live only); from_lsn: the changes
  // after it first. Returns once the server has accepted it (errors such as an unknown dataset
  // or a from_lsn past the last LSN come back here). A Connection with a watch still serves
  // other requests; the events wait for the stream.
  Result<std::unique_ptr<WatchStream>> Watch(const std::string& dataset,
                                             std::optional<uint64_t> from_lsn = std::nullopt);

  // Editing operators (edit/operators.h), run by the server next to the data. Each takes the
  // request message with its dataset set, and returns the server's reply.
  Result<wire::SelectReply> Select(const wire::SelectRequest& req);
  Result<wire::GraphCutReply> GraphCut(const wire::GraphCutRequest& req);
  Result<wire::CopyReply> Copy(const wire::CopyRequest& req);
  Result<CommitInfo> Paste(const wire::PasteRequest& req);
  Result<CommitInfo> Composite(const wire::CompositeRequest& req);
  Result<CommitInfo> ImportMedia(const wire::ImportMediaRequest& req);
  // Rendering (docs/PROTOCOL.md, "Rendering"): the image of a single-view request.
  Result<wire::RenderReply> Render(const wire::Render& req);
  // A sequence (a request with a path, or a progressive one: preview then image; a single
  // view works too): on_image gets every reply as it arrives, in order. A non-OK status from on_image cancels the rest and is returned.
  Status RenderSequence(const wire::Render& req,
                        const std::function<Status(const wire::RenderReply&)>& on_image);

  // A unary request of the table (service/requests.h), encoded and decoded with its op's pair.
  // The methods above that take values are this, for the op of their kind.
  template <typename Op>
  Result<typename Op::Out> Unary(const typename Op::In& in) {
    wire::Request req;
    Op::Put(in, &req);
    HVDB_ASSIGN_OR_RETURN(wire::Response r, Call(&req));
    return Op::TakeReply(r);
  }
  // One request, its one response (an error response as its Status): the wire level.
  Result<wire::Response> Call(wire::Request* req);

  // Pipelining: send a request (its id is assigned and returned), collect its responses later.
  Result<uint64_t> Send(wire::Request* req);
  // The next response to request `id` (responses to other requests are kept for later).
  Result<wire::Response> Receive(uint64_t id);

  wire::Role role() const { return role_; }
  bool broken() const { return broken_; }
  // "tcp HOST:PORT", "unix PATH" or "unix PATH + shared memory": what this connection uses.
  std::string transport() const;

 private:
  friend class QueryStream;
  friend class WatchStream;
  struct Impl;
  // A response with what came beside its message: the records of a RECORDS batch, or the ring
  // slot that holds them.
  struct Incoming {
    wire::Response r;
    std::vector<Point> records;
    int slot = -1;
  };
  explicit Connection(std::unique_ptr<Impl> impl);
  // The next response to `id`; a records attachment for it goes straight into *records
  // (when given) instead of in->records.
  Status ReceiveFull(uint64_t id, Incoming* in, std::vector<Point>* records);
  // Whether a response to `id` is here or bytes have come within `timeout`.
  Result<bool> WaitFor(uint64_t id, std::chrono::milliseconds timeout);
  // Ring slots go back to the server in one frame, when the client is about to wait.
  void ReleaseSlot(int slot);
  Status FlushReleases();
  std::unique_ptr<Impl> impl_;
  uint64_t next_id_ = 1;
  wire::Role role_ = wire::ROLE_NONE;
  bool broken_ = false;
  std::map<uint64_t, std::deque<Incoming>> pending_;
};

// A Connection that reconnects (with exponential backoff) when the server goes away.
class Client {
 public:
  explicit Client(Options options) : options_(std::move(options)) {}
  // Runs fn on a live connection, reconnecting and retrying when the connection breaks and
  // `idempotent` is set.
  template <typename T>
  Result<T> Run(bool idempotent, const std::function<Result<T>(Connection&)>& fn);
  Connection* connection() { return conn_.get(); }
  Status EnsureConnected();

 private:
  Options options_;
  std::unique_ptr<Connection> conn_;
  // Broken connections replaced by a reconnect: kept (closed, small) until the client goes,
  // because a QueryStream opened on one still points at it and may yet be destroyed.
  std::vector<std::unique_ptr<Connection>> retired_;
};

template <typename T>
Result<T> Client::Run(bool idempotent, const std::function<Result<T>(Connection&)>& fn) {
  auto delay = options_.backoff;
  Status last = Status::IOError("not attempted");
  const int attempts = std::max(1, options_.max_attempts);
  for (int attempt = 0; attempt < attempts; ++attempt) {
    if (attempt > 0) {
      std::this_thread::sleep_for(delay);
      delay *= 2;
    }
    Status st = EnsureConnected();
    if (!st.ok()) {
      // A refused token or protocol version will not change by retrying.
      if (st.code() != StatusCode::kIOError) return st;
      last = st;
      continue;
    }
    Result<T> r = fn(*conn_);
    if (r.ok() || !conn_->broken()) return r;
    last = r.status();
    retired_.push_back(std::move(conn_));
    if (!idempotent) return last;  // it may have been applied: the caller must decide
  }
  return last;
}

}  // namespace hvdb::client

#endif  // HVDB_CLIENT_CLIENT_H_
