// 8. End to end through hvdb-server: a full frame and 10,000-point windows through the local
// fast path (Unix socket + shared-memory ring) and through TCP loopback (records in frame
// attachments; the point-column encoding of protocol v1 for reference), each next to the same
// queries embedded and to the loopback limit of the same bytes (a plain socket pair moving
// them, request and answer, in the same run); then 1, 8 and 32 concurrent clients on both
// paths: queries/s and latency percentiles. The server is the real binary (HVDB_SERVER_BIN),
// started on a free loopback port and its own Unix socket, and stopped with SIGTERM.
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>

#include "bench/bench.h"
#include "client/client.h"

namespace hvdb::bench {

namespace {

const char* kExp = "8-server";

// A window over [0,1)^3 frame 0 holding about `want` of `n` uniform points.
Window RandomWindow(Rng& rng, size_t n, size_t want) {
  const double side = std::cbrt(static_cast<double>(want) / static_cast<double>(n));
  Window w;
  for (int a = 0; a < 3; ++a) {
    double lo = rng.Uniform() * (1 - side);
    w.lo[a] = lo;
    w.hi[a] = lo + side;
  }
  w.lo[3] = w.hi[3] = 0;
  return w;
}

class ServerProcess {
 public:
  ServerProcess(const std::string& data, const std::string& sock) {
    port_file_ = data + ".port";
    ::unlink(port_file_.c_str());
    std::vector<std::string> args = {HVDB_SERVER_BIN, "--data",      data,        "--listen",
                                     "127.0.0.1:0",   "--listen",    "unix:" + sock,
                                     "--port-file",   port_file_,    "--log-level", "warn",
                                     "--cache-mb",    "1024"};
    // HVDB_BENCH_SERVER_ARGS: more flags for the server (e.g. "--io-threads 1 --workers 2").
    if (const char* extra = std::getenv("HVDB_BENCH_SERVER_ARGS")) {
      std::istringstream in(extra);
      for (std::string a; in >> a;) args.push_back(a);
    }
    pid_ = ::fork();
    if (pid_ == 0) {
      std::vector<char*> argv;
      for (auto& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
    for (int i = 0; i < 1000 && port_ == 0; ++i) {
      std::ifstream in(port_file_);
      int p = 0;
      if (in >> p && p > 0) port_ = static_cast<uint16_t>(p);
      if (port_ == 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    if (port_ == 0) Die("hvdb-server did not start (" HVDB_SERVER_BIN ")");
  }
  ~ServerProcess() {
    ::kill(pid_, SIGTERM);
    int status = 0;
    ::waitpid(pid_, &status, 0);
  }
  uint16_t port() const { return port_; }

 private:
  std::string port_file_;
  pid_t pid_ = -1;
  uint16_t port_ = 0;
};

// The two ways a client on this machine reaches the server.
enum class Path { kTcp, kLocal, kTcpColumns, kEmbedded };

client::Options PathOptions(Path p, uint16_t port, const std::string& sock) {
  client::Options o;
  o.port = port;
  o.prefer_local = false;
  if (p == Path::kLocal) o.unix_path = sock;
  o.columns = p == Path::kTcpColumns;
  return o;
}

std::unique_ptr<client::Connection> Connect(const client::Options& o) {
  auto c = Check(client::Connection::Connect(o), "connect to hvdb-server");
  if (o.unix_path.empty() == (c->transport().find("shared memory") != std::string::npos)) {
    Die("connected without the transport asked for: " + c->transport());
  }
  return c;
}

// Runs the query through the server to the end, copying every batch into the caller's
// Batch (like Cursor::Next embedded), or looking at it in place (`view`); returns (ms, points).
// `reuse`: the caller's batch, kept across queries as a long-lived client keeps its buffer.
std::pair<double, uint64_t> RemoteQuery(client::Connection& c, const Region& r, bool view = false,
                                        Batch* reuse = nullptr) {
  Timer t;
  auto q = Check(c.Query("e2e", r), "remote query");
  uint64_t n = 0;
  if (view) {
    client::BatchView v;
    while (Check(q->NextView(&v), "remote batch")) n += v.points.size();
  } else {
    Batch own;
    Batch& b = reuse ? *reuse : own;
    while (Check(q->Next(&b), "remote batch")) n += b.points.size();
  }
  return {t.Ms(), n};
}

// The same embedded, into the caller's batch.
std::pair<double, uint64_t> EmbeddedQuery(Dataset& ds, const Region& r, Batch* b) {
  Timer t;
  auto cursor = Check(ds.Query(r, QueryOptions()), "query");
  uint64_t n = 0;
  while (Check(cursor->Next(b), "query next")) n += b->points.size();
  return {t.Ms(), n};
}

// The loopback limit for the same bytes: a connected socket pair (TCP on 127.0.0.1, or a Unix
// stream socket pair), a one-byte request, then `bytes` sent from one buffer and received into
// another, as a query's answer would be.
class SocketPair {
 public:
  SocketPair(bool tcp, size_t bytes) : src_(bytes, 7), dst_(bytes) {
    if (tcp) {
      int lst = ::socket(AF_INET, SOCK_STREAM, 0);
      sockaddr_in a{};
      a.sin_family = AF_INET;
      a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
      socklen_t len = sizeof(a);
      if (::bind(lst, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0 || ::listen(lst, 1) != 0 ||
          ::getsockname(lst, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
        Die("socket pair: listen on loopback");
      }
      fds_[0] = ::socket(AF_INET, SOCK_STREAM, 0);
      if (::connect(fds_[0], reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) Die("socket pair: connect");
      fds_[1] = ::accept(lst, nullptr, nullptr);
      ::close(lst);
      int one = 1;
      for (int fd : fds_) ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
    } else if (::socketpair(AF_UNIX, SOCK_STREAM, 0, fds_) != 0) {
      Die("socketpair");
    }
    server_ = std::thread([this] {
      char req;
      while (::recv(fds_[1], &req, 1, MSG_WAITALL) == 1 && req == 1) {
        for (size_t at = 0; at < src_.size();) {
          ssize_t n = ::send(fds_[1], src_.data() + at, src_.size() - at, MSG_NOSIGNAL);
          if (n <= 0) return;
          at += static_cast<size_t>(n);
        }
      }
    });
  }
  ~SocketPair() {
    char stop = 0;
    (void)!::send(fds_[0], &stop, 1, MSG_NOSIGNAL);
    server_.join();
    ::close(fds_[0]);
    ::close(fds_[1]);
  }
  // One request and its answer; ms.
  double RoundTrip() {
    Timer t;
    char req = 1;
    if (::send(fds_[0], &req, 1, 0) != 1) Die("socket pair: send");
    for (size_t at = 0; at < dst_.size();) {
      ssize_t n = ::recv(fds_[0], dst_.data() + at, dst_.size() - at, 0);
      if (n <= 0) Die("socket pair: recv");
      at += static_cast<size_t>(n);
    }
    return t.Ms();
  }

 private:
  std::vector<char> src_, dst_;
  int fds_[2] = {-1, -1};
  std::thread server_;
};

const char* PathName(Path p) {
  return p == Path::kLocal ? "local" : p == Path::kTcp ? "tcp" : p == Path::kEmbedded ? "embedded" : "tcp_columns";
}

}  // namespace

void RunServer(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  const std::string dir = c.scratch + "/e2e";
  const std::string sock = c.scratch + "/e2e.sock";
  RemoveAll(dir);
  RemoveAll(dir + "-embedded");
  const size_t n = c.e2e_points;
  const uint64_t frame_bytes = static_cast<uint64_t>(n) * kPointRecordSize;
  Log("8 server: one frame of %zu points, windows of ~%zu points", n, c.win_result);
  std::vector<Window> windows;
  nlohmann::json fp = {{"points", n}};
  nlohmann::json wp = {{"points", n}, {"result", c.win_result}};
  // The embedded side reads its own copy of the dataset (the server holds the other's lock),
  // open through the whole experiment: every figure below is measured interleaved with the
  // others, rep by rep, so that a noisy machine moves them together.
  Db emb = Db::Create(dir + "-embedded", "e2e", c.DbOptions(), c.fps);
  {
    auto pts = UniformPoints(n, c.seed + 8000, 0);
    Db db = Db::Create(dir, "e2e", c.DbOptions(), c.fps);
    Check(db.ds->BulkLoad(0, pts), "bulk load");
    db.Close();
    Check(emb.ds->BulkLoad(0, std::move(pts)), "bulk load (embedded copy)");
  }
  Rng rng(c.seed + 8001);
  for (int i = 0; i < c.win_queries; ++i) windows.push_back(RandomWindow(rng, n, c.win_result));
  QueryOptions qo;
  uint64_t win_points = 0;
  for (const Window& w : windows) win_points += RunQuery(*emb.ds, w, qo).points;
  const uint64_t win_bytes = win_points / windows.size() * kPointRecordSize;

  ServerProcess server(dir, sock);
  const std::vector<Path> paths = {Path::kLocal, Path::kTcp, Path::kTcpColumns};
  std::map<Path, std::unique_ptr<client::Connection>> conns;
  for (Path path : paths) conns[path] = Connect(PathOptions(path, server.port(), sock));
  SocketPair tcp_frame(true, frame_bytes), unix_frame(false, frame_bytes), tcp_win(true, win_bytes);
  // Warm: one pass of everything.
  RunQuery(*emb.ds, FrameWindow(0, c.fps), qo);
  for (Path path : paths) RemoteQuery(*conns[path], FrameWindow(0, c.fps));
  for (const Window& w : windows) {
    for (Path path : paths) RemoteQuery(*conns[path], w);
  }
  std::map<std::string, std::vector<double>> ms;  // figure -> samples
  const int frame_reps = 3 * c.warm_reps;
  for (int r = 0; r < frame_reps; ++r) {
    ms["frame.embedded"].push_back(RunQuery(*emb.ds, FrameWindow(0, c.fps), qo).ms);
    for (Path path : paths) {
      auto [t, got] = RemoteQuery(*conns[path], FrameWindow(0, c.fps));
      if (got != n) Die(std::string("8 server: the frame through ") + PathName(path) + " has " + std::to_string(got) + " points");
      ms[std::string("frame.") + PathName(path)].push_back(t);
    }
    ms["frame.local_view"].push_back(RemoteQuery(*conns[Path::kLocal], FrameWindow(0, c.fps), true).first);
    ms["frame.socketpair_tcp"].push_back(tcp_frame.RoundTrip());
    ms["frame.socketpair_unix"].push_back(unix_frame.RoundTrip());
  }
  for (const Window& w : windows) {
    ms["window.embedded"].push_back(RunQuery(*emb.ds, w, qo).ms);
    for (Path path : paths) ms[std::string("window.") + PathName(path)].push_back(RemoteQuery(*conns[path], w).first);
    ms["window.socketpair_tcp"].push_back(tcp_win.RoundTrip());
  }
  conns.clear();
  R.Add("e2e.frame.embedded", kExp, "ms", ms["frame.embedded"], fp, "full frame, embedded, warm");
  R.Add("e2e.window.embedded", kExp, "ms", ms["window.embedded"], wp, "10k-point window, embedded, warm");
  R.Add("e2e.frame.socketpair_tcp", kExp, "ms", ms["frame.socketpair_tcp"], {{"bytes", frame_bytes}},
        "the frame's bytes through a plain TCP loopback socket pair (request and answer)");
  R.Add("e2e.frame.socketpair_unix", kExp, "ms", ms["frame.socketpair_unix"], {{"bytes", frame_bytes}},
        "the frame's bytes through a plain Unix socket pair (request and answer)");
  R.Add("e2e.window.socketpair_tcp", kExp, "ms", ms["window.socketpair_tcp"], {{"bytes", win_bytes}},
        "a window's bytes through a plain TCP loopback socket pair (request and answer)");
  for (Path path : paths) {
    const std::string p = PathName(path);
    const std::string how = path == Path::kLocal ? "through the Unix socket and shared memory"
                            : path == Path::kTcp ? "through TCP loopback (records)"
                                                 : "through TCP loopback (point columns, v1)";
    R.Add("e2e.frame." + p, kExp, "ms", ms["frame." + p], fp, "full frame " + how + ", one client, warm");
    R.Add("e2e.window." + p, kExp, "ms", ms["window." + p], wp, "10k-point window " + how + ", warm");
    R.Ratio("e2e.frame." + p + "_over_embedded", kExp, "e2e.frame." + p, "e2e.frame.embedded",
            "full frame: " + p + " time / embedded time");
    R.Ratio("e2e.window." + p + "_over_embedded", kExp, "e2e.window." + p, "e2e.window.embedded",
            "10k window: " + p + " time / embedded time");
    R.Add("e2e.frame." + p + ".throughput", kExp, "MB/s",
          {static_cast<double>(frame_bytes) / 1e6 / (Median(ms["frame." + p]) / 1000)}, fp,
          "full frame " + how + " (64-byte points)");
  }
  R.Add("e2e.frame.local_view", kExp, "ms", ms["frame.local_view"], fp,
        "full frame through shared memory, read in place (QueryStream::NextView, no copy)");
  R.Ratio("e2e.frame.local_view_over_embedded", kExp, "e2e.frame.local_view", "e2e.frame.embedded",
          "full frame read in place / embedded time");
  R.Ratio("e2e.frame.tcp_over_socketpair", kExp, "e2e.frame.tcp", "e2e.frame.socketpair_tcp",
          "full frame through TCP / the same bytes through a plain TCP socket pair");
  R.Ratio("e2e.window.tcp_over_socketpair", kExp, "e2e.window.tcp", "e2e.window.socketpair_tcp",
          "10k window through TCP / its bytes through a plain TCP socket pair");
  R.AddTarget("e2e.frame.local_over_embedded", "<=", 1.25, "issue 13 goal",
              "full frame through the local fast path at most 1.25x embedded");
  R.AddTarget("e2e.window.local_over_embedded", "<=", 1.25, "issue 13 goal",
              "10k window through the local fast path at most 1.25x embedded");
  R.AddTarget("e2e.frame.tcp_over_socketpair", "<=", 1.5, "issue 13 goal",
              "full frame through TCP at most 1.5x the socket-pair limit for the same bytes");
  R.AddTarget("e2e.window.tcp_over_embedded", "<=", 1.5, "issue 13 goal",
              "10k window through TCP at most 1.5x embedded");

  // Concurrent clients: each connects first, then all issue their share of windows back to back,
  // each into its own batch kept from query to query.
  // "embedded" is the same with threads querying the embedded copy: how the machine itself
  // scales (caches, memory bandwidth, two cores), the peer for the served paths. Every client
  // count of every path runs once per round, rounds interleaved, so that the ratios compare
  // runs taken side by side; figures are medians over the rounds.
  const std::vector<Path> client_paths = {Path::kEmbedded, Path::kLocal, Path::kTcp};
  struct Run {
    std::vector<double> qps, mbps, lat;
  };
  std::map<std::pair<Path, int>, Run> runs;
  for (int round = 0; round < c.e2e_rounds; ++round) {
    for (Path path : client_paths) {
      const bool embedded = path == Path::kEmbedded;
      for (int clients : c.e2e_clients) {
        const int per = std::max(1, c.e2e_queries / clients);
        std::vector<std::vector<double>> lat(static_cast<size_t>(clients));
        std::atomic<uint64_t> points{0};
        std::vector<std::unique_ptr<client::Connection>> clients_conns;
        for (int t = 0; t < clients && !embedded; ++t) {
          clients_conns.push_back(Connect(PathOptions(path, server.port(), sock)));
        }
        std::mutex mu;
        std::condition_variable cv;
        bool go = false;
        std::vector<std::thread> threads;
        for (int t = 0; t < clients; ++t) {
          threads.emplace_back([&, t] {
            {
              std::unique_lock<std::mutex> l(mu);
              cv.wait(l, [&] { return go; });
            }
            Rng crng(c.seed + 8100 + static_cast<uint64_t>(t) + 1000u * static_cast<uint64_t>(round));
            Batch batch;
            for (int q = 0; q < per; ++q) {
              const Window& w = windows[crng.Next() % windows.size()];
              auto [q_ms, got] =
                  embedded ? EmbeddedQuery(*emb.ds, w, &batch)
                           : RemoteQuery(*clients_conns[static_cast<size_t>(t)], w, false, &batch);
              lat[static_cast<size_t>(t)].push_back(q_ms);
              points += got;
            }
          });
        }
        Timer wall;
        {
          std::lock_guard<std::mutex> l(mu);
          go = true;
        }
        cv.notify_all();
        for (auto& th : threads) th.join();
        const double secs = wall.Ms() / 1000;
        Run& r = runs[{path, clients}];
        size_t count = 0;
        for (const auto& l : lat) {
          r.lat.insert(r.lat.end(), l.begin(), l.end());
          count += l.size();
        }
        r.qps.push_back(static_cast<double>(count) / secs);
        r.mbps.push_back(static_cast<double>(points.load()) * kPointRecordSize / 1e6 / secs);
      }
    }
  }
  Curve qps_c{"server_clients", kExp, "10k-point windows against concurrent clients",
              "clients", "windows per second", true, false, {}};
  for (Path path : client_paths) {
    const std::string p = PathName(path);
    Series qps_s{path == Path::kEmbedded ? "embedded (threads, in process)"
                 : path == Path::kLocal  ? "local fast path (Unix socket + ring)"
                                         : "TCP loopback (records)",
                 {}, {}, path == Path::kEmbedded ? "dashed" : "line"};
    for (int clients : c.e2e_clients) {
      Run& r = runs[{path, clients}];
      std::sort(r.lat.begin(), r.lat.end());
      auto pct = [&](double q) { return r.lat[std::min(r.lat.size() - 1, static_cast<size_t>(q * r.lat.size()))]; };
      const std::string f = "e2e." + p + ".clients" + std::to_string(clients);
      nlohmann::json params = {{"clients", clients}, {"queries", r.lat.size()}, {"points", n},
                               {"rounds", c.e2e_rounds}};
      R.Add(f + ".qps", kExp, "queries/s", r.qps, params, "windows per second, all clients (one sample a round)");
      R.Add(f + ".mbps", kExp, "MB/s", r.mbps, params, "result bytes per second, all clients");
      R.Add(f + ".latency", kExp, "ms", r.lat, params,
            "window latency seen by a client (median; p95, p99 in params)");
      R.Get(f + ".latency").params["p95_ms"] = pct(0.95);
      R.Get(f + ".latency").params["p99_ms"] = pct(0.99);
      qps_s.x.push_back(clients);
      qps_s.y.push_back(Median(r.qps));
      Log("8 server: %s, %d clients: %.0f windows/s, p50 %.2f ms, p95 %.2f ms, p99 %.2f ms",
          p.c_str(), clients, Median(r.qps), pct(0.5), pct(0.95), pct(0.99));
    }
    qps_c.series.push_back(qps_s);
    if (c.e2e_clients.size() >= 2) {
      const std::string last = "e2e." + p + ".clients" + std::to_string(c.e2e_clients.back());
      const std::string prev =
          "e2e." + p + ".clients" + std::to_string(c.e2e_clients[c.e2e_clients.size() - 2]);
      R.Ratio("e2e." + p + ".clients_scaling", kExp, last + ".qps", prev + ".qps",
              "windows/s with the most clients / with the next fewer");
      if (path != Path::kEmbedded) {
        R.AddTarget("e2e." + p + ".clients_scaling", ">=", 1.0, "issue 13 goal",
                    "more clients do not make the server slower in total");
      }
    }
  }
  R.AddCurve(qps_c);
  emb.Close();
  RemoveAll(dir);
  RemoveAll(dir + "-embedded");
}

}  // namespace hvdb::bench
