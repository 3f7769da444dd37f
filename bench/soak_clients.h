// The clients of hostile-soak (bench/hostile_soak.cc): the hostile kinds, each a bounded loop on
// its own thread until g_stop_hostile (TCP and WebSocket non-readers, slow readers, ping floods,
// malformed frames, pre-auth squatters), and the normal clients whose whole-frame window queries
// are timed. Everything dials the server on loopback; the frames are built by hand (wire.h) so
// that they can be broken on purpose.
#ifndef HVDB_BENCH_SOAK_CLIENTS_H_
#define HVDB_BENCH_SOAK_CLIENTS_H_

#include <sys/socket.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <map>
#include <mutex>
#include <set>
#include <string>

#include <nlohmann/json.hpp>

#include "client/client.h"

namespace hvdb::soak {

using Clock = std::chrono::steady_clock;

inline const std::string kDataset = "soak";
inline constexpr double kFps = 10.0;
inline constexpr int kQueriesPerNonReader = 32;  // the server's default --max-inflight

// Set when the hostile phase ends (or the server died, or RSS passed --safety-mb): every
// hostile loop then closes its sockets and returns.
extern std::atomic<bool> g_stop_hostile;

// Sockets used by blocking (Beast) calls: shut down from outside when the phase ends, so that no
// thread waits on a server that stopped answering.
class FdRegistry {
 public:
  void Add(int fd) {
    std::lock_guard<std::mutex> l(mu_);
    fds_.insert(fd);
  }
  void Remove(int fd) {
    std::lock_guard<std::mutex> l(mu_);
    fds_.erase(fd);
  }
  void ShutdownAll() {
    std::lock_guard<std::mutex> l(mu_);
    for (int fd : fds_) ::shutdown(fd, SHUT_RDWR);
  }

 private:
  std::mutex mu_;
  std::set<int> fds_;
};
extern FdRegistry g_blocking_fds;

struct Setup {
  uint16_t port = 0, http_port = 0;
  uint32_t frames = 8;
  int non_readers = 50, ws_non_readers = 25, slow_readers = 8, ping_floods = 4, malformed = 4,
      squatters = 300;
};

// What the hostile clients managed, for the JSON (so a run shows the load really happened).
// The keys are made up front: threads only look them up.
class Counters {
 public:
  Counters() {
    for (const char* k : {"non_reader_conns", "ws_conns", "ws_failed",
                          "slow_conns", "slow_bytes_read", "slow_closed", "ping_conns",
                          "pings_sent", "ping_conns_closed", "malformed_sent",
                          "malformed_closed_by_server", "squatter_connects", "squatter_drops",
                          "squatters_open_at_end"}) {
      m_[k];
    }
  }
  std::atomic<long>& operator[](const std::string& k) { return m_.at(k); }
  nlohmann::json ToJson() const {
    nlohmann::json j;
    for (auto& [k, v] : m_) j[k] = v.load();
    return j;
  }
 private:
  std::map<std::string, std::atomic<long>> m_;
};

// The hostile kinds, one thread each (Malformed: one per sender, seed = its index). They run
// until g_stop_hostile.
void NonReaders(const Setup& s, Counters& c);         // (a) TCP, never read
void WsNonReaders(const Setup& s, Counters& c);       // (b) WebSocket, never read
void SlowReaders(const Setup& s, Counters& c);        // (c) 4 KiB every 100 ms
void PingFloods(const Setup& s, Counters& c);         // (d) 1 and 8 MiB pings, pongs unread
void Malformed(const Setup& s, int seed, Counters& c);  // (e) broken frames
void Squatters(const Setup& s, Counters& c);          // (f) connect and say nothing

// The normal clients' connection: TCP only, one attempt, short timeouts.
client::Options ClientOptions(uint16_t port);
// k normal clients for `seconds`: throughput, latency percentiles, errors and refusals. With
// connect_early they connect before the timed window; else inside it.
nlohmann::json RunNormals(const Setup& s, int k, double seconds, bool connect_early);

}  // namespace hvdb::soak

#endif  // HVDB_BENCH_SOAK_CLIENTS_H_
