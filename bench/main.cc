// hvdb-bench: the storage benchmark suite (issue 7). One command runs the thesis's experiments
// side by side with the physical limits and the peers and writes one JSON file plus PNG plots.
// bench/README.md documents the experiments, the JSON schema and the latest figures.
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include <CLI/CLI.hpp>

#include "bench/bench.h"

namespace hvdb::bench {

Config Config::Quick() {
  Config c;
  c.quick = true;
  c.warm_reps = 5;
  c.cold_reps = 3;
  c.limit_reps = 3;
  c.lod_frames = 2;
  c.lod_points = 100'000;
  c.win_min = 20'000;
  c.win_max = 100'000;
  c.win_step = 40'000;
  c.win_result = 1'000;
  c.win_queries = 20;
  c.win_cold = 3;
  c.pcl_sizes = {100'000};
  c.ins_total = 100'000;
  c.ins_durable_total = 20'000;
  c.rt_small_frames = 4;
  c.rt_small_points = 20'000;
  c.rt_large_frames = 2;
  c.rt_large_points = 50'000;
  c.bulk_reps = 2;
  c.rt4d_max_points = 40'000;
  c.slice_frames = 136;
  c.slice_points = 2'000;
  c.e2e_points = 100'000;
  c.e2e_queries = 64;
  c.e2e_rounds = 1;
  c.small_frames = 200;
  return c;
}

Options Config::DbOptions(bool sync) const {
  Options o;
  o.cache_bytes = cache_mib << 20;
  o.block_size = block_kib << 10;
  o.lod_levels = lod_levels;
  o.sync = sync;
  o.merge_fanout = merge_fanout;
  if (read_engine == "uring") o.env = Env::Posix(Env::ReadEngine::kIoUring);
  if (read_engine == "preadv") o.env = Env::Posix(Env::ReadEngine::kPreadv);
  return o;
}

namespace {

std::string Shell(const std::string& cmd) {
  std::string out;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return out;
  char buf[256];
  while (std::fgets(buf, sizeof(buf), p) != nullptr) out += buf;
  ::pclose(p);
  while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
  return out;
}

std::string Now() {
  std::time_t t = std::time(nullptr);
  char buf[64];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%SZ", std::gmtime(&t));
  return buf;
}

std::string Quote(const std::string& s) {
  std::string q = "'";
  for (char ch : s) q += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
  return q + "'";
}

nlohmann::json ConfigJson(const Config& c) {
  return {{"quick", c.quick},
          {"seed", c.seed},
          {"cache_mib", c.cache_mib},
          {"block_kib", c.block_kib},
          {"lod_levels", c.lod_levels},
          {"fps", c.fps},
          {"warm_reps", c.warm_reps},
          {"cold_reps", c.cold_reps},
          {"limit_reps", c.limit_reps},
          {"lod_frames", c.lod_frames},
          {"lod_points", c.lod_points},
          {"win_min", c.win_min},
          {"win_max", c.win_max},
          {"win_step", c.win_step},
          {"win_result", c.win_result},
          {"win_queries", c.win_queries},
          {"win_cold", c.win_cold},
          {"pcl_sizes", c.pcl_sizes},
          {"peers", c.peers},
          {"ins_total", c.ins_total},
          {"ins_set", c.ins_set},
          {"ins_durable_total", c.ins_durable_total},
          {"merge_fanout", c.merge_fanout},
          {"rt_small_frames", c.rt_small_frames},
          {"rt_small_points", c.rt_small_points},
          {"rt_large_frames", c.rt_large_frames},
          {"rt_large_points", c.rt_large_points},
          {"rt4d_max_points", c.rt4d_max_points},
          {"bulk_reps", c.bulk_reps},
          {"slice_frames", c.slice_frames},
          {"slice_points", c.slice_points},
          {"slice_spans", c.slice_spans},
          {"e2e_points", c.e2e_points},
          {"e2e_clients", c.e2e_clients},
          {"e2e_queries", c.e2e_queries},
          {"e2e_rounds", c.e2e_rounds},
          {"small_frames", c.small_frames},
          {"small_points", c.small_points}};
}

int Main(int argc, char** argv) {
  bool quick = false;
  for (int i = 1; i < argc; ++i) quick = quick || std::string(argv[i]) == "--quick";
  Ctx ctx;
  Config& c = ctx.cfg;
  c = quick ? Config::Quick() : Config();

  std::string out = "hvdb-bench.json", plots, plot_script = HVDB_BENCH_PLOT_SCRIPT, python;
  bool no_plots = false, keep_scratch = false;
  std::vector<int> only;
  CLI::App app{
      "hvdb-bench: the storage benchmark suite. Runs the thesis's experiments (1 Table 8.2 "
      "level-of-detail loading, 2 Figure 8.13 window queries, 3 Figure 8.14 dynamic inserts, 4 "
      "Table 8.1 against the R*-tree, 5 peers on the same windows, 6 physical limits, 7 "
      "hyperslices, 9 small frames on disk) with the thesis's sizes by default, and writes one JSON file (schema: "
      "bench/README.md) and PNG plots."};
  app.add_flag("--quick", quick, "small sizes for a CI smoke run (under 2 minutes)");
  app.add_option("--out", out, "JSON file to write")->capture_default_str();
  app.add_option("--plots", plots, "directory for the PNG plots (default: the JSON's directory)");
  app.add_flag("--no-plots", no_plots, "do not run the plot script");
  app.add_option("--plot-script", plot_script, "the matplotlib script that draws the curves")
      ->capture_default_str();
  app.add_option("--python", python,
                 "Python with matplotlib (default: /usr/bin/python3, where Debian's "
                 "python3-matplotlib is, else python3 on PATH)");
  app.add_option("--scratch", c.scratch,
                 "directory for the datasets (several GB at full size; removed at the end; "
                 "default: $TMPDIR/hvdb-bench-PID)");
  app.add_flag("--keep-scratch", keep_scratch, "leave the scratch directory in place");
  app.add_option("--only", only, "experiments to run (1-9; 6 is part of every other one)")
      ->delimiter(',');
  app.add_option("--seed", c.seed, "random seed of the synthetic points")->capture_default_str();
  app.add_option("--cache-mib", c.cache_mib, "hvdb buffer pool (and R*-tree buffer) in MiB")
      ->capture_default_str();
  app.add_option("--block-kib", c.block_kib, "hvdb block size in KiB")->capture_default_str();
  app.add_option("--read-engine", c.read_engine,
                 "how hvdb's batched cold reads reach the device: default (io_uring where the "
                 "kernel allows it), uring, or preadv (one request after another per loader)")
      ->check(CLI::IsMember({"default", "uring", "preadv"}))
      ->capture_default_str();
  app.add_option("--lod-levels", c.lod_levels, "coarsest level l (levels 0..l)")->capture_default_str();
  app.add_option("--warm-reps", c.warm_reps, "timed repetitions of warm figures")->capture_default_str();
  app.add_option("--cold-reps", c.cold_reps, "timed repetitions of cold figures")->capture_default_str();
  app.add_option("--limit-reps", c.limit_reps, "repetitions of each physical-limit measurement")
      ->capture_default_str();
  auto* g1 = app.add_option_group("1 level of detail (Table 8.2)");
  g1->add_option("--lod-frames", c.lod_frames, "identical frames")->capture_default_str();
  g1->add_option("--lod-points", c.lod_points, "points per frame (also the bulk-load comparison)")
      ->capture_default_str();
  auto* g2 = app.add_option_group("2 and 5 window queries (Figure 8.13) and peers");
  g2->add_option("--win-min", c.win_min, "smallest frame")->capture_default_str();
  g2->add_option("--win-max", c.win_max, "largest frame")->capture_default_str();
  g2->add_option("--win-step", c.win_step, "frame size step")->capture_default_str();
  g2->add_option("--win-result", c.win_result, "points a window returns")->capture_default_str();
  g2->add_option("--win-queries", c.win_queries, "windows per frame size (warm)")->capture_default_str();
  g2->add_option("--win-cold", c.win_cold, "cold windows per frame size and level")->capture_default_str();
  g2->add_option("--pcl-sizes", c.pcl_sizes, "frame sizes PCL outofcore is built for")
      ->delimiter(',')
      ->capture_default_str();
  g2->add_flag("!--no-peers", c.peers, "skip nanoflann and PCL");
  auto* g3 = app.add_option_group("3 dynamic inserts (Figure 8.14)");
  g3->add_option("--ins-total", c.ins_total, "points inserted without fsync")->capture_default_str();
  g3->add_option("--ins-set", c.ins_set, "points per set (one commit)")->capture_default_str();
  g3->add_option("--ins-durable-total", c.ins_durable_total, "points inserted with durable commits")
      ->capture_default_str();
  g3->add_option("--merge-fanout", c.merge_fanout,
                 "the logarithmic method's fan-out (the no-fsync run is repeated with 2, the thesis's)")
      ->check(CLI::Range(2, 16))
      ->capture_default_str();
  auto* g4 = app.add_option_group("4 against the R*-tree (Table 8.1)");
  g4->add_option("--rt-small-frames", c.rt_small_frames, "frames of the small-frame set")->capture_default_str();
  g4->add_option("--rt-small-points", c.rt_small_points, "points per small frame")->capture_default_str();
  g4->add_option("--rt-large-frames", c.rt_large_frames, "frames of the large-frame set")->capture_default_str();
  g4->add_option("--rt-large-points", c.rt_large_points, "points per large frame")->capture_default_str();
  g4->add_option("--rt4d-max-points", c.rt4d_max_points,
                 "points inserted into the 4D R*-tree per frame set; the frame cut short is "
                 "timed on its prefix and scaled (0: all frames)")
      ->capture_default_str();
  g4->add_option("--bulk-reps", c.bulk_reps, "repetitions of the bulk-load comparison")->capture_default_str();
  auto* g7 = app.add_option_group("7 hyperslices");
  g7->add_option("--slice-frames", c.slice_frames, "frames")->capture_default_str();
  g7->add_option("--slice-points", c.slice_points, "points per frame")->capture_default_str();
  g7->add_option("--slice-spans", c.slice_spans, "frames spanned by the tilted slices")
      ->delimiter(',')
      ->capture_default_str();
  auto* g8 = app.add_option_group("8 end to end through hvdb-server");
  g8->add_option("--e2e-points", c.e2e_points, "points in the served frame")->capture_default_str();
  g8->add_option("--e2e-clients", c.e2e_clients, "concurrent client counts")
      ->delimiter(',')
      ->capture_default_str();
  g8->add_option("--e2e-queries", c.e2e_queries,
                 "windows per client count and round (split among clients)")
      ->capture_default_str();
  g8->add_option("--e2e-rounds", c.e2e_rounds, "interleaved rounds of every client count")
      ->capture_default_str()->check(CLI::Range(1, 100));
  auto* g9 = app.add_option_group("9 small frames on disk");
  g9->add_option("--small-frames", c.small_frames, "frames bulk loaded")->capture_default_str();
  g9->add_option("--small-points", c.small_points, "points per frame")->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  c.only.insert(only.begin(), only.end());
  for (int e : c.only) {
    if (e < 1 || e > 9) {
      std::cerr << "hvdb-bench: --only takes experiments 1-9, got " << e << "\n";
      return 2;
    }
  }
  if (c.win_step == 0 || c.ins_set == 0 || c.lod_frames == 0 || c.lod_points == 0 ||
      c.win_min == 0 || c.win_max < c.win_min || c.win_result == 0 || c.win_queries < 1 ||
      c.win_cold < 1 || c.ins_total == 0 || c.ins_durable_total == 0 ||
      c.rt_small_frames == 0 || c.rt_small_points == 0 || c.rt_large_frames == 0 ||
      c.rt_large_points == 0 || c.slice_frames == 0 || c.slice_points == 0 ||
      c.e2e_points == 0 || c.e2e_queries < 1 || c.small_frames == 0 || c.small_points == 0 || c.e2e_clients.empty() ||
      std::any_of(c.e2e_clients.begin(), c.e2e_clients.end(), [](int n) { return n < 1 || n > 256; }) ||
      c.bulk_reps < 1 || c.warm_reps < 1 || c.cold_reps < 1 || c.limit_reps < 1) {
    std::cerr << "hvdb-bench: sizes, steps and repetitions must be positive (and win-max >= "
                 "win-min)\n";
    return 2;
  }
  if (c.scratch.empty()) {
    const char* tmp = std::getenv("TMPDIR");
    c.scratch = std::string(tmp && *tmp ? tmp : "/tmp") + "/hvdb-bench-" + std::to_string(::getpid());
  }
  c.scratch = std::filesystem::absolute(c.scratch).string();
  MakeDirs(c.scratch);
  std::filesystem::path out_path = std::filesystem::absolute(out);
  if (plots.empty()) plots = out_path.parent_path().string();
  MakeDirs(out_path.parent_path().string());

  std::string command;
  for (int i = 0; i < argc; ++i) command += (i ? " " : "") + std::string(argv[i]);
  nlohmann::json run;
  run["schema"] = "hvdb-bench/1";
  run["command"] = command;
  run["started"] = Now();
  run["quick"] = c.quick;
  run["config"] = ConfigJson(c);
  run["machine"] = MachineInfo(c.scratch);
  run["git"] = {{"commit", Shell("git -C " + Quote(HVDB_SOURCE_DIR) + " rev-parse HEAD 2>/dev/null")},
                {"dirty", !Shell("git -C " + Quote(HVDB_SOURCE_DIR) +
                                 " status --porcelain -- storage bench 2>/dev/null")
                               .empty()}};
  Log("hvdb-bench%s: scratch %s, output %s", c.quick ? " --quick" : "", c.scratch.c_str(),
      out_path.c_str());

  ctx.limits = std::make_unique<Limits>(c.scratch + "/limits", c.limit_reps);
  Timer total;
  nlohmann::json times = nlohmann::json::object();
  auto step = [&](int e, const char* name, void (*fn)(Ctx&)) {
    if (!c.Runs(e)) return;
    Timer t;
    fn(ctx);
    times[name] = t.Ms() / 1000.0;
    Log("%s done in %.1f s", name, t.Ms() / 1000.0);
  };
  // 6 (the physical limits) is measured inside each experiment for the bytes it moves; the
  // machine's raw bandwidths are recorded here.
  {
    Timer t;
    const uint64_t bytes = c.lod_points * kPointRecordSize;
    Limits& l = *ctx.limits;
    Figure& m = ctx.report.AddLimit("limit.memcpy", "6-limits", l, bytes, false);
    Figure& s = ctx.report.AddLimit("limit.seqread", "6-limits", l, bytes, true);
    const double mb = static_cast<double>(bytes) / 1e6;
    ctx.report.Add("limit.memcpy.bandwidth", "6-limits", "GB/s", {mb / m.median()},
                   {{"bytes", bytes}}, "memcpy bandwidth (median rep)");
    ctx.report.Add("limit.seqread.bandwidth", "6-limits", "GB/s", {mb / s.median()},
                   {{"bytes", bytes}}, "cold sequential read bandwidth (median rep)");
    times["6-limits"] = t.Ms() / 1000.0;
  }
  step(1, "1-lod", RunLod);
  if (c.Runs(2) || c.Runs(5)) {
    Config saved = c;
    if (!c.Runs(5)) c.peers = false;
    step(c.Runs(2) ? 2 : 5, "2-windows+5-peers", RunWindows);
    c = saved;
  }
  step(3, "3-inserts", RunInserts);
  step(4, "4-rtree", RunRTree);
  step(7, "7-slices", RunSlices);
  step(8, "8-server", RunServer);
  step(9, "9-small-frames", RunSmallFrames);
  ctx.limits.reset();

  nlohmann::json j = ctx.report.ToJson();
  const std::string stem = out_path.stem().string();
  for (auto& cv : j["curves"]) cv["png"] = stem + "." + cv["name"].get<std::string>() + ".png";
  for (auto& [k, v] : j.items()) run[k] = v;
  run["experiment_seconds"] = times;
  run["duration_s"] = total.Ms() / 1000.0;
  run["finished"] = Now();
  double load[3] = {0, 0, 0};
  if (::getloadavg(load, 3) == 3) run["machine"]["loadavg_at_end"] = {load[0], load[1], load[2]};
  {
    std::ofstream f(out_path);
    f << run.dump(1) << "\n";
    if (!f) Die("write " + out_path.string());
  }
  Log("wrote %s: %zu figures, %zu targets met, %zu missed", out_path.c_str(),
      run["figures"].size(), run["targets_met"].get<size_t>(), run["targets_missed"].get<size_t>());
  if (!keep_scratch) RemoveAll(c.scratch);
  if (!no_plots && !run["curves"].empty()) {
    MakeDirs(plots);
    if (python.empty()) python = ::access("/usr/bin/python3", X_OK) == 0 ? "/usr/bin/python3" : "python3";
    std::string cmd = Quote(python) + " " + Quote(plot_script) + " " + Quote(out_path.string()) + " " +
                      Quote(plots);
    int rc = std::system(cmd.c_str());
    if (rc != 0) {
      std::cerr << "hvdb-bench: plotting failed (" << cmd
                << "); the JSON is complete, rerun the script or pass --no-plots\n";
      return 1;
    }
    Log("plots in %s", plots.c_str());
  }
  return 0;
}

}  // namespace
}  // namespace hvdb::bench

int main(int argc, char** argv) { return hvdb::bench::Main(argc, argv); }
