// Session: one client connection (TCP or Unix socket, or a browser's WebSocket: the transport
// decodes its bytes into requests, server/transport.h). All I/O and session state live on the
// session's strand; request work runs on the server's worker pool and posts its responses
// back. session.cc: handshake, dispatch, the write queue; session_stream.cc: the streamed
// requests (query batches and render sequences) under flow control.
#ifndef HVDB_SERVER_SESSION_H_
#define HVDB_SERVER_SESSION_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "protocol/shm.h"
#include "protocol/wire.h"
#include "render/job.h"
#include "server/server.h"
#include "server/transport.h"
#include "service/requests.h"

namespace hvdb::server {

// Errors go out as the request table's error responses (service/requests.h).
using service::ErrorResponse;

class Session : public std::enable_shared_from_this<Session> {
 public:
  // `unix_socket`: the connection came in on the Unix socket (the fast path may be offered);
  // `loopback`: a TCP peer on this machine (the Unix socket's path is advertised to it). The
  // transport's handlers run on `strand`.
  Session(Server* server, Strand strand, std::shared_ptr<Transport> transport, bool unix_socket,
          bool loopback);
  void Start();
  // Closes the connection and cancels its requests. Safe from any thread.
  void Close();
  // Sends one error frame and closes (used for refused connections too).
  void Refuse(const Status& st);
  // Whether its Hello was accepted (it counts towards --max-connections).
  bool authenticated() const { return authenticated_; }
  // The largest ping payload answered (a pong is queued like any response; bigger pings would
  // let a client that never reads grow the server by whatever it sends).
  static constexpr size_t kMaxPingPayload = 64u << 10;

 private:
  using Clock = std::chrono::steady_clock;
  // An in-flight request.
  struct Op {
    uint64_t id = 0;
    std::string kind;
    Clock::time_point start = Clock::now();
    std::atomic<bool> cancelled{false};
    // Queries: the cursor is set on a worker and cancelled from the strand.
    std::mutex mu;
    std::unique_ptr<Cursor> cursor;
    void Cancel() {
      cancelled = true;
      if (watch_flow) watch_flow->Close();
      std::lock_guard<std::mutex> l(mu);
      if (cursor) cursor->Cancel();
    }
    wire::PointEncoding encoding = wire::COLUMNS;
    wire::CodecParams codec;  // encoding HVDB7
    bool shm = false;  // RECORDS batches go through the shared-memory ring
    uint32_t slots_held = 0;  // ring slots granted to it or with the client for it
    uint64_t points = 0;
    bool paused = false;
    // Renders: the job (set on a worker), its slot of the server's renderer pool, and the next
    // image of a sequence (advanced on the strand).
    bool is_render = false;
    std::unique_ptr<render::RenderJob> render_job;
    std::optional<render::RendererPool::Lease> render_lease;
    size_t next_image = 0;
    // Watches (session_watch.cc): the subscription (ends with the op), what crosses from the
    // publishing thread to the strand, and the LSN of the last event queued for the client.
    struct WatchFlow {
      std::atomic<uint32_t> inflight{0};
      std::atomic<bool> overflow{false};
      // Events posted and not yet written, by WatchCost: a replay waits while kReplayWindow
      // are (pacing).
      std::mutex mu;
      std::condition_variable cv;
      size_t unwritten = 0;
      bool closed = false;
      void Close() {
        std::lock_guard<std::mutex> l(mu);
        closed = true;
        cv.notify_all();
      }
      void Written(size_t cost) {
        std::lock_guard<std::mutex> l(mu);
        unwritten -= std::min(unwritten, cost);
        cv.notify_all();
      }
    };
    std::unique_ptr<WatchHandle> watch;
    std::shared_ptr<WatchFlow> watch_flow;
    std::string watch_dataset;
    uint64_t watch_sent_lsn = 0;
    size_t watch_queued = 0;  // bytes of its events queued, not yet written
  };
  // Reads the next message (the Hello, then requests) and serves it.
  void ReadNext();
  void OnHello();
  void Dispatch(wire::Request req);
  void Send(const google::protobuf::Message& m);
  void SendRecords(const wire::Response& r, std::vector<Point> records, size_t count);
  void Enqueue(OutFrame f);
  // Results held for this connection: queued to send, or being made by a granted task. Past
  // the connection's high-water mark its queries pause and no more requests are read.
  size_t Buffered() const { return bytes_queued_ + bytes_reserved_; }
  bool CanRead() const;
  void Reserve(int64_t delta);
  void SendError(uint64_t id, const Status& st, wire::ErrorCode code = wire::ERROR_UNSPECIFIED);
  void WriteNext();
  void ArmTimer();
  void CloseOnStrand();
  // Ends request `id`: records its latency and forgets it.
  void Finish(uint64_t id);
  // Runs fn on a worker; its response is sent and the request finished on the strand.
  void RunOnWorker(uint64_t id, std::function<wire::Response()> fn);
  void HandleIngest(uint64_t id, const wire::Ingest& ing);

  // ---- session_watch.cc ----
  // Subscribes on a worker (a resumed watch reads the log first); events come to the strand.
  void HandleWatch(std::shared_ptr<Op> op, const wire::Watch& w);
  // On the strand: queues the event for the client, or, when the client does not keep up (its
  // queue at the high-water mark and not draining, or too many events on their way to the
  // strand: ev null), ends the watch with a LAGGED event naming the LSN to resume from.
  void OnWatchEvent(uint64_t id, const ChangeEvent* ev);
  // Events on their way from the publishing thread to the strand, per watch.
  static constexpr uint32_t kMaxWatchInflight = 4096;
  // A replay (a watch resumed from an LSN) runs ahead of what the client has read by at most
  // this many bytes of events (WatchCost); stuck for kNotReading, it ends with LAGGED.
  static constexpr size_t kReplayWindow = 256u << 10;
  // An event's size on the wire, about (its frames dominate).
  static size_t WatchCost(const ChangeEvent& ev) { return 64 + 5 * ev.frames.size(); }

  // ---- session_stream.cc ----
  void HandleQuery(std::shared_ptr<Op> op, const wire::Query& q);
  // What the strand lets one worker task produce: ring slots to fill (fast path), or a number
  // of batches and record buffers to fill them in. The task holds its own reference to the
  // ring: a close on the strand cannot unmap it under the worker.
  struct Grant {
    std::vector<int> slots;
    std::vector<std::vector<Point>> bufs;
    size_t batches = 0;
    std::shared_ptr<wire::ShmRing> ring;
    size_t reserved = 0;  // bytes counted for the batches until they are delivered
  };
  static constexpr size_t kSlotsPerTask = 4;
  static constexpr size_t kBatchesPerTask = 2;
  // Record buffers (1 MiB) kept for reuse by a connection: what the high-water mark lets be
  // queued. More are allocated while a fast reader keeps several tasks' worth in flight.
  static constexpr size_t kMaxSpares = 2;
  static constexpr size_t kSpareBytes = wire::kMaxBatchPoints * sizeof(Point);
  void KeepSpare(std::vector<Point> buf);
  // Queued results that have not drained for this long: the client is taken as not reading.
  static constexpr std::chrono::milliseconds kNotReading{1000};
  // How long results may sit unread while the server's memory budget is crowded.
  static constexpr std::chrono::seconds kStallWhileCrowded{5};
  Grant MakeGrant(const std::shared_ptr<Op>& op);
  // Whether a query task or the next image may start: the connection is under its high-water
  // mark, and under the server's budget or holding nothing.
  bool MayProduce() const;
  // On the strand: starts the op's next batches on a worker if the connection has room (queued
  // bytes under the high-water mark, and free ring slots for the fast path); else pauses it.
  void Schedule(std::shared_ptr<Op> op);
  // What a task made: frames to send (with the records or ring slot of each batch), buffers and
  // slots it did not use, and whether the query ended.
  struct Made {
    wire::Response resp;
    std::vector<Point> records;  // RECORDS over the socket: the first `count`
    size_t count = 0;
    int held_slot = -1;          // RECORDS in a ring slot
  };
  struct Produced {
    std::vector<Made> made;
    std::vector<std::vector<Point>> back;
    std::vector<int> unused;
    bool finished = false;
    size_t reserved = 0;  // the grant's
  };
  // Makes the granted batches (any thread; touches only the op and the grant).
  Produced Produce(Op* op, Grant g);
  // On the strand: sends them, returns what was not used, schedules the next task.
  void Deliver(std::shared_ptr<Op> op, Produced out);
  // A task off the strand: Produce, then Deliver on the strand.
  void Pump(std::shared_ptr<Op> op, Grant g);
  void ResumePaused();
  // Ring slots (on the strand): -1 when none is free.
  int AcquireSlot();
  // A slot back in the free list, off its query's count.
  void ReturnSlot(int slot);
  void OnRelease(const wire::ReleaseSlots& r);
  std::vector<Point> TakeSpare();
  // Render requests: a slot of the server's renderer pool, then one image at a time on a
  // worker, sequences under the same flow control as queries.
  void HandleRender(std::shared_ptr<Op> op, const wire::Render& request);
  void RenderNext(std::shared_ptr<Op> op);

  Server* server_;
  const bool unix_socket_, loopback_;
  Strand strand_;
  std::shared_ptr<Transport> transport_;
  boost::asio::steady_timer timer_;
  Clock::time_point deadline_;
  wire::Hello hello_msg_;
  wire::Request request_;
  bool hello_done_ = false;
  std::atomic<bool> authenticated_{false};
  bool read_paused_ = false;  // back-pressure: ReadNext waits for the queue to drain
  bool reading_ = false;      // a Read is outstanding
  Role role_ = Role::kNone;
  bool closed_ = false;
  bool close_after_write_ = false;
  // Outbound frames; bytes_queued_ is what flow control looks at.
  std::deque<OutFrame> out_;
  size_t bytes_queued_ = 0;
  size_t bytes_reserved_ = 0;
  bool results_queued_ = false;  // a query's batches have been queued
  bool read_results_ = false;    // and a write completed after that: the client reads
  Clock::time_point last_drain_ = Clock::now();  // last write completed, or queue became busy
  bool writing_ = false;
  bool corked_ = false;  // frames are being queued together: write once they all are
  std::map<uint64_t, std::shared_ptr<Op>> ops_;
  // The fast path: the ring (shared with workers writing into it, so it outlives a close while
  // a batch is being made) and which slots the client holds.
  std::shared_ptr<wire::ShmRing> ring_;
  std::vector<int> free_slots_;
  std::vector<uint8_t> slot_held_;  // 1: sent to the client, not yet released
  std::vector<std::weak_ptr<Op>> slot_owner_;  // the query each slot was granted to
  // Record buffers of written RECORDS frames, reused for the next batches.
  std::vector<std::vector<Point>> spare_;
  // Bulk ingest: points of frames whose last chunk has not come yet.
  std::map<std::pair<std::string, uint32_t>, std::vector<Point>> ingest_;
  // The Gaussian records of a frame's chunks (Ingest.gaussians), beside ingest_'s points.
  std::map<std::pair<std::string, uint32_t>, GaussianColumns> ingest_gaussians_;
  size_t ingest_bytes_ = 0;
  std::set<std::pair<std::string, uint32_t>> ingest_failed_;  // until their `last` chunk
};

}  // namespace hvdb::server

#endif  // HVDB_SERVER_SESSION_H_
