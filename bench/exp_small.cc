// 9. Small frames on disk (issue 35): many frames of few points, bulk loaded, and the space
// their files take on the device (allocated blocks, st_blocks * 512, as `du` counts), against
// the bytes of their points: a frame's fixed cost is what it takes beyond its points.
#include <sys/stat.h>

#include <filesystem>

#include "bench/bench.h"

namespace hvdb::bench {

namespace {

const char* kExp = "9-small-frames";

// Allocated bytes of every file under `dir` (and of the tree files alone).
void AllocatedBytes(const std::string& dir, uint64_t* all, uint64_t* trees, uint64_t* files) {
  *all = *trees = *files = 0;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    struct stat st;
    if (::lstat(e.path().c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    const auto bytes = static_cast<uint64_t>(st.st_blocks) * 512;
    *all += bytes;
    ++*files;
    if (e.path().extension() == ".kdt") *trees += bytes;
  }
}

}  // namespace

void RunSmallFrames(Ctx& ctx) {
  const Config& c = ctx.cfg;
  Report& R = ctx.report;
  const std::string dir = c.scratch + "/small";
  Log("9 small frames: %u frames of %zu points", c.small_frames, c.small_points);
  Db db = Db::Create(dir, "small", c.DbOptions(), c.fps);
  std::vector<double> ms;
  for (uint32_t f = 0; f < c.small_frames; ++f) {
    std::vector<Point> pts = UniformPoints(c.small_points, c.seed + 900 + f, f);
    Timer t;
    Check(db.ds->BulkLoad(f, std::move(pts)), "bulk load");
    ms.push_back(t.Ms());
  }
  db.Close();  // a clean close: the checkpoint has written every frame state
  uint64_t all = 0, trees = 0, files = 0;
  AllocatedBytes(db.DatasetDir(), &all, &trees, &files);
  const uint64_t points = uint64_t{c.small_frames} * c.small_points * kPointRecordSize;
  const nlohmann::json p = {{"frames", c.small_frames},
                            {"frame_points", c.small_points},
                            {"point_bytes", points},
                            {"allocated_bytes", all},
                            {"tree_allocated_bytes", trees},
                            {"files", files},
                            {"block_bytes", c.block_kib * 1024}};
  R.Add("small.bulkload", kExp, "ms", ms, p, "BulkLoad of one small frame (durable)");
  auto fixed = [&](const std::string& name, double v, const std::string& unit,
                   const std::string& what) {
    Figure& f = R.Add(name, kExp, unit, {}, p, what);
    f.fixed = Figure::Stats{v, v, v, 1};
  };
  const double frames = c.small_frames;
  fixed("small.allocated_per_frame", static_cast<double>(all) / frames / 1024, "KiB",
        "allocated bytes of the dataset's files per frame (st_blocks * 512, as du counts)");
  fixed("small.fixed_per_frame", (static_cast<double>(all) - static_cast<double>(points)) /
                                     frames / 1024,
        "KiB", "a frame's fixed cost on disk: allocated bytes beyond its points, per frame");
  fixed("small.x_points", static_cast<double>(all) / static_cast<double>(points), "ratio",
        "allocated bytes of the dataset / bytes of its points (64 per point)");
  R.AddTarget("small.fixed_per_frame", "<=", 64, "issue 35 goal",
              "a frame's fixed cost on disk within 64 KiB");
  R.AddTarget("small.x_points", "<=", 1.5, "issue 35 goal",
              "small frames take at most 1.5x their points on disk");
  Log("9 small frames: %.1f KiB allocated per frame, %.2fx the points", all / frames / 1024,
      static_cast<double>(all) / static_cast<double>(points));
  RemoveAll(dir);
}

}  // namespace hvdb::bench
