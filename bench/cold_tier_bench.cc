// cold-tier-bench: the compressed cold tier (storage/cold_tree.h) on the real Panoptic video,
// every stored attribute (position, normal, colour, covariance, id, frame, flags), beside its
// raw copy in the same run:
//   - bytes on disk after `compact` against the raw dataset (target <= 0.25);
//   - the whole video streamed from the compressed tier (cold: evicted; and with the files in the
//     page cache but the block cache empty, i.e. decoding only) against the raw tier warm
//     (target >= 0.5x its speed), and against the raw tier cold;
//   - windows of ~8 000 points cold, compressed against raw (target <= 2x);
//   - the compaction's own speed.
// Each figure is the median of --reps whole passes. bench/README.md explains the method.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "bench/util.h"
#include "blockcode/record_block.h"
#include "formats/ply.h"
#include "storage/database.h"

using namespace hvdb;
using namespace hvdb::bench;
using json = nlohmann::json;

namespace {

constexpr double kFps = 29.97;

json Stat(const std::vector<double>& v) {
  return {{"median", Median(v)},
          {"min", *std::min_element(v.begin(), v.end())},
          {"max", *std::max_element(v.begin(), v.end())},
          {"samples", v}};
}

// ~`want` points around a random point of a random frame: a box grown until it holds them.
std::vector<Window> MakeWindows(const std::vector<std::vector<Point>>& frames, size_t count,
                                size_t want, uint64_t seed) {
  Rng rng(seed);
  std::vector<Window> out;
  for (size_t i = 0; i < count; ++i) {
    const uint32_t f = static_cast<uint32_t>(rng.Next() % frames.size());
    const auto& pts = frames[f];
    const Point& c = pts[rng.Next() % pts.size()];
    double lo = 0, hi = 2.0;  // half size in metres, by bisection on the count
    for (int it = 0; it < 30; ++it) {
      const double h = (lo + hi) / 2;
      size_t n = 0;
      for (const Point& p : pts) {
        n += std::abs(p.x - c.x) <= h && std::abs(p.y - c.y) <= h && std::abs(p.z - c.z) <= h;
      }
      (n < want ? lo : hi) = h;
    }
    Window w;
    w.lo = {c.x - hi, c.y - hi, c.z - hi, (f - 0.25) / kFps};
    w.hi = {c.x + hi, c.y + hi, c.z + hi, (f + 0.25) / kFps};
    out.push_back(w);
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  std::string panoptic = std::string(HVDB_SOURCE_DIR) +
                         "/../shared/data/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds";
  std::string scratch = "/tmp/hvdb-cold-bench-" + std::to_string(::getpid());
  std::string out_path = "bench/results/cold_tier.json";
  int reps = 5;
  size_t windows = 20;
  CLI::App app{"cold-tier-bench: the compressed cold tier against the raw tier, on the real "
               "Panoptic video (see bench/README.md)"};
  app.add_option("--panoptic", panoptic, "Folder of the Panoptic ptcloud_hd*.ply frames");
  app.add_option("--scratch", scratch, "Where the two databases go (removed at the end)");
  app.add_option("--out", out_path, "JSON result");
  app.add_option("--reps", reps, "Whole passes per figure (the median is reported)")
      ->check(CLI::Range(1, 100));
  app.add_option("--windows", windows, "Windows per pass")->check(CLI::Range(1, 1000));
  CLI11_PARSE(app, argc, argv);

  // The 16 frames, as `hvdb import --units-scale 0.01` reads them.
  std::vector<std::string> files;
  for (const std::string& f : FilesUnder(panoptic)) {
    if (f.find("ptcloud_hd") != std::string::npos && f.ends_with(".ply")) files.push_back(f);
  }
  std::sort(files.begin(), files.end());  // frame order
  std::vector<std::vector<Point>> frames;
  for (const std::string& f : files) {
    formats::ReadOptions ro;
    ro.scale = 0.01;
    frames.push_back(Check(formats::ReadPly(f, ro), "read " + f));
  }
  if (frames.empty()) Die("no ptcloud_hd*.ply under " + panoptic);
  uint64_t points = 0;
  for (const auto& f : frames) points += f.size();
  Log("%zu frames, %llu points", frames.size(), static_cast<unsigned long long>(points));

  Options opts;
  opts.cold_after_s = 0;  // only the explicit compaction below
  MakeDirs(scratch);
  Db raw = Db::Create(scratch + "/raw", "panoptic", opts, kFps);
  Db cold = Db::Create(scratch + "/cold", "panoptic", opts, kFps);
  for (uint32_t f = 0; f < frames.size(); ++f) {
    Check(raw.ds->BulkLoad(f, frames[f]).status(), "load raw");
    Check(cold.ds->BulkLoad(f, frames[f]).status(), "load cold");
  }
  SyncFiles(scratch);
  const uint64_t raw_disk = DiskBytes(raw.DatasetDir());
  const uint64_t before_disk = DiskBytes(cold.DatasetDir());
  Timer tc;
  CompactInfo ci = Check(cold.ds->Compact(0, UINT32_MAX), "compact");
  const double compact_ms = tc.Ms();
  SyncFiles(scratch);
  const uint64_t cold_disk = DiskBytes(cold.DatasetDir());
  const DatasetStats cs = cold.ds->Stats();
  Log("compacted %u frames in %.0f ms: %llu -> %llu bytes on disk", ci.frames, compact_ms,
      static_cast<unsigned long long>(before_disk), static_cast<unsigned long long>(cold_disk));

  // The whole video, one query, as a client streams it.
  const Window video = [] {
    Window w;
    w.lo = {-1e9, -1e9, -1e9, -1e9};
    w.hi = {1e9, 1e9, 1e9, 1e9};
    return w;
  }();
  auto stream = [&](Db& d, int mode) {  // 0 warm, 1 cold, 2 page cache warm + pool cold
    std::vector<double> ms;
    if (mode == 0) {
      d.Reopen(false);
      RunQuery(*d.ds, video, {});  // untimed: fills the block cache
    }
    for (int r = 0; r < reps; ++r) {
      if (mode == 1) d.Reopen(true);
      if (mode == 2) {
        d.Reopen(false);
        RunQuery(*d.ds, video, {});  // the files' pages are cached...
        d.Reopen(false);             // ...the block cache is not
      }
      QueryRun q = RunQuery(*d.ds, video, {});
      if (q.points != points) Die("stream returned " + std::to_string(q.points) + " points");
      ms.push_back(q.ms);
    }
    return ms;
  };
  const auto raw_warm = stream(raw, 0);
  const auto raw_cold = stream(raw, 1);
  const auto cold_cold = stream(cold, 1);
  const auto cold_paged = stream(cold, 2);
  const auto cold_warm = stream(cold, 0);
  auto mps = [&](const std::vector<double>& ms) { return points / Median(ms) / 1e3; };
  Log("stream: raw warm %.1f ms, raw cold %.1f, compressed cold %.1f, compressed paged %.1f, "
      "compressed warm %.1f", Median(raw_warm), Median(raw_cold), Median(cold_cold),
      Median(cold_paged), Median(cold_warm));

  // Cold windows: each one after the cold protocol, raw and compressed interleaved.
  const auto wins = MakeWindows(frames, windows, 8000, 7);
  std::vector<double> win_raw, win_cold, win_points;
  for (int r = 0; r < reps; ++r) {
    std::vector<double> a, b;
    for (const Window& w : wins) {
      raw.Reopen(true);
      QueryRun qa = RunQuery(*raw.ds, w, {});
      cold.Reopen(true);
      QueryRun qb = RunQuery(*cold.ds, w, {});
      if (qa.points != qb.points) Die("a window differs between the tiers");
      a.push_back(qa.ms);
      b.push_back(qb.ms);
      if (r == 0) win_points.push_back(static_cast<double>(qa.points));
    }
    win_raw.push_back(Median(a));
    win_cold.push_back(Median(b));
  }
  Log("cold windows (~%.0f points): raw %.2f ms, compressed %.2f ms", Median(win_points),
      Median(win_raw), Median(win_cold));

  // The decoding kernel alone, one thread: the video's records in blocks of 1 024 (file order),
  // each decoded once per pass (what a cold read adds to the raw format's I/O).
  std::vector<std::string> coded;
  std::vector<uint32_t> counts;
  for (const auto& f : frames) {
    std::vector<uint8_t> recs(f.size() * kPointRecordSize);
    EncodePoints(f, recs.data());
    for (size_t at = 0; at < f.size(); at += 1024) {
      const auto n = static_cast<uint32_t>(std::min<size_t>(1024, f.size() - at));
      coded.emplace_back();
      blockcode::EncodeRecordBlock(recs.data() + at * kPointRecordSize, n, &coded.back());
      counts.push_back(n);
    }
  }
  std::vector<double> kernel_ms;
  std::vector<uint8_t> block(1024 * kPointRecordSize);
  for (int r = 0; r < reps; ++r) {
    Timer tk;
    for (size_t i = 0; i < coded.size(); ++i) {
      uint32_t n = 0;
      std::string err;
      if (!blockcode::DecodeRecordBlock(reinterpret_cast<const uint8_t*>(coded[i].data()),
                                        coded[i].size(), block.data(), 1024, &n, &err) ||
          n != counts[i]) {
        Die("record block: " + err);
      }
    }
    kernel_ms.push_back(tk.Ms());
  }
  Log("decoding kernel: %.1f M points/s on one thread", points / Median(kernel_ms) / 1e3);

  const double size_ratio = static_cast<double>(cold_disk) / static_cast<double>(raw_disk);
  const double stream_ratio = Median(raw_warm) / Median(cold_cold);
  const double paged_ratio = Median(raw_warm) / Median(cold_paged);
  const double window_ratio = Median(win_cold) / Median(win_raw);
  json out = {
      {"schema", "hvdb-cold-tier-bench/1"},
      {"command", "build/bench/cold-tier-bench --reps " + std::to_string(reps)},
      {"machine", MachineInfo(scratch)},
      {"data", {{"frames", frames.size()}, {"points", points},
                {"attributes", "position, normal, colour, covariance (isotropic, from the "
                               "reader), id, frame, flags: every field of the 64-byte record"}}},
      {"size",
       {{"raw_dataset_disk_bytes", raw_disk},
        {"compressed_dataset_disk_bytes", cold_disk},
        {"compressed_tree_bytes", cs.cold_tree_bytes},
        {"bytes_per_point", static_cast<double>(cs.cold_tree_bytes) / static_cast<double>(points)},
        {"of_64_byte_records", static_cast<double>(cs.cold_tree_bytes) / (64.0 * static_cast<double>(points))},
        {"ratio_to_raw_on_disk", size_ratio},
        {"target", "<= 0.25"},
        {"met", size_ratio <= 0.25}}},
      {"compact", {{"ms", compact_ms}, {"mpoints_per_s", points / compact_ms / 1e3}}},
      {"decode_kernel", {{"ms", Stat(kernel_ms)},
                         {"mpoints_per_s_one_thread", points / Median(kernel_ms) / 1e3}}},
      {"stream",
       {{"raw_warm_ms", Stat(raw_warm)},
        {"raw_cold_ms", Stat(raw_cold)},
        {"compressed_cold_ms", Stat(cold_cold)},
        {"compressed_page_cache_warm_ms", Stat(cold_paged)},
        {"compressed_warm_ms", Stat(cold_warm)},
        {"mpoints_per_s",
         {{"raw_warm", mps(raw_warm)}, {"raw_cold", mps(raw_cold)},
          {"compressed_cold", mps(cold_cold)}, {"compressed_page_cache_warm", mps(cold_paged)},
          {"compressed_warm", mps(cold_warm)}}},
        {"compressed_cold_vs_raw_warm", stream_ratio},
        {"compressed_page_cache_warm_vs_raw_warm", paged_ratio},
        {"compressed_cold_vs_raw_cold", Median(raw_cold) / Median(cold_cold)},
        {"target", "compressed >= 0.5x raw warm"},
        {"met", stream_ratio >= 0.5}}},
      {"windows",
       {{"count", wins.size()},
        {"points_median", Median(win_points)},
        {"raw_cold_ms", Stat(win_raw)},
        {"compressed_cold_ms", Stat(win_cold)},
        {"compressed_vs_raw_cold", window_ratio},
        {"target", "<= 2"},
        {"met", window_ratio <= 2.0}}},
  };
  raw.Close();
  cold.Close();
  RemoveAll(scratch);
  std::ofstream(out_path) << out.dump(2) << "\n";
  std::printf("size %.3f of raw (%.1f bytes/point); stream compressed cold %.2fx raw warm "
              "(page-cache warm %.2fx); cold window %.2fx raw cold -> %s\n",
              size_ratio, static_cast<double>(cs.cold_tree_bytes) / static_cast<double>(points),
              stream_ratio, paged_ratio, window_ratio, out_path.c_str());
  return 0;
}
