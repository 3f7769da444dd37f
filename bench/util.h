// Shared pieces of hvdb-bench: timing, synthetic points, page-cache eviction, physical limits,
// opening databases cold, and the machine description.
#ifndef HVDB_BENCH_UTIL_H_
#define HVDB_BENCH_UTIL_H_

#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "storage/database.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::bench {

using Clock = std::chrono::steady_clock;

inline double MsBetween(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

class Timer {
 public:
  Timer() : t0_(Clock::now()) {}
  double Ms() const { return MsBetween(t0_, Clock::now()); }
  void Reset() { t0_ = Clock::now(); }

 private:
  Clock::time_point t0_;
};

// Progress lines on stderr, prefixed with the time since the run started.
void Log(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
// A failure of the engine or the OS ends the run: the numbers would not be trustworthy.
[[noreturn]] void Die(const std::string& what);
void Check(const Status& s, const std::string& what);
template <typename T>
T Check(Result<T> r, const std::string& what) {
  if (!r.ok()) Die(what + ": " + r.status().ToString());
  return std::move(r).value();
}

// Deterministic fast random numbers (splitmix64).
class Rng {
 public:
  explicit Rng(uint64_t seed) : s_(seed) {}
  uint64_t Next() {
    uint64_t z = (s_ += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
  }
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }  // [0, 1)
  float UniformF() { return static_cast<float>(Next() >> 40) * 0x1.0p-24f; }  // [0, 1)

 private:
  uint64_t s_;
};

// n points uniformly distributed in the unit cube [0, 1)^3, every field of the 64-byte record
// filled (covariance, normal, colour, flags) as an ingested point would be; ids 0.
std::vector<Point> UniformPoints(size_t n, uint64_t seed, uint32_t frame = 0);

// --- files -------------------------------------------------------------------------------------
std::vector<std::string> FilesUnder(const std::string& path);  // regular files, recursive
// Bytes the files under `path` occupy on disk (allocated blocks, as du reports).
uint64_t DiskBytes(const std::string& path);
uint64_t FileBytes(const std::string& path);  // apparent size (st_size), recursive
void RemoveAll(const std::string& path);
void MakeDirs(const std::string& path);
// Drops every file under `path` from the page cache: fdatasync (dirty pages cannot be dropped),
// then posix_fadvise(POSIX_FADV_DONTNEED).
void Evict(const std::string& path);
// fdatasync of every file under `path` and of the directories: what makes a peer's files as
// durable as hvdb's (which fsyncs what it writes).
void SyncFiles(const std::string& path);
// Fraction of the bytes under `path` resident in the page cache (mincore), to prove an eviction.
double ResidentFraction(const std::string& path);

// This process's minor page faults and bytes it caused to be read from the device (readahead
// included: /proc/self/io read_bytes), to say where a cold query's time goes.
struct ProcCounters {
  uint64_t minor_faults = 0, read_bytes = 0;
};
ProcCounters ReadProcCounters();

// --- physical limits (issue item 6) ----------------------------------------------------------
// The time to move the same bytes without any index: cold, a sequential read of a file on the
// same file system after eviction (both O_DIRECT in 4 MiB requests and buffered read() with
// kernel readahead; the limit is the faster); warm, memcpy from a resident buffer into a reused
// batch-sized buffer (what a consumer of 16384-point batches receives at the least).
class Limits {
 public:
  explicit Limits(std::string scratch_dir, int reps = 5);
  ~Limits();
  struct Cold {
    std::vector<double> direct, buffered;  // ms per rep
    double direct_ms() const;
    double buffered_ms() const;
    double best_ms() const { return std::min(direct_ms(), buffered_ms()); }
    const std::vector<double>& best() const {
      return direct_ms() <= buffered_ms() ? direct : buffered;
    }
  };
  const std::vector<double>& Warm(uint64_t bytes);  // ms per rep, cached per byte count
  const Cold& ColdRead(uint64_t bytes);             // ms per rep, cached per byte count
  // {"kind", "bytes", "ms", ...}: the limit for `bytes`, cold or warm, for a figure's JSON.
  nlohmann::json Describe(uint64_t bytes, bool cold);
  double LimitMs(uint64_t bytes, bool cold);
  std::vector<double> Samples(uint64_t bytes, bool cold);
  int reps() const { return reps_; }

 private:
  void EnsureFile(uint64_t bytes);
  std::string dir_, file_;
  int reps_;
  uint64_t file_bytes_ = 0;
  std::vector<uint8_t> src_, dst_;
  std::map<uint64_t, std::vector<double>> warm_;
  std::map<uint64_t, Cold> cold_;
};

// A raw durable append: write `bytes` at the end of a file and fdatasync (the physical limit of
// a durable commit of that many bytes). Median of reps, in ms.
double AppendSyncMs(const std::string& scratch_dir, uint64_t bytes, int reps);

// The physical limit of a durable bulk write: write `bytes` to a new file in 4 MiB chunks and
// fdatasync it. ms per rep.
std::vector<double> WriteSyncMs(const std::string& scratch_dir, uint64_t bytes, int reps);

// The device's limit for a query's scattered block reads: `blocks` distinct random blocks of
// `file` (sorted), evicted first, all submitted at once with io_uring and waited for. ms per rep.
std::vector<double> RandomBlocksMs(const std::string& file, size_t blocks, size_t block_bytes,
                                   int reps, uint64_t seed);

// --- hvdb ------------------------------------------------------------------------------------
// A database with one dataset open. Reopen(cold=true) is the cold protocol: close everything
// (the buffer pool goes), evict the dataset's files, reopen, evict again (the open read the
// headers and checksum tables), so the next query finds neither the pool nor the page cache warm.
struct Db {
  std::string dir, name;
  Options opts;
  std::unique_ptr<Database> db;
  std::shared_ptr<Dataset> ds;
  double last_resident = 0;  // ResidentFraction after the last cold reopen

  static Db Create(const std::string& dir, const std::string& name, const Options& opts,
                   double fps = 30);
  void Reopen(bool cold);
  void Close();
  std::string DatasetDir() const { return dir + "/" + name; }
  // Blocks the buffer pool has loaded from disk so far (its misses): after a cold reopen, the
  // difference across a query is the number of block reads the query issued.
  uint64_t BlocksRead() const { return db->Cache().misses; }
};

struct QueryRun {
  double ms = 0;
  uint64_t points = 0;
  uint32_t frames = 0;                 // frames the query read
  std::vector<double> level_ms;       // progressive: time when each level was complete
  std::vector<uint64_t> level_points;  // progressive: points of each level
};
// Runs the query to the end and counts the points of every batch (the engine has copied them
// into the batch, as a consumer receives them; the physical limit does the same copy).
QueryRun RunQuery(Dataset& ds, const Region& region, const QueryOptions& qo);

// A window covering all space of one frame.
Window FrameWindow(uint32_t frame, double fps);
// The tree files of one frame, and their total size.
std::vector<std::string> FrameTreeFiles(const Db& db, uint32_t frame);

// --- machine ---------------------------------------------------------------------------------
nlohmann::json MachineInfo(const std::string& scratch_dir);

// Median of a sample (copy).
double Median(std::vector<double> v);

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_UTIL_H_
