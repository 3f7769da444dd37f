// The selection commands of `hvdb`: select (a region, or a lasso, marquee or 3D brush seen
// through a camera) and graphcut (4D graph-cut object selection), both into label bits.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/common.h"

namespace hvdb::cli {
namespace {

struct SelectArgs {
  std::string name;
  int bit = 0;
  std::string mode = "replace";
  RegionArgs region;
  CameraArgs camera;
  std::vector<double> lasso, rect, brush;
  double pixel_radius = 5, radius = 0.02;
  bool nearest = false;
  bool json = false;
  CLI::Option *lasso_opt = nullptr, *rect_opt = nullptr, *brush_opt = nullptr;
};

struct GraphCutArgs {
  std::string name;
  int fg_bit = 1, bg_bit = 2, out_bit = 0;
  RegionArgs roi;
  int k = 8;
  double intra_radius = 0.02, inter_radius = 0.04;
  bool colour_only = false;
  bool json = false;
};

// What CLI11 fills in for these subcommands: static, so that registering them allocates
// nothing but what CLI11 does (see Context in common.h).
struct SelectionArgs {
  SelectArgs select;
  GraphCutArgs graphcut;
} select_args;

int CmdSelect(Context& ctx, const SelectArgs& a) {
  const std::string cmd = "select";
  int rc = kExitOk;
  edit::SelectRequest req;
  std::optional<Region> region;
  if (!ParseRegion(a.region, cmd, &region, &rc)) return rc;
  if (!region) {
    return Usage(cmd,
                 "a region is required: --box X0 X1 Y0 Y1 Z0 Z1 T0 T1, or --normal NX NY NZ "
                 "NT --offset B --thickness DB");
  }
  req.region = *region;
  req.bit = a.bit;
  static const std::map<std::string, edit::SelectMode> kModes = {
      {"replace", edit::SelectMode::kReplace},
      {"add", edit::SelectMode::kAdd},
      {"subtract", edit::SelectMode::kSubtract},
      {"intersect", edit::SelectMode::kIntersect}};
  req.mode = kModes.at(a.mode);  // CLI11 checked it

  const bool lasso = a.lasso_opt->count() > 0, rect = a.rect_opt->count() > 0,
             brush = a.brush_opt->count() > 0;
  const bool have_camera = a.camera.file_opt->count() > 0 || a.camera.look_at_opt->count() > 0;
  if (!lasso && !rect && !brush) {
    if (have_camera) {
      return Usage(cmd, "a camera (--camera, --look-at) is for --lasso, --rect or --brush");
    }
  } else {
    if (!have_camera) {
      return Usage(cmd, std::string(lasso  ? "--lasso"
                                    : rect ? "--rect"
                                           : "--brush") +
                            " is drawn through a camera: give --camera FILE.json or --look-at "
                            "EX EY EZ TX TY TZ --fov DEG --size W H");
    }
    std::vector<std::array<double, 2>> polygon;
    if (lasso) {
      if (a.lasso.size() % 2 != 0) {
        return Usage(cmd, "--lasso takes pixel pairs U V (got " + std::to_string(a.lasso.size()) +
                              " numbers)");
      }
      if (a.lasso.size() < 6) return Usage(cmd, "--lasso needs at least 3 vertices");
      for (size_t i = 0; i < a.lasso.size(); i += 2)
        polygon.push_back({a.lasso[i], a.lasso[i + 1]});
    } else if (rect) {
      const double u0 = std::min(a.rect[0], a.rect[2]), u1 = std::max(a.rect[0], a.rect[2]);
      const double v0 = std::min(a.rect[1], a.rect[3]), v1 = std::max(a.rect[1], a.rect[3]);
      if (!(u0 < u1) || !(v0 < v1)) {
        return Usage(cmd, "--rect U0 V0 U1 V1: the corners must differ in both U and V");
      }
      polygon = {{u0, v0}, {u1, v0}, {u1, v1}, {u0, v1}};
    }
    for (const auto& q : polygon) {
      if (!std::isfinite(q[0]) || !std::isfinite(q[1])) {
        return Usage(cmd, std::string(lasso ? "--lasso" : "--rect") + " must be finite");
      }
    }
    if (brush && (!std::isfinite(a.brush[0]) || !std::isfinite(a.brush[1]))) {
      return Usage(cmd, "--brush U V must be finite");
    }
    CameraInfo camera;
    if (a.camera.file_opt->count() > 0) {
      Result<CameraInfo> c = ReadCameraFile(a.camera.file);
      if (!c.ok()) return Fail(c.status());
      camera = *c;
    } else {
      std::optional<CameraInfo> c = LookAtCamera(a.camera, cmd, &rc);
      if (!c) return rc;
      camera = *c;
    }
    if (brush) {
      edit::Brush b;
      b.camera = camera;
      b.u = a.brush[0];
      b.v = a.brush[1];
      b.pixel_radius = a.pixel_radius;
      b.radius = a.radius;
      b.depth = a.nearest ? edit::Brush::Depth::kNearest : edit::Brush::Depth::kMedian;
      req.shape = b;
    } else {
      req.shape = edit::Lasso{camera, std::move(polygon)};
    }
  }

  Result<edit::SelectResult> r = ctx.db().Select(a.name, req);
  if (!r.ok()) return Fail(r.status());
  const std::string shape = lasso ? "lasso" : rect ? "rect" : brush ? "brush" : "region";
  if (!a.json) {
    std::printf("%s: %llu points matched; %llu carry bit %d after %s\n", shape.c_str(),
                static_cast<unsigned long long>(r->matched),
                static_cast<unsigned long long>(r->selected), a.bit, a.mode.c_str());
    if (r->brush_center) {
      std::printf("brush centre (%.4f, %.4f, %.4f) m\n", (*r->brush_center)[0],
                  (*r->brush_center)[1], (*r->brush_center)[2]);
    }
  }
  CommitOutput out;
  out.lsn = r->lsn;
  out.fields = {{"dataset", a.name}, {"bit", a.bit},          {"mode", a.mode},
                {"shape", shape},    {"matched", r->matched}, {"selected", r->selected}};
  if (r->brush_center) out.fields["brush_center"] = *r->brush_center;
  out.if_none = CommitOutput::IfNone::kSayNothingChanged;
  PrintCommit(a.json, out);
  return kExitOk;
}

int CmdGraphCut(Context& ctx, const GraphCutArgs& a) {
  const std::string cmd = "graphcut";
  if (a.fg_bit == a.bg_bit) {
    return Usage(cmd,
                 "--fg-bit and --bg-bit must differ (both are " + std::to_string(a.fg_bit) + ")");
  }
  int rc = kExitOk;
  std::optional<Region> roi;
  if (!ParseRegion(a.roi, cmd, &roi, &rc)) return rc;
  if (!roi) {
    return Usage(cmd,
                 "a region of interest is required: --box X0 X1 Y0 Y1 Z0 Z1 T0 T1, or "
                 "--normal NX NY NZ NT --offset B --thickness DB");
  }
  edit::GraphCutRequest req;
  req.roi = *roi;
  req.foreground_bit = a.fg_bit;
  req.background_bit = a.bg_bit;
  req.out_bit = a.out_bit;
  req.params.k = a.k;
  req.params.intra_radius = a.intra_radius;
  req.params.inter_radius = a.inter_radius;
  req.params.use_normals = !a.colour_only;
  Result<edit::GraphCutReply> r = ctx.db().GraphCut(a.name, req);
  if (!r.ok()) return Fail(r.status());
  const edit::GraphCutResult& c = r->cut;
  if (!a.json) {
    std::printf("%llu of %llu points in the ROI selected into bit %d\n",
                static_cast<unsigned long long>(r->selected),
                static_cast<unsigned long long>(r->roi_points), a.out_bit);
    std::printf("energy %.6g; %llu intra-frame and %llu inter-frame edges\n", c.energy,
                static_cast<unsigned long long>(c.intra_edges),
                static_cast<unsigned long long>(c.inter_edges));
    std::printf(
        "time: load %.1f ms, neighbours %.1f ms, GMM %.1f ms, graph %.1f ms, max-flow %.1f ms, "
        "commit %.1f ms%s%s\n",
        r->load_ms, c.neighbours_ms, c.gmm_ms, c.graph_ms, c.maxflow_ms, r->commit_ms,
        c.warm ? " (a re-cut: the server's last graph and flow reused" : "",
        !c.warm ? "" : r->labels_only ? "; only labels changed: the labelled points read)" : ")");
  }
  CommitOutput out;
  out.lsn = r->lsn;
  out.fields = {{"dataset", a.name},
                {"out_bit", a.out_bit},
                {"roi_points", r->roi_points},
                {"selected", r->selected},
                {"energy", c.energy},
                {"intra_edges", c.intra_edges},
                {"inter_edges", c.inter_edges},
                {"recut", c.warm},
                {"labels_only", r->labels_only},
                {"timings_ms",
                 {{"load", r->load_ms},
                  {"neighbours", c.neighbours_ms},
                  {"gmm", c.gmm_ms},
                  {"graph", c.graph_ms},
                  {"maxflow", c.maxflow_ms},
                  {"commit", r->commit_ms}}}};
  out.if_none = CommitOutput::IfNone::kSayNothingChanged;
  PrintCommit(a.json, out);
  return kExitOk;
}

}  // namespace

void AddSelectCommands(CLI::App& app, Context& ctx) {
  SelectArgs& select = select_args.select;
  CLI::App* select_cmd = app.add_subcommand(
      "select",
      "Select points into label bit B: those of a region (--box or --normal/--offset/--thickness),"
      " or only those under a lasso, marquee or 3D brush seen through a camera");
  select_cmd->add_option("name", select.name, "Dataset")->required();
  AddBit(select_cmd, "--bit", &select.bit, "Label bit 0..31 that holds the selection")->required();
  select_cmd
      ->add_option("--mode", select.mode,
                   "How the new set combines with the points already carrying the bit: "
                   "replace, add, subtract or intersect")
      ->capture_default_str()
      ->check(CLI::IsMember({"replace", "add", "subtract", "intersect"}));
  AddRegionOptions(select_cmd, &select.region,
                   "Region (required): what is viewed; nothing outside it is selected");
  const std::string shape = "Shape (optional; without one the whole region is selected)";
  select.lasso_opt =
      select_cmd
          ->add_option("--lasso", select.lasso,
                       "U0 V0 U1 V1 U2 V2 ...: the region's points projecting inside this polygon "
                       "(pixels, >= 3 vertices)")
          ->group(shape);
  select.rect_opt = select_cmd
                        ->add_option("--rect", select.rect,
                                     "U0 V0 U1 V1: a marquee, the rectangle between these corners "
                                     "(pixels)")
                        ->expected(4)
                        ->group(shape);
  select.brush_opt =
      select_cmd
          ->add_option("--brush", select.brush,
                       "U V: the 3D paintbrush, a sphere of --radius metres around the surface "
                       "under pixel (U, V)")
          ->expected(2)
          ->group(shape);
  select.lasso_opt->excludes(select.rect_opt)->excludes(select.brush_opt);
  select.rect_opt->excludes(select.brush_opt);
  select_cmd
      ->add_option("--pixel-radius", select.pixel_radius,
                   "With --brush: the surface depth is taken from the points within R pixels")
      ->capture_default_str()
      ->check(Positive())
      ->needs(select.brush_opt)
      ->group(shape);
  select_cmd->add_option("--radius", select.radius, "With --brush: the brush's radius in metres")
      ->capture_default_str()
      ->check(Positive())
      ->needs(select.brush_opt)
      ->group(shape);
  select_cmd
      ->add_flag("--nearest", select.nearest,
                 "With --brush: the nearest depth under the brush (default: the median)")
      ->needs(select.brush_opt)
      ->group(shape);
  const std::string camera = "Camera (for --lasso, --rect and --brush)";
  CameraArgs& ca = select.camera;
  ca.file_opt = select_cmd
                    ->add_option("--camera", ca.file,
                                 "FILE.json: {\"fx\", \"fy\", \"cx\", \"cy\", \"width\", "
                                 "\"height\", \"world_from_camera\": [16 numbers, row-major]} "
                                 "(pinhole; x right, y down, z forward)")
                    ->group(camera);
  ca.look_at_opt = select_cmd
                       ->add_option("--look-at", ca.look_at,
                                    "EX EY EZ TX TY TZ: a pinhole camera at the eye looking at "
                                    "the target (needs --fov and --size)")
                       ->expected(6)
                       ->excludes(ca.file_opt)
                       ->group(camera);
  CLI::Option* fov =
      select_cmd->add_option("--fov", ca.fov, "With --look-at: vertical field of view in degrees")
          ->check(CLI::Range(0.001, 179.0))
          ->needs(ca.look_at_opt)
          ->group(camera);
  CLI::Option* size =
      select_cmd
          ->add_option("--size", ca.size, "With --look-at: image width and height W H in pixels")
          ->expected(2)
          ->check(CLI::Range(1u, 100000u))
          ->needs(ca.look_at_opt)
          ->group(camera);
  select_cmd
      ->add_option("--up", ca.up, "With --look-at: the world direction shown upwards in the image")
      ->expected(3)
      ->capture_default_str()
      ->needs(ca.look_at_opt)
      ->group(camera);
  ca.look_at_opt->needs(fov)->needs(size);
  select_cmd->add_flag("--json", select.json, "Print JSON");
  select_cmd->footer(
      "Prints the points the shape matched, those carrying the bit afterwards and the lsn of the\n"
      "change (0: nothing changed), plus the brush's centre. Positions are those the viewer sees:\n"
      "projected ones for a slice. Undo with 'hvdb undo NAME LSN'. Example (a marquee):\n"
      "  hvdb select walk --bit 1 --box -2 2 -2 2 -2 2 0 0.1 --rect 290 100 350 200 \\\n"
      "      --look-at -0.3 -0.9 -3 -0.3 -0.9 0 --fov 50 --size 640 480");
  ctx.Add(select_cmd, [](Context& c) { return CmdSelect(c, select_args.select); });

  GraphCutArgs& graphcut = select_args.graphcut;
  CLI::App* graphcut_cmd = app.add_subcommand(
      "graphcut",
      "4D graph-cut object selection: from foreground and background strokes (label bits, e.g. "
      "made with select) to the whole object inside a region of interest");
  graphcut_cmd->add_option("name", graphcut.name, "Dataset")->required();
  AddBit(graphcut_cmd, "--fg-bit", &graphcut.fg_bit, "Label bit of the foreground strokes")
      ->required();
  AddBit(graphcut_cmd, "--bg-bit", &graphcut.bg_bit, "Label bit of the background strokes")
      ->required();
  AddBit(graphcut_cmd, "--out-bit", &graphcut.out_bit,
         "Label bit that receives the selection (set inside it, cleared elsewhere in the ROI)")
      ->required();
  AddRegionOptions(graphcut_cmd, &graphcut.roi,
                   "Region of interest (required): the points the cut decides on");
  graphcut_cmd
      ->add_option("--k", graphcut.k, "Intra-frame neighbours per point (inter-frame: k / 2)")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  graphcut_cmd
      ->add_option("--intra-radius", graphcut.intra_radius,
                   "Neighbours within a frame are at most this far (metres)")
      ->capture_default_str()
      ->check(Positive());
  graphcut_cmd
      ->add_option("--inter-radius", graphcut.inter_radius,
                   "Neighbours in the next frame are at most this far (metres)")
      ->capture_default_str()
      ->check(Positive());
  graphcut_cmd->add_flag("--colour-only", graphcut.colour_only,
                         "Link costs from colours only (default: colours and normals)");
  graphcut_cmd->add_flag("--json", graphcut.json, "Print JSON");
  graphcut_cmd->footer(
      "Prints the ROI's points, those selected, the energy, the intra- and inter-frame edge\n"
      "counts, the time of each step (load, neighbours, GMM, graph, max-flow, commit) and the\n"
      "lsn. The radii should exceed the sampling distance of the points.");
  ctx.Add(graphcut_cmd, [](Context& c) { return CmdGraphCut(c, select_args.graphcut); });
}

}  // namespace hvdb::cli
