// 3. Thesis Figure 8.14, dynamic inserts: sets of ins_set random points committed one
// transaction at a time into an initially empty frame (the logarithmic method's Bkd-tree
// forest), the time of every set and the running average; once without and once with a
// durable commit (log fsync) per set, and once more without, with the thesis's binary method
// (fan-out 2) as the peer of the configured fan-out: the rebuilds per point, and warm windows
// on the forest each leaves (queries visit more trees with a wider fan-out).
#include <numeric>

#include "bench/bench.h"

namespace hvdb::bench {

namespace {

const char* kExp = "3-inserts";

struct InsertRun {
  std::string tag;  // figure names: ins.<tag>.*
  bool durable;
  uint32_t fanout;
};

// Warm windows of ~10 k points on the forest the inserts left: one warm pass, then each timed.
std::vector<double> ForestWindows(Dataset& ds, size_t n, const Config& c) {
  const double side = std::cbrt(10'000.0 / static_cast<double>(n));
  Rng rng(c.seed + 350);
  std::vector<Window> ws(static_cast<size_t>(c.win_queries));
  for (Window& w : ws) {
    for (int a = 0; a < 3; ++a) {
      w.lo[a] = rng.Uniform() * (1 - side);
      w.hi[a] = w.lo[a] + side;
    }
    w.lo[3] = -0.25 / c.fps;
    w.hi[3] = 0.25 / c.fps;
  }
  QueryOptions qo;
  for (const Window& w : ws) RunQuery(ds, w, qo);
  std::vector<double> ms;
  for (const Window& w : ws) ms.push_back(RunQuery(ds, w, qo).ms);
  return ms;
}

}  // namespace

void RunInserts(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  Curve curve{"inserts", kExp,
              "Figure 8.14: " + std::to_string(c.ins_set) + "-point sets into an empty Bkd-tree",
              "points in the tree", "time per set (ms)", false, true, {}};

  // The physical limit of a durable commit: appending the same bytes and fdatasync.
  const uint64_t set_bytes = c.ins_set * kPointRecordSize;
  std::vector<double> sync_samples;
  for (int r = 0; r < c.limit_reps; ++r) {
    sync_samples.push_back(AppendSyncMs(c.scratch, set_bytes, 5));
  }
  R.Add("ins.limit.append_fdatasync", kExp, "ms", sync_samples, {{"bytes", set_bytes}},
        "physical limit of a durable commit: append the set's bytes to a file and fdatasync "
        "(each sample the median of 5)");

  std::vector<InsertRun> runs = {{"nosync", false, c.merge_fanout},
                                 {"durable", true, c.merge_fanout}};
  if (c.merge_fanout != 2) runs.push_back({"nosync.binary", false, 2});
  for (const InsertRun& ir : runs) {
    const bool durable = ir.durable;
    const size_t total = durable ? c.ins_durable_total : c.ins_total;
    const std::string& tag = ir.tag;
    const std::string dir = c.scratch + "/ins_" + tag;
    Log("3 inserts (%s, fan-out %u): %zu points in sets of %zu", tag.c_str(), ir.fanout, total,
        c.ins_set);
    Options opts = c.DbOptions(durable);
    opts.merge_fanout = ir.fanout;
    Db db = Db::Create(dir, "ins", opts, c.fps);
    const std::vector<Point> pts = UniformPoints(total, c.seed + 300 + durable);
    std::vector<double> ms, x, avg, faults;
    double sum = 0;
    const ProcCounters run0 = ReadProcCounters();
    Timer run;
    for (size_t at = 0; at < total; at += c.ins_set) {
      const size_t n = std::min(c.ins_set, total - at);
      Transaction txn;
      txn.Insert(std::vector<Point>(pts.begin() + static_cast<std::ptrdiff_t>(at),
                                    pts.begin() + static_cast<std::ptrdiff_t>(at + n)));
      const ProcCounters p0 = ReadProcCounters();
      Timer t;
      Check(db.ds->Commit(txn), "commit");
      const double m = t.Ms();
      faults.push_back(static_cast<double>(ReadProcCounters().minor_faults - p0.minor_faults));
      ms.push_back(m);
      sum += m;
      x.push_back(static_cast<double>(at + n));
      avg.push_back(sum / static_cast<double>(ms.size()));
      if (ms.size() % 500 == 0) {
        Log("3 inserts (%s): %zu points, average %.3f ms per set", tag.c_str(), at + n,
            avg.back());
      }
    }
    // Sustained means the merges are done too: the merger builds trees in the background,
    // so the run ends when it has caught up (wall time from the first commit).
    Timer drain;
    Check(db.ds->WaitForMerges(), "wait for merges");
    const double drain_ms = drain.Ms();
    const double wall_ms = run.Ms();
    const uint64_t run_faults = ReadProcCounters().minor_faults - run0.minor_faults;
    DatasetStats st = db.ds->Stats();
    nlohmann::json p = {{"set_points", c.ins_set},
                        {"merge_fanout", ir.fanout},
                        {"merges", st.merges},
                        // Points the merger wrote into trees per point inserted: the
                        // logarithmic method's rebuilds (about log_k(n / T0's capacity)).
                        {"rebuilds_per_point", static_cast<double>(st.merged_points) /
                                                   static_cast<double>(total)},
                        {"drain_ms", drain_ms},
                        {"wall_ms", wall_ms},
                        {"total_points", total},
                        {"sets", ms.size()},
                        {"sync", durable != 0},
                        {"trees_at_end", st.trees},
                        {"buffered_points_at_end", st.buffered_points},
                        {"wal_bytes_at_end", st.wal_bytes},
                        // Page faults (the process's, merger included): first touches of
                        // fresh memory, each costly on a fresh VM (bench/README.md).
                        {"page_faults", run_faults},
                        {"page_faults_per_set_median", Median(faults)}};
    const std::string f = "ins." + tag;
    R.Add(f + ".set", kExp, "ms", ms, p, "time of one Commit of a " + std::to_string(c.ins_set) +
                                             "-point insert (one sample per set)");
    Figure& mean = R.Add(f + ".set.mean", kExp, "ms", {}, p,
                         "average time per set over the whole run (min/max: of the sets)");
    const auto [mn, mx] = std::minmax_element(ms.begin(), ms.end());
    mean.fixed = Figure::Stats{sum / static_cast<double>(ms.size()), *mn, *mx, ms.size()};
    Figure& rate = R.Add(f + ".rate", kExp, "Mpoints/s", {}, p,
                         "sustained insert rate: points / wall time of the run, from the "
                         "first commit until the merger has built every tree");
    const double r = static_cast<double>(total) / wall_ms / 1e3;
    rate.fixed = Figure::Stats{r, r, r, 1};
    if (!durable) {
      R.Add(f + ".window", kExp, "ms", ForestWindows(*db.ds, total, c),
            {{"merge_fanout", ir.fanout}, {"trees", st.trees}, {"buffered_points", st.buffered_points}},
            "warm ~10 k-point window on the frame the inserts built (its forest and T0; the "
            "points left in T0, scanned whole by every window, weigh more than the trees' "
            "count: no ratio between fan-outs is drawn from it)");
    }
    db.Close();
    RemoveAll(dir);

    if (tag == "nosync.binary") continue;  // its figures are the peer's; the curve is the thesis's
    curve.series.push_back({tag == "durable" ? "every set (durable commit)" : "every set (no fsync)",
                            x, ms, "points"});
    curve.series.push_back({tag == "durable" ? "running average (durable)"
                                             : "running average (no fsync)",
                            x, avg, "line"});
  }
  if (c.merge_fanout != 2) {
    R.Ratio("ins.nosync.rate.x_binary", kExp, "ins.nosync.rate", "ins.nosync.binary.rate",
            "sustained insert rate with the configured fan-out / with the thesis's binary method");
  }
  R.AddTarget("ins.nosync.set.mean", "<=", 110, "thesis 2008, Figure 8.14",
              "under 110 ms per 1000-point insert");
  R.AddTarget("ins.nosync.set.mean", "<=", 0.5, "issue 7 goal",
              "1000-point sets under 0.5 ms on average");
  R.AddTarget("ins.nosync.rate", ">=", 2.0, "issue 7 goal", ">= 2 million points/s sustained");
  R.AddTarget("ins.durable.set", "<=", 0.5, "issue 7 goal",
              "a durable 1000-point commit within 0.5 ms including the fsync (median commit)");
  R.AddTarget("ins.nosync.rate", ">=", 2.0, "issue 14 goal",
              ">= 2 million points/s sustained, the merger's work included");
  R.Ratio("ins.durable.set.x_fdatasync", kExp, "ins.durable.set", "ins.limit.append_fdatasync",
          "durable commit (median) / raw append + fdatasync of the same bytes");
  R.AddTarget("ins.durable.set.x_fdatasync", "<=", 1.5, "issue 14 goal",
              "a durable commit within 1.5x a bare append + fdatasync of its bytes (medians)");
  curve.series.push_back({"thesis 2008 bound", {0, static_cast<double>(c.ins_total)}, {110, 110},
                          "dashed"});
  R.AddCurve(curve);
}

}  // namespace hvdb::bench
