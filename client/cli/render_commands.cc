// The render command of `hvdb`: a region's points through a camera into PNG or EXR images,
// or a camera path into a sequence or a video (MP4, WebM); the same render job runs in this process (--data) or in
// hvdb-server (--server).
#include <array>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/common.h"
#include "render/job.h"
#include "render/renderer.h"
#include "render/request.h"

namespace hvdb::cli {
namespace {

namespace fs = std::filesystem;

struct RenderArgs {
  std::string name;
  RegionArgs region;
  int lod = 0;
  uint32_t label_mask = 0;
  std::vector<int> highlight;  // bits drawn as an overlay
  bool texture = false, billboards = false;
  std::vector<float> highlight_color;
  CameraArgs camera;  // --camera, --look-at/--fov/--up; --size (any camera) in camera.size
  uint32_t dataset_camera = 0;
  std::string mode = "auto";
  bool view_dependent = false;
  std::vector<double> background;
  std::string renderer = "auto";
  std::string out;
  std::string path, out_dir;
  std::string format = "png";
  std::string video;  // --video OUT.mp4|webm
  double fps = 30;
  std::vector<double> shadow_light;  // --shadow-light X Y Z
  bool shadow_directional = false;
  uint32_t shadow_casters = 0;
  float shadow_strength = 0.6f;
  bool json = false;
  CLI::Option *dataset_camera_opt = nullptr, *size_opt = nullptr, *path_opt = nullptr,
              *video_opt = nullptr, *out_dir_opt = nullptr;
};

// What CLI11 fills in for these subcommands: static, so that registering them allocates
// nothing but what CLI11 does (see Context in common.h).
RenderArgs render_args;

// Writes `bytes` to `path` (replacing it); IOError naming the file.
Status WriteFileBytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (out) out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  if (out) out.close();
  if (!out) return Status::IOError("cannot write '" + path + "': " + std::strerror(errno));
  return Status::OK();
}

// True if `path` ends with `ext` (".png"), in any case.
bool HasExtension(const std::string& path, const std::string& ext) {
  if (path.size() <= ext.size()) return false;
  for (size_t i = 0; i < ext.size(); ++i) {
    const char c = path[path.size() - ext.size() + i];
    if (std::tolower(static_cast<unsigned char>(c)) != ext[i]) return false;
  }
  return true;
}

int CmdRender(Context& ctx, const RenderArgs& a) {
  const std::string cmd = "render";
  int rc = kExitOk;
  const bool sequence = a.path_opt->count() > 0;
  std::optional<Region> region;
  if (!ParseRegion(a.region, cmd, &region, &rc)) return rc;
  const bool look_at = a.camera.look_at_opt->count() > 0,
             camera_file = a.camera.file_opt->count() > 0,
             dataset_camera = a.dataset_camera_opt->count() > 0;
  render::ImageFormat format = render::ImageFormat::kPng;
  const bool video = a.video_opt->count() > 0;
  if (video) {
    if (HasExtension(a.video, ".mp4")) {
      format = render::ImageFormat::kMp4;
    } else if (HasExtension(a.video, ".webm")) {
      format = render::ImageFormat::kWebm;
    } else {
      return Usage(cmd, "--video '" + a.video + "': the file name must end in .mp4 or .webm");
    }
    if (!sequence) return Usage(cmd, "--video needs --path CAMERAS.json: one frame per camera");
  } else if (sequence) {
    if (a.out_dir_opt->count() == 0) {
      return Usage(cmd, "--path needs --out-dir DIR for images, or --video OUT.mp4|webm");
    }
    format = a.format == "exr" ? render::ImageFormat::kExr : render::ImageFormat::kPng;
  } else {
    if (!look_at && !camera_file && !dataset_camera) {
      return Usage(cmd,
                   "a camera is required: --look-at EX EY EZ TX TY TZ --fov DEG, --camera "
                   "FILE.json or --dataset-camera ID (or --path CAMERAS.json for a sequence)");
    }
    if (!region) {
      return Usage(cmd,
                   "a region is required: --box X0 X1 Y0 Y1 Z0 Z1 T0 T1, or --normal NX NY NZ NT "
                   "--offset B --thickness DB");
    }
    if (a.out.empty()) {
      return Usage(cmd,
                   "--out FILE.png or FILE.exr is required (or --path CAMERAS.json "
                   "--out-dir DIR for a sequence)");
    }
    if (HasExtension(a.out, ".exr")) {
      format = render::ImageFormat::kExr;
    } else if (!HasExtension(a.out, ".png")) {
      return Usage(cmd, "--out '" + a.out + "': the file name must end in .png or .exr");
    }
  }

  render::RenderRequest req;
  req.dataset = a.name;
  // Any level >= 0: beyond the dataset's coarsest, storage refuses it (Dataset::CheckLod).
  req.lod = static_cast<uint32_t>(a.lod);
  req.label_mask = a.label_mask;
  uint32_t highlight = 0;
  for (int b : a.highlight) highlight |= 1u << b;
  req.highlight_mask = highlight;
  // Unset unless asked: the render job's auto picks the frame's best picture.
  if (a.texture || a.mode == "textured") req.texture = true;
  if (a.billboards || a.mode == "billboards") req.billboards = true;
  if (!a.highlight_color.empty()) {
    req.highlight_color = {a.highlight_color[0], a.highlight_color[1], a.highlight_color[2],
                           a.highlight_color[3]};
  }
  if (a.mode == "visibility") req.mode = render::Mode::kVisibility;
  if (a.mode == "probabilistic") req.mode = render::Mode::kProbabilistic;
  if (a.mode == "gaussian") req.mode = render::Mode::kGaussian;
  req.view_dependent = a.view_dependent;
  req.renderer = a.renderer == "egl"   ? render::RendererKind::kEgl
                 : a.renderer == "cpu" ? render::RendererKind::kCpu
                                       : render::RendererKind::kAuto;
  req.format = format;
  if (video) req.video_fps = a.fps;
  if (!a.background.empty()) {
    // Given as the PNG shows it (sRGB); the renderer blends in linear light.
    std::array<float, 4> bg{0, 0, 0, 1.0f};
    for (size_t i = 0; i < 3; ++i) bg[i] = render::SrgbToLinear(static_cast<float>(a.background[i]));
    req.background = bg;
  }
  if (!a.shadow_light.empty()) {
    req.shadow_light = {a.shadow_light[0], a.shadow_light[1], a.shadow_light[2]};
    req.shadow_directional = a.shadow_directional;
    req.shadow_casters = a.shadow_casters;
    // 0 means the default; a user's 0 means no darkening: the smallest float.
    req.shadow_strength = a.shadow_strength == 0 ? 1e-30f : a.shadow_strength;
  }
  req.region = region;
  // --size: the size of a look-at camera; for any other camera, the size it is scaled to.
  const bool sized = a.size_opt->count() > 0;
  if (sized && !look_at) {
    req.width = a.camera.size[0];
    req.height = a.camera.size[1];
  }
  if (sequence) {
    std::ifstream in(a.path, std::ios::binary);
    if (!in) {
      return Fail(
          Status::IOError("cannot read camera path '" + a.path + "': " + std::strerror(errno)));
    }
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    Status st = render::ParseCameraPath(text, &req);
    if (!st.ok()) return Fail(Status(st.code(), a.path + ": " + st.message()));
    if (req.path.empty()) {
      return Fail(Status::InvalidArgument(a.path + ": the camera path has no cameras"));
    }
    if (req.frames.empty() && !region) {
      return Usage(cmd, "the entries of '" + a.path +
                            "' have no \"frame\": give the region to show, --box X0 X1 Y0 Y1 Z0 "
                            "Z1 T0 T1 or --normal NX NY NZ NT --offset B --thickness DB");
    }
    if (!req.frames.empty() && region && !std::holds_alternative<Window>(*region)) {
      return Usage(cmd, "the entries of '" + a.path +
                            "' show frames: a region with them must be a --box (its x y z "
                            "bounds apply to every frame)");
    }
  } else if (look_at) {
    CameraArgs c = a.camera;
    if (!sized) c.size = {640, 480};
    std::optional<CameraInfo> camera = LookAtCamera(c, cmd, &rc);
    if (!camera) return rc;
    req.view = *camera;
  } else if (camera_file) {
    Result<CameraInfo> camera = ReadCameraFile(a.camera.file);
    if (!camera.ok()) return Fail(camera.status());
    req.view = *camera;
  } else {
    req.view = render::DatasetCameraView{a.dataset_camera};
  }

  // The render library's warnings (the CPU fallback of --renderer auto) in our own voice.
  render::SetLogHandler([](const std::string& msg) {
    bool note = msg.rfind("note: ", 0) == 0;
    std::fprintf(stderr, "hvdb: %s%s\n", note ? "" : "warning: ", msg.c_str());
  });
  const Clock::time_point start = Clock::now();
  json images = json::array();
  uint64_t total_points = 0;
  double total_ms = 0;
  std::string renderer, choice, mode_used, mode_choice;
  bool fallback = false;
  bool made_dir = false;
  std::string codec;
  Status st = ctx.db().Render(req, [&](const render::RenderReply& r) -> Status {
    std::string file = a.out;
    if (video) {
      file = a.video;
      codec = r.video_codec;
      if (!a.json) {
        std::fprintf(stderr, "\rhvdb: frame %u of %u", r.index + 1, r.images);
        if (r.last) std::fprintf(stderr, "\n");
      }
      if (r.last) {
        // Written whole at the end, through a temporary name: a failed render leaves nothing.
        const std::string tmp = a.video + ".partial";
        HVDB_RETURN_IF_ERROR(WriteFileBytes(tmp, r.video));
        std::error_code ec;
        fs::rename(tmp, a.video, ec);
        if (ec) {
          fs::remove(tmp, ec);
          return Status::IOError("cannot write '" + a.video + "': " + ec.message());
        }
      }
    } else if (sequence) {
      if (!made_dir) {
        std::error_code ec;
        fs::create_directories(a.out_dir, ec);
        if (ec) {
          return Status::IOError("cannot create directory '" + a.out_dir + "': " + ec.message());
        }
        made_dir = true;
      }
      file = (fs::path(a.out_dir) /
              Printf("frame_%04u.%s", r.index, format == render::ImageFormat::kExr ? "exr" : "png"))
                 .string();
    }
    if (!video) {
      HVDB_RETURN_IF_ERROR(WriteFileBytes(file, format == render::ImageFormat::kExr ? r.exr : r.png));
    }
    if (images.empty()) {
      renderer = r.renderer_used;
      choice = r.renderer_choice;
      mode_used = r.mode_used;
      mode_choice = r.mode_choice;
      fallback = r.fallback;
      if (fallback && ctx.db().remote()) {
        std::fprintf(stderr,
                     "hvdb: warning: hvdb-server at %s could make no EGL context and rendered "
                     "with the CPU renderer (its log says why)\n",
                     ctx.db().where().c_str());
      }
    }
    total_points += r.points;
    total_ms += r.render_ms;
    images.push_back({{"index", r.index},
                      {"file", file},
                      {"width", r.width},
                      {"height", r.height},
                      {"points", r.points},
                      {"render_ms", r.render_ms},
                      {"mode", r.mode_used}});
    if (!a.json && !video) {
      if (sequence) {
        std::printf("%s (%ux%u): %llu points in %.1f ms, %s\n", file.c_str(), r.width,
                    r.height, static_cast<unsigned long long>(r.points), r.render_ms,
                    r.mode_used.c_str());
      } else {
        std::printf("rendered %s (%ux%u): %llu points in %.1f ms with %s%s; mode %s (%s)\n",
                    file.c_str(), r.width, r.height,
                    static_cast<unsigned long long>(r.points), r.render_ms,
                    r.renderer_used.c_str(), r.fallback ? " (fallback: no EGL context)" : "",
                    r.mode_used.c_str(), r.mode_choice.c_str());
      }
      std::fflush(stdout);
    }
    return Status::OK();
  });
  render::SetLogHandler(nullptr);
  if (!st.ok()) {
    if (sequence && !video && !images.empty()) {
      st = Status(st.code(), st.message() + " (" + std::to_string(images.size()) + " of " +
                                 std::to_string(req.path.size()) + " images were written to " +
                                 a.out_dir + ")");
    }
    return Fail(st);
  }
  const double ms = MsSince(start);
  if (video) {
    if (a.json) {
      PrintJson({{"dataset", a.name},
                 {"video", a.video},
                 {"codec", codec},
                 {"frames", images.size()},
                 {"fps", a.fps},
                 {"width", images.empty() ? 0u : images[0]["width"].get<uint32_t>()},
                 {"height", images.empty() ? 0u : images[0]["height"].get<uint32_t>()},
                 {"renderer", renderer},
                 {"mode", mode_used},
                 {"mode_choice", mode_choice},
                 {"points", total_points},
                 {"render_ms", total_ms},
                 {"elapsed_ms", ms}});
    } else {
      std::printf("rendered %zu frames into %s (%s, %g fps) with %s: %.2f s in all (%.1f frames/s)\n",
                  images.size(), a.video.c_str(), codec.c_str(), a.fps, renderer.c_str(), ms / 1e3,
                  images.size() * 1e3 / ms);
    }
  } else if (a.json) {
    PrintJson({{"dataset", a.name},
               {"renderer", renderer},
               {"renderer_choice", choice},
               {"fallback", fallback},
               {"mode", mode_used},
               {"mode_choice", mode_choice},
               {"images", images},
               {"points", total_points},
               {"render_ms", total_ms},
               {"elapsed_ms", ms}});
  } else if (sequence) {
    std::printf("rendered %zu image%s into %s with %s%s, mode %s: %llu points in %.1f ms (%.2f s "
                "in all)\n",
                images.size(), images.size() == 1 ? "" : "s", a.out_dir.c_str(), renderer.c_str(),
                fallback ? " (fallback: no EGL context)" : "", mode_used.c_str(),
                static_cast<unsigned long long>(total_points), total_ms, ms / 1e3);
  }
  return kExitOk;
}

}  // namespace

void AddRenderCommands(CLI::App& app, Context& ctx) {
  CLI::App* render_cmd = app.add_subcommand(
      "render",
      "Render a region's points through a camera into an image (EWA splatting), or a camera "
      "path over frames into a sequence of images");
  RenderArgs& ra = render_args;
  render_cmd->add_option("name", ra.name, "Dataset")->required();
  AddRegionOptions(render_cmd, &ra.region,
                   "Region (required, unless every entry of the --path file has a frame)");
  render_cmd
      ->add_option("--lod", ra.lod,
                   "Level of detail: 0 = full resolution; each level up about half the points, "
                   "drawn as splats 2^(1/2) larger")
      ->capture_default_str()
      ->check(NonNegative());
  render_cmd->add_option("--label-mask", ra.label_mask,
                         "Only points with (label & MASK) != 0 (decimal or 0x hex)");
  render_cmd->add_flag("--texture", ra.texture,
                       "colour from the frame's stored photos over the points' depth (thesis "
                       "6.3): sharper than the points, one view of one frame (what --mode auto "
                       "draws where the frame has photos and no billboards)");
  render_cmd->add_flag("--billboards", ra.billboards,
                       "draw the frame's billboards (hvdb-ingest run --filter billboard) instead "
                       "of its points: one view-dependent depth per pixel, colour from the "
                       "photos (thesis 6.3); one view of one frame");
  render_cmd
      ->add_option("--highlight", ra.highlight,
                   "Show a selection: points carrying label BIT (repeatable) drawn in "
                   "their colour blended toward --highlight-color")
      ->check(CLI::Range(0, 31));
  render_cmd
      ->add_option("--highlight-color", ra.highlight_color,
                   "R G B A in [0, 1] (sRGB; A: how much of it), default 1 0.45 0 0.5")
      ->expected(4)
      ->check(CLI::Range(0.f, 1.f));
  const std::string rcamera = "Camera (one is required, unless --path gives them)";
  CameraArgs& rc = ra.camera;
  rc.look_at_opt = render_cmd
                       ->add_option("--look-at", rc.look_at,
                                    "EX EY EZ TX TY TZ: a pinhole camera at the eye looking at "
                                    "the target (needs --fov)")
                       ->expected(6)
                       ->group(rcamera);
  CLI::Option* rfov =
      render_cmd->add_option("--fov", rc.fov, "With --look-at: vertical field of view in degrees")
          ->check(CLI::Range(0.001, 179.0))
          ->needs(rc.look_at_opt)
          ->group(rcamera);
  rc.look_at_opt->needs(rfov);
  render_cmd
      ->add_option("--up", rc.up,
                   "With --look-at: the world direction shown upwards in the image (y points "
                   "down in Panoptic data)")
      ->expected(3)
      ->capture_default_str()
      ->needs(rc.look_at_opt)
      ->group(rcamera);
  rc.file_opt = render_cmd
                    ->add_option("--camera", rc.file,
                                 "FILE.json: {\"fx\", \"fy\", \"cx\", \"cy\", \"width\", "
                                 "\"height\", \"world_from_camera\": [16 numbers, row-major]} "
                                 "(pinhole; x right, y down, z forward)")
                    ->excludes(rc.look_at_opt)
                    ->group(rcamera);
  ra.dataset_camera_opt =
      render_cmd
          ->add_option("--dataset-camera", ra.dataset_camera,
                       "ID: one of the dataset's own cameras ('hvdb describe NAME --json' lists "
                       "them)")
          ->excludes(rc.look_at_opt)
          ->excludes(rc.file_opt)
          ->group(rcamera);
  ra.size_opt = render_cmd
                    ->add_option("--size", rc.size,
                                 "W H: image size in pixels (with --look-at: default 640 480; "
                                 "else the camera is scaled to it)")
                    ->expected(2)
                    ->check(CLI::Range(1u, render::kMaxImageSize))
                    ->group(rcamera);
  const std::string look = "Appearance";
  render_cmd
      ->add_option("--mode", ra.mode,
                   "auto: a Gaussian-splat dataset's splats as 3DGS draws them (gaussian), else "
                   "the frame's best picture (its billboards where stored, else its photos "
                   "as --texture, else the points in visibility mode; one view of one frame); "
                   "the points: visibility (fuzzy depth test, blending: thesis fig. 5.2) or "
                   "probabilistic (front to back until opaque: 5.4.1); gaussian (the 3DGS "
                   "rasteriser, sorted, opacity and SH colour; any dataset); textured (= "
                   "--texture); billboards (= --billboards). The output says which mode drew")
      ->capture_default_str()
      ->check(CLI::IsMember(
          {"auto", "visibility", "probabilistic", "gaussian", "textured", "billboards"}))
      ->group(look);
  render_cmd
      ->add_flag("--view-dependent", ra.view_dependent,
                 "Weight each point by how close its source camera is to the view (needs a "
                 "dataset with cameras)")
      ->group(look);
  render_cmd
      ->add_option("--background", ra.background,
                   "R G B in 0..1: the colour of empty pixels, as it appears in the PNG "
                   "(default black)")
      ->expected(3)
      ->check(CLI::Range(0.0, 1.0))
      ->group(look);
  render_cmd
      ->add_option("--renderer", ra.renderer,
                   "egl (OpenGL through headless EGL: the GPU, or Mesa's llvmpipe), cpu, or auto "
                   "(egl where a context can be made, else cpu with a warning)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "egl", "cpu"}))
      ->group(look);
  const std::string shadows = "Shadows (thesis 9.4)";
  CLI::Option* light =
      render_cmd
          ->add_option("--shadow-light", ra.shadow_light,
                       "X Y Z: a point light there (outside the casters) casts the shadows of "
                       "the --shadow-casters points onto everything else")
          ->expected(3)
          ->group(shadows);
  render_cmd
      ->add_flag("--shadow-directional", ra.shadow_directional,
                 "--shadow-light X Y Z is the direction towards a light infinitely far away "
                 "(the sun) instead of a position")
      ->needs(light)
      ->group(shadows);
  CLI::Option* casters =
      render_cmd
          ->add_option("--shadow-casters", ra.shadow_casters,
                       "BIT: points carrying this label bit (0..31) cast the shadows")
          ->needs(light)
          ->group(shadows);
  light->needs(casters);
  render_cmd
      ->add_option("--shadow-strength", ra.shadow_strength,
                   "S in [0, 1]: how much a fully shadowed pixel is darkened")
      ->capture_default_str()
      ->needs(light)
      ->group(shadows);
  const std::string output = "Output (--out, or --path with --out-dir or --video)";
  CLI::Option* out =
      render_cmd
          ->add_option("--out", ra.out, "FILE.png (8-bit sRGB) or FILE.exr (float RGBA and Z)")
          ->group(output);
  ra.path_opt = render_cmd
                    ->add_option("--path", ra.path,
                                 "CAMERAS.json: a sequence, one image per camera: {\"cameras\": "
                                 "[{\"look_at\": {\"eye\", \"target\", \"up\", "
                                 "\"fov_y_deg\", \"width\", \"height\"}} | {\"camera\": {...}} "
                                 "| {\"dataset_camera\": ID}, ...]}, each with \"frame\": F to "
                                 "show that frame")
                    ->excludes(out)
                    ->excludes(rc.look_at_opt)
                    ->excludes(rc.file_opt)
                    ->excludes(ra.dataset_camera_opt)
                    ->group(output);
  ra.out_dir_opt =
      render_cmd
          ->add_option("--out-dir", ra.out_dir,
                       "With --path: the directory for frame_0000.png, frame_0001.png, ... "
                       "(made if missing)")
          ->needs(ra.path_opt)
          ->group(output);
  ra.video_opt = render_cmd
                     ->add_option("--video", ra.video,
                                  "With --path: OUT.mp4 (H.264) or OUT.webm (VP9), one frame per "
                                  "camera of the path, written when the last is encoded")
                     ->needs(ra.path_opt)
                     ->excludes(ra.out_dir_opt)
                     ->group(output);
  render_cmd->add_option("--fps", ra.fps, "With --video: frames a second of the video")
      ->capture_default_str()
      ->check(CLI::Range(0.001, 1000.0))
      ->needs(ra.video_opt)
      ->group(output);
  render_cmd->add_option("--format", ra.format, "With --path: png or exr")
      ->capture_default_str()
      ->check(CLI::IsMember({"png", "exr"}))
      ->needs(ra.path_opt)
      ->group(output);
  render_cmd->add_flag("--json", ra.json, "Print JSON");
  render_cmd->footer(
      "Prints the renderer used, the points drawn and the time, per image. The same request runs\n"
      "in this process on --data DIR or in hvdb-server with --server: the images are the same.\n"
      "Example, frame 5 of the demo dataset (29.97 fps) seen from 3 m in front:\n"
      "  hvdb render panoptic --box -10 10 -10 10 -10 10 0.15 0.18 \\\n"
      "      --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 --size 640 480 --out demo.png\n"
      "A sequence: hvdb render panoptic --path cameras.json --out-dir frames/\n"
      "A video of it: hvdb render panoptic --path cameras.json --video walk.mp4 --fps 30\n"
      "Shadows of the points labelled with bit 2 from a lamp 2 m above (y down):\n"
      "  hvdb render panoptic ... --shadow-light 0 -2 0 --shadow-casters 2 --out lit.png");
  ctx.Add(render_cmd, [](Context& c) { return CmdRender(c, render_args); });
}

}  // namespace hvdb::cli
