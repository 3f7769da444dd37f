// 8. End to end through hvdb-server: a full frame and a 10,000-point window over loopback
// against the same queries embedded, then 1, 8 and 32 concurrent clients issuing windows:
// queries/s, MB/s and latency percentiles. The server is the real binary (HVDB_SERVER_BIN),
// started on a free loopback port and stopped with SIGTERM.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <fstream>
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
  explicit ServerProcess(const std::string& data) {
    port_file_ = data + ".port";
    ::unlink(port_file_.c_str());
    pid_ = ::fork();
    if (pid_ == 0) {
      ::execl(HVDB_SERVER_BIN, HVDB_SERVER_BIN, "--data", data.c_str(), "--listen", "127.0.0.1:0",
              "--port-file", port_file_.c_str(), "--log-level", "warn", "--cache-mb", "1024",
              static_cast<char*>(nullptr));
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

std::unique_ptr<client::Connection> Connect(uint16_t port) {
  client::Options o;
  o.port = port;
  return Check(client::Connection::Connect(o), "connect to hvdb-server");
}

// Runs the query through the server to the end; returns (ms, points).
std::pair<double, uint64_t> RemoteQuery(client::Connection& c, const Region& r) {
  Timer t;
  auto q = Check(c.Query("e2e", r), "remote query");
  Batch b;
  uint64_t n = 0;
  while (Check(q->Next(&b), "remote batch")) n += b.points.size();
  return {t.Ms(), n};
}

}  // namespace

void RunServer(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  const std::string dir = c.scratch + "/e2e";
  RemoveAll(dir);
  const size_t n = c.e2e_points;
  Log("8 server: one frame of %zu points, windows of ~%zu points", n, c.win_result);
  std::vector<Window> windows;
  {
    Db db = Db::Create(dir, "e2e", c.DbOptions(), c.fps);
    Check(db.ds->BulkLoad(0, UniformPoints(n, c.seed + 8000, 0)), "bulk load");
    Rng rng(c.seed + 8001);
    for (int i = 0; i < c.win_queries; ++i) windows.push_back(RandomWindow(rng, n, c.win_result));
    // Embedded, warm (one untimed pass first).
    QueryOptions qo;
    RunQuery(*db.ds, FrameWindow(0, c.fps), qo);
    std::vector<double> frame_ms, win_ms;
    for (int r = 0; r < c.warm_reps; ++r) frame_ms.push_back(RunQuery(*db.ds, FrameWindow(0, c.fps), qo).ms);
    for (const Window& w : windows) RunQuery(*db.ds, w, qo);
    for (const Window& w : windows) win_ms.push_back(RunQuery(*db.ds, w, qo).ms);
    nlohmann::json p = {{"points", n}};
    R.Add("e2e.frame.embedded", kExp, "ms", frame_ms, p, "full frame, embedded, warm");
    R.Add("e2e.window.embedded", kExp, "ms", win_ms, {{"points", n}, {"result", c.win_result}},
          "10k-point window, embedded, warm");
    db.Close();
  }
  ServerProcess server(dir);
  {
    auto conn = Connect(server.port());
    RemoteQuery(*conn, FrameWindow(0, c.fps));
    std::vector<double> frame_ms, win_ms;
    for (int r = 0; r < c.warm_reps; ++r) frame_ms.push_back(RemoteQuery(*conn, FrameWindow(0, c.fps)).first);
    for (const Window& w : windows) RemoteQuery(*conn, w);
    for (const Window& w : windows) win_ms.push_back(RemoteQuery(*conn, w).first);
    R.Add("e2e.frame.server", kExp, "ms", frame_ms, {{"points", n}},
          "full frame through hvdb-server over loopback, one client, warm");
    R.Add("e2e.window.server", kExp, "ms", win_ms, {{"points", n}, {"result", c.win_result}},
          "10k-point window through hvdb-server, one client, warm");
    R.Ratio("e2e.frame.server_over_embedded", kExp, "e2e.frame.server", "e2e.frame.embedded",
            "full frame: server time / embedded time");
    R.Ratio("e2e.window.server_over_embedded", kExp, "e2e.window.server", "e2e.window.embedded",
            "10k window: server time / embedded time");
    const double mb = static_cast<double>(n) * kPointRecordSize / 1e6;
    R.Add("e2e.frame.server.throughput", kExp, "MB/s", {mb / (Median(frame_ms) / 1000)},
          {{"points", n}}, "full frame through the server (64-byte points)");
  }
  // Concurrent clients: each issues its share of windows back to back.
  Curve qps_c{"server_clients", kExp, "Windows through hvdb-server against concurrent clients",
              "clients", "queries per second", true, false, {}};
  Series qps_s{"windows/s", {}, {}, "line"};
  for (int clients : c.e2e_clients) {
    const int per = std::max(1, c.e2e_queries / clients);
    std::vector<std::vector<double>> lat(static_cast<size_t>(clients));
    std::atomic<uint64_t> points{0};
    std::vector<std::thread> threads;
    Timer wall;
    for (int t = 0; t < clients; ++t) {
      threads.emplace_back([&, t] {
        auto conn = Connect(server.port());
        Rng rng(c.seed + 8100 + static_cast<uint64_t>(t));
        for (int q = 0; q < per; ++q) {
          auto [ms, got] = RemoteQuery(*conn, windows[rng.Next() % windows.size()]);
          lat[static_cast<size_t>(t)].push_back(ms);
          points += got;
        }
      });
    }
    for (auto& th : threads) th.join();
    const double secs = wall.Ms() / 1000;
    std::vector<double> all;
    for (const auto& l : lat) all.insert(all.end(), l.begin(), l.end());
    std::sort(all.begin(), all.end());
    auto pct = [&](double p) { return all[std::min(all.size() - 1, static_cast<size_t>(p * all.size()))]; };
    const std::string f = "e2e.clients" + std::to_string(clients);
    nlohmann::json p = {{"clients", clients}, {"queries", all.size()}, {"points", n}};
    R.Add(f + ".qps", kExp, "queries/s", {all.size() / secs}, p, "windows per second, all clients");
    R.Add(f + ".mbps", kExp, "MB/s", {points.load() * kPointRecordSize / 1e6 / secs}, p,
          "result bytes per second, all clients");
    R.Add(f + ".latency", kExp, "ms", all, p, "window latency seen by a client (median; p95, p99 in params)");
    R.Get(f + ".latency").params["p95_ms"] = pct(0.95);
    R.Get(f + ".latency").params["p99_ms"] = pct(0.99);
    qps_s.x.push_back(clients);
    qps_s.y.push_back(all.size() / secs);
    Log("8 server: %d clients: %.0f windows/s, p50 %.2f ms, p95 %.2f ms, p99 %.2f ms", clients,
        all.size() / secs, pct(0.5), pct(0.95), pct(0.99));
  }
  qps_c.series.push_back(qps_s);
  R.AddCurve(qps_c);
  RemoveAll(dir);
}

}  // namespace hvdb::bench
