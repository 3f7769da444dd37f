// rados-bench: the RADOS store (storage/rados_env.h) next to the local store in the same run,
// through the same engine: bulk load, a full frame cold and warm, random windows cold and
// warm, and inserts (median commit time); then several hvdb-servers on one dataset in the
// pool: window queries/s answered by 1, 2 and 3 of them (the writer and readers that follow
// it) under the same client load, and how long a commit takes to reach a reader. The cluster
// is the one-node cluster of scripts/ceph-dev.sh on this machine (--start-cluster DIR starts
// and stops one), so the figures show the cost of the object protocol on one machine, not a
// cluster's throughput (bench/README.md says what N OSD hosts should give). Writes JSON.
#include <CLI/CLI.hpp>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <thread>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "bench/util.h"
#include "client/client.h"
#include "storage/database.h"
#include "storage/rados_env.h"

namespace {

using namespace hvdb;
using namespace hvdb::bench;
using nlohmann::json;

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

struct Config {
  size_t points_per_frame = 1000000;
  uint32_t frames = 4;
  int windows = 10000;
  int inserts = 100;
  size_t insert_points = 1000;
  int reps = 3;
  double reader_seconds = 2;  // per measured interval (reps of them per server count)
  int reader_clients = 6;
};

std::vector<Window> RandomWindows(int n, uint32_t frames) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 0.95);
  std::vector<Window> wins(static_cast<size_t>(n));
  for (Window& w : wins) {
    for (int a = 0; a < 3; ++a) w.lo[a] = u(rng), w.hi[a] = w.lo[a] + 0.05;
    uint32_t f = static_cast<uint32_t>(rng() % frames);
    w.lo[3] = w.hi[3] = f / 30.0;
  }
  return wins;
}

json RunStore(const std::string& name, Env* env, const std::string& dir, const Config& c) {
  Log("%s: %s", name.c_str(), dir.c_str());
  Options o;
  o.env = env;
  o.cache_bytes = 512u << 20;
  auto open = [&] {
    auto db = Check(Database::Open(dir, o), "open " + dir);
    return db;
  };
  auto db = open();
  DatasetInfo info;
  info.name = "b";
  info.fps = 30;
  auto ds = Check(db->CreateDataset(info), "create");
  // Bulk load.
  std::vector<double> load;
  uint64_t bytes = 0;
  for (uint32_t f = 0; f < c.frames; ++f) {
    auto pts = UniformPoints(c.points_per_frame, 100 + f, f);
    bytes += pts.size() * kPointRecordSize;
    Timer t;
    Check(ds->BulkLoad(f, std::move(pts)), "bulk load");
    load.push_back(t.Ms());
  }
  double load_ms = 0;
  for (double v : load) load_ms += v;
  auto frame_query = [&](Dataset& d, uint32_t f) {
    Timer t;
    auto r = RunQuery(d, Region(FrameWindow(f, 30)), QueryOptions{});
    if (r.points != c.points_per_frame) Die("frame query returned " + std::to_string(r.points));
    return t.Ms();
  };
  const std::vector<Window> wins = RandomWindows(c.windows, c.frames);
  auto windows = [&](Dataset& d) {
    Timer t;
    uint64_t n = 0;
    for (const Window& w : wins) n += RunQuery(d, Region(w), QueryOptions{}).points;
    if (n == 0) Die("windows returned nothing");
    return t.Ms();
  };
  // Cold: the database reopened (its buffer pool gone; local files evicted from the page cache).
  auto reopen_cold = [&] {
    ds.reset();
    db.reset();
    if (!env) Evict(dir);
    db = open();
    ds = Check(db->GetDataset("b"), "get");
  };
  std::vector<double> frame_cold, frame_warm, win_cold, win_warm;
  for (int r = 0; r < c.reps; ++r) {
    reopen_cold();
    frame_cold.push_back(frame_query(*ds, static_cast<uint32_t>(r) % c.frames));
    frame_warm.push_back(frame_query(*ds, static_cast<uint32_t>(r) % c.frames));
  }
  for (int r = 0; r < c.reps; ++r) {
    reopen_cold();
    win_cold.push_back(windows(*ds));
    win_warm.push_back(windows(*ds));
  }
  std::vector<double> commits;
  for (int i = 0; i < c.inserts; ++i) {
    auto pts = UniformPoints(c.insert_points, 1000 + i, static_cast<uint32_t>(i) % c.frames);
    Transaction t;
    t.Insert(pts);
    Timer tm;
    Check(ds->Commit(t), "commit");
    commits.push_back(tm.Ms());
  }
  const double frame_mb = c.points_per_frame * kPointRecordSize / 1e6;
  json j = {{"bulk_load_ms", load_ms},
            {"bulk_load_mpts_s", c.frames * c.points_per_frame / load_ms / 1e3},
            {"bulk_load_mb_s", bytes / 1e3 / load_ms},
            {"frame_cold_ms", Median(frame_cold)},
            {"frame_cold_mb_s", frame_mb / Median(frame_cold) * 1e3},
            {"frame_warm_ms", Median(frame_warm)},
            {"frame_warm_mb_s", frame_mb / Median(frame_warm) * 1e3},
            {"windows_cold_per_s", c.windows / Median(win_cold) * 1e3},
            {"windows_warm_per_s", c.windows / Median(win_warm) * 1e3},
            {"commit_ms_median", Median(commits)}};
  ds.reset();
  (void)db->DropDataset("b");
  Log("%s: %s", name.c_str(), j.dump().c_str());
  return j;
}

// An hvdb-server child on the pool; its port once it listens.
struct ServerChild {
  pid_t pid = -1;
  uint16_t port = 0;
};

ServerChild StartServer(const std::string& bin, const std::string& store, const std::string& data,
                        const std::string& work, int i) {
  const std::string port_file = work + "/port-" + std::to_string(i);
  ServerChild s;
  s.pid = fork();
  if (s.pid == 0) {
    int fd = ::open((work + "/server-" + std::to_string(i) + ".log").c_str(),
                    O_WRONLY | O_CREAT | O_TRUNC, 0644);
    dup2(fd, 1);
    dup2(fd, 2);
    execl(bin.c_str(), bin.c_str(), "--store", store.c_str(), "--data", data.c_str(), "--listen",
          "127.0.0.1:0", "--listen", ("unix:" + work + "/s" + std::to_string(i)).c_str(),
          "--port-file", port_file.c_str(), "--log-level", "warn", static_cast<char*>(nullptr));
    _exit(127);
  }
  for (int t = 0; t < 300 && s.port == 0; ++t) {
    std::ifstream in(port_file);
    int p = 0;
    if (in >> p) s.port = static_cast<uint16_t>(p);
    if (s.port == 0) std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  if (s.port == 0) Die("server " + std::to_string(i) + " did not start (see " + work + ")");
  return s;
}

std::unique_ptr<client::Connection> ConnectTo(uint16_t port) {
  client::Options o;
  o.port = port;
  return Check(client::Connection::Connect(o), "connect to port " + std::to_string(port));
}

// 1, 2 and 3 servers on one dataset in the pool (the first the writer, the others readers that
// follow it): window queries/s of a fixed set of clients spread over them, and the delay until
// a commit on the writer is answered by a reader.
json RunReaders(Env* env, const std::string& store, const std::string& bin, const Config& c) {
  const std::string data = "readers-" + std::to_string(std::random_device{}());
  {
    Options o;
    o.env = env;
    auto db = Check(Database::Open(data, o), "open " + data);
    DatasetInfo info;
    info.name = "b";
    info.fps = 30;
    auto ds = Check(db->CreateDataset(info), "create");
    for (uint32_t f = 0; f < c.frames; ++f) {
      Check(ds->BulkLoad(f, UniformPoints(c.points_per_frame, 100 + f, f)), "bulk load");
    }
  }
  char tmpl[] = "/tmp/hvdb-readers-XXXXXX";
  const std::string work = mkdtemp(tmpl);
  std::vector<ServerChild> servers;
  for (int i = 0; i < 3; ++i) servers.push_back(StartServer(bin, store, data, work, i));
  const std::vector<Window> wins = RandomWindows(4096, c.frames);
  json per_count = json::array();
  double base = 0;
  for (int k = 1; k <= 3; ++k) {
    std::atomic<bool> stop{false};
    std::atomic<uint64_t> done{0};
    std::vector<std::thread> clients;
    for (int i = 0; i < c.reader_clients; ++i) {
      clients.emplace_back([&, i] {
        auto conn = ConnectTo(servers[static_cast<size_t>(i % k)].port);
        for (size_t q = static_cast<size_t>(i) * 577; !stop; ++q) {
          auto stream = Check(conn->Query("b", wins[q % wins.size()]), "query");
          Batch b;
          while (Check(stream->Next(&b), "next")) {
          }
          ++done;
        }
      });
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(1000));  // caches warm
    std::vector<double> runs;  // c.reps intervals of reader_seconds each
    for (int r = 0; r < c.reps; ++r) {
      const uint64_t before = done.load();
      Timer t;
      std::this_thread::sleep_for(
          std::chrono::milliseconds(static_cast<int>(c.reader_seconds * 1e3)));
      runs.push_back((done.load() - before) / (t.Ms() / 1e3));
    }
    const double qps = Median(runs);
    stop = true;
    for (auto& th : clients) th.join();
    if (k == 1) base = qps;
    Log("readers: %d server(s): %.0f windows/s", k, qps);
    per_count.push_back({{"servers", k}, {"windows_per_s", qps}, {"over_one", qps / base},
                         {"runs", runs}});
  }
  // A commit on the writer until a reader answers with it (the reader follows the writer's
  // watch events, and looks every 100 ms besides).
  auto writer = ConnectTo(servers[0].port), reader = ConnectTo(servers[1].port);
  std::vector<double> lag;
  std::mt19937 phase(3);
  for (int i = 0; i < 20; ++i) {
    // At a random point of the reader's polling period, not in step with it.
    std::this_thread::sleep_for(std::chrono::milliseconds(phase() % 100));
    Transaction txn;
    txn.Insert(UniformPoints(100, 5000 + static_cast<uint64_t>(i), 0));
    auto info = Check(writer->Commit("b", txn), "commit");
    Timer t;
    while (Check(reader->Describe("b"), "describe").last_lsn < info.lsn) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    lag.push_back(t.Ms());
  }
  writer.reset();
  reader.reset();
  for (auto it = servers.rbegin(); it != servers.rend(); ++it) {
    kill(it->pid, SIGTERM);
    waitpid(it->pid, nullptr, 0);
  }
  RemoveAll(work);
  {
    Options o;
    o.env = env;
    auto db = Check(Database::Open(data, o), "reopen " + data);
    (void)db->DropDataset("b");
  }
  return {{"clients", c.reader_clients},
          {"seconds_per_run", c.reader_seconds},
          {"window_extent", 0.05},
          {"by_servers", per_count},
          {"commit_visible_on_reader_ms_median", Median(lag)},
          {"follow_interval_ms", 100}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"rados-bench: the RADOS store next to the local store, same engine, same run"};
  std::string out = "rados.json", conf, start_dir, scratch = "/tmp/hvdb-rados-bench";
  bool quick = false;
  Config c;
  app.add_option("--out", out, "JSON output")->capture_default_str();
  app.add_option("--ceph-conf", conf, "ceph.conf of a running cluster");
  app.add_option("--start-cluster", start_dir,
                 "start a one-node cluster in this folder (scripts/ceph-dev.sh) and stop it after");
  app.add_option("--scratch", scratch, "folder of the local store")->capture_default_str();
  app.add_option("--points", c.points_per_frame, "points per frame")->capture_default_str();
  app.add_option("--frames", c.frames, "frames")->capture_default_str();
  std::string server_bin = HVDB_SERVER_PATH;
  app.add_option("--server", server_bin, "the hvdb-server binary of the readers experiment")
      ->capture_default_str();
  app.add_flag("--quick", quick, "small sizes (CI smoke run)");
  CLI11_PARSE(app, argc, argv);
  if (quick) c = Config{50000, 2, 100, 10, 1000, 1, 1, 3};
  if (conf.empty() == start_dir.empty()) {
    std::fprintf(stderr, "rados-bench: give --ceph-conf FILE or --start-cluster DIR\n");
    return 2;
  }
  const std::string script = std::string(HVDB_SOURCE_DIR) + "/scripts/ceph-dev.sh";
  if (!start_dir.empty()) {
    if (std::system(("bash " + script + " start " + start_dir).c_str()) != 0) Die("cluster start");
    conf = start_dir + "/ceph.conf";
  }
  RadosSpec spec;
  spec.pool = "hvdb-bench";
  spec.conf = conf;
  auto env = Check(OpenRadosEnv(spec), "connect");
  RemoveAll(scratch);
  MakeDirs(scratch);
  json local = RunStore("local", nullptr, scratch + "/db", c);
  json rados = RunStore("rados", env.get(), "bench-" + std::to_string(std::random_device{}()), c);
  json readers = RunReaders(env.get(), "rados:" + spec.pool + "?conf=" + conf, server_bin, c);
  env.reset();
  if (!start_dir.empty()) (void)std::system(("bash " + script + " stop " + start_dir).c_str());
  RemoveAll(scratch);
  json ratios;
  for (auto& [k, v] : local.items()) ratios[k] = rados[k].get<double>() / v.get<double>();
  json j = {{"benchmark", "rados"},
            {"quick", quick},
            {"points_per_frame", c.points_per_frame},
            {"frames", c.frames},
            {"windows", c.windows},
            {"inserts", c.inserts},
            {"insert_points", c.insert_points},
            {"local", local},
            {"rados", rados},
            {"rados_over_local", ratios},
            {"readers", readers},
            {"note", "one-node cluster on this machine (BlueStore on a file): the object path's "
                     "cost, not a cluster's throughput; several servers share its 2 cores"}};
  std::ofstream(out) << j.dump(2) << "\n";
  std::printf("%s\n", j.dump(2).c_str());
  return 0;
}
