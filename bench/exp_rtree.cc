// 4. Thesis Table 8.1, against the R*-tree (libspatialindex, disk storage manager, 64 KiB
// pages): insertion time per frame, full-frame query time and size on disk, for hvdb (one
// Bkd-tree per frame, bulk loaded) and for the R*-tree both as one 4D tree over (x, y, z, t)
// grown by insertion and as one 3D tree per frame bulk loaded with STR.
// Plus the bulk-load comparison of one lod_points frame: hvdb vs R*-tree STR vs PCL outofcore.
#include <cinttypes>

#include "bench/bench.h"
#include "bench/peer_pcl.h"
#include "bench/peer_rtree.h"

namespace hvdb::bench {

namespace {

const char* kExp = "4-rtree";

std::vector<Point> FramePoints(const Config& c, int cfg, uint32_t frame, size_t n) {
  return UniformPoints(n, c.seed + 1000 * static_cast<uint64_t>(cfg + 1) + frame, frame);
}

void EvictFiles(const std::vector<std::string>& files) {
  for (const std::string& f : files) Evict(f);
}

uint64_t DiskBytesOf(const std::vector<std::string>& files) {
  uint64_t b = 0;
  for (const std::string& f : files) b += DiskBytes(f);
  return b;
}

struct Side {
  std::string name;  // hvdb, rtree3d, rtree4d
  std::vector<double> insert_ms, warm_ms, cold_ms;
  uint64_t disk_bytes = 0, frames = 0, result_points = 0;
};

void Emit(Report& R, const std::string& tag, const Side& s, const nlohmann::json& base,
          size_t points, Limits& limits, uint64_t stored_points) {
  const std::string f = "t81." + tag + "." + s.name;
  nlohmann::json p = base;
  p["frames_inserted"] = s.frames;
  R.Add(f + ".insert", kExp, "ms", s.insert_ms, p, "insert one frame, durable (one sample per frame)");
  p["result_points"] = s.result_points;
  const uint64_t bytes = s.result_points * kPointRecordSize;
  R.Add(f + ".query.warm", kExp, "ms", s.warm_ms, p, "query one full frame, warm");
  R.AttachLimit(f + ".query.warm", limits, bytes, false);
  R.Add(f + ".query.cold", kExp, "ms", s.cold_ms, p, "query one full frame, cold");
  R.AttachLimit(f + ".query.cold", limits, bytes, true);
  Figure& sz = R.Add(f + ".size", kExp, "MB", {static_cast<double>(s.disk_bytes) / 1e6}, p,
                     "size on disk of every file (allocated blocks)");
  (void)sz;
  (void)points;
  p["points_stored"] = stored_points;
  const double raw = static_cast<double>(stored_points * kPointRecordSize);
  Figure& x = R.Add(f + ".size.x_raw", kExp, "ratio", {}, p, "size on disk / raw point bytes");
  const double v = static_cast<double>(s.disk_bytes) / raw;
  x.fixed = Figure::Stats{v, v, v, 1};
}

void RunTable81(Ctx& ctx, const std::string& tag, int cfg, uint32_t frames, size_t points) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  const std::string dir = c.scratch + "/t81_" + tag;
  RemoveAll(dir);
  MakeDirs(dir);
  const nlohmann::json base = {{"frames", frames}, {"points_per_frame", points},
                               {"page_bytes", 65536}};
  Log("4 table 8.1 (%s): %u frames of %zu points", tag.c_str(), frames, points);

  // hvdb
  Side h{"hvdb", {}, {}, {}, 0, frames, 0};
  {
    Db db = Db::Create(dir + "/hvdb", "t81", c.DbOptions(), c.fps);
    for (uint32_t f = 0; f < frames; ++f) {
      std::vector<Point> pts = FramePoints(c, cfg, f, points);
      Timer t;
      Check(db.ds->BulkLoad(f, std::move(pts)), "bulk load");
      h.insert_ms.push_back(t.Ms());
    }
    db.Reopen(false);
    h.disk_bytes = DiskBytes(db.DatasetDir());
    h.result_points = RunQuery(*db.ds, FrameWindow(0, c.fps), {}).points;
    for (int r = 0; r < c.warm_reps; ++r) h.warm_ms.push_back(RunQuery(*db.ds, FrameWindow(0, c.fps), {}).ms);
    for (int r = 0; r < c.cold_reps; ++r) {
      db.Reopen(true);
      h.cold_ms.push_back(RunQuery(*db.ds, FrameWindow((static_cast<uint32_t>(r) * 7) % frames, c.fps), {}).ms);
    }
    db.Close();
    RemoveAll(dir + "/hvdb");
  }
  Log("4 table 8.1 (%s): hvdb insert %.1f ms/frame, query warm %.1f cold %.1f ms", tag.c_str(),
      Median(h.insert_ms), Median(h.warm_ms), Median(h.cold_ms));

  RTreePeer::Params rp;
  rp.buffer_pages = static_cast<uint32_t>(c.cache_mib * 1024 / 64);  // the same memory as hvdb's pool
  rp.fps = c.fps;
  const double big = 1e9;

  // R*-tree, one 3D tree per frame, bulk loaded (STR).
  Side r3{"rtree3d", {}, {}, {}, 0, frames, 0};
  {
    rp.dim = 3;
    std::vector<std::unique_ptr<RTreePeer>> trees;
    std::vector<std::string> files;
    MakeDirs(dir + "/r3");
    for (uint32_t f = 0; f < frames; ++f) {
      std::vector<Point> pts = FramePoints(c, cfg, f, points);
      char name[32];
      std::snprintf(name, sizeof(name), "/r3/%05u", f);
      Timer t;
      auto tree = RTreePeer::BulkLoad(dir + name, rp, pts);
      tree->Sync();
      r3.insert_ms.push_back(t.Ms());
      tree->Close();
      for (const std::string& fl : tree->Files()) files.push_back(fl);
      trees.push_back(std::move(tree));
    }
    r3.disk_bytes = DiskBytesOf(files);
    const double lo[3] = {-big, -big, -big}, hi[3] = {big, big, big};
    std::vector<Point> out;
    trees[0]->Reopen();
    r3.result_points = trees[0]->Query(lo, hi, &out);
    for (int r = 0; r < c.warm_reps; ++r) {
      out.clear();
      Timer t;
      trees[0]->Query(lo, hi, &out);
      r3.warm_ms.push_back(t.Ms());
    }
    trees[0]->Close();
    for (int r = 0; r < c.cold_reps; ++r) {
      RTreePeer& tr = *trees[(static_cast<size_t>(r) * 7) % frames];
      EvictFiles(tr.Files());
      tr.Reopen();
      EvictFiles(tr.Files());
      out.clear();
      Timer t;
      tr.Query(lo, hi, &out);
      r3.cold_ms.push_back(t.Ms());
      tr.Close();
    }
    trees.clear();
    RemoveAll(dir + "/r3");
  }
  Log("4 table 8.1 (%s): R*-tree 3D insert %.1f ms/frame, query warm %.1f cold %.1f ms",
      tag.c_str(), Median(r3.insert_ms), Median(r3.warm_ms), Median(r3.cold_ms));

  // R*-tree, one 4D tree grown one point at a time, synced after each frame; at most
  // rt4d_max_points points (see Config).
  const size_t budget = c.rt4d_max_points ? c.rt4d_max_points : SIZE_MAX;
  Side r4{"rtree4d", {}, {}, {}, 0, 0, 0};
  size_t inserted4 = 0, projected4 = 0;
  uint32_t frames4 = 0;
  {
    rp.dim = 4;
    MakeDirs(dir + "/r4");
    auto tree = RTreePeer::Create(dir + "/r4/tree", rp);
    for (uint32_t f = 0; f < frames && inserted4 < budget; ++f) {
      std::vector<Point> pts = FramePoints(c, cfg, f, points);
      const size_t n = std::min(points, budget - inserted4);
      Timer t;
      tree->Insert(std::span<const Point>(pts.data(), n));
      tree->Sync();
      double ms = t.Ms();
      if (n < points) {
        ms *= static_cast<double>(points) / static_cast<double>(n);
        ++projected4;
      }
      r4.insert_ms.push_back(ms);
      inserted4 += n;
      frames4 = f + 1;
      Log("4 table 8.1 (%s): R*-tree 4D: frame %u: %zu points in %.0f ms%s", tag.c_str(), f, n,
          t.Ms(), n < points ? " (frame cut short)" : "");
    }
    tree->Close();
    r4.disk_bytes = DiskBytesOf(tree->Files());
    auto lo_hi = [&](uint32_t f, double* lo, double* hi) {
      for (int a = 0; a < 3; ++a) {
        lo[a] = -big;
        hi[a] = big;
      }
      lo[3] = (f - 0.25) / c.fps;
      hi[3] = (f + 0.25) / c.fps;
    };
    double lo[4], hi[4];
    std::vector<Point> out;
    tree->Reopen();
    lo_hi(0, lo, hi);
    r4.result_points = tree->Query(lo, hi, &out);
    for (int r = 0; r < c.warm_reps; ++r) {
      out.clear();
      Timer t;
      tree->Query(lo, hi, &out);
      r4.warm_ms.push_back(t.Ms());
    }
    for (int r = 0; r < c.cold_reps; ++r) {
      tree->Close();
      EvictFiles(tree->Files());
      tree->Reopen();
      EvictFiles(tree->Files());
      // Rotate over the complete frames (frame 0 when even that one was cut short).
      const auto complete = static_cast<uint32_t>(std::max<size_t>(1, inserted4 / points));
      lo_hi((static_cast<uint32_t>(r) * 7) % complete, lo, hi);
      out.clear();
      Timer t;
      tree->Query(lo, hi, &out);
      r4.cold_ms.push_back(t.Ms());
    }
    tree.reset();
    RemoveAll(dir + "/r4");
  }
  Log("4 table 8.1 (%s): R*-tree 4D insert %.1f ms/frame, query warm %.1f cold %.1f ms",
      tag.c_str(), Median(r4.insert_ms), Median(r4.warm_ms), Median(r4.cold_ms));
  RemoveAll(dir);

  Limits& limits = *ctx.limits;
  const std::string p4 = "t81." + tag + ".rtree4d.";
  r4.frames = frames4;
  // The size per point of a cut-short 4D tree: its bytes over the points it holds.
  const uint64_t r4_points = inserted4;
  for (const Side* s : {&h, &r3, &r4}) {
    Emit(R, tag, *s, base, points, limits, s == &r4 ? r4_points : s->frames * points);
  }
  {
    Figure& f4 = R.Get(p4 + "insert");
    f4.params["points_inserted"] = inserted4;
    f4.params["frames_projected_from_a_prefix"] = projected4;
    f4.params["note"] = "the 4D tree got the frames in order up to rt4d_max_points points; a "
                        "frame cut short is timed on its prefix and scaled to the whole frame";
  }
  const std::string p = "t81." + tag + ".";
  for (const char* peer : {"rtree3d", "rtree4d"}) {
    const std::string q = p + peer;
    R.Ratio(q + ".insert.x_hvdb", kExp, q + ".insert", p + "hvdb.insert",
            std::string(peer) + " insertion per frame / hvdb's (speed-up of hvdb)");
    R.Ratio(q + ".query.warm.x_hvdb", kExp, q + ".query.warm", p + "hvdb.query.warm",
            std::string(peer) + " full-frame query / hvdb's, warm");
    R.Ratio(q + ".query.cold.x_hvdb", kExp, q + ".query.cold", p + "hvdb.query.cold",
            std::string(peer) + " full-frame query / hvdb's, cold");
    R.Ratio(q + ".size.x_hvdb", kExp, q + ".size.x_raw", p + "hvdb.size.x_raw",
            std::string(peer) + " size on disk / hvdb's (per point)");
  }
  R.AddTarget(p + "hvdb.size.x_raw", "<=", 1.1, "issue 7 goal",
              "size on disk within 1.1x of the raw point bytes");
  if (tag == "small") {
    R.AddTarget(p + "hvdb.insert", "<=", 7000, "thesis 2008, Table 8.1",
                "7 s to insert a 200k-point frame");
  }
}

void RunBulk(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  const std::string E = "4-bulk";
  const std::string dir = c.scratch + "/bulk";
  RemoveAll(dir);
  MakeDirs(dir);
  Log("4 bulk load: %zu points, hvdb vs R*-tree STR%s", c.lod_points, c.peers ? " vs PCL" : "");
  const std::vector<Point> pts = UniformPoints(c.lod_points, c.seed);  // experiment 1's frame
  const nlohmann::json p = {{"points", c.lod_points}, {"reps", c.bulk_reps}};
  std::vector<double> hv, rt, pc;
  {
    Db db = Db::Create(dir + "/hvdb", "bulk", c.DbOptions(), c.fps);
    for (int r = 0; r < c.bulk_reps; ++r) {
      std::vector<Point> copy = pts;
      Timer t;
      Check(db.ds->BulkLoad(static_cast<uint32_t>(r), std::move(copy)), "bulk load");
      hv.push_back(t.Ms());
    }
    db.Close();
    RemoveAll(dir + "/hvdb");
  }
  R.Add("bulk.hvdb", E, "ms", hv, p, "hvdb BulkLoad of one frame (build, write, fsync)");
  R.Add("bulk.limit.write_fsync", E, "ms",
        WriteSyncMs(dir, c.lod_points * kPointRecordSize, c.limit_reps), p,
        "physical limit: write the frame's bytes to a new file and fdatasync");
  R.Ratio("bulk.hvdb.x_write_fsync", E, "bulk.hvdb", "bulk.limit.write_fsync",
          "hvdb bulk load / writing the same bytes durably");
  R.AddTarget("bulk.hvdb", "<=", 500, "issue 7 goal", "bulk load of a 1.5M-point frame in under 0.5 s");
  R.AddTarget("bulk.hvdb", "<=", 500, "issue 14 goal", "bulk load of a 1.5M-point frame in under 0.5 s");
  {
    RTreePeer::Params rp;
    rp.dim = 3;
    rp.buffer_pages = static_cast<uint32_t>(c.cache_mib * 1024 / 64);
    for (int r = 0; r < c.bulk_reps; ++r) {
      Timer t;
      auto tree = RTreePeer::BulkLoad(dir + "/rtree", rp, pts);
      tree->Sync();
      rt.push_back(t.Ms());
      tree.reset();
    }
  }
  R.Add("bulk.rtree_str", E, "ms", rt, p,
        "libspatialindex R*-tree STR bulk load, 64 KiB pages, flushed and fsynced");
  R.Ratio("bulk.rtree_str.x_hvdb", E, "bulk.rtree_str", "bulk.hvdb",
          "R*-tree STR bulk load / hvdb bulk load (speed-up of hvdb)");
  R.AddTarget("bulk.rtree_str.x_hvdb", ">=", 10, "issue 7 goal",
              "bulk load >= 10x faster than the R*-tree's bulk load");
  if (c.peers) {
    for (int r = 0; r < c.bulk_reps; ++r) {
      const std::string pd = dir + "/pcl";
      RemoveAll(pd);
      Timer t;
      auto oc = PclOctree::Build(pd, pts);
      SyncFiles(pd);
      pc.push_back(t.Ms());
      oc.reset();
      RemoveAll(pd);
    }
    R.Add("bulk.pcl", E, "ms", pc, p,
          "pcl::outofcore build with LOD (addPointCloud_and_genLOD), flushed and fsynced");
    R.Ratio("bulk.pcl.x_hvdb", E, "bulk.pcl", "bulk.hvdb",
            "PCL out-of-core build / hvdb bulk load (speed-up of hvdb)");
    R.AddTarget("bulk.pcl.x_hvdb", ">=", 10, "issue 7 goal",
                "bulk load >= 10x faster than PCL's out-of-core build");
    R.AddTarget("bulk.pcl.x_hvdb", ">=", 3, "issue 14 goal", "bulk load >= 3x faster than PCL's build");
  }
  RemoveAll(dir);
  Log("4 bulk load: hvdb %.0f ms, R*-tree STR %.0f ms, PCL %.0f ms", Median(hv), Median(rt),
      Median(pc));
}

}  // namespace

void RunRTree(Ctx& ctx) {
  const Config& c = ctx.cfg;
  RunBulk(ctx);
  RunTable81(ctx, "small", 0, c.rt_small_frames, c.rt_small_points);
  RunTable81(ctx, "large", 1, c.rt_large_frames, c.rt_large_points);

  Report& R = ctx.report;
  Curve ins{"table81_insert", kExp, "Table 8.1: insertion time per frame", "frame",
            "time to insert the frame (ms)", false, true, {}};
  for (const char* tag : {"small", "large"}) {
    for (const char* side : {"hvdb", "rtree3d", "rtree4d"}) {
      const Figure& f = R.Get(std::string("t81.") + tag + "." + side + ".insert");
      std::vector<double> x;
      for (size_t i = 0; i < f.samples.size(); ++i) x.push_back(static_cast<double>(i));
      std::string label = std::string(side) + " (" + tag + " frames)";
      if (f.params.value("frames_projected_from_a_prefix", 0) > 0) {
        label += ", last frame projected from " +
                 std::to_string(f.params.value("points_inserted", 0)) + " points";
      }
      ins.series.push_back({label, x, f.samples, std::string(tag) == "small" ? "line" : "points"});
    }
  }
  R.AddCurve(ins);
}

}  // namespace hvdb::bench
