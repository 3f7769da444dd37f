// ServerStats: counters and latency percentiles for the `stats` request.
#ifndef HVDB_SERVER_STATS_H_
#define HVDB_SERVER_STATS_H_

#include <atomic>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace hvdb::server {

class ServerStats {
 public:
  struct Summary {
    std::string kind;
    uint64_t count;
    double p50_ms, p95_ms, p99_ms;
  };
  // Records one finished request of `kind` that took `ms` milliseconds.
  void Record(const std::string& kind, double ms);
  // Percentiles over the last kWindow requests of each kind.
  std::vector<Summary> Summaries() const;

  std::atomic<uint64_t> connections_open{0}, connections_total{0};
  std::atomic<uint64_t> bytes_in{0}, bytes_out{0};

 private:
  static constexpr size_t kWindow = 4096;
  struct Kind {
    uint64_t count = 0;
    std::vector<double> recent;  // ring buffer of the last kWindow latencies
  };
  mutable std::mutex mu_;
  std::map<std::string, Kind> kinds_;
};

}  // namespace hvdb::server

#endif  // HVDB_SERVER_STATS_H_
