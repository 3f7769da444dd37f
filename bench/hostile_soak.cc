// hostile-soak: the whole server under hostile load (issue 37). Starts a real hvdb-server, loads
// a generated dataset through the client library, measures K normal clients alone (whole-frame
// window queries), then the same clients beside hostile ones: TCP non-readers, WebSocket
// non-readers, slow readers, ping floods, malformed frames and pre-auth squatters, and alone
// once more after those closed. The server's RSS is sampled every 100 ms throughout. The JSON
// (bench/results/soak.json) holds throughput, latencies, RSS and pass/fail against the issue's
// targets: loaded / unloaded >= 0.9 (the better unloaded phase) and max RSS - baseline <=
// --budget-mb. Not a ctest test: a soak of ~50 s whose figures are the point.
//   hostile-soak [--budget-mb 256] [--server-arg=--max-preauth --server-arg=64] [--out FILE]
// Every loop is bounded in count and time, everything is on loopback, and a watchdog ends the
// run (server included) after --max-seconds. Exit status: 0 pass, 3 a target missed, 1 error.
// The clients themselves are in soak_clients.cc; here: the command line, the server process,
// the phases, the RSS sampler and the JSON report.
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/client.h"
#include "soak_clients.h"

namespace {

using nlohmann::json;
using namespace std::chrono_literals;
using namespace hvdb;
using namespace hvdb::soak;

Clock::time_point g_t0 = Clock::now();
double Secs() { return std::chrono::duration<double>(Clock::now() - g_t0).count(); }
void Log(const std::string& s) { std::fprintf(stderr, "[%6.1f s] %s\n", Secs(), s.c_str()); }

// ---- The server process ----

std::atomic<pid_t> g_server{-1};
std::atomic<int> g_server_exit{-1};  // its wait status, when it exited by itself

long RssKib(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/status");
  std::string key;
  long value = -1;
  while (in >> key) {
    if (key == "VmRSS:" && in >> value) break;
  }
  return value;
}

// CPU seconds (user + system) of the server, and of this process (hostile and normal clients
// share the machine's cores with the server: the ratio is read beside them).
double ServerCpu(pid_t pid) {
  std::ifstream in("/proc/" + std::to_string(pid) + "/stat");
  std::string line;
  std::getline(in, line);
  if (line.rfind(')') == std::string::npos) return 0;  // gone
  std::istringstream f(line.substr(line.rfind(')') + 1));
  std::string field;
  double ticks = 0;
  for (int i = 3; i <= 15 && f >> field; ++i) {
    if (i >= 14) ticks += std::stod(field);  // utime, stime
  }
  return ticks / static_cast<double>(::sysconf(_SC_CLK_TCK));
}
// Busy CPU seconds of the whole machine (all but idle and iowait in /proc/stat): what others
// took during a phase is this less the server's and ours.
double MachineCpu() {
  std::ifstream in("/proc/stat");
  std::string cpu;
  double v, busy = 0;
  in >> cpu;
  for (int i = 0; i < 8 && in >> v; ++i) busy += (i == 3 || i == 4) ? 0 : v;
  return busy / static_cast<double>(::sysconf(_SC_CLK_TCK));
}
double SelfCpu() {
  rusage u{};
  ::getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec) * 1e-6;
}

// What a shell command prints (the server's --help, the source's commit).
std::string Output(const std::string& cmd) {
  std::string out;
  if (FILE* p = ::popen(cmd.c_str(), "r")) {
    char b[4096];
    for (size_t n; (n = std::fread(b, 1, sizeof b, p)) > 0;) out.append(b, n);
    ::pclose(p);
  }
  while (!out.empty() && out.back() == '\n') out.pop_back();
  return out;
}

pid_t StartServer(const std::vector<std::string>& args, const std::string& log_file) {
  pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(::open("/dev/null", O_WRONLY), STDOUT_FILENO);
    ::dup2(::open(log_file.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644), STDERR_FILENO);
    std::vector<char*> av;
    for (auto& a : args) av.push_back(const_cast<char*>(a.c_str()));
    av.push_back(nullptr);
    ::execv(av[0], av.data());
    ::_exit(127);
  }
  return pid;
}

void StopServer() {
  pid_t pid = g_server.exchange(-1);
  if (pid <= 0) return;
  ::kill(pid, SIGTERM);
  for (int i = 0; i < 100; ++i) {
    if (::waitpid(pid, nullptr, WNOHANG) == pid) return;
    std::this_thread::sleep_for(100ms);
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, nullptr, 0);
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"hostile-soak: hvdb-server under hostile load; normal clients' throughput and the "
               "server's RSS against their targets (issue 37)"};
  app.option_defaults()->always_capture_default();
  Setup s;
  int clients = 4;
  uint32_t points = 100000;
  double duration = 10, ramp = 2, settle = 5, max_seconds = 0;
  size_t budget_mb = 256, safety_mb = 4096;
  bool no_budget_flag = false, keep = false;
  std::string out = std::string(HVDB_SOURCE_DIR) + "/bench/results/soak.json";
  std::string server_bin = HVDB_SERVER_PATH;
  std::vector<std::string> server_args;
  std::string note;
  app.add_option("--clients", clients, "normal clients");
  app.add_option("--duration", duration, "seconds each phase measures");
  app.add_option("--frames", s.frames, "frames of the dataset");
  app.add_option("--points", points, "points per frame");
  app.add_option("--non-readers", s.non_readers, "(a) TCP non-readers");
  app.add_option("--ws-non-readers", s.ws_non_readers, "(b) WebSocket non-readers");
  app.add_option("--slow-readers", s.slow_readers, "(c) readers of 4 KiB every 100 ms");
  app.add_option("--ping-floods", s.ping_floods, "(d) ping floods");
  app.add_option("--malformed", s.malformed, "(e) malformed-frame senders");
  app.add_option("--squatters", s.squatters, "(f) pre-auth squatters");
  app.add_option("--ramp", ramp, "seconds the hostile clients get before the normal ones start");
  app.add_option("--settle", settle, "seconds after the hostile clients closed, for 'after' RSS");
  app.add_option("--budget-mb", budget_mb, "target for max RSS - baseline; also the server's "
                                           "--memory-budget when it has that flag");
  app.add_flag("--no-budget-flag", no_budget_flag, "do not pass --memory-budget to the server");
  app.add_option("--safety-mb", safety_mb, "RSS growth at which the hostile clients are stopped "
                                           "early (protects the machine)");
  app.add_option("--max-seconds", max_seconds,
                 "the whole run; past it the run is killed (0: 3 phases + ramp + settle + 60 s)");
  app.add_option("--server", server_bin, "the hvdb-server binary");
  app.add_option("--server-arg", server_args, "another server argument, repeatable "
                                              "(--server-arg=--max-preauth --server-arg=64)");
  app.add_option("--out", out, "JSON output");
  app.add_option("--note", note, "a line for the JSON, e.g. which server build this is");
  app.add_flag("--keep", keep, "keep the temporary data folder and the server's log");
  CLI11_PARSE(app, argc, argv);
  g_t0 = Clock::now();
  if (max_seconds <= 0) max_seconds = 3 * duration + ramp + settle + 60;
  const std::string load_start = Output("cat /proc/loadavg");  // others on the cores move figures
  ::signal(SIGPIPE, SIG_IGN);
  rlimit nofile{};  // ~450 hostile sockets here, as many in the server (which inherits this)
  if (::getrlimit(RLIMIT_NOFILE, &nofile) == 0) {
    nofile.rlim_cur = nofile.rlim_max;
    ::setrlimit(RLIMIT_NOFILE, &nofile);
  }

  // The server: TCP and HTTP on ephemeral loopback ports, a fresh data folder.
  char tmpl[] = "/tmp/hvdb-soak-XXXXXX";
  if (!::mkdtemp(tmpl)) return std::perror("mkdtemp"), 1;
  const std::string tmp = tmpl, port_file = tmp + "/port", log_file = tmp + "/server.log";
  // An older server refuses flags it does not know: --memory-budget only where --help has it.
  const bool budget_flag =
      !no_budget_flag && Output("'" + server_bin + "' --help 2>&1").find("--memory-budget") !=
                             std::string::npos;
  std::vector<std::string> args = {server_bin, "--data", tmp + "/data", "--listen", "127.0.0.1:0",
                                   "--http", "127.0.0.1:0", "--port-file", port_file,
                                   "--log-level", "warn"};
  if (budget_flag) args.insert(args.end(), {"--memory-budget", std::to_string(budget_mb)});
  args.insert(args.end(), server_args.begin(), server_args.end());
  std::string cmdline;
  for (auto& a : args) cmdline += (cmdline.empty() ? "" : " ") + a;
  Log("starting " + cmdline);
  const pid_t pid = StartServer(args, log_file);
  g_server = pid;

  // The watchdog ends a run that hangs, server included; the sampler takes the server's RSS
  // every 100 ms with the phase it belongs to, and notices when the server dies.
  std::atomic<bool> done{false}, safety_stop{false};
  std::atomic<int> phase{0};  // 0 load, 1 unloaded, 2 hostile, 3 after
  std::atomic<long> baseline_kib{-1};
  std::mutex samples_mu;
  std::vector<std::array<double, 3>> samples;  // seconds, MiB, phase
  std::thread watchdog([&]() {
    auto limit = g_t0 + std::chrono::milliseconds(static_cast<long>(max_seconds * 1000));
    while (!done && Clock::now() < limit) std::this_thread::sleep_for(100ms);
    if (done) return;
    Log("over --max-seconds: killing the server and giving up");
    if (pid_t p = g_server.exchange(-1); p > 0) ::kill(p, SIGKILL);
    if (!keep) std::filesystem::remove_all(tmp);
    ::_exit(1);
  });
  std::thread sampler([&]() {
    for (; !done; std::this_thread::sleep_for(100ms)) {
      pid_t p = g_server;
      int st;
      if (p <= 0) continue;
      if (::waitpid(p, &st, WNOHANG) == p) {
        g_server = -1;
        g_server_exit = st;
        Log("the server exited (wait status " + std::to_string(st) + ")");
        g_stop_hostile = true;
      } else if (long kib = RssKib(p); kib > 0) {
        std::lock_guard<std::mutex> l(samples_mu);
        samples.push_back({Secs(), kib / 1024.0, static_cast<double>(phase.load())});
        if (phase == 2 && baseline_kib > 0 &&
            kib - baseline_kib > static_cast<long>(safety_mb) * 1024 &&
            !safety_stop.exchange(true)) {
          Log("RSS grew past --safety-mb: stopping the hostile clients early");
          g_stop_hostile = true;
        }
      }
    }
  });
  auto finish_threads = [&]() {
    done = true;
    sampler.join();
    watchdog.join();
  };
  auto bail = [&](const std::string& why) {
    Log("error: " + why + " (server log: " + log_file + ")");
    finish_threads();
    StopServer();
    return 1;
  };
  for (int i = 0; i < 1000 && s.http_port == 0 && g_server > 0; ++i) {
    std::ifstream in(port_file);
    int p = 0, h = 0;
    if (in >> p >> h && p > 0 && h > 0) {
      s.port = static_cast<uint16_t>(p);
      s.http_port = static_cast<uint16_t>(h);
    }
    std::this_thread::sleep_for(10ms);
  }
  if (s.http_port == 0) return bail("the server did not start");

  // The dataset, through the client library; then every frame read for a second (warm cache).
  {
    auto c = client::Connection::Connect(ClientOptions(s.port));
    if (!c.ok()) return bail("connect: " + c.status().ToString());
    DatasetInfo info;
    info.name = kDataset;
    info.fps = kFps;
    if (auto r = (*c)->CreateDataset(info); !r.ok()) return bail(r.status().ToString());
    std::mt19937_64 rng(37);
    std::uniform_real_distribution<float> u(0.f, 10.f);
    for (uint32_t f = 0; f < s.frames; ++f) {
      std::vector<Point> pts(points);
      for (auto& p : pts) {
        p.x = u(rng), p.y = u(rng), p.z = u(rng);
        p.frame = f;
        p.r = static_cast<uint8_t>(rng()), p.g = static_cast<uint8_t>(rng()), p.b = 128;
      }
      if (auto r = (*c)->Ingest(kDataset, f, pts); !r.ok()) return bail(r.status().ToString());
    }
    Log("loaded " + std::to_string(s.frames) + " frames x " + std::to_string(points) + " points");
  }
  RunNormals(s, 1, 1.0, true);
  // A phase's figures with the CPU the server, this process and everything else used meanwhile
  // (other_cpu_s well above 0: the machine was shared, the figure is not the server's alone).
  auto measure = [&](bool connect_early) {
    double c0 = ServerCpu(pid), s0 = SelfCpu(), m0 = MachineCpu();
    json r = RunNormals(s, clients, duration, connect_early);
    double server = ServerCpu(pid) - c0, self = SelfCpu() - s0;
    r["server_cpu_s"] = server;
    r["soak_cpu_s"] = self;
    r["other_cpu_s"] = MachineCpu() - m0 - server - self;
    return r;
  };

  phase = 1;
  Log("phase 1: " + std::to_string(clients) + " normal clients alone");
  json unloaded = measure(true);
  Log("unloaded: " + unloaded.dump());

  baseline_kib = RssKib(pid);
  phase = 2;
  Log("phase 2: hostile clients, then the normal clients again");
  Counters cnt;
  std::vector<std::thread> hostile;
  hostile.emplace_back(NonReaders, std::cref(s), std::ref(cnt));
  hostile.emplace_back(WsNonReaders, std::cref(s), std::ref(cnt));
  hostile.emplace_back(SlowReaders, std::cref(s), std::ref(cnt));
  hostile.emplace_back(PingFloods, std::cref(s), std::ref(cnt));
  for (int i = 0; i < s.malformed; ++i) {
    hostile.emplace_back(Malformed, std::cref(s), i, std::ref(cnt));
  }
  // The squatters come last: first, they would take every connection the server has and the
  // other kinds would test nothing but its refusal.
  auto half_ramp = std::chrono::milliseconds(static_cast<long>(ramp * 500));
  std::this_thread::sleep_for(half_ramp);
  hostile.emplace_back(Squatters, std::cref(s), std::ref(cnt));
  std::this_thread::sleep_for(half_ramp);
  json loaded = measure(false);
  Log("loaded: " + loaded.dump());
  g_stop_hostile = true;
  g_blocking_fds.ShutdownAll();
  for (auto& t : hostile) t.join();
  phase = 3;
  Log("hostile clients closed; settling");
  std::this_thread::sleep_for(std::chrono::milliseconds(static_cast<long>(settle * 1000)));
  const bool alive = g_server > 0;
  const double after_mb = alive ? RssKib(pid) / 1024.0 : -1;
  // Alone again: whether the server recovered, and a second reference for the ratio.
  json again = alive ? measure(true) : json{{"queries_per_s", 0.0}};
  Log("unloaded again: " + again.dump());
  finish_threads();
  StopServer();

  // Figures and verdict.
  const double base_mb = baseline_kib / 1024.0;
  double max_mb = base_mb;
  json series = json::array();
  for (size_t i = 0; i < samples.size(); ++i) {
    auto& x = samples[i];
    if (x[2] >= 2) max_mb = std::max(max_mb, x[1]);
    if (i % 5 == 0) series.push_back({std::round(x[0] * 10) / 10, std::round(x[1]), int(x[2])});
  }
  // The reference is the better of the two unloaded phases: on a shared machine either may have
  // been slowed by others, and a server slower after the attack must not pass for it.
  const double qps0 = std::max(unloaded["queries_per_s"].get<double>(),
                               again["queries_per_s"].get<double>());
  const double qps1 = loaded["queries_per_s"];
  const double ratio = qps0 > 0 ? qps1 / qps0 : 0;
  const bool pass_tp = ratio >= 0.9;
  const bool pass_mem = alive && max_mb - base_mb <= static_cast<double>(budget_mb);
  std::vector<std::string> log_tail;  // the server's last words (warnings and errors)
  long log_lines = 0;
  std::ifstream log_in(log_file);
  for (std::string line; std::getline(log_in, line); ++log_lines) {
    log_tail.push_back(line.substr(0, 300));
    if (log_tail.size() > 8) log_tail.erase(log_tail.begin());
  }
  json j = {
      {"benchmark", "hostile-soak"},
      {"note", note},
      {"server", {{"command", cmdline}, {"extra_flags", server_args},
                  {"memory_budget_flag_passed", budget_flag},
                  {"soak_tree", Output("git -C '" HVDB_SOURCE_DIR "' describe --always --dirty")},
                  {"alive_at_end", alive}, {"exit_status", g_server_exit.load()},
                  {"log_lines", log_lines}, {"log_tail", log_tail}}},
      {"machine", {{"cpus", std::thread::hardware_concurrency()}, {"loadavg_start", load_start},
                   {"loadavg_end", Output("cat /proc/loadavg")}}},
      {"dataset", {{"frames", s.frames}, {"points_per_frame", points}}},
      {"normal_clients", clients},
      {"duration_s", duration},
      {"ramp_s", ramp},
      {"phases", "load, unloaded, hostile (ramp, then loaded), settle, unloaded_again"},
      {"hostile", {{"non_readers", s.non_readers}, {"ws_non_readers", s.ws_non_readers},
                   {"slow_readers", s.slow_readers}, {"ping_floods", s.ping_floods},
                   {"malformed", s.malformed}, {"squatters", s.squatters},
                   {"queries_per_non_reader", kQueriesPerNonReader},
                   {"stopped_early_for_safety", safety_stop.load()}}},
      {"hostile_activity", cnt.ToJson()},
      {"unloaded", unloaded},
      {"loaded", loaded},
      {"unloaded_again", again},
      {"throughput_ratio", ratio},
      {"throughput_ratio_reference", "max(unloaded, unloaded_again) queries/s"},
      {"rss_mb", {{"baseline", base_mb}, {"max", max_mb}, {"max_over_baseline", max_mb - base_mb},
                  {"after", after_mb}, {"after_over_baseline", alive ? after_mb - base_mb : -1},
                  {"settle_s", settle}}},
      {"rss_series", {{"columns", {"s", "MiB", "phase"}}, {"every_ms", 500},
                      {"phases", "0 load, 1 unloaded, 2 hostile, 3 after"}, {"rows", series}}},
      {"targets", {{"throughput_ratio_min", 0.9}, {"budget_mb", budget_mb}}},
      {"pass", {{"throughput", pass_tp}, {"memory", pass_mem}, {"all", pass_tp && pass_mem}}},
  };
  std::filesystem::path op(out);
  if (op.has_parent_path()) std::filesystem::create_directories(op.parent_path());
  std::ofstream(out) << j.dump(2) << "\n";
  std::printf("throughput loaded/unloaded %.3f (%.1f / %.1f queries/s, p99 %.1f / %.1f ms): %s\n",
              ratio, qps1, qps0, loaded["p99_ms"].get<double>(), unloaded["p99_ms"].get<double>(),
              pass_tp ? "pass" : "FAIL");
  std::printf("RSS baseline %.0f MiB, max %.0f MiB (+%.0f, budget %zu), after %.0f MiB: %s\n",
              base_mb, max_mb, max_mb - base_mb, budget_mb, after_mb, pass_mem ? "pass" : "FAIL");
  std::printf("wrote %s\n", out.c_str());
  if (!keep) std::filesystem::remove_all(tmp);
  return pass_tp && pass_mem ? 0 : 3;
}
