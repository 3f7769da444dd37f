// hvdb-server: the storage engine served over the wire protocol (docs/PROTOCOL.md).
//
// Threads: `io_threads` run the Boost.Asio event loop (accept, read, write; every connection
// has its own strand) and make query batches, a bounded task at a time (two batches or four
// ring slots); `worker_threads` run what can take long (commits, edits, bulk loads, renders),
// so it never stalls the network. Results stream batch by batch: a query makes its next batches
// only while its connection has less than `outbound_high_water` bytes queued and, on the local
// fast path, free ring slots (flow control).
#ifndef HVDB_SERVER_SERVER_H_
#define HVDB_SERVER_SERVER_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <list>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <utility>  // before Asio: Boost 1.74's awaitable.hpp needs std::exchange

#include <boost/asio.hpp>

#include "edit/operators.h"
#include "render/renderer_pool.h"
#include "server/stats.h"
#include "service/service.h"
#include "storage/database.h"

namespace hvdb::server {

enum class LogLevel { kError = 0, kWarn = 1, kInfo = 2, kDebug = 3 };
void Log(LogLevel level, const std::string& msg);
void SetLogLevel(LogLevel level);

struct Config {
  std::string data_dir = "./data";
  // Where the data lives: "" for files under data_dir, or "rados:POOL?conf=FILE" for a Ceph
  // RADOS pool (storage/rados_env.h), data_dir then being the name prefix in the pool.
  std::string store;
  // When another server holds the data (its write lease): serve reads, follow that writer's
  // commits every follow_interval_ms, refuse writes with NOT_LEADER naming it, and take over
  // once its lease ends, instead of refusing to start. On by default with a RADOS store.
  bool follow = false;
  uint32_t follow_interval_ms = 100;
  // A reader also watches the writer's changes (a watch on its LEADER address) and follows
  // each at once; the interval is then only the safety net. Off: it follows every interval.
  bool follow_events = true;
  // Where this server tells clients to send writes while it is the writer ("": its TCP
  // --listen address with the bound port).
  std::string advertise;
  // Addresses to listen on: HOST:PORT (port 0: any free port, printed at start) and at most
  // one unix:PATH (the local fast path; "unix:" alone is DATA_DIR/hvdb.sock). Loopback TCP
  // clients are told the Unix socket's path and switch to it.
  std::vector<std::string> listen = {"127.0.0.1:7878", "unix:"};
  unsigned io_threads = std::max(1u, std::thread::hardware_concurrency());
  unsigned worker_threads = std::max(1u, std::thread::hardware_concurrency());
  size_t cache_mb = 256;
  // Frames not written for this many seconds go to the cold tier (Options::cold_after_s).
  uint32_t cold_after_s = 3600;
  uint32_t max_frame_bytes = 16u << 20;
  uint32_t max_connections = 256;
  // Connections that have not completed their Hello have a pool of their own: when it is full,
  // a new one pushes out the one that has waited longest, so silent sockets cannot keep
  // authenticated clients out (docs/PROTOCOL.md, "Limits").
  uint32_t max_preauth = 64;
  uint32_t max_inflight = 32;  // requests in flight per connection
  uint32_t idle_timeout_s = 300;
  uint32_t handshake_timeout_s = 5;
  // Results buffered for one connection (queued to send, or being made) before its queries
  // pause and the server stops reading its requests (back-pressure).
  size_t outbound_high_water = 4u << 20;
  // All connections' buffered results together ("" budget: DefaultMemoryBudget()). Past it a
  // connection that already holds results gets no more until it reads them.
  // The same number also bounds the memory that import and render jobs hold together
  // (service::JobConfig; docs/PROTOCOL.md, "Limits").
  size_t memory_budget = 0;
  // Seconds one import or render job may run (0: no bound).
  uint32_t max_job_seconds = 600;
  size_t max_ingest_bytes = 512u << 20;   // per connection, points of frames not yet loaded
  uint32_t max_slice_frames = 64;
  // Render requests (docs/PROTOCOL.md, "Rendering"): at most this many at once, server-wide
  // (more get OVERLOADED); each holds at most max_render_points points in memory.
  uint32_t max_renders = 2;
  uint64_t max_render_points = 16u << 20;
  // Slots of the shared-memory ring of each fast-path connection (1 MiB each; 0: no ring).
  uint32_t shm_slots = 16;
  bool sync = true;
  std::string token_file;  // lines "TOKEN ro|rw"; required for a non-loopback address
  std::string port_file;   // written with the bound port once listening
  // HTTP/WebSocket for the browser (server/http.h): HOST:PORT, "" for none; the web viewer's
  // files ("": DefaultWebRoot()); other origins whose pages may open the WebSocket.
  std::string http_listen;
  std::string web_root;
  std::vector<std::string> http_origins;
};

// Where the web viewer's files are when --web-root is not given: the source tree's web/ for a
// binary in its build tree, else the installed share/hvdb/web.
std::string DefaultWebRoot();

// --memory-budget's default: an eighth of the machine's memory.
size_t DefaultMemoryBudget();

enum class Role { kNone, kReadOnly, kReadWrite };

class Session;
class HttpFrontend;

class Server {
 public:
  static Result<std::unique_ptr<Server>> Create(const Config& config);
  ~Server();
  // Runs until Stop() (or SIGINT/SIGTERM when handle_signals). Returns when all work is done.
  void Run(bool handle_signals);
  // Stops accepting, cancels in-flight work, closes connections. Thread-safe.
  void Stop();
  uint16_t port() const { return port_; }
  // The --http port (0 if none) and the web root it serves.
  uint16_t http_port() const;
  std::string web_root() const;
  // The absolute path of the Unix socket ("" if none).
  const std::string& local_socket() const { return local_socket_; }

  // For sessions.
  const Config& config() const { return config_; }
  Database& db() { return *db_; }
  // "writer" or "reader", and the writer's address; NotLeader naming it, for a refused write.
  std::string role() const { return db_->follower() ? "reader" : "writer"; }
  Status NotLeader(const std::string& what) const;
  // What the stats and server_stats requests report of this server.
  service::ServerCounters Counters();
  boost::asio::thread_pool& workers() { return workers_; }
  boost::asio::io_context& io() { return io_; }
  ServerStats& stats() { return stats_; }
  render::RendererPool& renders() { return renders_; }
  // The last graph cut's graph and flow, for re-cuts after more strokes (edit/operators.h).
  edit::GraphCutCache& graph_cuts() { return graph_cuts_; }
  // The executor every request runs through (service/service.h).
  service::Service& service() { return service_; }
  // Role of a token; kNone if it is unknown (or tokens are required and none was given).
  // Failed attempts are logged (at most one line a second, never the token).
  Role Authenticate(const std::string& token);
  // A closed connection leaves; `freed` bytes of results went with it.
  void Forget(Session* s, size_t freed);
  // Starts serving a connection in the pre-authentication pool (when the pool is full the
  // connection there longest is closed to make room); the HTTP front end admits its WebSockets
  // here too.
  void Admit(std::shared_ptr<Session> session);
  // After a good Hello: moves the session out of the pre-authentication pool; false (and the
  // caller refuses it as OVERLOADED) when --max-connections are authenticated already.
  bool Authenticated(Session* s);
  // OVERLOADED for a connection past --max-connections.
  Status AtConnectionLimit() const;
  // Results buffered in all connections (server-wide memory budget). Past 5/8 of it the server
  // is crowded: connections that hold results get none more, and the next quarter is for
  // connections that hold nothing (a client that reads is never starved by ones that do not);
  // past 7/8 no connection gets more. The last eighth is for what connections hold besides
  // results (their state, the allocator's slack), so that the process stays within the budget.
  void AddBuffered(int64_t delta) { buffered_ += delta; }
  bool Crowded() const { return buffered_.load() >= static_cast<int64_t>(budget_ / 8 * 5); }
  bool OverBudget() const { return buffered_.load() >= static_cast<int64_t>(budget_ / 8 * 7); }
  int64_t buffered() const { return buffered_.load(); }
  size_t budget() const { return budget_; }

 private:
  Server(Config config, std::unique_ptr<Database> db);
  Status Listen();
  Status ListenUnix(const std::string& path);
  // While a reader: refreshes from the writer's files and tries to take over (server.cc).
  void FollowLoop();
  // While a reader: watches the writer's changes and wakes FollowLoop on each (server.cc).
  void LeaderWatchLoop();
  void Accept();
  void AcceptUnix();

  Config config_;
  std::unique_ptr<Env> store_env_;  // the RADOS store (outlives db_), null for files
  std::unique_ptr<Database> db_;
  boost::asio::io_context io_;
  boost::asio::thread_pool workers_;
  render::RendererPool renders_;
  edit::GraphCutCache graph_cuts_;
  service::Service service_;
  boost::asio::ip::tcp::acceptor acceptor_;
  boost::asio::local::stream_protocol::acceptor unix_acceptor_;
  std::string tcp_listen_;    // "" if none
  std::string local_socket_;  // "" if none
  boost::asio::signal_set signals_;
  std::unique_ptr<HttpFrontend> http_;
  std::map<std::string, Role> tokens_;
  bool require_token_ = false;
  std::string advertise_;
  std::thread follower_;
  std::mutex follow_mu_;
  std::condition_variable follow_cv_;
  bool follow_stop_ = false;
  bool follow_wake_ = false;  // the writer published a change (follow_mu_)
  std::atomic<bool> watch_stop_{false};
  uint16_t port_ = 0;
  ServerStats stats_;
  std::mutex mu_;
  std::set<std::shared_ptr<Session>> sessions_;
  // The pre-authentication pool, oldest first, and how many have authenticated.
  std::list<std::weak_ptr<Session>> preauth_;
  size_t authenticated_ = 0;
  std::atomic<bool> stopping_{false};
  size_t budget_ = 0;
  std::atomic<int64_t> buffered_{0};
  // Failed token attempts since the last logged one (logging is rate-limited).
  std::mutex auth_log_mu_;
  std::chrono::steady_clock::time_point last_auth_log_{};
  uint64_t auth_failures_unlogged_ = 0;
  // Returning freed memory to the OS after connections close (at most once a second).
  std::atomic<bool> trim_pending_{false};
  std::atomic<size_t> freed_since_trim_{0};
  boost::asio::basic_waitable_timer<std::chrono::steady_clock, boost::asio::wait_traits<std::chrono::steady_clock>,
                                    boost::asio::strand<boost::asio::io_context::executor_type>>
      trim_timer_;  // on a strand of its own: armed from any network thread
  void TrimSoon();
  static constexpr size_t kTrimAfterBytes = 4u << 20;
};

}  // namespace hvdb::server

#endif  // HVDB_SERVER_SERVER_H_
