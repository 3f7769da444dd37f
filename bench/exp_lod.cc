// 1. Thesis Table 8.2, level-of-detail loading: identical frames of lod_points points; the time
// to load one frame at each level of detail (cold and warm) and to stream it progressively.
#include <cinttypes>

#include "bench/bench.h"

namespace hvdb::bench {

namespace {

const char* kExp = "1-lod";

std::string L(int k) { return "lod.level" + std::to_string(k); }

}  // namespace

void RunLod(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  Limits& limits = *ctx.limits;
  const std::string dir = c.scratch + "/lod";
  Log("1 lod: %u frames of %zu points", c.lod_frames, c.lod_points);

  Db db = Db::Create(dir, "lod", c.DbOptions(), c.fps);
  const std::vector<Point> pts = UniformPoints(c.lod_points, c.seed);
  const uint64_t raw = c.lod_points * kPointRecordSize;
  std::vector<double> load_ms;
  for (uint32_t f = 0; f < c.lod_frames; ++f) {
    std::vector<Point> copy = pts;  // BulkLoad takes the points by value: copy outside the timer
    Timer t;
    Check(db.ds->BulkLoad(f, std::move(copy)), "bulk load");
    load_ms.push_back(t.Ms());
  }
  const nlohmann::json frame_params = {{"points", c.lod_points}, {"frames", c.lod_frames},
                                       {"levels", c.lod_levels + 1},
                                       {"block_bytes", c.block_kib * 1024}};
  R.Add("lod.bulkload", kExp, "ms", load_ms, frame_params,
        "BulkLoad of one frame (build in core, write, fsync), one sample per frame");
  R.Add("lod.limit.write_fsync", kExp, "ms", WriteSyncMs(c.scratch, raw, c.limit_reps),
        frame_params, "physical limit: write the frame's bytes to a new file and fdatasync");
  R.Ratio("lod.bulkload.x_write_fsync", kExp, "lod.bulkload", "lod.limit.write_fsync",
          "bulk load / writing the same bytes durably");
  std::vector<double> rate;
  for (double ms : load_ms) rate.push_back(c.lod_points / ms / 1e3);
  R.Add("lod.bulkload.rate", kExp, "Mpoints/s", rate, frame_params);

  uint64_t tree_bytes = 0;
  for (const std::string& f : FrameTreeFiles(db, 0)) tree_bytes += FileBytes(f);
  R.Add("lod.frame.tree_bytes", kExp, "MB", {tree_bytes / 1e6}, frame_params,
        "size of one frame's tree file");
  Figure& sz = R.Add("lod.frame.size.x_raw", kExp, "ratio", {}, frame_params,
                     "tree file bytes / raw point bytes (n x 64)");
  sz.fixed = Figure::Stats{static_cast<double>(tree_bytes) / raw,
                           static_cast<double>(tree_bytes) / raw,
                           static_cast<double>(tree_bytes) / raw, 1};
  R.AddTarget("lod.frame.size.x_raw", "<=", 1.1, "issue 7 goal",
              "size on disk within 1.1x of the raw point bytes");

  // Loading the frame at each level of detail: lod = k returns levels k..l (the frame at
  // resolution k), as the thesis's table reads.
  const int L_max = c.lod_levels;
  std::vector<double> lv, warm_med, cold_med, memcpy_med, seq_med, pts_at;
  double max_resident = 0;
  for (int k = L_max; k >= 0; --k) {
    QueryOptions qo;
    qo.lod = k;
    // Warm: after one untimed pass, frame 0 from the buffer pool.
    db.Reopen(false);
    QueryRun first = RunQuery(*db.ds, FrameWindow(0, c.fps), qo);
    std::vector<double> warm;
    for (int r = 0; r < c.warm_reps; ++r) warm.push_back(RunQuery(*db.ds, FrameWindow(0, c.fps), qo).ms);
    // Cold: a different frame each rep, nothing cached.
    std::vector<double> cold, blocks;
    for (int r = 0; r < c.cold_reps; ++r) {
      uint32_t f = static_cast<uint32_t>(r) % c.lod_frames;
      db.Reopen(true);
      max_resident = std::max(max_resident, db.last_resident);
      const uint64_t b0 = db.BlocksRead();
      QueryRun q = RunQuery(*db.ds, FrameWindow(f, c.fps), qo);
      blocks.push_back(static_cast<double>(db.BlocksRead() - b0));
      if (q.points != first.points) Die("lod: frames differ in point count");
      cold.push_back(q.ms);
    }
    const uint64_t bytes = first.points * kPointRecordSize;
    nlohmann::json p = frame_params;
    p["level"] = k;
    p["result_points"] = first.points;
    p["result_bytes"] = bytes;
    R.Add(L(k) + ".warm", kExp, "ms", warm, p,
          "load one frame at level of detail " + std::to_string(k) + " (levels >= k), warm");
    R.AttachLimit(L(k) + ".warm", limits, bytes, false);
    p["page_cache_resident_after_evict"] = max_resident;
    p["blocks_read_median"] = Median(blocks);
    R.Add(L(k) + ".cold", kExp, "ms", cold, p,
          "load one frame at level of detail " + std::to_string(k) + ", cold (evicted, new pool)");
    R.AttachLimit(L(k) + ".cold", limits, bytes, true);
    lv.push_back(k);
    warm_med.push_back(Median(warm));
    cold_med.push_back(Median(cold));
    memcpy_med.push_back(limits.LimitMs(bytes, false));
    seq_med.push_back(limits.LimitMs(bytes, true));
    pts_at.push_back(static_cast<double>(first.points));
    Log("1 lod: level %d: %" PRIu64 " points, warm %.2f ms, cold %.2f ms", k, first.points,
        warm_med.back(), cold_med.back());
  }
  R.AddTarget(L(L_max) + ".cold", "<=", 38, "thesis 2008, Table 8.2",
              "coarsest level of a 1.5M-point frame in 38 ms");
  R.AddTarget(L(0) + ".cold", "<=", 1161, "thesis 2008, Table 8.2",
              "full 1.5M-point frame in 1161 ms");

  // The physical limit for the whole frame, and hvdb as a multiple of it.
  R.AddLimit("lod.limit.memcpy", kExp, limits, raw, false).params["points"] = c.lod_points;
  R.AddLimit("lod.limit.seqread", kExp, limits, raw, true).params["points"] = c.lod_points;
  R.Ratio("lod.full.warm.x_memcpy", kExp, L(0) + ".warm", "lod.limit.memcpy",
          "full frame warm / memcpy of the same bytes");
  R.AddTarget("lod.full.warm.x_memcpy", "<=", 2, "issue 7 goal",
              "full 1.5M-point frame warm within 2x of memcpy of the same bytes");
  R.Ratio("lod.full.cold.x_seqread", kExp, L(0) + ".cold", "lod.limit.seqread",
          "full frame cold / sequential read of the same bytes");
  R.AddTarget("lod.full.cold.x_seqread", "<=", 1.5, "issue 7 goal",
              "full 1.5M-point frame cold within 1.5x of a sequential read");
  R.AddTarget("lod.full.cold.x_seqread", "<=", 1.5, "issue 14 goal",
              "full 1.5M-point frame cold within 1.5x of a sequential read");

  // Progressive streaming of the full frame: every level once, coarse first.
  std::vector<std::vector<double>> warm_lvl(static_cast<size_t>(L_max) + 1),
      cold_lvl(static_cast<size_t>(L_max) + 1);
  std::vector<double> warm_total, cold_total;
  uint64_t prog_points = 0;
  QueryOptions prog;
  prog.progressive = true;
  db.Reopen(false);
  prog_points = RunQuery(*db.ds, FrameWindow(0, c.fps), prog).points;
  for (int r = 0; r < c.warm_reps; ++r) {
    QueryRun q = RunQuery(*db.ds, FrameWindow(0, c.fps), prog);
    warm_total.push_back(q.ms);
    for (size_t i = 0; i < q.level_ms.size() && i < warm_lvl.size(); ++i) warm_lvl[i].push_back(q.level_ms[i]);
  }
  for (int r = 0; r < c.cold_reps; ++r) {
    db.Reopen(true);
    QueryRun q = RunQuery(*db.ds, FrameWindow(static_cast<uint32_t>(r) % c.lod_frames, c.fps), prog);
    cold_total.push_back(q.ms);
    for (size_t i = 0; i < q.level_ms.size() && i < cold_lvl.size(); ++i) cold_lvl[i].push_back(q.level_ms[i]);
  }
  nlohmann::json pp = frame_params;
  pp["result_points"] = prog_points;
  pp["result_bytes"] = prog_points * kPointRecordSize;
  R.Add("lod.progressive.warm", kExp, "ms", warm_total, pp,
        "stream the full frame progressively (coarse levels first), warm");
  R.AttachLimit("lod.progressive.warm", limits, prog_points * kPointRecordSize, false);
  R.Add("lod.progressive.cold", kExp, "ms", cold_total, pp,
        "stream the full frame progressively, cold");
  R.AttachLimit("lod.progressive.cold", limits, prog_points * kPointRecordSize, true);
  R.Add("lod.progressive.first_level.cold", kExp, "ms", cold_lvl[0], pp,
        "progressive stream, cold: time until the coarsest level is complete");
  std::vector<double> tl, tw, tc;
  for (size_t i = 0; i < warm_lvl.size(); ++i) {
    tl.push_back(static_cast<double>(L_max) - static_cast<double>(i));
    tw.push_back(Median(warm_lvl[i]));
    tc.push_back(Median(cold_lvl[i]));
  }
  db.Close();
  RemoveAll(dir);

  Curve lvl{"lod_levels", kExp,
            "Table 8.2: one frame of " + std::to_string(c.lod_points) + " points at each level",
            "level of detail (0 = full resolution)", "time to load (ms)", false, true, {}};
  lvl.series.push_back({"hvdb cold", lv, cold_med, "line"});
  lvl.series.push_back({"hvdb warm", lv, warm_med, "line"});
  lvl.series.push_back({"sequential read (cold limit)", lv, seq_med, "dashed"});
  lvl.series.push_back({"memcpy (warm limit)", lv, memcpy_med, "dashed"});
  lvl.series.push_back({"thesis 2008", {static_cast<double>(L_max), 0}, {38, 1161}, "points"});
  R.AddCurve(lvl);
  Curve pr{"lod_progressive", kExp, "Progressive stream of one frame: time until each level is complete",
           "level completed (coarse to fine)", "elapsed (ms)", false, true, {}};
  pr.series.push_back({"hvdb cold", tl, tc, "line"});
  pr.series.push_back({"hvdb warm", tl, tw, "line"});
  pr.invertx = true;
  R.AddCurve(pr);
}

}  // namespace hvdb::bench
