// 7. Hyperslices (thesis 8.2): a slice orthogonal to t (one frame) and tilted slices spanning
// 8, 32 and 128 frames, at each level of detail, cold and warm.
//
// A tilted slice has the normal (a, 0, 0, 1) over (x, y, z, s t) with s = 1 m/s: across
// x in [0, 1] its hyperplane moves by a seconds, so a = span / fps makes it cross `span`
// frames. Its half-thickness 1 / (2 fps) gives each frame a slab of x of width 1 / span: a
// tilted slice returns about one frame's worth of points, spread over `span` frames.
#include <cinttypes>

#include "bench/bench.h"

namespace hvdb::bench {

namespace {

const char* kExp = "7-slices";

}  // namespace

void RunSlices(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  Limits& limits = *ctx.limits;
  const std::string dir = c.scratch + "/slice";
  Log("7 slices: %u frames of %zu points", c.slice_frames, c.slice_points);
  Db db = Db::Create(dir, "slice", c.DbOptions(), c.fps);
  for (uint32_t f = 0; f < c.slice_frames; ++f) {
    Check(db.ds->BulkLoad(f, UniformPoints(c.slice_points, c.seed + 7000 + f, f)), "bulk load");
  }
  const uint32_t mid = c.slice_frames / 2;
  struct Kind {
    std::string name;
    int span;  // 0: orthogonal to t
  };
  std::vector<Kind> kinds = {{"t", 0}};
  for (int s : c.slice_spans) {
    if (static_cast<uint32_t>(s) + 2 > c.slice_frames) {
      Log("7 slices: span %d skipped: only %u frames", s, c.slice_frames);
      continue;
    }
    kinds.push_back({"span" + std::to_string(s), s});
  }
  Curve warm_c{"slices_warm", kExp, "Hyperslices at each level of detail, warm",
               "level of detail (0 = full resolution)", "median query time (ms)", false, true, {}};
  Curve cold_c{"slices_cold", kExp, "Hyperslices at each level of detail, cold",
               "level of detail (0 = full resolution)", "median query time (ms)", false, true, {}};
  for (const Kind& k : kinds) {
    Slice s;
    if (k.span == 0) {
      s.normal = {0, 0, 0, 1};
      s.offset = mid / c.fps;
      s.thickness = 0.25 / c.fps;
    } else {
      const double a = k.span / c.fps;
      s.normal = {a, 0, 0, 1};
      s.offset = (mid + k.span / 2.0) / c.fps;
      s.thickness = 0.5 / c.fps;
      s.max_frames = static_cast<uint32_t>(k.span) + 4;
      s.on_too_many_frames = Slice::FrameBound::kClip;
    }
    Series sw{k.span == 0 ? "orthogonal to t (1 frame)" : "tilted, " + std::to_string(k.span) + " frames",
              {}, {}, "line"};
    Series sc = sw;
    for (int lod = 0; lod <= c.lod_levels; ++lod) {
      QueryOptions qo;
      qo.lod = lod;
      db.Reopen(false);
      QueryRun first = RunQuery(*db.ds, s, qo);
      std::vector<double> warm, cold;
      for (int r = 0; r < c.warm_reps; ++r) warm.push_back(RunQuery(*db.ds, s, qo).ms);
      double resident = 0;
      std::vector<double> blocks;
      for (int r = 0; r < c.cold_reps; ++r) {
        db.Reopen(true);
        resident = std::max(resident, db.last_resident);
        const uint64_t b0 = db.BlocksRead();
        cold.push_back(RunQuery(*db.ds, s, qo).ms);
        blocks.push_back(static_cast<double>(db.BlocksRead() - b0));
      }
      const uint64_t bytes = first.points * kPointRecordSize;
      nlohmann::json p = {{"span_frames", k.span},
                          {"frames_read", first.frames},
                          {"level", lod},
                          {"temporal_lod", true},
                          {"points_per_frame", c.slice_points},
                          {"result_points", first.points},
                          {"result_bytes", bytes}};
      const std::string f = "slice." + k.name + ".l" + std::to_string(lod);
      R.Add(f + ".warm", kExp, "ms", warm, p, "hyperslice query, warm");
      R.AttachLimit(f + ".warm", limits, bytes, false);
      p["page_cache_resident_after_evict"] = resident;
      p["blocks_read_median"] = Median(blocks);
      R.Add(f + ".cold", kExp, "ms", cold, p, "hyperslice query, cold");
      R.AttachLimit(f + ".cold", limits, bytes, true);
      sw.x.push_back(lod);
      sw.y.push_back(Median(warm));
      sc.x.push_back(lod);
      sc.y.push_back(Median(cold));
      Log("7 slices: %s level %d: %u frames, %" PRIu64 " points, warm %.2f ms, cold %.2f ms",
          k.name.c_str(), lod, first.frames, first.points, Median(warm), Median(cold));
    }
    warm_c.series.push_back(sw);
    cold_c.series.push_back(sc);
  }
  db.Close();
  RemoveAll(dir);
  R.AddCurve(warm_c);
  R.AddCurve(cold_c);
}

}  // namespace hvdb::bench
