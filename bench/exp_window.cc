// 2. Thesis Figure 8.13, window queries: one frame of uniformly random points per size, windows
// that return ~win_result points, timed at full resolution and at the coarsest level, cold and
// warm. 5. The peers on the same points and the same windows: nanoflann's in-memory kd-tree
// (the upper bound without durability) and PCL's out-of-core octree (build, box query, and its
// level-of-detail query).
#include <algorithm>
#include <filesystem>
#include <cinttypes>
#include <cmath>

#include "bench/bench.h"
#include "bench/peer_kdtree.h"
#include "bench/peer_pcl.h"

namespace hvdb::bench {

namespace {

const char* kExp = "2-windows";
const char* kExpPeers = "5-peers";

struct Box {
  double lo[3], hi[3];
};

std::vector<Box> MakeWindows(size_t n, size_t want, int count, uint64_t seed) {
  const double side = std::min(1.0, std::cbrt(static_cast<double>(want) / static_cast<double>(n)));
  Rng rng(seed);
  std::vector<Box> out(static_cast<size_t>(count));
  for (Box& b : out) {
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = rng.Uniform() * (1 - side);
      b.hi[a] = b.lo[a] + side;
    }
  }
  return out;
}

Window ToWindow(const Box& b, uint32_t frame, double fps) {
  Window w;
  w.lo = {b.lo[0], b.lo[1], b.lo[2], (frame - 0.25) / fps};
  w.hi = {b.hi[0], b.hi[1], b.hi[2], (frame + 0.25) / fps};
  return w;
}

std::string N(size_t n) { return "win.n" + std::to_string(n); }

// The dataset's largest tree file (one frame, bulk loaded: its only one).
std::string TreeFileOf(const std::string& dataset_dir) {
  std::string best;
  uintmax_t size = 0;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dataset_dir + "/trees", ec)) {
    if (e.path().extension() == ".kdt" && e.file_size() > size) {
      size = e.file_size();
      best = e.path().string();
    }
  }
  return best;
}

// Median of counts as a double.
double MedianCount(const std::vector<uint64_t>& v) {
  std::vector<double> d(v.begin(), v.end());
  return Median(d);
}

}  // namespace

void RunWindows(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  Limits& limits = *ctx.limits;
  std::vector<size_t> sizes;
  for (size_t n = c.win_min; n <= c.win_max; n += c.win_step) sizes.push_back(n);
  if (sizes.empty()) return;
  const int L = c.lod_levels;
  const std::string dir = c.scratch + "/win";
  Log("2 windows: %zu frame sizes %zu..%zu, %zu-point windows", sizes.size(), sizes.front(),
      sizes.back(), c.win_result);

  Db db = Db::Create(dir, "win", c.DbOptions(), c.fps);
  std::vector<double> xs, bulk_ms;
  for (size_t i = 0; i < sizes.size(); ++i) {
    std::vector<Point> pts = UniformPoints(sizes[i], c.seed + 100 + i);
    Timer t;
    Check(db.ds->BulkLoad(static_cast<uint32_t>(i), std::move(pts)), "bulk load");
    bulk_ms.push_back(t.Ms());
    xs.push_back(static_cast<double>(sizes[i]));
  }

  // Medians per size, for the curves.
  std::vector<double> h0w, hLw, h0c, hLc, nano, nano_build, pcl_x, pclw, pclc, pcllw, pcllc,
      pcl_build;
  size_t pcl_max = 0;
  for (size_t i = 0; i < sizes.size(); ++i) {
    const size_t n = sizes[i];
    const auto frame = static_cast<uint32_t>(i);
    const std::vector<Box> boxes = MakeWindows(n, c.win_result, c.win_queries, c.seed + 200 + i);
    nlohmann::json base = {{"frame_points", n},
                           {"window_points_wanted", c.win_result},
                           {"windows", c.win_queries}};
    R.Add(N(n) + ".hvdb.bulkload", kExp, "ms", {bulk_ms[i]}, base, "BulkLoad of the frame");

    // hvdb, warm: one untimed pass over every window, then each window timed once.
    std::vector<uint64_t> counts0, countsL;
    for (int lod : {0, L}) {
      QueryOptions qo;
      qo.lod = lod;
      db.Reopen(false);
      for (const Box& b : boxes) RunQuery(*db.ds, ToWindow(b, frame, c.fps), qo);
      std::vector<double> ms;
      for (const Box& b : boxes) {
        QueryRun q = RunQuery(*db.ds, ToWindow(b, frame, c.fps), qo);
        ms.push_back(q.ms);
        (lod == 0 ? counts0 : countsL).push_back(q.points);
      }
      nlohmann::json p = base;
      p["level"] = lod;
      p["result_points_median"] = MedianCount(lod == 0 ? counts0 : countsL);
      const auto bytes = static_cast<uint64_t>(p["result_points_median"].get<double>()) *
                         kPointRecordSize;
      p["result_bytes"] = bytes;
      std::string name = N(n) + ".hvdb.l" + std::to_string(lod) + ".warm";
      R.Add(name, kExp, "ms", ms, p, "window query, warm (one sample per window)");
      R.AttachLimit(name, limits, bytes, false);
      (lod == 0 ? h0w : hLw).push_back(Median(ms));
    }
    // hvdb, cold: every window on a database reopened with its files evicted.
    for (int lod : {0, L}) {
      QueryOptions qo;
      qo.lod = lod;
      std::vector<double> ms, blocks, faults, device_bytes;
      std::vector<uint64_t> counts;
      double resident = 0;
      for (int j = 0; j < c.win_cold && j < c.win_queries; ++j) {
        db.Reopen(true);
        resident = std::max(resident, db.last_resident);
        const uint64_t b0 = db.BlocksRead();
        const ProcCounters p0 = ReadProcCounters();
        QueryRun q = RunQuery(*db.ds, ToWindow(boxes[static_cast<size_t>(j)], frame, c.fps), qo);
        const ProcCounters p1 = ReadProcCounters();
        blocks.push_back(static_cast<double>(db.BlocksRead() - b0));
        faults.push_back(static_cast<double>(p1.minor_faults - p0.minor_faults));
        device_bytes.push_back(static_cast<double>(p1.read_bytes - p0.read_bytes));
        ms.push_back(q.ms);
        counts.push_back(q.points);
      }
      nlohmann::json p = base;
      p["level"] = lod;
      p["windows"] = ms.size();
      p["result_points_median"] = MedianCount(counts);
      const auto bytes = static_cast<uint64_t>(MedianCount(counts)) * kPointRecordSize;
      p["result_bytes"] = bytes;
      p["page_cache_resident_after_evict"] = resident;
      p["blocks_read_median"] = Median(blocks);
      p["page_faults_median"] = Median(faults);
      p["device_read_bytes_median"] = Median(device_bytes);
      p["block_bytes"] = c.block_kib * 1024;
      std::string name = N(n) + ".hvdb.l" + std::to_string(lod) + ".cold";
      R.Add(name, kExp, "ms", ms, p, "window query, cold (evicted files, new buffer pool)");
      R.AttachLimit(name, limits, bytes, true);
      // The device's own limit for that many scattered blocks, all in flight at once (the
      // sequential limit above reads the result's bytes in one run, which a window cannot).
      const std::string tree = TreeFileOf(db.DatasetDir());
      if (!tree.empty()) {
        std::vector<double> lim = RandomBlocksMs(
            tree, static_cast<size_t>(Median(blocks)), c.block_kib * 1024, c.win_cold,
            c.seed + 77);
        const std::string ln = N(n) + ".limit.blocks.l" + std::to_string(lod) + ".cold";
        R.Add(ln, kExp, "ms", lim, {{"blocks", Median(blocks)}, {"block_bytes", c.block_kib * 1024}},
              "as many random blocks of the tree file as the cold window read, evicted, all "
              "submitted at once with io_uring");
        R.Ratio(name + ".x_blocks", kExp, name, ln,
                "cold window / reading its number of blocks at the device's queue depth");
      }
      (lod == 0 ? h0c : hLc).push_back(Median(ms));
    }

    Log("2 windows: n=%zu: hvdb warm %.3f / %.3f ms, cold %.3f / %.3f ms (full / coarsest)", n,
        h0w.back(), hLw.back(), h0c.back(), hLc.back());
    if (!c.peers) continue;
    const std::vector<Point> pts = UniformPoints(n, c.seed + 100 + i, frame);
    // nanoflann: build, then the same windows (in memory: warm only).
    {
      Timer t;
      KdTreePeer kd(pts);
      double build = t.Ms();
      std::vector<Point> out;
      for (const Box& b : boxes) {
        out.clear();
        kd.Box(b.lo, b.hi, &out);
      }
      std::vector<double> ms;
      bool match = true;
      for (size_t j = 0; j < boxes.size(); ++j) {
        out.clear();
        Timer q;
        uint64_t got = kd.Box(boxes[j].lo, boxes[j].hi, &out);
        ms.push_back(q.Ms());
        match = match && got == counts0[j];
      }
      if (!match) Die("nanoflann and hvdb disagree on a window's points");
      nlohmann::json p = base;
      p["leaf_max_size"] = 16;
      p["results_match_hvdb"] = match;
      R.Add(N(n) + ".nanoflann", kExpPeers, "ms", ms, p,
            "nanoflann in-memory kd-tree, same windows, points copied out");
      R.Add(N(n) + ".nanoflann.build", kExpPeers, "ms", {build}, base, "nanoflann index build");
      nano.push_back(Median(ms));
      nano_build.push_back(build);
    }
    // PCL's out-of-core octree on the selected sizes.
    if (std::find(c.pcl_sizes.begin(), c.pcl_sizes.end(), n) != c.pcl_sizes.end()) {
      const std::string pdir = c.scratch + "/pcl_n" + std::to_string(n);
      RemoveAll(pdir);
      Timer t;
      auto oc = PclOctree::Build(pdir, pts);
      SyncFiles(pdir);
      double build = t.Ms();
      oc->Reopen();
      const uint64_t lod_depth = oc->depth() >= 2 ? oc->depth() - 2 : 0;
      nlohmann::json p = base;
      p["depth"] = oc->depth();
      p["lod_depth"] = lod_depth;
      p["point_type"] = "pcl::PointXYZRGBNormal";
      p["disk_bytes"] = DiskBytes(pdir);
      p["files"] = FilesUnder(pdir).size();
      R.Add(N(n) + ".pcl.build", kExpPeers, "ms", {build}, p,
            "pcl::outofcore build with LOD (addPointCloud_and_genLOD), flush and fsync");
      for (int lodq = 0; lodq < 2; ++lodq) {
        const uint64_t depth = lodq ? lod_depth : oc->depth();
        auto run = [&](const Box& b) {
          return lodq ? oc->BoxAtDepth(b.lo, b.hi, depth) : oc->Box(b.lo, b.hi);
        };
        for (const Box& b : boxes) run(b);
        std::vector<double> warm;
        std::vector<uint64_t> counts;
        for (const Box& b : boxes) {
          Timer q;
          counts.push_back(run(b));
          warm.push_back(q.Ms());
        }
        std::vector<double> cold;
        for (int j = 0; j < c.win_cold && j < c.win_queries; ++j) {
          oc->Reopen();
          Evict(pdir);
          Timer q;
          run(boxes[static_cast<size_t>(j)]);
          cold.push_back(q.Ms());
        }
        nlohmann::json pq = p;
        pq["query_depth"] = depth;
        pq["result_points_median"] = MedianCount(counts);
        if (!lodq) pq["results_match_hvdb"] = counts == counts0;
        const std::string name = N(n) + (lodq ? ".pcl_lod" : ".pcl");
        R.Add(name + ".warm", kExpPeers, "ms", warm, pq,
              lodq ? "pcl::outofcore level-of-detail box query (coarser depth), warm"
                   : "pcl::outofcore box query at full depth, warm");
        pq["windows"] = cold.size();
        R.Add(name + ".cold", kExpPeers, "ms", cold, pq,
              lodq ? "pcl::outofcore level-of-detail box query, cold (reopened, evicted)"
                   : "pcl::outofcore box query at full depth, cold (reopened, evicted)");
        (lodq ? pcllw : pclw).push_back(Median(warm));
        (lodq ? pcllc : pclc).push_back(Median(cold));
      }
      oc.reset();
      RemoveAll(pdir);
      pcl_x.push_back(static_cast<double>(n));
      pcl_build.push_back(build);
      pcl_max = n;
    }
    Log("2 windows: n=%zu: nanoflann %.3f ms%s", n, nano.back(),
        pcl_x.empty() || pcl_x.back() != static_cast<double>(n)
            ? ""
            : (", PCL warm " + std::to_string(pclw.back()) + " ms, cold " +
               std::to_string(pclc.back()) + " ms").c_str());
  }
  db.Close();
  RemoveAll(dir);

  // Targets and ratios at the largest frame.
  const size_t nmax = sizes.back();
  const std::string top = N(nmax) + ".hvdb";
  R.AddTarget(top + ".l0.warm", "<=", 0.3, "issue 7 goal",
              "10k-point window on a 2M-point frame, warm, <= 0.3 ms");
  R.AddTarget(top + ".l0.cold", "<=", 2, "issue 7 goal",
              "10k-point window on a 2M-point frame, cold, <= 2 ms");
  R.AddTarget(top + ".l0.cold", "<=", 2, "issue 14 goal", "10k-point window on a 2M frame, cold");
  R.AddTarget(top + ".l0.warm", "<=", 0.3, "issue 14 goal", "10k-point window on a 2M frame, warm");
  R.AddTarget(top + ".l" + std::to_string(L) + ".cold", "<=", 100, "thesis 2008, Figure 8.13",
              "coarse 10k window under 100 ms");
  R.AddTarget(top + ".l0.cold", "<=", 100, "thesis 2008, Figure 8.13",
              "10k window under 100 ms (the thesis's full-resolution curve stays below it)");
  if (c.peers) {
    R.Ratio(top + ".l0.warm.x_nanoflann", kExpPeers, top + ".l0.warm", N(nmax) + ".nanoflann",
            "hvdb warm window / nanoflann in-memory window (the price of durability and paging)");
    R.Ratio(N(nmax) + ".hvdb.bulkload.x_nanoflann_build", kExpPeers, top + ".bulkload",
            N(nmax) + ".nanoflann.build",
            "hvdb bulk load (durable) / nanoflann in-memory build");
    if (pcl_max != 0) {
      const std::string hp = N(pcl_max) + ".hvdb", pp = N(pcl_max) + ".pcl";
      R.Ratio(pp + ".warm.x_hvdb", kExpPeers, pp + ".warm", hp + ".l0.warm",
              "PCL out-of-core box query / hvdb window, warm (speed-up of hvdb)");
      R.Ratio(pp + ".cold.x_hvdb", kExpPeers, pp + ".cold", hp + ".l0.cold",
              "PCL out-of-core box query / hvdb window, cold");
      R.AddTarget(pp + ".cold.x_hvdb", ">=", 1, "issue 14 goal",
                  "a cold window faster than PCL's out-of-core box query");
      R.Ratio(N(pcl_max) + ".pcl_lod.warm.x_hvdb", kExpPeers, N(pcl_max) + ".pcl_lod.warm",
              hp + ".l" + std::to_string(L) + ".warm",
              "PCL level-of-detail query / hvdb coarsest level, warm");
      R.Ratio(N(pcl_max) + ".pcl_lod.cold.x_hvdb", kExpPeers, N(pcl_max) + ".pcl_lod.cold",
              hp + ".l" + std::to_string(L) + ".cold",
              "PCL level-of-detail query / hvdb coarsest level, cold");
      R.Ratio(pp + ".build.x_hvdb", kExpPeers, pp + ".build", hp + ".bulkload",
              "PCL out-of-core build / hvdb bulk load");
    }
  }

  Curve warm{"windows_warm", kExp,
             "Figure 8.13: " + std::to_string(c.win_result) + "-point windows, warm",
             "points in the frame", "median query time (ms)", false, true, {}};
  warm.series.push_back({"hvdb full resolution", xs, h0w, "line"});
  warm.series.push_back({"hvdb coarsest level", xs, hLw, "line"});
  if (!nano.empty()) warm.series.push_back({"nanoflann (in memory)", xs, nano, "line"});
  if (!pcl_x.empty()) {
    warm.series.push_back({"PCL outofcore", pcl_x, pclw, "points"});
    warm.series.push_back({"PCL outofcore LOD", pcl_x, pcllw, "points"});
  }
  R.AddCurve(warm);
  Curve cold{"windows_cold", kExp,
             "Figure 8.13: " + std::to_string(c.win_result) + "-point windows, cold",
             "points in the frame", "median query time (ms)", false, true, {}};
  cold.series.push_back({"hvdb full resolution", xs, h0c, "line"});
  cold.series.push_back({"hvdb coarsest level", xs, hLc, "line"});
  if (!pcl_x.empty()) {
    cold.series.push_back({"PCL outofcore", pcl_x, pclc, "points"});
    cold.series.push_back({"PCL outofcore LOD", pcl_x, pcllc, "points"});
  }
  cold.series.push_back({"thesis 2008 bound (coarse)", {xs.front(), xs.back()}, {100, 100}, "dashed"});
  R.AddCurve(cold);
  Curve build{"windows_build", kExp, "Building the index of one frame", "points in the frame",
              "build time (ms)", false, true, {}};
  build.series.push_back({"hvdb bulk load (durable)", xs, bulk_ms, "line"});
  if (!nano_build.empty()) build.series.push_back({"nanoflann (in memory)", xs, nano_build, "line"});
  if (!pcl_x.empty()) build.series.push_back({"PCL outofcore (with LOD)", pcl_x, pcl_build, "points"});
  R.AddCurve(build);
}

}  // namespace hvdb::bench
