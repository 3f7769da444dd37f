// hvdb-bench: the run's configuration and the experiments (issue 7, items 1-8).
#ifndef HVDB_BENCH_BENCH_H_
#define HVDB_BENCH_BENCH_H_

#include <cstdint>
#include <set>
#include <string>
#include <vector>

#include "bench/report.h"
#include "bench/util.h"

namespace hvdb::bench {

// Every size is a parameter; the defaults are the thesis's values, Config::Quick() the CI scale.
struct Config {
  bool quick = false;
  std::set<int> only;  // experiments to run (empty: all)
  std::string scratch;
  uint64_t seed = 2008;
  size_t cache_mib = 1024;  // hvdb's buffer pool (and the R*-tree's buffer, in pages)
  uint32_t block_kib = 64;
  std::string read_engine = "default";  // default | uring | preadv: the Env's batched reads
  int lod_levels = 5;  // l: levels 0..5, the thesis's 6 levels
  double fps = 30;
  int warm_reps = 10;
  int cold_reps = 5;
  int limit_reps = 5;

  // 1. Table 8.2: level-of-detail loading.
  uint32_t lod_frames = 20;
  size_t lod_points = 1'500'000;

  // 2. Figure 8.13: window queries (and 5., the peers on the same windows).
  size_t win_min = 100'000, win_max = 2'000'000, win_step = 100'000;
  size_t win_result = 10'000;
  int win_queries = 50;  // windows per frame size (warm: each timed once after a warm pass)
  int win_cold = 10;     // cold windows per frame size and level
  std::vector<size_t> pcl_sizes = {500'000, 1'000'000, 2'000'000};
  bool peers = true;

  // 3. Figure 8.14: dynamic inserts.
  size_t ins_total = 2'000'000;
  size_t ins_set = 1000;
  size_t ins_durable_total = 2'000'000;
  uint32_t merge_fanout = Options().merge_fanout;  // the logarithmic method's (2: the thesis's)

  // 4. Table 8.1: against the R*-tree.
  uint32_t rt_small_frames = 60;
  size_t rt_small_points = 200'000;
  uint32_t rt_large_frames = 2;
  size_t rt_large_points = 1'750'000;
  // The 4D R*-tree is grown by one-at-a-time insertion (frames arrive over time) at ~150-250 us
  // per point with 64 KiB nodes: all 60 + 2 frames would take hours. It gets the frames in
  // order up to this many points; a frame cut short counts with its time scaled to the whole
  // frame (a lower bound: the tree only gets slower as it grows). 0: everything.
  size_t rt4d_max_points = 600'000;
  int bulk_reps = 3;  // bulk loads of a lod_points frame: hvdb vs R*-tree STR vs PCL

  // 7. Hyperslices.
  uint32_t slice_frames = 136;
  size_t slice_points = 100'000;
  std::vector<int> slice_spans = {8, 32, 128};

  // 8. End to end through hvdb-server.
  size_t e2e_points = 2'000'000;
  std::vector<int> e2e_clients = {1, 8, 32};
  int e2e_queries = 1280;  // windows per client count and round, shared among the clients
  int e2e_rounds = 5;      // rounds of every client count on every path, interleaved

  // 9. Small frames on disk.
  uint32_t small_frames = 3000;
  size_t small_points = 2000;

  static Config Quick();
  bool Runs(int experiment) const { return only.empty() || only.count(experiment) > 0; }
  Options DbOptions(bool sync = true) const;
};

struct Ctx {
  Config cfg;
  Report report;
  std::unique_ptr<Limits> limits;
};

void RunLod(Ctx& ctx);        // 1 (+6)
void RunWindows(Ctx& ctx);    // 2 and 5 (+6)
void RunInserts(Ctx& ctx);    // 3
void RunRTree(Ctx& ctx);      // 4 (and the bulk-load comparison)
void RunSlices(Ctx& ctx);     // 7 (+6)
void RunServer(Ctx& ctx);     // 8
void RunSmallFrames(Ctx& ctx);  // 9

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_BENCH_H_
