// The data commands of `hvdb`: datasets, create, describe, import, export, window and slice.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/splat_files.h"
#include "client/cli/common.h"
#include "client/export.h"
#include "codec/codec.h"
#include "formats/ply.h"
#include "formats/point_files.h"

namespace hvdb::cli {
namespace {

namespace fs = std::filesystem;

struct CreateArgs {
  std::string name;
  double fps = 0;
  double scale = 1.0;
  uint32_t frames = 0;
  bool gaussians = false;
};

struct ImportArgs {
  std::string name;
  uint32_t frame = 0;
  std::vector<std::string> files;
  double units_scale = 1.0;
  std::vector<double> rotate;  // splat files: Euler degrees about x, y, z
  double sigma = 0.005;
  bool keep_ids = false;
  bool skip_invalid = false;
  bool json = false;
};

struct ExportArgs {
  std::string name, dir;
  std::string codec = "hvdb7";
  int qp = 16, qc = 8, qn = 12;
  bool temporal = false;
  int spz_version = 3;
  uint32_t first = 0, count = 0;
};

struct QueryArgs {
  std::string name;
  int lod = 0;
  bool progressive = false;
  uint32_t label_mask = 0;
  std::string out;
  std::string codec = "raw";
  int qp = 16;
  bool ascii = false;
  bool json = false;
};

struct WindowArgs {
  QueryArgs q;
  std::vector<double> box;
};

struct SliceArgs {
  QueryArgs q;
  std::vector<double> normal;
  double offset = 0;
  double thickness = 0;
  bool clip_frames = false;
  uint32_t max_frames = 0;
  std::vector<double> clip_box;
};

// What CLI11 fills in for these subcommands: static, so that registering them allocates
// nothing but what CLI11 does (see Context in common.h).
struct DataArgs {
  NameArgs datasets, describe;
  CreateArgs create;
  ImportArgs imports;
  ExportArgs exports;
  WindowArgs window;
  SliceArgs slice;
} data_args;

int CmdDatasets(Context& ctx, const NameArgs& a) {
  Result<std::vector<std::string>> names = ctx.db().ListDatasets();
  if (!names.ok()) return Fail(names.status());
  json list = json::array();
  if (!a.json && !names->empty()) {
    std::printf("%-24s %10s %14s %10s\n", "name", "frames", "points", "fps");
  }
  for (const std::string& name : *names) {
    Result<DatasetInfo> got = ctx.db().Describe(name);
    if (!got.ok()) return Fail(got.status());
    const DatasetInfo& info = *got;
    if (a.json) {
      list.push_back({{"name", name},
                      {"frames", info.frame_count},
                      {"points", info.point_count},
                      {"fps", info.fps}});
    } else {
      std::printf("%-24s %10u %14llu %10g\n", name.c_str(), info.frame_count,
                  static_cast<unsigned long long>(info.point_count), info.fps);
    }
  }
  if (a.json) PrintJson(list);
  return kExitOk;
}

int CmdCreate(Context& ctx, const CreateArgs& a) {
  DatasetInfo want;
  want.name = a.name;
  want.fps = a.fps;
  want.space_time_scale = a.scale;
  want.frame_count = a.frames;
  want.gaussians = a.gaussians;
  Result<DatasetInfo> info = ctx.db().CreateDataset(want);
  if (!info.ok()) return Fail(info.status());
  std::printf("created %sdataset '%s' (%g fps, space-time scale %g m/s)\n",
              info->gaussians ? "Gaussian-splat " : "", info->name.c_str(), info->fps,
              info->space_time_scale);
  return kExitOk;
}

int CmdDescribe(Context& ctx, const NameArgs& a) {
  Result<DatasetInfo> got = ctx.db().Describe(a.name);
  if (!got.ok()) return Fail(got.status());
  const DatasetInfo& info = *got;
  double duration = info.fps > 0 ? info.frame_count / info.fps : 0;
  // The bytes of each storage tier (docs/FORMAT.md, "Compressed tree file").
  Result<client::StatsReport> report = ctx.db().Stats(a.name);
  if (!report.ok()) return Fail(report.status());
  DatasetStats st;
  for (const auto& e : report->datasets) {
    if (e.name == a.name) st = e.stats;
  }
  const json tiers = {
      {"hot", {{"points", st.points - st.cold_points},
               {"tree_bytes", st.tree_bytes - st.cold_tree_bytes},
               // Points not yet in a tree: in the frame's buffer (and the log), 64 bytes each.
               {"buffered_points", st.buffered_points},
               {"buffer_bytes", st.buffered_points * kPointRecordSize}}},
      {"cold", {{"frames", st.cold_frames}, {"points", st.cold_points},
                {"tree_bytes", st.cold_tree_bytes}}},
      {"gaussians", {{"segments", st.gaussian_segments}, {"records", st.gaussian_records},
                     {"bytes", st.gaussian_bytes}}}};
  if (a.json) {
    json cams = json::array();
    for (const CameraInfo& c : info.cameras) {
      cams.push_back({{"id", c.id}, {"name", c.name}, {"width", c.width}, {"height", c.height}});
    }
    PrintJson({{"name", info.name},
               {"fps", info.fps},
               {"space_time_scale", info.space_time_scale},
               {"frames", info.frame_count},
               {"duration_s", duration},
               {"points", info.point_count},
               {"bounds_min", info.bounds_min},
               {"bounds_max", info.bounds_max},
               {"last_lsn", info.last_lsn},
               {"gaussians", info.gaussians},
               {"storage", tiers},
               {"cameras", cams}});
    return kExitOk;
  }
  std::printf("dataset   %s%s\n", info.name.c_str(),
              info.gaussians ? " (Gaussian splats)" : "");
  std::printf("fps       %g\n", info.fps);
  std::printf("scale     %g m/s (space-time)\n", info.space_time_scale);
  std::printf("frames    %u (%.3f s)\n", info.frame_count, duration);
  std::printf("points    %llu\n", static_cast<unsigned long long>(info.point_count));
  std::printf("bounds    x %.3f .. %.3f  y %.3f .. %.3f  z %.3f .. %.3f m\n", info.bounds_min[0],
              info.bounds_max[0], info.bounds_min[1], info.bounds_max[1], info.bounds_min[2],
              info.bounds_max[2]);
  std::printf("cameras   %zu\n", info.cameras.size());
  std::printf("last lsn  %llu\n", static_cast<unsigned long long>(info.last_lsn));
  std::printf("storage   hot %.1f MiB (%llu points, %llu of them buffered), cold %.1f MiB (%u "
              "frames, %llu points)\n",
              static_cast<double>(st.tree_bytes - st.cold_tree_bytes +
                                  st.buffered_points * kPointRecordSize) / (1 << 20),
              static_cast<unsigned long long>(st.points - st.cold_points),
              static_cast<unsigned long long>(st.buffered_points),
              static_cast<double>(st.cold_tree_bytes) / (1 << 20), st.cold_frames,
              static_cast<unsigned long long>(st.cold_points));
  if (info.gaussians) {
    std::printf("gaussians %.1f MiB (%llu records in %llu segments)\n",
                static_cast<double>(st.gaussian_bytes) / (1 << 20),
                static_cast<unsigned long long>(st.gaussian_records),
                static_cast<unsigned long long>(st.gaussian_segments));
  }
  return kExitOk;
}

// Scales positions and covariances by the import's units and puts the points in its frame.
void PlaceFrame(const formats::ReadOptions& ro, std::vector<Point>* pts) {
  for (Point& p : *pts) {
    p.x = static_cast<float>(p.x * ro.scale);
    p.y = static_cast<float>(p.y * ro.scale);
    p.z = static_cast<float>(p.z * ro.scale);
    for (float& c : p.cov) c = static_cast<float>(c * ro.scale * ro.scale);
    p.frame = ro.frame;
  }
}

// A frame from an hvdb7 stream (hvdb export), placed as a PLY file would be: scaled, at the
// import's frame, ids kept only on request (by the caller). *reference holds the stream's
// decoded points afterwards, for the next file if it was coded temporally.
Result<std::vector<Point>> ReadStreamFrame(const std::string& path, const formats::ReadOptions& ro,
                                           codec::Reference* reference) {
  Result<std::vector<Point>> pts =
      formats::ReadHvdb7File(path, reference->points.empty() ? nullptr : reference);
  if (!pts.ok()) return pts.status();
  reference->points = *pts;
  PlaceFrame(ro, &*pts);
  return pts;
}

// A frame from a Draco file (hvdb export --codec draco), placed as ReadStreamFrame does.
Result<std::vector<Point>> ReadDracoFrame(const std::string& path, const formats::ReadOptions& ro) {
  Result<std::vector<Point>> pts = formats::ReadDracoFile(path);
  if (!pts.ok()) return pts.status();
  PlaceFrame(ro, &*pts);
  // Draco files carry no covariances: the import's default.
  const float sigma2 = static_cast<float>(ro.default_sigma * ro.default_sigma);
  for (Point& p : *pts) p.cov = {sigma2, 0, 0, sigma2, 0, sigma2};
  return pts;
}

int CmdExport(Context& ctx, const ExportArgs& a) {
  client::ExportOptions o;
  if (a.codec == "3dgs" || a.codec == "spz" || a.codec == "splat" || a.codec == "glb") {
    o.splats = a.codec == "spz"     ? formats::GaussianFormat::kSpz
               : a.codec == "splat" ? formats::GaussianFormat::kSplat
               : a.codec == "glb"   ? formats::GaussianFormat::kGlb
                                    : formats::GaussianFormat::k3dgsPly;
    o.spz_version = a.spz_version;
  } else {
    Status st = formats::ParseFileCodec(a.codec, &o.codec);
    if (!st.ok()) return Usage("export", st.message());
  }
  if (a.temporal && (o.codec != formats::FileCodec::kHvdb7 ||
                     o.splats != formats::GaussianFormat::kUnknown)) {
    return Usage("export", "--temporal is for --codec hvdb7");
  }
  o.encode.qp = a.qp;
  o.encode.qc = a.qc;
  o.encode.qn = a.qn;
  o.encode.attributes = codec::kAllAttributes;
  o.encode.progressive = true;
  o.temporal = a.temporal;
  o.first = a.first;
  o.count = a.count;
  Clock::time_point start = Clock::now();
  std::unique_ptr<ProgressBar> bar;
  Result<std::vector<std::string>> files =
      client::ExportFrames(ctx.db(), a.name, a.dir, o, [&](size_t done, size_t total) {
        if (!bar) bar = std::make_unique<ProgressBar>(total);
        bar->Update(done, done);
      });
  if (bar) bar->Clear();
  if (!files.ok()) return Fail(files.status());
  uint64_t bytes = 0;
  for (const std::string& f : *files) bytes += fs::file_size(f);
  std::printf("exported %zu frames of '%s' to %s (%s, %.1f MB) in %.2f s\n", files->size(),
              a.name.c_str(), a.dir.c_str(), a.codec.c_str(), bytes / 1e6, MsSince(start) / 1e3);
  return kExitOk;
}

int CmdImport(Context& ctx, const ImportArgs& args) {
  Result<std::vector<std::string>> files = ExpandSequence(args.files);
  if (!files.ok()) return Fail(files.status());
  ImportArgs a = args;
  a.files = std::move(files).value();
  if (a.files.size() - 1 > UINT32_MAX - uint64_t{a.frame}) {
    return Usage("import", "--frame " + std::to_string(a.frame) + " plus " +
                               std::to_string(a.files.size()) + " files passes frame 2^32-1");
  }
  // An unknown dataset is reported before any file is read.
  Result<DatasetInfo> info = ctx.db().Describe(a.name);
  if (!info.ok()) return Fail(info.status());
  if (!a.rotate.empty() && !info->gaussians) {
    return Usage("import", "--rotate is for splat files (a dataset made with --gaussians)");
  }
  // Splat files are moved before loading, their covariances and SH with them.
  formats::Similarity move;
  if (!a.rotate.empty()) {
    move = formats::Similarity::FromEulerDegrees(a.rotate[0], a.rotate[1], a.rotate[2]);
  }
  move.scale = a.units_scale;
  Clock::time_point start = Clock::now();
  ProgressBar bar(a.files.size());
  uint64_t total = 0, skipped_total = 0;
  json frames = json::array();
  codec::Reference reference;  // the previous decoded stream, for temporal ones
  std::vector<std::string> last_ignored;  // splat files' properties read over, last said
  // Each frame's load is atomic and durable: on a failure at file i, say which frames made it.
  auto done = [&](size_t i) {
    return i == 0 ? std::string("no frame was loaded")
                  : "frames " + std::to_string(a.frame) + ".." +
                        std::to_string(a.frame + static_cast<uint32_t>(i) - 1) + " were loaded";
  };
  bar.Update(0, 0);
  for (size_t i = 0; i < a.files.size(); ++i) {
    formats::ReadOptions ro;
    ro.scale = a.units_scale;
    ro.frame = a.frame + static_cast<uint32_t>(i);
    ro.force_frame = true;
    ro.default_sigma = a.sigma;
    ro.skip_invalid = a.skip_invalid;
    uint64_t skipped = 0;
    // A Gaussian-splat dataset reads every file as splats; another refuses one it recognises.
    GaussianColumns records;
    std::vector<std::string> ignored;
    const formats::GaussianFormat sniffed =
        info->gaussians ? formats::GaussianFormat::kUnknown : SniffSplatFile(a.files[i]);
    if (sniffed != formats::GaussianFormat::kUnknown) {
      bar.Clear();
      return Fail(Status::InvalidArgument(
          a.files[i] + " is a " + formats::GaussianFormatName(sniffed) +
          " file of Gaussian splats, and '" + a.name +
          "' holds plain points: import it into a dataset made with `hvdb create NAME --fps F "
          "--gaussians` (" + done(i) + ")"));
    }
    Result<std::vector<Point>> pts =
        info->gaussians ? ReadSplatFrame(a.files[i], ro.frame, move, &records, &ignored)
        : formats::IsHvdb7File(a.files[i]) ? ReadStreamFrame(a.files[i], ro, &reference)
        : formats::IsDracoFile(a.files[i]) ? ReadDracoFrame(a.files[i], ro)
                                           : ReadPlyNoting(a.files[i], ro, &skipped, &bar);
    if (!pts.ok()) {
      bar.Clear();
      return Fail(Status(pts.status().code(), pts.status().message() + " (" + done(i) + ")"));
    }
    if (!a.keep_ids) {
      for (Point& p : *pts) p.id = 0;
    }
    size_t n = pts->size();
    Result<uint64_t> loaded = ctx.db().BulkLoad(a.name, ro.frame, std::move(pts).value(),
                                                info->gaussians ? &records : nullptr);
    if (!loaded.ok()) {
      bar.Clear();
      return Fail(Status(loaded.status().code(),
                         a.files[i] + " -> frame " + std::to_string(ro.frame) + ": " +
                             loaded.status().message() + " (" + done(i) + ")"));
    }
    total += n;
    skipped_total += skipped;
    frames.push_back(
        {{"frame", ro.frame}, {"file", a.files[i]}, {"points", n}, {"skipped_invalid", skipped}});
    if (!ignored.empty()) {
      // Said once per file set of them: a sequence from one trainer repeats the same ones.
      frames.back()["ignored_properties"] = ignored;
      if (ignored != last_ignored && !a.json) {
        std::string list;
        for (const std::string& p : ignored) list += (list.empty() ? "" : ", ") + p;
        bar.Clear();
        std::fprintf(stderr, "note: %s: vertex properties not kept (hvdb stores 3DGS's own): %s\n",
                     a.files[i].c_str(), list.c_str());
      }
      last_ignored = ignored;
    }
    bar.Update(i + 1, total);
  }
  bar.Clear();
  double ms = MsSince(start);
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"points", total},
               {"skipped_invalid", skipped_total},
               {"frames", frames},
               {"elapsed_ms", ms}});
  } else {
    std::printf("imported %llu points into frames %u..%u of '%s' in %.2f s%s\n",
                static_cast<unsigned long long>(total), a.frame,
                a.frame + static_cast<uint32_t>(a.files.size() - 1), a.name.c_str(), ms / 1e3,
                skipped_total ? Printf(" (skipped %llu with a NaN or infinite coordinate)",
                                       static_cast<unsigned long long>(skipped_total))
                                    .c_str()
                              : "");
  }
  return kExitOk;
}

// --codec 3dgs|spz|glb|splat: the format of a crop of a Gaussian-splat dataset, else kUnknown.
formats::GaussianFormat SplatCodec(const std::string& codec) {
  return codec == "3dgs"    ? formats::GaussianFormat::k3dgsPly
         : codec == "spz"   ? formats::GaussianFormat::kSpz
         : codec == "glb"   ? formats::GaussianFormat::kGlb
         : codec == "splat" ? formats::GaussianFormat::kSplat
                            : formats::GaussianFormat::kUnknown;
}

int RunQuery(Context& ctx, const Region& region, const QueryArgs& q, const std::string& command) {
  Clock::time_point start = Clock::now();
  std::unique_ptr<formats::PointWriter> writer;
  if (q.codec != "raw" && q.out.empty()) return Usage(command, "--codec needs --out FILE");
  // A crop of a Gaussian-splat scene as a splat file: the points are collected (one frame's),
  // then written with their records.
  const formats::GaussianFormat splats = SplatCodec(q.codec);
  std::vector<Point> crop;
  if (splats != formats::GaussianFormat::kUnknown) {
    if (command != "window") return Usage(command, "--codec " + q.codec + " is for window");
    Result<DatasetInfo> info = ctx.db().Describe(q.name);
    if (!info.ok()) return Fail(info.status());
    if (!info->gaussians) {
      return Fail(Status::InvalidArgument(
          "--codec " + q.codec + ": '" + q.name + "' is not a Gaussian-splat dataset (made with "
          "hvdb create --gaussians); --codec raw writes its points as PLY"));
    }
  } else if (!q.out.empty()) {
    formats::FileCodec fc = formats::FileCodec::kRaw;
    codec::EncodeOptions eo;
    eo.qp = q.qp;
    eo.qn = 12;
    eo.attributes = codec::kAllAttributes;
    eo.progressive = true;
    Status parsed = formats::ParseFileCodec(q.codec, &fc);
    if (!parsed.ok()) return Usage(command, parsed.message());
    // A CSV of a Gaussian-splat dataset's points carries their records too.
    bool gaussians = false;
    if (fc == formats::FileCodec::kRaw && q.out.ends_with(".csv")) {
      Result<DatasetInfo> info = ctx.db().Describe(q.name);
      if (!info.ok()) return Fail(info.status());
      gaussians = info->gaussians;
    }
    Result<std::unique_ptr<formats::PointWriter>> w =
        fc == formats::FileCodec::kRaw ? formats::OpenPointWriter(q.out, q.ascii, gaussians)
                                       : formats::OpenCompressedWriter(q.out, fc, eo);
    if (!w.ok()) return Fail(w.status());
    writer = std::move(w).value();
  }
  QueryOptions opts;
  opts.lod = q.lod;
  opts.progressive = q.progressive;
  opts.label_mask = q.label_mask;
  Result<std::unique_ptr<client::QueryResults>> cursor = ctx.db().Query(q.name, region, opts);
  if (!cursor.ok()) {
    Status s = cursor.status();
    if (s.code() == StatusCode::kLimitExceeded && command == "slice") {
      s = Status(s.code(), s.message() + " (use --clip-frames or raise --max-frames)");
    }
    return Fail(s);
  }
  std::map<int, uint64_t> per_level;
  uint64_t total = 0;
  Batch batch;
  while (true) {
    batch.points.clear();
    Result<bool> more = (*cursor)->Next(&batch);
    if (!more.ok()) return Fail(more.status());
    if (!batch.points.empty()) {
      per_level[batch.level] += batch.points.size();
      total += batch.points.size();
      if (writer && writer->wants_gaussians()) {
        Result<GaussianColumns> records = ctx.db().ReadGaussians(q.name, batch.points);
        if (!records.ok()) return Fail(records.status());
        GaussianColumns wide;  // every line at degree 3: one header for the file
        wide.sh_degree = kMaxGaussianShDegree;
        wide.values.resize(batch.points.size() * wide.stride());
        for (size_t i = 0; i < batch.points.size(); ++i) {
          WidenRecord(records->record(i), records->sh_degree, wide.record(i), wide.sh_degree);
        }
        Status s = writer->AppendGaussians(batch.points, wide);
        if (!s.ok()) return Fail(s);
      } else if (writer) {
        Status s = writer->Append(batch.points);
        if (!s.ok()) return Fail(s);
      }
      if (splats != formats::GaussianFormat::kUnknown) {
        crop.insert(crop.end(), batch.points.begin(), batch.points.end());
      }
    }
    if (!*more) break;
  }
  if (writer) {
    Status s = writer->Finish();
    if (!s.ok()) return Fail(s);
  }
  if (splats != formats::GaussianFormat::kUnknown) {
    std::set<uint32_t> held;
    for (const Point& p : crop) held.insert(p.frame);
    if (held.size() > 1) {
      return Fail(Status::InvalidArgument(
          "--codec " + q.codec + ": the window holds points of several frames, and a splat file "
          "is one scene: narrow the time range of --box to one frame (hvdb export writes a file "
          "a frame)"));
    }
    Status s = client::WriteSplatFile(ctx.db(), q.name, q.out, splats, 3, &crop);
    if (!s.ok()) return Fail(s);
  }
  double ms = MsSince(start);
  const std::vector<uint32_t>& frames = (*cursor)->frames();
  if (q.json) {
    json levels = json::object();
    for (const auto& [level, n] : per_level) levels[std::to_string(level)] = n;
    json j = {{"points", total},
              {"frames_read", frames.size()},
              {"frames", frames},
              {"levels", levels},
              {"elapsed_ms", ms}};
    if (command == "slice") j["clipped"] = (*cursor)->clipped();
    if (writer || splats != formats::GaussianFormat::kUnknown) j["out"] = q.out;
    PrintJson(j);
    return kExitOk;
  }
  std::printf("%llu points from %zu frame%s in %.1f ms%s\n", static_cast<unsigned long long>(total),
              frames.size(), frames.size() == 1 ? "" : "s", ms,
              (*cursor)->clipped() ? " (slice clipped to the frame bound)" : "");
  for (const auto& [level, n] : per_level) {
    std::printf("  level %d: %llu\n", level, static_cast<unsigned long long>(n));
  }
  if (writer || splats != formats::GaussianFormat::kUnknown) {
    std::printf("written to %s\n", q.out.c_str());
  }
  return kExitOk;
}

int CmdWindow(Context& ctx, const WindowArgs& a) {
  int rc = kExitOk;
  std::optional<hvdb::Window> w = BoxToWindow(a.box, "window", "--box", &rc);
  if (!w) return rc;
  return RunQuery(ctx, Region(*w), a.q, "window");
}

int CmdSlice(Context& ctx, const SliceArgs& a) {
  int rc = kExitOk;
  std::optional<hvdb::Slice> s = MakeSlice(a.normal, a.offset, a.thickness, a.clip_frames,
                                           a.max_frames, a.clip_box, "slice", &rc);
  if (!s) return rc;
  return RunQuery(ctx, Region(*s), a.q, "slice");
}

void AddQueryOptions(CLI::App* cmd, QueryArgs* q) {
  cmd->add_option("name", q->name, "Dataset")->required();
  cmd->add_option("--lod", q->lod,
                  "Finest level returned: 0 = full resolution, each level up about half the points")
      ->check(NonNegative());
  cmd->add_flag("--progressive", q->progressive, "Coarse levels first across all frames");
  cmd->add_option("--label-mask", q->label_mask,
                  "Only points with (label & MASK) != 0 (decimal or 0x hex)");
  cmd->add_option("--out", q->out, "Write the points to FILE.ply or FILE.csv, batch by batch");
  cmd->add_flag("--ascii", q->ascii, "With --out FILE.ply: ascii instead of binary");
  cmd->add_option("--codec", q->codec,
                  "With --out: raw (PLY/CSV), hvdb7 (docs/CODEC.md, every attribute) or draco "
                  "(positions, colours, ids, frames); window of a Gaussian-splat dataset: 3dgs, "
                  "spz, glb or splat (the crop as one splat file, with opacity and SH)")
      ->capture_default_str()
      ->check(CLI::IsMember({"raw", "hvdb7", "draco", "3dgs", "spz", "glb", "splat"}));
  cmd->add_option("--qp", q->qp, "With --codec hvdb7|draco: position bits over the extent")
      ->capture_default_str()
      ->check(CLI::Range(1, 30));
  cmd->add_flag("--json", q->json,
                "Print a JSON summary: points, frames read, per-level counts, elapsed ms");
}

}  // namespace

void AddDataCommands(CLI::App& app, Context& ctx) {
  NameArgs& datasets = data_args.datasets;
  CLI::App* datasets_cmd = app.add_subcommand("datasets", "List the datasets");
  datasets_cmd->add_flag("--json", datasets.json, "Print JSON");
  ctx.Add(datasets_cmd, [](Context& c) { return CmdDatasets(c, data_args.datasets); });

  CreateArgs& create = data_args.create;
  CLI::App* create_cmd = app.add_subcommand("create", "Create an empty dataset");
  create_cmd->add_option("name", create.name, "Dataset name: [A-Za-z0-9_.-], up to 64")->required();
  create_cmd->add_option("--fps", create.fps, "Frames per second")->required()->check(Positive());
  create_cmd
      ->add_option("--scale", create.scale,
                   "Space/time scale s in m/s: slices are taken over (x, y, z, s t)")
      ->capture_default_str()
      ->check(Positive());
  create_cmd->add_option("--frames", create.frames, "Declared number of frames");
  create_cmd->add_flag("--gaussians", create.gaussians,
                       "A Gaussian-splat dataset: its points also keep 3DGS attributes (opacity, "
                       "spherical harmonics), loaded from 3DGS PLY, SPZ, GLB or .splat files");
  ctx.Add(create_cmd, [](Context& c) { return CmdCreate(c, data_args.create); });

  NameArgs& describe = data_args.describe;
  CLI::App* describe_cmd =
      app.add_subcommand("describe", "Show a dataset's frame rate, extent and size");
  describe_cmd->add_option("name", describe.name, "Dataset")->required();
  describe_cmd->add_flag("--json", describe.json, "Print JSON");
  ctx.Add(describe_cmd, [](Context& c) { return CmdDescribe(c, data_args.describe); });

  ImportArgs& imports = data_args.imports;
  CLI::App* import_cmd = app.add_subcommand(
      "import", "Bulk-load PLY files into consecutive frames N, N+1, ... (replaces nothing)");
  import_cmd->add_option("name", imports.name, "Dataset")->required();
  import_cmd->add_option("files", imports.files,
                         "Files, one frame each; a directory: its files in name order")
      ->required();
  import_cmd->add_option("--frame", imports.frame, "Frame of the first file")->required();
  import_cmd
      ->add_option("--units-scale", imports.units_scale,
                   "Multiply positions by this (0.01: the files are in centimetres); splats' "
                   "scales follow")
      ->capture_default_str()
      ->check(Positive());
  import_cmd
      ->add_option("--rotate", imports.rotate,
                   "Splat files: rotate by X Y Z degrees about the x, then y, then z axis "
                   "(e.g. 180 0 0 turns a y-down trainer's scene y-up); covariances and "
                   "spherical harmonics turn with the splats")
      ->expected(3);
  import_cmd
      ->add_option("--sigma", imports.sigma,
                   "Standard deviation in metres for points without a covariance")
      ->capture_default_str()
      ->check(NonNegative());
  import_cmd->add_flag("--keep-ids", imports.keep_ids,
                       "Keep the files' point ids (default: the engine assigns new ones)");
  import_cmd->add_flag("--skip-invalid", imports.skip_invalid, kSkipInvalidHelp);
  import_cmd->add_flag("--json", imports.json, "Print a JSON summary");
  import_cmd->footer(
      "Files may be PLY, hvdb7 streams (hvdb export, hvdb-codec) or Draco files "
      "(hvdb export --codec draco); temporal hvdb7 streams must follow the frame "
      "they were coded against. A Gaussian-splat dataset (hvdb create --gaussians) takes "
      "3DGS PLY, SPZ (versions 2-4), GLB (glTF KHR_gaussian_splatting) and .splat files, told "
      "apart by their content; a directory is a sequence, one file a frame in name order.");
  ctx.Add(import_cmd, [](Context& c) { return CmdImport(c, data_args.imports); });

  ExportArgs& exports = data_args.exports;
  CLI::App* export_cmd = app.add_subcommand(
      "export", "Write frames as files DIR/NAME_FFFFFF.hv7 (or .drc, .ply, .spz, .splat, .glb), "
                "one per frame");
  export_cmd->add_option("name", exports.name, "Dataset")->required();
  export_cmd->add_option("dir", exports.dir, "Output directory (created if missing)")->required();
  export_cmd
      ->add_option("--codec", exports.codec,
                   "hvdb7 (docs/CODEC.md), draco or raw (PLY); Gaussian splats: 3dgs (the "
                   "3DGS PLY), spz, splat or glb (glTF KHR_gaussian_splatting)")
      ->capture_default_str()
      ->check(CLI::IsMember({"raw", "hvdb7", "draco", "3dgs", "spz", "splat", "glb"}));
  export_cmd
      ->add_option("--spz-version", exports.spz_version,
                   "--codec spz: 2, 3 (gzip; every SPZ reader reads them) or 4 (zstd streams, "
                   "the 2025 reference library and later)")
      ->capture_default_str()
      ->check(CLI::Range(2, 4));
  export_cmd->add_option("--qp", exports.qp, "Position bits over each frame's extent")
      ->capture_default_str()
      ->check(CLI::Range(1, 30));
  export_cmd->add_option("--qc", exports.qc, "hvdb7: colour bits (8: exact)")
      ->capture_default_str()
      ->check(CLI::Range(1, 8));
  export_cmd->add_option("--qn", exports.qn, "hvdb7: normal bits (16: exact)")
      ->capture_default_str()
      ->check(CLI::Range(1, 16));
  export_cmd->add_flag("--temporal", exports.temporal,
                       "hvdb7: code each frame against the previous one (import in order)");
  export_cmd->add_option("--first", exports.first, "First frame")->capture_default_str();
  export_cmd->add_option("--count", exports.count, "Frames (0: to the last)")
      ->capture_default_str();
  ctx.Add(export_cmd, [](Context& c) { return CmdExport(c, data_args.exports); });

  WindowArgs& window = data_args.window;
  CLI::App* window_cmd = app.add_subcommand("window", "Query a 4D box");
  AddQueryOptions(window_cmd, &window.q);
  window_cmd->add_option("--box", window.box, "X0 X1 Y0 Y1 Z0 Z1 T0 T1 (metres, seconds)")
      ->expected(8)
      ->required();
  ctx.Add(window_cmd, [](Context& c) { return CmdWindow(c, data_args.window); });

  SliceArgs& slice = data_args.slice;
  CLI::App* slice_cmd = app.add_subcommand(
      "slice", "Query a hyperslice |N . (x, y, z, s t) - B| <= DB, projected to 3D");
  AddQueryOptions(slice_cmd, &slice.q);
  slice_cmd->add_option("--normal", slice.normal, "NX NY NZ NT (normalised; not all zero)")
      ->expected(4)
      ->required();
  slice_cmd->add_option("--offset", slice.offset, "B")->required();
  slice_cmd->add_option("--thickness", slice.thickness, "DB >= 0")
      ->required()
      ->check(NonNegative());
  slice_cmd->add_flag("--clip-frames", slice.clip_frames,
                      "Read only the first frames when the slice spans too many (else error)");
  slice_cmd->add_option("--max-frames", slice.max_frames,
                        "Bound on frames read (default: the database's, 64)");
  slice_cmd->add_option("--clip-box", slice.clip_box, "X0 X1 Y0 Y1 Z0 Z1 T0 T1: clip the slice")
      ->expected(8);
  ctx.Add(slice_cmd, [](Context& c) { return CmdSlice(c, data_args.slice); });
}

}  // namespace hvdb::cli
