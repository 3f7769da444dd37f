// live-bench: how fast a commit reaches those who follow it (issue 34). Real processes on one
// data directory: a writing hvdb-server, a reading one that follows it by watch events (the
// default), and one that follows it every --follow-interval-ms (100, the old way), side by side
// in one run. A client commits small transactions at random moments on the writer's Unix socket;
// for each it times, from the writer's acknowledgement:
//   watch_event  the change's event at a client watching the writer (Unix socket);
//   reader_events / reader_polling  the first Describe of each reader that shows the change.
// Writes medians and p99 as JSON (--out, default stdout).
#include <fcntl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client/client.h"

namespace {

using Clock = std::chrono::steady_clock;
using json = nlohmann::json;
namespace fs = std::filesystem;
using namespace hvdb;

[[noreturn]] void Die(const std::string& why) {
  std::fprintf(stderr, "live-bench: %s\n", why.c_str());
  std::exit(1);
}
template <typename T>
T Check(Result<T> r, const std::string& what) {
  if (!r.ok()) Die(what + ": " + r.status().ToString());
  return std::move(r).value();
}

struct Child {
  pid_t pid = -1;
  std::string sock;
};

Child Start(const std::string& work, const std::string& name, std::vector<std::string> extra) {
  Child c;
  c.sock = work + "/" + name + ".sock";
  const std::string port_file = work + "/" + name + ".port";
  std::vector<std::string> args = {HVDB_SERVER_PATH, "--data", work + "/data", "--listen",
                                   "127.0.0.1:0", "--listen", "unix:" + c.sock, "--port-file",
                                   port_file, "--log-level", "warn"};
  args.insert(args.end(), extra.begin(), extra.end());
  c.pid = ::fork();
  if (c.pid == 0) {
    int fd = ::open((work + "/" + name + ".log").c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    ::dup2(fd, 1);
    ::dup2(fd, 2);
    std::vector<char*> argv;
    for (auto& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  for (int i = 0; i < 300; ++i) {
    std::ifstream in(port_file);
    int p = 0;
    if (in >> p && p > 0) return c;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  Die("hvdb-server " + name + " did not start (see " + work + "/" + name + ".log)");
}

std::unique_ptr<client::Connection> Connect(const Child& c) {
  client::Options o;
  o.unix_path = c.sock;
  return Check(client::Connection::Connect(o), "connect to " + c.sock);
}

json Summary(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  auto q = [&](double p) { return v.empty() ? 0 : v[std::min(v.size() - 1, size_t(p * v.size()))]; };
  return {{"n", v.size()}, {"median_ms", q(0.5)}, {"p99_ms", q(0.99)}, {"max_ms", v.empty() ? 0 : v.back()}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"live-bench: commit -> watch event -> reader, with a reader that follows by events "
               "and one that polls, in one run (JSON)"};
  int commits = 200;
  std::string out;
  app.add_option("--commits", commits, "Transactions timed")->capture_default_str()
      ->check(CLI::Range(1, 100000));
  app.add_option("--out", out, "Write the JSON here (default: stdout)");
  CLI11_PARSE(app, argc, argv);

  std::string work = (fs::temp_directory_path() / "hvdb_live_XXXXXX").string();
  if (::mkdtemp(work.data()) == nullptr) Die("mkdtemp failed");
  Child writer = Start(work, "writer", {});
  auto w = Connect(writer);
  DatasetInfo info;
  info.name = "live";
  info.fps = 30;
  Check(w->CreateDataset(info), "create");
  Child events = Start(work, "reader-events", {"--follow"});
  Child polling = Start(work, "reader-polling", {"--follow", "--no-follow-events"});
  auto re = Connect(events), rp = Connect(polling);
  Check(re->Describe("live"), "describe on the reader");  // opens the dataset there
  Check(rp->Describe("live"), "describe on the reader");

  // The watcher: arrival time of each LSN's event.
  auto wc = Connect(writer);
  auto watch = Check(wc->Watch("live"), "watch");
  std::mutex mu;
  std::map<uint64_t, Clock::time_point> arrived;
  std::atomic<bool> stop{false};
  std::thread watcher([&] {
    ChangeEvent ev;
    while (!stop) {
      auto got = watch->Next(&ev, std::chrono::milliseconds(100));
      if (!got.ok()) Die("watch: " + got.status().ToString());
      if (*got && ev.kind != ChangeEvent::Kind::kLive) {
        std::lock_guard<std::mutex> l(mu);
        arrived[ev.lsn] = Clock::now();
      }
    }
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(500));  // the readers' watches connect

  std::mt19937_64 rng(34);
  std::vector<double> event_ms, reader_events_ms, reader_polling_ms, commit_ms;
  auto follow = [](client::Connection& r, uint64_t lsn, Clock::time_point ack) {
    for (;;) {
      auto d = r.Describe("live");
      if (d.ok() && d->last_lsn >= lsn) {
        return std::chrono::duration<double, std::milli>(Clock::now() - ack).count();
      }
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    }
  };
  for (int i = 0; i < commits; ++i) {
    std::this_thread::sleep_for(std::chrono::microseconds(rng() % 50000));  // a random moment
    Transaction t;
    std::vector<Point> pts(100);
    for (auto& p : pts) {
      p.x = static_cast<float>(rng() % 1000) / 1000;
      p.y = static_cast<float>(rng() % 1000) / 1000;
      p.z = 1;
      p.frame = static_cast<uint32_t>(i % 30);
    }
    t.Insert(std::move(pts));
    const auto sent = Clock::now();
    CommitInfo c = Check(w->Commit("live", t), "commit");
    const auto ack = Clock::now();
    commit_ms.push_back(std::chrono::duration<double, std::milli>(ack - sent).count());
    double a = 0, b = 0;
    std::thread pe([&] { a = follow(*re, c.lsn, ack); });
    std::thread pp([&] { b = follow(*rp, c.lsn, ack); });
    pe.join();
    pp.join();
    reader_events_ms.push_back(a);
    reader_polling_ms.push_back(b);
    for (int spin = 0; spin < 1000; ++spin) {
      std::lock_guard<std::mutex> l(mu);
      if (auto it = arrived.find(c.lsn); it != arrived.end()) {
        // Published before the reply is sent: an event may come before the acknowledgement.
        event_ms.push_back(std::max(0.0, std::chrono::duration<double, std::milli>(it->second - ack).count()));
        break;
      }
    }
  }
  stop = true;
  watcher.join();
  watch.reset();
  for (const Child& c : {writer, events, polling}) {
    ::kill(c.pid, SIGTERM);
    ::waitpid(c.pid, nullptr, 0);
  }
  fs::remove_all(work);

  json j = {{"bench", "live"},
            {"commits", commits},
            {"commit_ack", Summary(commit_ms)},
            {"watch_event_after_ack", Summary(event_ms)},
            {"reader_lag_events", Summary(reader_events_ms)},
            {"reader_lag_polling_100ms", Summary(reader_polling_ms)},
            {"targets", {{"watch_event_ms", 5}, {"reader_lag_ms", 10}}}};
  const double m = j["reader_lag_events"]["median_ms"].get<double>();
  j["reader_lag_speedup"] = m > 0 ? j["reader_lag_polling_100ms"]["median_ms"].get<double>() / m : 0;
  if (out.empty()) {
    std::printf("%s\n", j.dump(2).c_str());
  } else {
    std::ofstream(out) << j.dump(2) << "\n";
  }
  return 0;
}
