// hvdb: the command line of the 3D-video database, embedded on a data directory like sqlite3,
// or talking to an hvdb-server like psql:
//
//   hvdb --data DIR create walk --fps 29.97
//   hvdb --data DIR import walk --frame 0 --units-scale 0.01 f380.ply f381.ply
//   hvdb --data DIR window walk --box -2 2 -2 2 -2 2 0 1 --out all.ply
//   hvdb --server 127.0.0.1:7878 slice walk --normal 0 0 0 1 --offset 0.0334 --thickness 0.01
//   hvdb --data DIR select walk --bit 1 --box -2 2 -2 2 -2 2 0 0.1 --rect 290 100 350 200
//       --look-at -0.3 -0.9 -3 -0.3 -0.9 0 --fov 50 --size 640 480     (one line)
//   hvdb --data DIR cut walk --bit 0 --clipboard man
//   hvdb --data DIR paste walk --clipboard man --translate 1 0 0 0
//   hvdb --server 127.0.0.1:7878 render walk --box -2 2 -2 2 -2 2 0.16 0.17
//       --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 --size 640 480 --out walk.png  (one line)
//
// Every subcommand runs the same code in both modes, through client::Backend (client/backend.h);
// only `check` (the data directory's files) is embedded-only and `ping` server-only.
//
// Positions are metres, times seconds (frame / fps). Exit status: 0 success, 1 an error from
// the database, the server or a file (printed as "hvdb: <status>"), 2 a usage error.
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "client/export.h"
#include "formats/ply.h"
#include "formats/point_files.h"
#include "render/job.h"
#include "render/renderer.h"
#include "storage/database.h"
#include "storage/status.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

constexpr int kExitOk = 0;
constexpr int kExitError = 1;
constexpr int kExitUsage = 2;

constexpr const char* kSkipInvalidHelp =
    "Leave out points with a NaN or infinite coordinate and say how many (default: such a file "
    "is an error and nothing of it is loaded)";

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

std::string Printf(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
std::string Printf(const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  int n = std::vsnprintf(buf, sizeof(buf), fmt, ap);
  va_end(ap);
  return std::string(buf, static_cast<size_t>(std::clamp(n, 0, static_cast<int>(sizeof(buf) - 1))));
}

// "12.3k", "4.56M": for rates on the progress bar.
std::string Human(double v) {
  if (v >= 1e9) return Printf("%.2fG", v / 1e9);
  if (v >= 1e6) return Printf("%.2fM", v / 1e6);
  if (v >= 1e3) return Printf("%.1fk", v / 1e3);
  return Printf("%.0f", v);
}

// "512 B", "12.3 KiB", "4.56 MiB": for byte counts.
std::string Bytes(uint64_t v) {
  auto d = static_cast<double>(v);
  if (v >= (uint64_t{1} << 30)) return Printf("%.2f GiB", d / (1 << 30));
  if (v >= (uint64_t{1} << 20)) return Printf("%.2f MiB", d / (1 << 20));
  if (v >= (uint64_t{1} << 10)) return Printf("%.1f KiB", d / (1 << 10));
  return Printf("%llu B", static_cast<unsigned long long>(v));
}

std::string Duration(double seconds) {
  auto s = static_cast<long long>(std::llround(std::max(0.0, seconds)));
  if (s >= 3600) return Printf("%lldh%02lldm", s / 3600, s / 60 % 60);
  if (s >= 60) return Printf("%lldm%02llds", s / 60, s % 60);
  return Printf("%llds", s);
}

void PrintJson(const json& j) {
  // Messages from the engine may quote file bytes: replace what is not UTF-8, never throw.
  std::cout << j.dump(-1, ' ', false, json::error_handler_t::replace) << "\n";
}

int Fail(const Status& s) {
  std::cerr << "hvdb: " << s.ToString() << "\n";
  return kExitError;
}

// command: the subcommand at fault, or "" for the top level.
int Usage(const std::string& command, const std::string& msg) {
  std::string cmd = command.empty() ? "hvdb" : "hvdb " + command;
  std::cerr << (command.empty() ? "hvdb: " : cmd + ": ") << msg << "\nRun '" << cmd
            << " --help' for usage.\n";
  return kExitUsage;
}

// Number checks with plain messages (CLI11's own print the whole double range).
CLI::Validator Positive() {
  return CLI::Validator(
      [](std::string& in) -> std::string {
        double v = 0;
        if (!CLI::detail::lexical_cast(in, v) || !(v > 0) || !std::isfinite(v)) {
          return "must be a number > 0, not '" + in + "'";
        }
        return {};
      },
      "> 0");
}
CLI::Validator NonNegative() {
  return CLI::Validator(
      [](std::string& in) -> std::string {
        double v = 0;
        if (!CLI::detail::lexical_cast(in, v) || !(v >= 0) || !std::isfinite(v)) {
          return "must be a number >= 0, not '" + in + "'";
        }
        return {};
      },
      ">= 0");
}

// Frames done / total, points per second and time left, redrawn in place on stderr. Only when
// stderr is a terminal: redirected output gets no carriage-return noise.
class ProgressBar {
 public:
  explicit ProgressBar(uint64_t total)
      : enabled_(isatty(STDERR_FILENO) != 0), total_(total), start_(Clock::now()) {}
  ~ProgressBar() { Clear(); }
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  void Update(uint64_t done, uint64_t points) {
    if (!enabled_) return;
    double s = MsSince(start_) / 1e3;
    constexpr uint64_t kWidth = 24;
    uint64_t filled = total_ ? kWidth * std::min(done, total_) / total_ : kWidth;
    std::string bar(filled, '#');
    bar.append(kWidth - filled, '.');
    std::string eta = done > 0 ? Duration(s / static_cast<double>(done) *
                                          static_cast<double>(total_ - std::min(done, total_)))
                               : "?";
    std::string rate = s > 0 ? Human(static_cast<double>(points) / s) : "-";
    std::fprintf(stderr, "\r[%s] %llu/%llu frames  %s pts/s  ETA %s\033[K", bar.c_str(),
                 static_cast<unsigned long long>(done), static_cast<unsigned long long>(total_),
                 rate.c_str(), eta.c_str());
    std::fflush(stderr);
    drawn_ = true;
  }
  void Clear() {
    if (drawn_) std::fputs("\r\033[K", stderr);
    drawn_ = false;
  }

 private:
  bool enabled_;
  bool drawn_ = false;
  uint64_t total_;
  Clock::time_point start_;
};

// ---------------------------------------------------------------------------------------------
// Arguments, filled in by CLI11.

struct GlobalArgs {
  std::string data = "./data";
  size_t cache_mb = 256;
  std::string server;
  std::string token;
  std::string wire = "records";
  // To tell options given from defaults.
  CLI::Option *data_opt = nullptr, *cache_opt = nullptr, *token_opt = nullptr;
};

struct CreateArgs {
  std::string name;
  double fps = 0;
  double scale = 1.0;
  uint32_t frames = 0;
};

struct ImportArgs {
  std::string name;
  uint32_t frame = 0;
  std::vector<std::string> files;
  double units_scale = 1.0;
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

struct EditArgs {
  std::string name;
  std::vector<double> delete_box, label_box, box, translate;
  std::optional<uint32_t> set_label, clear_label;
  uint32_t where_label = 0;
  std::string paste;
  std::optional<uint32_t> paste_frame;
  double units_scale = 1.0;
  bool skip_invalid = false;
  bool json = false;
  // To apply the operations in command-line order.
  CLI::Option *delete_opt = nullptr, *label_opt = nullptr, *box_opt = nullptr,
              *translate_opt = nullptr, *paste_opt = nullptr;
};

struct UndoArgs {
  std::string name;
  uint64_t lsn = 0;
  bool json = false;
};

struct NameArgs {  // datasets, describe, stats, check
  std::string name;
  bool json = false;
};

struct PingArgs {
  unsigned count = 1;
  bool json = false;
};

// The region an editing command works in: a 4D box, or a hyperslice as `slice` takes it.
struct RegionArgs {
  std::vector<double> box, normal, clip_box;
  double offset = 0, thickness = 0;
  bool clip_frames = false;
  uint32_t max_frames = 0;
  CLI::Option *box_opt = nullptr, *normal_opt = nullptr;
  CLI::Option *offset_opt = nullptr, *thickness_opt = nullptr;
};

// The camera a lasso, marquee or brush is drawn through.
struct CameraArgs {
  std::string file;
  std::vector<double> look_at;
  std::vector<double> up{0, -1, 0};
  double fov = 0;
  std::vector<uint32_t> size;
  CLI::Option *file_opt = nullptr, *look_at_opt = nullptr;
};

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

struct CopyArgs {  // copy and cut
  std::string name;
  int bit = 0;
  std::string clipboard;
  RegionArgs region;
  bool json = false;
};

struct PasteArgs {
  std::string name;
  std::string clipboard;
  std::vector<double> translate, matrix;
  bool json = false;
};

struct CompositeArgs {
  std::string name;
  std::string ply;
  double units_scale = 1.0;
  bool skip_invalid = false;
  uint32_t first_frame = 0;
  uint32_t frames = 0;
  std::string trajectory;
  bool json = false;
};

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
  std::string mode = "visibility";
  bool view_dependent = false;
  std::vector<double> background;
  std::string renderer = "auto";
  std::string out;
  std::string path, out_dir;
  std::string format = "png";
  bool json = false;
  CLI::Option *dataset_camera_opt = nullptr, *size_opt = nullptr, *path_opt = nullptr;
};

// A --box X0 X1 Y0 Y1 Z0 Z1 T0 T1 as a Window; nullopt (after a usage message) if malformed.
std::optional<Window> BoxToWindow(const std::vector<double>& v, const std::string& command,
                                  const std::string& option, int* rc) {
  if (v.size() != 8) {
    *rc = Usage(command, option + " takes 8 numbers X0 X1 Y0 Y1 Z0 Z1 T0 T1 (given once)");
    return std::nullopt;
  }
  Window w;
  static constexpr const char* kAxes[] = {"X", "Y", "Z", "T"};
  for (size_t i = 0; i < 4; ++i) {
    w.lo[i] = v[2 * i];
    w.hi[i] = v[2 * i + 1];
    if (!(w.lo[i] <= w.hi[i])) {
      *rc = Usage(command, option + ": " + kAxes[i] + "0 must be <= " + kAxes[i] + "1 (got " +
                               Printf("%g > %g", w.lo[i], w.hi[i]) + ")");
      return std::nullopt;
    }
  }
  return w;
}

// A hyperslice from --normal/--offset/--thickness (and the frame bound and --clip-box); nullopt
// (after a usage message) if malformed.
std::optional<hvdb::Slice> MakeSlice(const std::vector<double>& normal, double offset,
                                     double thickness, bool clip_frames, uint32_t max_frames,
                                     const std::vector<double>& clip_box,
                                     const std::string& command, int* rc) {
  hvdb::Slice s;
  if (normal.size() != 4) {
    *rc = Usage(command, "--normal takes 4 numbers NX NY NZ NT");
    return std::nullopt;
  }
  bool nonzero = false;
  for (size_t i = 0; i < 4; ++i) {
    s.normal[i] = normal[i];
    if (!std::isfinite(normal[i])) {
      *rc = Usage(command, "--normal must be finite");
      return std::nullopt;
    }
    nonzero |= normal[i] != 0;
  }
  if (!nonzero) {
    *rc = Usage(command, "--normal must not be all zero");
    return std::nullopt;
  }
  s.offset = offset;
  s.thickness = thickness;
  s.on_too_many_frames =
      clip_frames ? hvdb::Slice::FrameBound::kClip : hvdb::Slice::FrameBound::kError;
  s.max_frames = max_frames;
  if (!clip_box.empty()) {
    s.clip = BoxToWindow(clip_box, command, "--clip-box", rc);
    if (!s.clip) return std::nullopt;
  }
  return s;
}

// --box or --normal/--offset/--thickness as the region of an editing command, shown in the
// help under `group`.
void AddRegionOptions(CLI::App* cmd, RegionArgs* r, const std::string& group) {
  r->box_opt =
      cmd->add_option("--box", r->box, "X0 X1 Y0 Y1 Z0 Z1 T0 T1: a 4D box (metres, seconds)")
          ->expected(8)
          ->group(group);
  r->normal_opt =
      cmd->add_option("--normal", r->normal,
                      "NX NY NZ NT: instead, the hyperslice |N . (x, y, z, s t) - B| <= DB, as "
                      "'hvdb slice' shows it (with --offset B --thickness DB)")
          ->expected(4)
          ->group(group);
  r->offset_opt =
      cmd->add_option("--offset", r->offset, "B of the slice")->needs(r->normal_opt)->group(group);
  r->thickness_opt = cmd->add_option("--thickness", r->thickness, "DB >= 0 of the slice")
                         ->check(NonNegative())
                         ->needs(r->normal_opt)
                         ->group(group);
  // --normal's own needs are checked in ParseRegion: CLI11 reports a missing one of several in
  // the order of their addresses, so the message would change from build to build.
  r->normal_opt->excludes(r->box_opt);
  cmd->add_flag("--clip-frames", r->clip_frames,
                "With --normal: use only the first frames when the slice spans too many (else "
                "error)")
      ->needs(r->normal_opt)
      ->group(group);
  cmd->add_option("--max-frames", r->max_frames,
                  "With --normal: bound on the frames the slice spans (default: the "
                  "database's, 64)")
      ->needs(r->normal_opt)
      ->group(group);
  cmd->add_option("--clip-box", r->clip_box, "With --normal: X0 X1 Y0 Y1 Z0 Z1 T0 T1 clipping it")
      ->expected(8)
      ->needs(r->normal_opt)
      ->group(group);
}

// The region given by AddRegionOptions' options into *out (nullopt: none given). False (after
// a usage message, exit status in *rc) if malformed.
bool ParseRegion(const RegionArgs& r, const std::string& command, std::optional<Region>* out,
                 int* rc) {
  out->reset();
  if (r.box_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(r.box, command, "--box", rc);
    if (!w) return false;
    *out = Region(*w);
  } else if (r.normal_opt->count() > 0) {
    if (r.offset_opt->count() == 0 || r.thickness_opt->count() == 0) {
      *rc = Usage(command, "--normal needs --offset B and --thickness DB");
      return false;
    }
    std::optional<hvdb::Slice> s = MakeSlice(r.normal, r.offset, r.thickness, r.clip_frames,
                                             r.max_frames, r.clip_box, command, rc);
    if (!s) return false;
    *out = Region(*s);
  }
  return true;
}

// A label bit option: 0..31.
CLI::Option* AddBit(CLI::App* cmd, const std::string& name, int* bit, const std::string& help) {
  return cmd->add_option(name, *bit, help)->check(CLI::Range(0, 31));
}

// A --clipboard name: the rules of dataset names (it is a file DIR/clipboards/NAME.hvc).
std::optional<int> CheckClipboardName(const std::string& name, const std::string& command) {
  if (ValidateDatasetName(name).ok()) return std::nullopt;
  return Usage(command, "--clipboard '" + name +
                            "': a clipboard name is 1-64 letters, digits, '_', '-' or '.', not "
                            "starting with '.'");
}

using Vec3 = std::array<double, 3>;

Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

double Norm(const Vec3& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }

// The pinhole camera of --look-at EX EY EZ TX TY TZ --fov DEG --size W H [--up UX UY UZ]:
// OpenCV axes (x right, y down, z forward), square pixels, the principal point at the image
// centre (pixel centres at integers), `fov` the vertical field of view. world_from_camera's
// columns are the camera's axes and centre in the world.
std::optional<CameraInfo> LookAtCamera(const CameraArgs& a, const std::string& command, int* rc) {
  if (a.look_at.size() != 6) {
    *rc = Usage(command, "--look-at takes 6 numbers EX EY EZ TX TY TZ (eye and target)");
    return std::nullopt;
  }
  if (a.size.size() != 2) {
    *rc = Usage(command, "--size takes 2 numbers W H (pixels)");
    return std::nullopt;
  }
  if (a.up.size() != 3) {
    *rc = Usage(command, "--up takes 3 numbers UX UY UZ");
    return std::nullopt;
  }
  for (double v : a.look_at) {
    if (!std::isfinite(v)) {
      *rc = Usage(command, "--look-at must be finite");
      return std::nullopt;
    }
  }
  const Vec3 eye{a.look_at[0], a.look_at[1], a.look_at[2]};
  Vec3 forward{a.look_at[3] - eye[0], a.look_at[4] - eye[1], a.look_at[5] - eye[2]};
  const Vec3 up{a.up[0], a.up[1], a.up[2]};
  double fn = Norm(forward);
  if (!(fn > 0)) {
    *rc = Usage(command, "--look-at: the eye and the target must differ");
    return std::nullopt;
  }
  for (double& v : forward) v /= fn;
  Vec3 right = Cross(forward, up);  // the image's x: up x forward is to the right
  double rn = Norm(right);
  if (!(rn > 1e-9 * Norm(up)) || !std::isfinite(rn)) {
    *rc = Usage(command, Printf("--up %g %g %g is parallel to the view direction (or zero): give "
                                "another --up",
                                up[0], up[1], up[2]));
    return std::nullopt;
  }
  for (double& v : right) v /= rn;
  const Vec3 down = Cross(forward, right);  // y: x (right) x y (down) = z (forward)
  CameraInfo c;
  c.width = a.size[0];
  c.height = a.size[1];
  const double kPi = 3.14159265358979323846;
  c.fx = c.fy = 0.5 * c.height / std::tan(a.fov * kPi / 360.0);
  c.cx = 0.5 * c.width - 0.5;
  c.cy = 0.5 * c.height - 0.5;
  c.world_from_camera = {right[0], down[0], forward[0], eye[0],  //
                         right[1], down[1], forward[1], eye[1],  //
                         right[2], down[2], forward[2], eye[2],  //
                         0,        0,       0,          1};
  return c;
}

// A camera file: {"fx", "fy", "cx", "cy", "width", "height", "world_from_camera": [16 values,
// row-major]}. Its problems are errors of the file (exit status 1), named with the file.
Result<CameraInfo> ReadCameraFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::IOError("cannot read camera file '" + path + "': " + std::strerror(errno));
  }
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  auto bad = [&path](const std::string& why) {
    return Status::InvalidArgument(
        "camera file '" + path + "': " + why +
        " (expected {\"fx\", \"fy\", \"cx\", \"cy\", \"width\", \"height\", "
        "\"world_from_camera\": [16 numbers, row-major]})");
  };
  if (!j.is_object()) return bad("not a JSON object");
  CameraInfo c;
  for (auto [key, field] : {std::pair<const char*, double*>{"fx", &c.fx},
                            {"fy", &c.fy},
                            {"cx", &c.cx},
                            {"cy", &c.cy}}) {
    auto it = j.find(key);
    if (it == j.end() || !it->is_number()) {
      return bad(std::string("\"") + key + "\" is not a number");
    }
    *field = it->get<double>();
    if (!std::isfinite(*field)) return bad(std::string("\"") + key + "\" is not finite");
  }
  if (!(c.fx > 0) || !(c.fy > 0)) return bad("fx and fy must be > 0");
  for (auto [key, field] :
       {std::pair<const char*, uint32_t*>{"width", &c.width}, {"height", &c.height}}) {
    auto it = j.find(key);
    if (it == j.end() || !it->is_number_unsigned() || it->get<uint64_t>() == 0 ||
        it->get<uint64_t>() > UINT32_MAX) {
      return bad(std::string("\"") + key + "\" is not a positive integer");
    }
    *field = it->get<uint32_t>();
  }
  auto m = j.find("world_from_camera");
  if (m == j.end() || !m->is_array() || m->size() != 16) {
    return bad("\"world_from_camera\" is not an array of 16 numbers");
  }
  for (size_t i = 0; i < 16; ++i) {
    if (!(*m)[i].is_number() || !std::isfinite((*m)[i].get<double>())) {
      return bad("\"world_from_camera\" is not an array of 16 finite numbers");
    }
    c.world_from_camera[i] = (*m)[i].get<double>();
  }
  const auto& w = c.world_from_camera;
  if (w[12] != 0 || w[13] != 0 || w[14] != 0 || w[15] != 1) {
    return bad("the last row of \"world_from_camera\" must be 0 0 0 1");
  }
  // The operators project with the transpose of the rotation: it must be one.
  for (size_t i = 0; i < 3; ++i) {
    for (size_t k = 0; k < 3; ++k) {
      double d = w[i] * w[k] + w[4 + i] * w[4 + k] + w[8 + i] * w[8 + k];
      if (std::abs(d - (i == k ? 1.0 : 0.0)) > 1e-4) {
        return bad("the rotation of \"world_from_camera\" is not orthonormal");
      }
    }
  }
  Vec3 c0{w[0], w[4], w[8]}, c1{w[1], w[5], w[9]}, c2{w[2], w[6], w[10]};
  Vec3 x = Cross(c0, c1);
  if (x[0] * c2[0] + x[1] * c2[1] + x[2] * c2[2] < 0) {
    return bad("\"world_from_camera\" is a reflection (x right, y down, z forward is a "
               "right-handed frame)");
  }
  return c;
}

// A trajectory file: one line 'dx,dy,dz' (metres) per frame; blank lines and lines starting
// with '#' are skipped.
Result<std::vector<std::array<double, 3>>> ReadTrajectory(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::IOError("cannot read trajectory file '" + path + "': " + std::strerror(errno));
  }
  std::vector<std::array<double, 3>> out;
  std::string line;
  for (size_t n = 1; std::getline(in, line); ++n) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    std::array<double, 3> d{};
    const char* p = line.c_str();
    bool ok = true;
    for (size_t i = 0; i < 3 && ok; ++i) {
      char* end = nullptr;
      d[i] = std::strtod(p, &end);
      ok = end != p && std::isfinite(d[i]);
      p = end;
      while (ok && (*p == ' ' || *p == '\t')) ++p;
      if (ok && i < 2) ok = *p++ == ',';
    }
    if (!ok || *p != '\0') {
      return Status::InvalidArgument(path + ":" + std::to_string(n) +
                                     ": expected 'dx,dy,dz' (metres), got '" + line + "'");
    }
    out.push_back(d);
  }
  if (in.bad()) return Status::IOError("cannot read trajectory file '" + path + "'");
  return out;
}

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

// "no clipboard 'c'" said with where clipboards live.
Status ExplainClipboard(Status s, const client::Backend& b) {
  if (!s.IsNotFound() || s.message().rfind("no clipboard", 0) != 0) return s;
  return Status(s.code(), s.message() + (b.remote() ? " on " : " in ") + b.where() +
                              " ('hvdb copy' and 'hvdb cut' fill clipboards)");
}

// ---------------------------------------------------------------------------------------------
// The commands. Each returns the exit status and prints its own errors.

class Cli {
 public:
  explicit Cli(CLI::App& app);
  int Run();

 private:
  // Picks the data directory or the server; nothing is opened or connected before the first
  // request, so usage errors are reported before touching a file or the network. Returns the
  // exit status of a usage error, or nullopt.
  std::optional<int> MakeBackend();
  client::Backend& db() { return *backend_; }

  int CmdDatasets();
  int CmdCreate();
  int CmdDescribe();
  int CmdImport();
  int CmdExport();
  int CmdWindow();
  int CmdSlice();
  int RunQuery(const Region& region, const QueryArgs& q, const std::string& command);
  int CmdEdit();
  int CmdUndo();
  int CmdRedo();
  int CmdSelect();
  int CmdGraphCut();
  int CmdCopy(const CopyArgs& a, bool cut);
  int CmdPaste();
  int CmdComposite();
  int CmdRender();
  int CmdStats();
  int CmdCheck();
  int CmdDrop();
  int CmdPing();

  CLI::App& app_;
  std::unique_ptr<client::Backend> backend_;
  GlobalArgs g_;
  CreateArgs create_;
  ImportArgs import_;
  ExportArgs export_;
  WindowArgs window_;
  SliceArgs slice_;
  EditArgs edit_;
  UndoArgs undo_, redo_;
  NameArgs datasets_, describe_, stats_, check_, drop_;
  PingArgs ping_;
  SelectArgs select_;
  GraphCutArgs graphcut_;
  CopyArgs copy_, cut_;
  PasteArgs paste_;
  CompositeArgs composite_;
  RenderArgs render_;
  CLI::App *datasets_cmd_, *create_cmd_, *describe_cmd_, *import_cmd_, *export_cmd_, *window_cmd_, *slice_cmd_,
      *edit_cmd_, *undo_cmd_, *redo_cmd_, *select_cmd_, *graphcut_cmd_, *copy_cmd_, *cut_cmd_,
      *paste_cmd_, *composite_cmd_, *render_cmd_, *stats_cmd_, *check_cmd_, *drop_cmd_, *ping_cmd_;
};

void AddQueryOptions(CLI::App* cmd, QueryArgs* q) {
  cmd->add_option("name", q->name, "Dataset")->required();
  cmd->add_option("--lod", q->lod,
                  "Finest level returned: 0 = full resolution, each level up about half the points")
      ->check(CLI::Range(0, 8));
  cmd->add_flag("--progressive", q->progressive, "Coarse levels first across all frames");
  cmd->add_option("--label-mask", q->label_mask,
                  "Only points with (label & MASK) != 0 (decimal or 0x hex)");
  cmd->add_option("--out", q->out, "Write the points to FILE.ply or FILE.csv, batch by batch");
  cmd->add_flag("--ascii", q->ascii, "With --out FILE.ply: ascii instead of binary");
  cmd->add_option("--codec", q->codec,
                  "With --out: raw (PLY/CSV), hvdb7 (docs/CODEC.md, every attribute) or draco "
                  "(positions, colours, ids, frames)")
      ->capture_default_str()
      ->check(CLI::IsMember({"raw", "hvdb7", "draco"}));
  cmd->add_option("--qp", q->qp, "With --codec hvdb7|draco: position bits over the extent")
      ->capture_default_str()
      ->check(CLI::Range(1, 30));
  cmd->add_flag("--json", q->json,
                "Print a JSON summary: points, frames read, per-level counts, elapsed ms");
}

Cli::Cli(CLI::App& app) : app_(app) {
  // At most one; none is reported by Run(), so that an unknown word is named as such.
  app.require_subcommand(0, 1);
  app.footer(
      "Positions are metres, times seconds (t = frame / fps). Each command has --help.\n"
      "Editing: select and graphcut mark points in label bits; copy, cut and paste move them\n"
      "through named clipboards; composite inserts an object; every change prints an lsn for\n"
      "undo (and redo). render draws a region through a camera into PNG or EXR images.\n"
      "With --server HOST:PORT every command but check runs on an hvdb-server instead of --data;\n"
      "a server that needs a token gets it from --token or the environment variable HVDB_TOKEN.\n"
      "Exit status: 0 success, 1 error (printed as 'hvdb: <status>'), 2 usage error.\n"
      "Example: hvdb create walk --fps 30 && hvdb import walk --frame 0 --units-scale 0.01 *.ply");
  app.fallthrough();  // global options may also follow the subcommand
  g_.data_opt = app.add_option("--data", g_.data, "Data directory")->capture_default_str();
  g_.cache_opt = app.add_option("--cache-mb", g_.cache_mb, "Block cache size in MiB (>= 8)")
                     ->capture_default_str()
                     ->check(CLI::Range(size_t{8}, size_t{1} << 30));
  app.add_option("--server", g_.server,
                 "HOST:PORT or unix:PATH of an hvdb-server to work on, instead of a data "
                 "directory (a server on this machine is reached through its Unix socket and "
                 "shared memory by itself)");
  app.add_option("--wire", g_.wire,
                 "With --server: how query results travel: records (default; shared memory on "
                 "this machine), columns, draco or hvdb7 (compressed, docs/CODEC.md)")
      ->capture_default_str()
      ->check(CLI::IsMember({"records", "columns", "draco", "hvdb7"}));
  g_.token_opt = app.add_option(
      "--token", g_.token,
      "Access token for --server (default: $HVDB_TOKEN; the environment keeps it out of ps)");
  app.failure_message([](const CLI::App* a, const CLI::Error& e) {
    auto subs = a->get_subcommands();
    std::string cmd = subs.empty() ? "hvdb" : "hvdb " + subs.front()->get_name();
    return "hvdb: " + std::string(e.what()) + "\nRun '" + cmd + " --help' for usage.\n";
  });

  datasets_cmd_ = app.add_subcommand("datasets", "List the datasets");
  datasets_cmd_->add_flag("--json", datasets_.json, "Print JSON");

  create_cmd_ = app.add_subcommand("create", "Create an empty dataset");
  create_cmd_->add_option("name", create_.name, "Dataset name: [A-Za-z0-9_.-], up to 64")
      ->required();
  create_cmd_->add_option("--fps", create_.fps, "Frames per second")->required()->check(Positive());
  create_cmd_
      ->add_option("--scale", create_.scale,
                   "Space/time scale s in m/s: slices are taken over (x, y, z, s t)")
      ->capture_default_str()
      ->check(Positive());
  create_cmd_->add_option("--frames", create_.frames, "Declared number of frames");

  describe_cmd_ = app.add_subcommand("describe", "Show a dataset's frame rate, extent and size");
  describe_cmd_->add_option("name", describe_.name, "Dataset")->required();
  describe_cmd_->add_flag("--json", describe_.json, "Print JSON");

  import_cmd_ = app.add_subcommand(
      "import", "Bulk-load PLY files into consecutive frames N, N+1, ... (replaces nothing)");
  import_cmd_->add_option("name", import_.name, "Dataset")->required();
  import_cmd_->add_option("files", import_.files, "PLY files, one frame each")->required();
  import_cmd_->add_option("--frame", import_.frame, "Frame of the first file")->required();
  import_cmd_
      ->add_option("--units-scale", import_.units_scale,
                   "Multiply positions by this (0.01: the files are in centimetres)")
      ->capture_default_str()
      ->check(Positive());
  import_cmd_
      ->add_option("--sigma", import_.sigma,
                   "Standard deviation in metres for points without a covariance")
      ->capture_default_str()
      ->check(NonNegative());
  import_cmd_->add_flag("--keep-ids", import_.keep_ids,
                        "Keep the files' point ids (default: the engine assigns new ones)");
  import_cmd_->add_flag("--skip-invalid", import_.skip_invalid, kSkipInvalidHelp);
  import_cmd_->add_flag("--json", import_.json, "Print a JSON summary");
  import_cmd_->footer("Files may be PLY, hvdb7 streams (hvdb export, hvdb-codec) or Draco files "
                      "(hvdb export --codec draco); temporal hvdb7 streams must follow the frame "
                      "they were coded against.");

  export_cmd_ = app.add_subcommand(
      "export", "Write frames as files DIR/NAME_FFFFFF.hv7 (or .drc, .ply), one per frame");
  export_cmd_->add_option("name", export_.name, "Dataset")->required();
  export_cmd_->add_option("dir", export_.dir, "Output directory (created if missing)")->required();
  export_cmd_->add_option("--codec", export_.codec, "hvdb7 (docs/CODEC.md), draco or raw (PLY)")
      ->capture_default_str()
      ->check(CLI::IsMember({"raw", "hvdb7", "draco"}));
  export_cmd_->add_option("--qp", export_.qp, "Position bits over each frame's extent")
      ->capture_default_str()
      ->check(CLI::Range(1, 30));
  export_cmd_->add_option("--qc", export_.qc, "hvdb7: colour bits (8: exact)")
      ->capture_default_str()
      ->check(CLI::Range(1, 8));
  export_cmd_->add_option("--qn", export_.qn, "hvdb7: normal bits (16: exact)")
      ->capture_default_str()
      ->check(CLI::Range(1, 16));
  export_cmd_->add_flag("--temporal", export_.temporal,
                        "hvdb7: code each frame against the previous one (import in order)");
  export_cmd_->add_option("--first", export_.first, "First frame")->capture_default_str();
  export_cmd_->add_option("--count", export_.count, "Frames (0: to the last)")->capture_default_str();

  window_cmd_ = app.add_subcommand("window", "Query a 4D box");
  AddQueryOptions(window_cmd_, &window_.q);
  window_cmd_->add_option("--box", window_.box, "X0 X1 Y0 Y1 Z0 Z1 T0 T1 (metres, seconds)")
      ->expected(8)
      ->required();

  slice_cmd_ = app.add_subcommand(
      "slice", "Query a hyperslice |N . (x, y, z, s t) - B| <= DB, projected to 3D");
  AddQueryOptions(slice_cmd_, &slice_.q);
  slice_cmd_->add_option("--normal", slice_.normal, "NX NY NZ NT (normalised; not all zero)")
      ->expected(4)
      ->required();
  slice_cmd_->add_option("--offset", slice_.offset, "B")->required();
  slice_cmd_->add_option("--thickness", slice_.thickness, "DB >= 0")
      ->required()
      ->check(NonNegative());
  slice_cmd_->add_flag("--clip-frames", slice_.clip_frames,
                       "Read only the first frames when the slice spans too many (else error)");
  slice_cmd_->add_option("--max-frames", slice_.max_frames,
                         "Bound on frames read (default: the database's, 64)");
  slice_cmd_->add_option("--clip-box", slice_.clip_box, "X0 X1 Y0 Y1 Z0 Z1 T0 T1: clip the slice")
      ->expected(8);

  edit_cmd_ = app.add_subcommand(
      "edit", "Apply edits as one atomic transaction, in command-line order; prints its lsn");
  edit_cmd_->add_option("name", edit_.name, "Dataset")->required();
  edit_.delete_opt =
      edit_cmd_->add_option("--delete-box", edit_.delete_box, "Delete the points in this box")
          ->expected(8);
  edit_.label_opt = edit_cmd_
                        ->add_option("--label-box", edit_.label_box,
                                     "Change the labels of the points in this box")
                        ->expected(8);
  edit_cmd_->add_option("--set-label", edit_.set_label, "With --label-box: set these bits")
      ->needs(edit_.label_opt);
  edit_cmd_->add_option("--clear-label", edit_.clear_label, "With --label-box: clear these bits")
      ->needs(edit_.label_opt);
  edit_.box_opt =
      edit_cmd_->add_option("--box", edit_.box, "Selection moved by --translate")->expected(8);
  edit_.translate_opt = edit_cmd_
                            ->add_option("--translate", edit_.translate,
                                         "DX DY DZ DT (metres, seconds): move the --box points")
                            ->expected(4)
                            ->needs(edit_.box_opt);
  edit_.box_opt->needs(edit_.translate_opt);
  edit_cmd_->add_option("--where-label", edit_.where_label,
                        "Boxes select only points with (label & MASK) != 0");
  edit_.paste_opt = edit_cmd_->add_option("--paste", edit_.paste, "Insert the points of FILE.ply");
  edit_cmd_->add_option("--frame", edit_.paste_frame, "With --paste: the frame to insert into")
      ->needs(edit_.paste_opt);
  edit_.paste_opt->needs("--frame");
  edit_cmd_->add_option("--units-scale", edit_.units_scale, "With --paste: position multiplier")
      ->check(Positive());
  edit_cmd_
      ->add_flag("--skip-invalid", edit_.skip_invalid,
                 std::string("With --paste: ") + kSkipInvalidHelp)
      ->needs(edit_.paste_opt);
  edit_cmd_->add_flag("--json", edit_.json, "Print JSON");

  undo_cmd_ = app.add_subcommand(
      "undo", "Revert a committed edit (commits its inverse); 'hvdb redo' undoes the undo");
  undo_cmd_->add_option("name", undo_.name, "Dataset")->required();
  undo_cmd_
      ->add_option("lsn", undo_.lsn,
                   "Sequence number printed by edit, select, graphcut, cut, paste or composite")
      ->required();
  undo_cmd_->add_flag("--json", undo_.json, "Print JSON");
  undo_cmd_->footer(
      "Undo goes through the transaction log: it reads transaction LSN's changes from the log and\n"
      "commits their inverse as a new transaction with its own lsn (printed), so the undo is\n"
      "itself atomic, durable and undoable: 'hvdb redo NAME UNDO_LSN' re-applies the edit.\n"
      "An edit is refused if a later transaction changed the same points: undo that one first.");

  redo_cmd_ = app.add_subcommand(
      "redo", "Re-apply an undone edit: reverts the undo whose lsn 'hvdb undo' printed");
  redo_cmd_->add_option("name", redo_.name, "Dataset")->required();
  redo_cmd_->add_option("lsn", redo_.lsn, "Sequence number of the undo (as printed by undo)")
      ->required();
  redo_cmd_->add_flag("--json", redo_.json, "Print JSON");
  redo_cmd_->footer(
      "Undo and redo go through the transaction log: 'hvdb undo NAME LSN' commits the inverse of\n"
      "transaction LSN as a new transaction U; 'hvdb redo NAME U' commits the inverse of U, which\n"
      "is the original edit again, as a further transaction R (printed). Nothing is rewritten or\n"
      "forgotten: the log keeps every step, each one atomic and durable, and 'hvdb undo NAME R'\n"
      "undoes the redo. Example:\n"
      "  hvdb cut walk --bit 0 --clipboard man   # committed lsn 7\n"
      "  hvdb undo walk 7                        # committed lsn 8: the points are back\n"
      "  hvdb redo walk 8                        # committed lsn 9: cut again");

  select_cmd_ = app.add_subcommand(
      "select",
      "Select points into label bit B: those of a region (--box or --normal/--offset/--thickness),"
      " or only those under a lasso, marquee or 3D brush seen through a camera");
  select_cmd_->add_option("name", select_.name, "Dataset")->required();
  AddBit(select_cmd_, "--bit", &select_.bit, "Label bit 0..31 that holds the selection")
      ->required();
  select_cmd_
      ->add_option("--mode", select_.mode,
                   "How the new set combines with the points already carrying the bit: "
                   "replace, add, subtract or intersect")
      ->capture_default_str()
      ->check(CLI::IsMember({"replace", "add", "subtract", "intersect"}));
  AddRegionOptions(select_cmd_, &select_.region,
                   "Region (required): what is viewed; nothing outside it is selected");
  const std::string shape = "Shape (optional; without one the whole region is selected)";
  select_.lasso_opt =
      select_cmd_
          ->add_option("--lasso", select_.lasso,
                       "U0 V0 U1 V1 U2 V2 ...: the region's points projecting inside this polygon "
                       "(pixels, >= 3 vertices)")
          ->group(shape);
  select_.rect_opt = select_cmd_
                         ->add_option("--rect", select_.rect,
                                      "U0 V0 U1 V1: a marquee, the rectangle between these corners "
                                      "(pixels)")
                         ->expected(4)
                         ->group(shape);
  select_.brush_opt =
      select_cmd_
          ->add_option("--brush", select_.brush,
                       "U V: the 3D paintbrush, a sphere of --radius metres around the surface "
                       "under pixel (U, V)")
          ->expected(2)
          ->group(shape);
  select_.lasso_opt->excludes(select_.rect_opt)->excludes(select_.brush_opt);
  select_.rect_opt->excludes(select_.brush_opt);
  select_cmd_
      ->add_option("--pixel-radius", select_.pixel_radius,
                   "With --brush: the surface depth is taken from the points within R pixels")
      ->capture_default_str()
      ->check(Positive())
      ->needs(select_.brush_opt)
      ->group(shape);
  select_cmd_->add_option("--radius", select_.radius, "With --brush: the brush's radius in metres")
      ->capture_default_str()
      ->check(Positive())
      ->needs(select_.brush_opt)
      ->group(shape);
  select_cmd_
      ->add_flag("--nearest", select_.nearest,
                 "With --brush: the nearest depth under the brush (default: the median)")
      ->needs(select_.brush_opt)
      ->group(shape);
  const std::string camera = "Camera (for --lasso, --rect and --brush)";
  CameraArgs& ca = select_.camera;
  ca.file_opt = select_cmd_
                    ->add_option("--camera", ca.file,
                                 "FILE.json: {\"fx\", \"fy\", \"cx\", \"cy\", \"width\", "
                                 "\"height\", \"world_from_camera\": [16 numbers, row-major]} "
                                 "(pinhole; x right, y down, z forward)")
                    ->group(camera);
  ca.look_at_opt = select_cmd_
                       ->add_option("--look-at", ca.look_at,
                                    "EX EY EZ TX TY TZ: a pinhole camera at the eye looking at "
                                    "the target (needs --fov and --size)")
                       ->expected(6)
                       ->excludes(ca.file_opt)
                       ->group(camera);
  CLI::Option* fov = select_cmd_
                         ->add_option("--fov", ca.fov,
                                      "With --look-at: vertical field of view in degrees")
                         ->check(CLI::Range(0.001, 179.0))
                         ->needs(ca.look_at_opt)
                         ->group(camera);
  CLI::Option* size = select_cmd_
                          ->add_option("--size", ca.size,
                                       "With --look-at: image width and height W H in pixels")
                          ->expected(2)
                          ->check(CLI::Range(1u, 100000u))
                          ->needs(ca.look_at_opt)
                          ->group(camera);
  select_cmd_
      ->add_option("--up", ca.up, "With --look-at: the world direction shown upwards in the image")
      ->expected(3)
      ->capture_default_str()
      ->needs(ca.look_at_opt)
      ->group(camera);
  ca.look_at_opt->needs(fov)->needs(size);
  select_cmd_->add_flag("--json", select_.json, "Print JSON");
  select_cmd_->footer(
      "Prints the points the shape matched, those carrying the bit afterwards and the lsn of the\n"
      "change (0: nothing changed), plus the brush's centre. Positions are those the viewer sees:\n"
      "projected ones for a slice. Undo with 'hvdb undo NAME LSN'. Example (a marquee):\n"
      "  hvdb select walk --bit 1 --box -2 2 -2 2 -2 2 0 0.1 --rect 290 100 350 200 \\\n"
      "      --look-at -0.3 -0.9 -3 -0.3 -0.9 0 --fov 50 --size 640 480");

  graphcut_cmd_ = app.add_subcommand(
      "graphcut",
      "4D graph-cut object selection: from foreground and background strokes (label bits, e.g. "
      "made with select) to the whole object inside a region of interest");
  graphcut_cmd_->add_option("name", graphcut_.name, "Dataset")->required();
  AddBit(graphcut_cmd_, "--fg-bit", &graphcut_.fg_bit, "Label bit of the foreground strokes")
      ->required();
  AddBit(graphcut_cmd_, "--bg-bit", &graphcut_.bg_bit, "Label bit of the background strokes")
      ->required();
  AddBit(graphcut_cmd_, "--out-bit", &graphcut_.out_bit,
         "Label bit that receives the selection (set inside it, cleared elsewhere in the ROI)")
      ->required();
  AddRegionOptions(graphcut_cmd_, &graphcut_.roi,
                   "Region of interest (required): the points the cut decides on");
  graphcut_cmd_
      ->add_option("--k", graphcut_.k, "Intra-frame neighbours per point (inter-frame: k / 2)")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  graphcut_cmd_
      ->add_option("--intra-radius", graphcut_.intra_radius,
                   "Neighbours within a frame are at most this far (metres)")
      ->capture_default_str()
      ->check(Positive());
  graphcut_cmd_
      ->add_option("--inter-radius", graphcut_.inter_radius,
                   "Neighbours in the next frame are at most this far (metres)")
      ->capture_default_str()
      ->check(Positive());
  graphcut_cmd_->add_flag("--colour-only", graphcut_.colour_only,
                          "Link costs from colours only (default: colours and normals)");
  graphcut_cmd_->add_flag("--json", graphcut_.json, "Print JSON");
  graphcut_cmd_->footer(
      "Prints the ROI's points, those selected, the energy, the intra- and inter-frame edge\n"
      "counts, the time of each step (load, neighbours, GMM, graph, max-flow, commit) and the\n"
      "lsn. The radii should exceed the sampling distance of the points.");

  for (auto [cmd, args, cut] : {std::tuple<CLI::App**, CopyArgs*, bool>{&copy_cmd_, &copy_, false},
                                {&cut_cmd_, &cut_, true}}) {
    *cmd = app.add_subcommand(
        cut ? "cut" : "copy",
        cut ? "Move the points carrying label bit B (in a region, if given) to a named "
              "clipboard: copies them, then deletes them in one transaction"
            : "Copy the points carrying label bit B (in a region, if given) to a named clipboard");
    (*cmd)->add_option("name", args->name, "Dataset")->required();
    AddBit(*cmd, "--bit", &args->bit, "Label bit of the points (e.g. set by select or graphcut)")
        ->required();
    (*cmd)
        ->add_option("--clipboard", args->clipboard,
                     "Clipboard name (letters, digits, '_', '-', '.'); replaced if it exists")
        ->required();
    AddRegionOptions(*cmd, &args->region,
                     "Region (optional): only the points in it (default: all frames)");
    (*cmd)->add_flag("--json", args->json, "Print JSON");
    (*cmd)->footer(
        "Clipboards are files DIR/clipboards/NAME.hvc of the data directory: the embedded CLI on\n"
        "--data DIR and hvdb-server --data DIR share them, and they outlive the session. 'hvdb\n"
        "paste' inserts a clipboard's points." +
        std::string(cut ? "\nPrints the lsn of the deletion: 'hvdb undo NAME LSN' puts the points "
                          "back."
                        : ""));
  }

  paste_cmd_ = app.add_subcommand(
      "paste", "Insert a clipboard's points as new points, moved by --matrix and --translate");
  paste_cmd_->add_option("name", paste_.name, "Dataset")->required();
  paste_cmd_->add_option("--clipboard", paste_.clipboard, "Clipboard name (see copy, cut)")
      ->required();
  paste_cmd_
      ->add_option("--translate", paste_.translate,
                   "DX DY DZ DT: add this (metres, seconds; DT moves them to later frames)")
      ->expected(4);
  paste_cmd_
      ->add_option("--matrix", paste_.matrix,
                   "16 numbers: a row-major 4x4 matrix over (x, y, z, t) applied before "
                   "--translate (default: identity)")
      ->expected(16);
  paste_cmd_->add_flag("--json", paste_.json, "Print JSON");
  paste_cmd_->footer(
      "Each point (x, y, z, t) becomes MATRIX (x, y, z, t) + (DX, DY, DZ, DT); its frame follows\n"
      "the new t. Prints the lsn: 'hvdb undo NAME LSN' removes the pasted points again.");

  composite_cmd_ = app.add_subcommand(
      "composite",
      "Insert an object (a PLY point cloud) into consecutive frames, still or along a trajectory");
  composite_cmd_->add_option("name", composite_.name, "Dataset")->required();
  composite_cmd_->add_option("--ply", composite_.ply, "FILE.ply: the object")->required();
  composite_cmd_
      ->add_option("--units-scale", composite_.units_scale,
                   "Multiply the object's positions by this (0.01: the file is in centimetres)")
      ->capture_default_str()
      ->check(Positive());
  composite_cmd_->add_option("--first-frame", composite_.first_frame, "First frame F")->required();
  composite_cmd_->add_option("--frames", composite_.frames, "Number of frames N (> 0)")
      ->required()
      ->check(CLI::Range(1u, UINT32_MAX));
  composite_cmd_->add_option(
      "--trajectory", composite_.trajectory,
      "FILE.csv: one line 'dx,dy,dz' (metres) per frame, offsetting the object in frame F + i "
      "(default: it stays put)");
  composite_cmd_->add_flag("--skip-invalid", composite_.skip_invalid, kSkipInvalidHelp);
  composite_cmd_->add_flag("--json", composite_.json, "Print JSON");
  composite_cmd_->footer(
      "All frames are inserted in one transaction; prints its lsn ('hvdb undo NAME LSN' removes\n"
      "the object again). Blank lines and lines starting with '#' in the trajectory are skipped.");

  render_cmd_ = app.add_subcommand(
      "render",
      "Render a region's points through a camera into an image (EWA splatting), or a camera "
      "path over frames into a sequence of images");
  RenderArgs& ra = render_;
  render_cmd_->add_option("name", ra.name, "Dataset")->required();
  AddRegionOptions(render_cmd_, &ra.region,
                   "Region (required, unless every entry of the --path file has a frame)");
  render_cmd_
      ->add_option("--lod", ra.lod,
                   "Level of detail: 0 = full resolution; each level up about half the points, "
                   "drawn as splats 2^(1/2) larger")
      ->capture_default_str()
      ->check(CLI::Range(0, 16));
  render_cmd_->add_option("--label-mask", ra.label_mask,
                          "Only points with (label & MASK) != 0 (decimal or 0x hex)");
  render_cmd_->add_flag("--texture", ra.texture,
                        "colour from the frame's stored photos over the points' depth (thesis "
                        "6.3): sharper than the points, one view of one frame");
  render_cmd_->add_flag("--billboards", ra.billboards,
                        "draw the frame's billboards (hvdb-ingest run --filter billboard) instead "
                        "of its points: one view-dependent depth per pixel, colour from the "
                        "photos (thesis 6.3); one view of one frame");
  render_cmd_->add_option("--highlight", ra.highlight,
                          "Show a selection: points carrying label BIT (repeatable) drawn in "
                          "their colour blended toward --highlight-color")
      ->check(CLI::Range(0, 31));
  render_cmd_->add_option("--highlight-color", ra.highlight_color,
                          "R G B A in [0, 1] (sRGB; A: how much of it), default 1 0.45 0 0.5")
      ->expected(4)
      ->check(CLI::Range(0.f, 1.f));
  const std::string rcamera = "Camera (one is required, unless --path gives them)";
  CameraArgs& rc = ra.camera;
  rc.look_at_opt = render_cmd_
                       ->add_option("--look-at", rc.look_at,
                                    "EX EY EZ TX TY TZ: a pinhole camera at the eye looking at "
                                    "the target (needs --fov)")
                       ->expected(6)
                       ->group(rcamera);
  CLI::Option* rfov =
      render_cmd_->add_option("--fov", rc.fov, "With --look-at: vertical field of view in degrees")
          ->check(CLI::Range(0.001, 179.0))
          ->needs(rc.look_at_opt)
          ->group(rcamera);
  rc.look_at_opt->needs(rfov);
  render_cmd_
      ->add_option("--up", rc.up,
                   "With --look-at: the world direction shown upwards in the image (y points "
                   "down in Panoptic data)")
      ->expected(3)
      ->capture_default_str()
      ->needs(rc.look_at_opt)
      ->group(rcamera);
  rc.file_opt = render_cmd_
                    ->add_option("--camera", rc.file,
                                 "FILE.json: {\"fx\", \"fy\", \"cx\", \"cy\", \"width\", "
                                 "\"height\", \"world_from_camera\": [16 numbers, row-major]} "
                                 "(pinhole; x right, y down, z forward)")
                    ->excludes(rc.look_at_opt)
                    ->group(rcamera);
  ra.dataset_camera_opt =
      render_cmd_
          ->add_option("--dataset-camera", ra.dataset_camera,
                       "ID: one of the dataset's own cameras ('hvdb describe NAME --json' lists "
                       "them)")
          ->excludes(rc.look_at_opt)
          ->excludes(rc.file_opt)
          ->group(rcamera);
  ra.size_opt = render_cmd_
                    ->add_option("--size", rc.size,
                                 "W H: image size in pixels (with --look-at: default 640 480; "
                                 "else the camera is scaled to it)")
                    ->expected(2)
                    ->check(CLI::Range(1u, render::kMaxImageSize))
                    ->group(rcamera);
  const std::string look = "Appearance";
  render_cmd_
      ->add_option("--mode", ra.mode,
                   "visibility (fuzzy depth test, blending: thesis fig. 5.2) or probabilistic "
                   "(front to back until opaque: 5.4.1)")
      ->capture_default_str()
      ->check(CLI::IsMember({"visibility", "probabilistic"}))
      ->group(look);
  render_cmd_
      ->add_flag("--view-dependent", ra.view_dependent,
                 "Weight each point by how close its source camera is to the view (needs a "
                 "dataset with cameras)")
      ->group(look);
  render_cmd_
      ->add_option("--background", ra.background,
                   "R G B in 0..1: the colour of empty pixels, as it appears in the PNG "
                   "(default black)")
      ->expected(3)
      ->check(CLI::Range(0.0, 1.0))
      ->group(look);
  render_cmd_
      ->add_option("--renderer", ra.renderer,
                   "egl (OpenGL through headless EGL: the GPU, or Mesa's llvmpipe), cpu, or auto "
                   "(egl where a context can be made, else cpu with a warning)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "egl", "cpu"}))
      ->group(look);
  const std::string output = "Output (--out, or --path with --out-dir)";
  CLI::Option* out =
      render_cmd_
          ->add_option("--out", ra.out, "FILE.png (8-bit sRGB) or FILE.exr (float RGBA and Z)")
          ->group(output);
  ra.path_opt = render_cmd_
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
  CLI::Option* out_dir =
      render_cmd_
          ->add_option("--out-dir", ra.out_dir,
                       "With --path: the directory for frame_0000.png, frame_0001.png, ... "
                       "(made if missing)")
          ->needs(ra.path_opt)
          ->group(output);
  ra.path_opt->needs(out_dir);
  render_cmd_->add_option("--format", ra.format, "With --path: png or exr")
      ->capture_default_str()
      ->check(CLI::IsMember({"png", "exr"}))
      ->needs(ra.path_opt)
      ->group(output);
  render_cmd_->add_flag("--json", ra.json, "Print JSON");
  render_cmd_->footer(
      "Prints the renderer used, the points drawn and the time, per image. The same request runs\n"
      "in this process on --data DIR or in hvdb-server with --server: the images are the same.\n"
      "Example, frame 5 of the demo dataset (29.97 fps) seen from 3 m in front:\n"
      "  hvdb render panoptic --box -10 10 -10 10 -10 10 0.15 0.18 \\\n"
      "      --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 --size 640 480 --out demo.png\n"
      "A sequence: hvdb render panoptic --path cameras.json --out-dir frames/");

  stats_cmd_ = app.add_subcommand("stats", "Storage and cache statistics");
  stats_cmd_->add_option("name", stats_.name, "Dataset (default: all)");
  stats_cmd_->add_flag("--json", stats_.json, "Print JSON");

  check_cmd_ = app.add_subcommand("check",
                                  "Verify checksums and tree invariants; exit status 1 if a "
                                  "problem is found (data directory only, not --server)");
  check_cmd_->add_option("name", check_.name, "Dataset (default: all)");
  check_cmd_->add_flag("--json", check_.json, "Print JSON");

  drop_cmd_ = app.add_subcommand("drop", "Delete a dataset and all its data");
  drop_cmd_->add_option("name", drop_.name, "Dataset")->required();

  ping_cmd_ = app.add_subcommand("ping", "Measure the round trip to the --server");
  ping_cmd_->add_option("--count", ping_.count, "Number of pings")
      ->capture_default_str()
      ->check(CLI::Range(1u, 100000u));
  ping_cmd_->add_flag("--json", ping_.json, "Print JSON");
}

std::optional<int> Cli::MakeBackend() {
  if (g_.server.empty()) {
    if (g_.token_opt->count() > 0) return Usage("", "--token is for --server HOST:PORT");
    if (g_.wire != "records") return Usage("", "--wire is for --server HOST:PORT");
    backend_ = client::MakeEmbeddedBackend(g_.data, g_.cache_mb << 20);
    return std::nullopt;
  }
  if (g_.data_opt->count() > 0) {
    return Usage("", "give --data DIR or --server HOST:PORT, not both");
  }
  if (g_.cache_opt->count() > 0) {
    return Usage("", "--cache-mb sizes the cache of a data directory; with --server the "
                     "server's own applies (hvdb-server --cache-mb)");
  }
  client::RemoteOptions ro;
  ro.address = g_.server;
  ro.token = g_.token;
  ro.wire = g_.wire;
  if (ro.token.empty()) {
    if (const char* env = std::getenv("HVDB_TOKEN")) ro.token = env;
  }
  Result<std::unique_ptr<client::Backend>> b = client::MakeRemoteBackend(ro);
  if (!b.ok()) return Usage("", b.status().message());
  backend_ = std::move(b).value();
  return std::nullopt;
}

int Cli::Run() {
  if (app_.get_subcommands().empty()) {
    return Usage("",
                 "a command is required: datasets, create, describe, import, export, window, slice, "
                 "edit, undo, redo, select, graphcut, copy, cut, paste, composite, render, "
                 "stats, check, drop or ping");
  }
  if (std::optional<int> rc = MakeBackend()) return *rc;
  if (datasets_cmd_->parsed()) return CmdDatasets();
  if (create_cmd_->parsed()) return CmdCreate();
  if (describe_cmd_->parsed()) return CmdDescribe();
  if (import_cmd_->parsed()) return CmdImport();
  if (export_cmd_->parsed()) return CmdExport();
  if (window_cmd_->parsed()) return CmdWindow();
  if (slice_cmd_->parsed()) return CmdSlice();
  if (edit_cmd_->parsed()) return CmdEdit();
  if (undo_cmd_->parsed()) return CmdUndo();
  if (redo_cmd_->parsed()) return CmdRedo();
  if (select_cmd_->parsed()) return CmdSelect();
  if (graphcut_cmd_->parsed()) return CmdGraphCut();
  if (copy_cmd_->parsed()) return CmdCopy(copy_, /*cut=*/false);
  if (cut_cmd_->parsed()) return CmdCopy(cut_, /*cut=*/true);
  if (paste_cmd_->parsed()) return CmdPaste();
  if (composite_cmd_->parsed()) return CmdComposite();
  if (render_cmd_->parsed()) return CmdRender();
  if (stats_cmd_->parsed()) return CmdStats();
  if (check_cmd_->parsed()) return CmdCheck();
  if (drop_cmd_->parsed()) return CmdDrop();
  if (ping_cmd_->parsed()) return CmdPing();
  return Usage("", "unknown command");
}

int Cli::CmdDatasets() {
  Result<std::vector<std::string>> names = db().ListDatasets();
  if (!names.ok()) return Fail(names.status());
  json list = json::array();
  if (!datasets_.json && !names->empty()) {
    std::printf("%-24s %10s %14s %10s\n", "name", "frames", "points", "fps");
  }
  for (const std::string& name : *names) {
    Result<DatasetInfo> got = db().Describe(name);
    if (!got.ok()) return Fail(got.status());
    const DatasetInfo& info = *got;
    if (datasets_.json) {
      list.push_back({{"name", name},
                      {"frames", info.frame_count},
                      {"points", info.point_count},
                      {"fps", info.fps}});
    } else {
      std::printf("%-24s %10u %14llu %10g\n", name.c_str(), info.frame_count,
                  static_cast<unsigned long long>(info.point_count), info.fps);
    }
  }
  if (datasets_.json) PrintJson(list);
  return kExitOk;
}

int Cli::CmdCreate() {
  DatasetInfo want;
  want.name = create_.name;
  want.fps = create_.fps;
  want.space_time_scale = create_.scale;
  want.frame_count = create_.frames;
  Result<DatasetInfo> info = db().CreateDataset(want);
  if (!info.ok()) return Fail(info.status());
  std::printf("created dataset '%s' (%g fps, space-time scale %g m/s)\n", info->name.c_str(),
              info->fps, info->space_time_scale);
  return kExitOk;
}

int Cli::CmdDescribe() {
  Result<DatasetInfo> got = db().Describe(describe_.name);
  if (!got.ok()) return Fail(got.status());
  const DatasetInfo& info = *got;
  double duration = info.fps > 0 ? info.frame_count / info.fps : 0;
  if (describe_.json) {
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
               {"cameras", cams}});
    return kExitOk;
  }
  std::printf("dataset   %s\n", info.name.c_str());
  std::printf("fps       %g\n", info.fps);
  std::printf("scale     %g m/s (space-time)\n", info.space_time_scale);
  std::printf("frames    %u (%.3f s)\n", info.frame_count, duration);
  std::printf("points    %llu\n", static_cast<unsigned long long>(info.point_count));
  std::printf("bounds    x %.3f .. %.3f  y %.3f .. %.3f  z %.3f .. %.3f m\n", info.bounds_min[0],
              info.bounds_max[0], info.bounds_min[1], info.bounds_max[1], info.bounds_min[2],
              info.bounds_max[2]);
  std::printf("cameras   %zu\n", info.cameras.size());
  std::printf("last lsn  %llu\n", static_cast<unsigned long long>(info.last_lsn));
  return kExitOk;
}

// A frame from an hvdb7 stream (hvdb export), placed as a PLY file would be: scaled, at the
// import's frame, ids kept only on request (by the caller). *reference holds the stream's
// decoded points afterwards, for the next file if it was coded temporally.
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

// Reads a PLY file for import, edit --paste or composite; points left out by ro.skip_invalid
// are said on stderr (after bar's line is cleared), so none goes missing unnoticed.
Result<std::vector<Point>> ReadPlyNoting(const std::string& path, const formats::ReadOptions& ro,
                                         uint64_t* skipped = nullptr, ProgressBar* bar = nullptr) {
  formats::ReadStats stats;
  Result<std::vector<Point>> pts = formats::ReadPly(path, ro, &stats);
  if (pts.ok() && stats.skipped_non_finite > 0) {
    if (bar) bar->Clear();
    std::fprintf(stderr, "hvdb: skipped %llu point%s with a NaN or infinite coordinate in %s\n",
                 static_cast<unsigned long long>(stats.skipped_non_finite),
                 stats.skipped_non_finite == 1 ? "" : "s", path.c_str());
  }
  if (skipped) *skipped = stats.skipped_non_finite;
  return pts;
}

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

int Cli::CmdExport() {
  const ExportArgs& a = export_;
  client::ExportOptions o;
  Status st = formats::ParseFileCodec(a.codec, &o.codec);
  if (!st.ok()) return Usage("export", st.message());
  if (a.temporal && o.codec != formats::FileCodec::kHvdb7) {
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
      client::ExportFrames(db(), a.name, a.dir, o, [&](size_t done, size_t total) {
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

int Cli::CmdImport() {
  const ImportArgs& a = import_;
  if (a.files.size() - 1 > UINT32_MAX - uint64_t{a.frame}) {
    return Usage("import", "--frame " + std::to_string(a.frame) + " plus " +
                               std::to_string(a.files.size()) + " files passes frame 2^32-1");
  }
  // An unknown dataset is reported before any file is read.
  Result<DatasetInfo> info = db().Describe(a.name);
  if (!info.ok()) return Fail(info.status());
  Clock::time_point start = Clock::now();
  ProgressBar bar(a.files.size());
  uint64_t total = 0, skipped_total = 0;
  json frames = json::array();
  codec::Reference reference;  // the previous decoded stream, for temporal ones
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
    Result<std::vector<Point>> pts =
        formats::IsHvdb7File(a.files[i])   ? ReadStreamFrame(a.files[i], ro, &reference)
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
    Result<uint64_t> loaded = db().BulkLoad(a.name, ro.frame, std::move(pts).value());
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

int Cli::CmdWindow() {
  int rc = kExitOk;
  std::optional<hvdb::Window> w = BoxToWindow(window_.box, "window", "--box", &rc);
  if (!w) return rc;
  return RunQuery(Region(*w), window_.q, "window");
}

int Cli::CmdSlice() {
  const SliceArgs& a = slice_;
  int rc = kExitOk;
  std::optional<hvdb::Slice> s = MakeSlice(a.normal, a.offset, a.thickness, a.clip_frames,
                                           a.max_frames, a.clip_box, "slice", &rc);
  if (!s) return rc;
  return RunQuery(Region(*s), a.q, "slice");
}

int Cli::RunQuery(const Region& region, const QueryArgs& q, const std::string& command) {
  Clock::time_point start = Clock::now();
  std::unique_ptr<formats::PointWriter> writer;
  if (q.codec != "raw" && q.out.empty()) return Usage(command, "--codec needs --out FILE");
  if (!q.out.empty()) {
    formats::FileCodec fc = formats::FileCodec::kRaw;
    codec::EncodeOptions eo;
    eo.qp = q.qp;
    eo.qn = 12;
    eo.attributes = codec::kAllAttributes;
    eo.progressive = true;
    Status parsed = formats::ParseFileCodec(q.codec, &fc);
    if (!parsed.ok()) return Usage(command, parsed.message());
    Result<std::unique_ptr<formats::PointWriter>> w =
        fc == formats::FileCodec::kRaw ? formats::OpenPointWriter(q.out, q.ascii)
                                      : formats::OpenCompressedWriter(q.out, fc, eo);
    if (!w.ok()) return Fail(w.status());
    writer = std::move(w).value();
  }
  QueryOptions opts;
  opts.lod = q.lod;
  opts.progressive = q.progressive;
  opts.label_mask = q.label_mask;
  Result<std::unique_ptr<client::QueryResults>> cursor = db().Query(q.name, region, opts);
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
      if (writer) {
        Status s = writer->Append(batch.points);
        if (!s.ok()) return Fail(s);
      }
    }
    if (!*more) break;
  }
  if (writer) {
    Status s = writer->Finish();
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
    if (writer) j["out"] = q.out;
    PrintJson(j);
    return kExitOk;
  }
  std::printf("%llu points from %zu frame%s in %.1f ms%s\n", static_cast<unsigned long long>(total),
              frames.size(), frames.size() == 1 ? "" : "s", ms,
              (*cursor)->clipped() ? " (slice clipped to the frame bound)" : "");
  for (const auto& [level, n] : per_level) {
    std::printf("  level %d: %llu\n", level, static_cast<unsigned long long>(n));
  }
  if (writer) std::printf("written to %s\n", q.out.c_str());
  return kExitOk;
}

int Cli::CmdEdit() {
  const EditArgs& a = edit_;
  // Each operation, keyed by where its first option appears on the command line.
  std::vector<std::pair<size_t, Transaction::Op>> ops;
  const std::vector<CLI::Option*>& order = edit_cmd_->parse_order();
  auto position = [&order](std::initializer_list<const CLI::Option*> opts) {
    for (size_t i = 0; i < order.size(); ++i) {
      if (std::find(opts.begin(), opts.end(), order[i]) != opts.end()) return i;
    }
    return order.size();
  };
  auto select = [&a](const hvdb::Window& w) {
    Selection sel;
    sel.region = w;
    sel.label_mask = a.where_label;
    return sel;
  };
  int rc = kExitOk;
  if (a.delete_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.delete_box, "edit", "--delete-box", &rc);
    if (!w) return rc;
    ops.emplace_back(position({a.delete_opt}), Transaction::DeleteSelOp{select(*w)});
  }
  if (a.label_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.label_box, "edit", "--label-box", &rc);
    if (!w) return rc;
    if (!a.set_label && !a.clear_label) {
      return Usage("edit", "--label-box needs --set-label BITS or --clear-label BITS");
    }
    size_t pos = position({a.label_opt});
    if (a.set_label) ops.emplace_back(pos, Transaction::LabelOp{select(*w), *a.set_label, true});
    if (a.clear_label) {
      ops.emplace_back(pos, Transaction::LabelOp{select(*w), *a.clear_label, false});
    }
  }
  if (a.translate_opt->count() > 0) {
    std::optional<hvdb::Window> w = BoxToWindow(a.box, "edit", "--box", &rc);
    if (!w) return rc;
    if (a.translate.size() != 4) return Usage("edit", "--translate takes 4 numbers DX DY DZ DT");
    Affine4 map;
    for (int i = 0; i < 4; ++i) map.c[i] = a.translate[i];
    ops.emplace_back(position({a.box_opt, a.translate_opt}),
                     Transaction::TransformOp{select(*w), map});
  }
  if (a.paste_opt->count() > 0) {
    formats::ReadOptions ro;
    ro.scale = a.units_scale;
    ro.frame = *a.paste_frame;
    ro.force_frame = true;
    ro.skip_invalid = a.skip_invalid;
    Result<std::vector<Point>> pts = ReadPlyNoting(a.paste, ro);
    if (!pts.ok()) return Fail(pts.status());
    for (Point& p : *pts) p.id = 0;  // pasted copies are new points
    ops.emplace_back(position({a.paste_opt}), Transaction::InsertOp{std::move(pts).value()});
  }
  if (ops.empty()) {
    return Usage("edit",
                 "nothing to do: give --delete-box, --label-box, --box/--translate or --paste");
  }
  std::stable_sort(ops.begin(), ops.end(),
                   [](const auto& x, const auto& y) { return x.first < y.first; });
  Transaction txn;
  for (auto& [pos, op] : ops) {
    std::visit(
        [&txn](auto&& o) {
          using T = std::decay_t<decltype(o)>;
          if constexpr (std::is_same_v<T, Transaction::InsertOp>) {
            txn.Insert(std::move(o.points));
          } else if constexpr (std::is_same_v<T, Transaction::DeleteSelOp>) {
            txn.DeleteSelection(std::move(o.sel));
          } else if constexpr (std::is_same_v<T, Transaction::TransformOp>) {
            txn.Transform(std::move(o.sel), o.map);
          } else if constexpr (std::is_same_v<T, Transaction::LabelOp>) {
            txn.SetLabel(std::move(o.sel), o.bits, o.set);
          }
        },
        op);
  }
  Result<CommitInfo> ci = db().Commit(a.name, txn);
  if (!ci.ok()) return Fail(ci.status());
  if (a.json) {
    PrintJson({{"lsn", ci->lsn}, {"inserted", ci->inserted}, {"removed", ci->removed}});
  } else {
    std::printf("committed lsn %llu (inserted %llu, removed %llu)\n",
                static_cast<unsigned long long>(ci->lsn),
                static_cast<unsigned long long>(ci->inserted),
                static_cast<unsigned long long>(ci->removed));
  }
  return kExitOk;
}

int Cli::CmdUndo() {
  Result<CommitInfo> ci = db().Revert(undo_.name, undo_.lsn);
  if (!ci.ok()) return Fail(ci.status());
  if (undo_.json) {
    PrintJson({{"reverted", undo_.lsn},
               {"lsn", ci->lsn},
               {"inserted", ci->inserted},
               {"removed", ci->removed}});
  } else {
    std::printf("reverted lsn %llu: committed lsn %llu (inserted %llu, removed %llu)\n",
                static_cast<unsigned long long>(undo_.lsn),
                static_cast<unsigned long long>(ci->lsn),
                static_cast<unsigned long long>(ci->inserted),
                static_cast<unsigned long long>(ci->removed));
  }
  return kExitOk;
}

int Cli::CmdRedo() {
  Result<CommitInfo> ci = db().Revert(redo_.name, redo_.lsn);
  if (!ci.ok()) return Fail(ci.status());
  if (redo_.json) {
    PrintJson({{"redone", redo_.lsn},
               {"lsn", ci->lsn},
               {"inserted", ci->inserted},
               {"removed", ci->removed}});
  } else {
    std::printf("redo: reverted lsn %llu: committed lsn %llu (inserted %llu, removed %llu)\n",
                static_cast<unsigned long long>(redo_.lsn),
                static_cast<unsigned long long>(ci->lsn),
                static_cast<unsigned long long>(ci->inserted),
                static_cast<unsigned long long>(ci->removed));
  }
  return kExitOk;
}

int Cli::CmdSelect() {
  const SelectArgs& a = select_;
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

  Result<edit::SelectResult> r = db().Select(a.name, req);
  if (!r.ok()) return Fail(r.status());
  const std::string shape = lasso ? "lasso" : rect ? "rect" : brush ? "brush" : "region";
  if (a.json) {
    json j = {{"dataset", a.name}, {"bit", a.bit},          {"mode", a.mode},
              {"shape", shape},    {"matched", r->matched}, {"selected", r->selected},
              {"lsn", r->lsn}};
    if (r->brush_center) j["brush_center"] = *r->brush_center;
    PrintJson(j);
    return kExitOk;
  }
  std::printf("%s: %llu points matched; %llu carry bit %d after %s\n", shape.c_str(),
              static_cast<unsigned long long>(r->matched),
              static_cast<unsigned long long>(r->selected), a.bit, a.mode.c_str());
  if (r->brush_center) {
    std::printf("brush centre (%.4f, %.4f, %.4f) m\n", (*r->brush_center)[0], (*r->brush_center)[1],
                (*r->brush_center)[2]);
  }
  if (r->lsn != 0) {
    std::printf("committed lsn %llu\n", static_cast<unsigned long long>(r->lsn));
  } else {
    std::printf("nothing changed (no commit, lsn 0)\n");
  }
  return kExitOk;
}

int Cli::CmdGraphCut() {
  const GraphCutArgs& a = graphcut_;
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
  Result<edit::GraphCutReply> r = db().GraphCut(a.name, req);
  if (!r.ok()) return Fail(r.status());
  const edit::GraphCutResult& c = r->cut;
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"out_bit", a.out_bit},
               {"roi_points", r->roi_points},
               {"selected", r->selected},
               {"energy", c.energy},
               {"intra_edges", c.intra_edges},
               {"inter_edges", c.inter_edges},
               {"lsn", r->lsn},
               {"recut", c.warm},
               {"timings_ms",
                {{"load", r->load_ms},
                 {"neighbours", c.neighbours_ms},
                 {"gmm", c.gmm_ms},
                 {"graph", c.graph_ms},
                 {"maxflow", c.maxflow_ms},
                 {"commit", r->commit_ms}}}});
    return kExitOk;
  }
  std::printf("%llu of %llu points in the ROI selected into bit %d\n",
              static_cast<unsigned long long>(r->selected),
              static_cast<unsigned long long>(r->roi_points), a.out_bit);
  std::printf("energy %.6g; %llu intra-frame and %llu inter-frame edges\n", c.energy,
              static_cast<unsigned long long>(c.intra_edges),
              static_cast<unsigned long long>(c.inter_edges));
  std::printf(
      "time: load %.1f ms, neighbours %.1f ms, GMM %.1f ms, graph %.1f ms, max-flow %.1f ms, "
      "commit %.1f ms%s\n",
      r->load_ms, c.neighbours_ms, c.gmm_ms, c.graph_ms, c.maxflow_ms, r->commit_ms,
      c.warm ? " (a re-cut: the server's last graph and flow reused)" : "");
  if (r->lsn != 0) {
    std::printf("committed lsn %llu\n", static_cast<unsigned long long>(r->lsn));
  } else {
    std::printf("nothing changed (no commit, lsn 0)\n");
  }
  return kExitOk;
}

int Cli::CmdCopy(const CopyArgs& a, bool cut) {
  const std::string cmd = cut ? "cut" : "copy";
  if (std::optional<int> rc = CheckClipboardName(a.clipboard, cmd)) return *rc;
  int rc = kExitOk;
  std::optional<Region> region;
  if (!ParseRegion(a.region, cmd, &region, &rc)) return rc;
  Result<edit::CopyResult> r = db().Copy(a.name, a.bit, region, a.clipboard, cut);
  if (!r.ok()) return Fail(r.status());
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"bit", a.bit},
               {"clipboard", a.clipboard},
               {"points", r->points},
               {"cut", cut},
               {"lsn", r->lsn}});
    return kExitOk;
  }
  std::printf("%s %llu points with bit %d to clipboard '%s'\n", cut ? "cut" : "copied",
              static_cast<unsigned long long>(r->points), a.bit, a.clipboard.c_str());
  if (cut && r->lsn != 0) {
    std::printf("committed lsn %llu ('hvdb undo %s %llu' puts them back)\n",
                static_cast<unsigned long long>(r->lsn), a.name.c_str(),
                static_cast<unsigned long long>(r->lsn));
  }
  return kExitOk;
}

int Cli::CmdPaste() {
  const PasteArgs& a = paste_;
  const std::string cmd = "paste";
  if (std::optional<int> rc = CheckClipboardName(a.clipboard, cmd)) return *rc;
  Affine4 map;
  if (!a.matrix.empty()) {
    if (a.matrix.size() != 16) return Usage(cmd, "--matrix takes 16 numbers (row-major 4x4)");
    for (size_t i = 0; i < 16; ++i) map.a[i] = a.matrix[i];
  }
  if (!a.translate.empty()) {
    if (a.translate.size() != 4) return Usage(cmd, "--translate takes 4 numbers DX DY DZ DT");
    for (size_t i = 0; i < 4; ++i) map.c[i] = a.translate[i];
  }
  for (double v : map.a) {
    if (!std::isfinite(v)) return Usage(cmd, "--matrix must be finite");
  }
  for (double v : map.c) {
    if (!std::isfinite(v)) return Usage(cmd, "--translate must be finite");
  }
  Result<CommitInfo> ci = db().Paste(a.name, a.clipboard, map);
  if (!ci.ok()) return Fail(ExplainClipboard(ci.status(), db()));
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"clipboard", a.clipboard},
               {"lsn", ci->lsn},
               {"inserted", ci->inserted},
               {"removed", ci->removed}});
    return kExitOk;
  }
  std::printf("pasted %llu points from clipboard '%s': committed lsn %llu\n",
              static_cast<unsigned long long>(ci->inserted), a.clipboard.c_str(),
              static_cast<unsigned long long>(ci->lsn));
  return kExitOk;
}

int Cli::CmdComposite() {
  const CompositeArgs& a = composite_;
  const std::string cmd = "composite";
  if (uint64_t{a.first_frame} + a.frames - 1 > UINT32_MAX) {
    return Usage(cmd, "--first-frame " + std::to_string(a.first_frame) + " plus --frames " +
                          std::to_string(a.frames) + " passes frame 2^32-1");
  }
  // An unknown dataset is reported before any file is read.
  Result<DatasetInfo> info = db().Describe(a.name);
  if (!info.ok()) return Fail(info.status());
  std::vector<std::array<double, 3>> trajectory;
  if (!a.trajectory.empty()) {
    Result<std::vector<std::array<double, 3>>> t = ReadTrajectory(a.trajectory);
    if (!t.ok()) return Fail(t.status());
    if (t->size() != a.frames) {
      return Fail(Status::InvalidArgument("trajectory file '" + a.trajectory + "' has " +
                                          std::to_string(t->size()) + " offsets for --frames " +
                                          std::to_string(a.frames) +
                                          " (one 'dx,dy,dz' line per frame)"));
    }
    trajectory = std::move(t).value();
  }
  formats::ReadOptions ro;
  ro.scale = a.units_scale;
  ro.skip_invalid = a.skip_invalid;
  Result<std::vector<Point>> object = ReadPlyNoting(a.ply, ro);
  if (!object.ok()) return Fail(object.status());
  if (object->empty()) {
    return Fail(Status::InvalidArgument("'" + a.ply + "' has no points to composite"));
  }
  Result<CommitInfo> ci = db().Composite(a.name, *object, a.first_frame, a.frames, trajectory);
  if (!ci.ok()) return Fail(ci.status());
  const uint32_t last = a.first_frame + (a.frames - 1);
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"object_points", object->size()},
               {"first_frame", a.first_frame},
               {"last_frame", last},
               {"moving", !trajectory.empty()},
               {"lsn", ci->lsn},
               {"inserted", ci->inserted},
               {"removed", ci->removed}});
    return kExitOk;
  }
  std::printf(
      "composited %zu points of %s into frames %u..%u (%llu points%s): committed lsn "
      "%llu\n",
      object->size(), a.ply.c_str(), a.first_frame, last,
      static_cast<unsigned long long>(ci->inserted),
      trajectory.empty() ? "" : ", along the trajectory", static_cast<unsigned long long>(ci->lsn));
  return kExitOk;
}

int Cli::CmdRender() {
  const RenderArgs& a = render_;
  const std::string cmd = "render";
  int rc = kExitOk;
  const bool sequence = a.path_opt->count() > 0;
  std::optional<Region> region;
  if (!ParseRegion(a.region, cmd, &region, &rc)) return rc;
  const bool look_at = a.camera.look_at_opt->count() > 0,
             camera_file = a.camera.file_opt->count() > 0,
             dataset_camera = a.dataset_camera_opt->count() > 0;
  wire::ImageFormat format = wire::IMAGE_PNG;
  if (sequence) {
    format = a.format == "exr" ? wire::IMAGE_EXR : wire::IMAGE_PNG;
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
      format = wire::IMAGE_EXR;
    } else if (!HasExtension(a.out, ".png")) {
      return Usage(cmd, "--out '" + a.out + "': the file name must end in .png or .exr");
    }
  }

  wire::Render req;
  req.set_dataset(a.name);
  req.set_lod(static_cast<uint32_t>(a.lod));
  req.set_label_mask(a.label_mask);
  uint32_t highlight = 0;
  for (int b : a.highlight) highlight |= 1u << b;
  req.set_highlight_mask(highlight);
  req.set_texture(a.texture);
  req.set_billboards(a.billboards);
  for (float v : a.highlight_color) req.add_highlight_color(v);
  req.set_mode(a.mode == "probabilistic" ? wire::RENDER_PROBABILISTIC : wire::RENDER_VISIBILITY);
  req.set_view_dependent(a.view_dependent);
  req.set_renderer(a.renderer == "egl"   ? wire::RENDERER_EGL
                   : a.renderer == "cpu" ? wire::RENDERER_CPU
                                         : wire::RENDERER_AUTO);
  req.set_format(format);
  if (!a.background.empty()) {
    // Given as the PNG shows it (sRGB); the renderer blends in linear light.
    for (double v : a.background) req.add_background(render::SrgbToLinear(static_cast<float>(v)));
    req.add_background(1.0f);
  }
  if (region) wire::ToWire(*region, req.mutable_region());
  // --size: the size of a look-at camera; for any other camera, the size it is scaled to.
  const bool sized = a.size_opt->count() > 0;
  if (sized && !look_at) {
    req.set_width(a.camera.size[0]);
    req.set_height(a.camera.size[1]);
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
    if (req.path_size() == 0) {
      return Fail(Status::InvalidArgument(a.path + ": the camera path has no cameras"));
    }
    if (req.frames_size() == 0 && !region) {
      return Usage(cmd, "the entries of '" + a.path +
                            "' have no \"frame\": give the region to show, --box X0 X1 Y0 Y1 Z0 "
                            "Z1 T0 T1 or --normal NX NY NZ NT --offset B --thickness DB");
    }
    if (req.frames_size() > 0 && region && !std::holds_alternative<Window>(*region)) {
      return Usage(cmd, "the entries of '" + a.path +
                            "' show frames: a region with them must be a --box (its x y z "
                            "bounds apply to every frame)");
    }
  } else if (look_at) {
    CameraArgs c = a.camera;
    if (!sized) c.size = {640, 480};
    std::optional<CameraInfo> camera = LookAtCamera(c, cmd, &rc);
    if (!camera) return rc;
    wire::ToWire(*camera, req.mutable_view()->mutable_camera());
  } else if (camera_file) {
    Result<CameraInfo> camera = ReadCameraFile(a.camera.file);
    if (!camera.ok()) return Fail(camera.status());
    wire::ToWire(*camera, req.mutable_view()->mutable_camera());
  } else {
    req.mutable_view()->set_dataset_camera(a.dataset_camera);
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
  std::string renderer, choice;
  bool fallback = false;
  bool made_dir = false;
  Status st = db().Render(req, [&](const wire::RenderReply& r) -> Status {
    std::string file = a.out;
    if (sequence) {
      if (!made_dir) {
        std::error_code ec;
        fs::create_directories(a.out_dir, ec);
        if (ec) {
          return Status::IOError("cannot create directory '" + a.out_dir + "': " + ec.message());
        }
        made_dir = true;
      }
      file = (fs::path(a.out_dir) /
              Printf("frame_%04u.%s", r.index(), format == wire::IMAGE_EXR ? "exr" : "png"))
                 .string();
    }
    HVDB_RETURN_IF_ERROR(WriteFileBytes(file, format == wire::IMAGE_EXR ? r.exr() : r.png()));
    if (images.empty()) {
      renderer = r.renderer_used();
      choice = r.renderer_choice();
      fallback = r.fallback();
      if (fallback && db().remote()) {
        std::fprintf(stderr,
                     "hvdb: warning: hvdb-server at %s could make no EGL context and rendered "
                     "with the CPU renderer (its log says why)\n",
                     db().where().c_str());
      }
    }
    total_points += r.points();
    total_ms += r.render_ms();
    images.push_back({{"index", r.index()},
                      {"file", file},
                      {"width", r.width()},
                      {"height", r.height()},
                      {"points", r.points()},
                      {"render_ms", r.render_ms()}});
    if (!a.json) {
      if (sequence) {
        std::printf("%s (%ux%u): %llu points in %.1f ms\n", file.c_str(), r.width(), r.height(),
                    static_cast<unsigned long long>(r.points()), r.render_ms());
      } else {
        std::printf("rendered %s (%ux%u): %llu points in %.1f ms with %s%s\n", file.c_str(),
                    r.width(), r.height(), static_cast<unsigned long long>(r.points()),
                    r.render_ms(), r.renderer_used().c_str(),
                    r.fallback() ? " (fallback: no EGL context)" : "");
      }
      std::fflush(stdout);
    }
    return Status::OK();
  });
  render::SetLogHandler(nullptr);
  if (!st.ok()) {
    if (sequence && !images.empty()) {
      st = Status(st.code(), st.message() + " (" + std::to_string(images.size()) + " of " +
                                 std::to_string(req.path_size()) + " images were written to " +
                                 a.out_dir + ")");
    }
    return Fail(st);
  }
  const double ms = MsSince(start);
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"renderer", renderer},
               {"renderer_choice", choice},
               {"fallback", fallback},
               {"images", images},
               {"points", total_points},
               {"render_ms", total_ms},
               {"elapsed_ms", ms}});
  } else if (sequence) {
    std::printf("rendered %zu image%s into %s with %s%s: %llu points in %.1f ms (%.2f s in all)\n",
                images.size(), images.size() == 1 ? "" : "s", a.out_dir.c_str(), renderer.c_str(),
                fallback ? " (fallback: no EGL context)" : "",
                static_cast<unsigned long long>(total_points), total_ms, ms / 1e3);
  }
  return kExitOk;
}

int Cli::CmdStats() {
  Result<client::StatsReport> report = db().Stats(stats_.name);
  if (!report.ok()) return Fail(report.status());
  json list = json::array();
  for (const client::StatsReport::Entry& e : report->datasets) {
    const DatasetStats& s = e.stats;
    if (stats_.json) {
      list.push_back({{"name", e.name},
                      {"frames_with_data", s.frames_with_data},
                      {"points", s.points},
                      {"tombstones", s.tombstones},
                      {"buffered_points", s.buffered_points},
                      {"trees", s.trees},
                      {"tree_bytes", s.tree_bytes},
                      {"wal_bytes", s.wal_bytes},
                      {"leaf_utilisation", s.leaf_utilisation},
                      {"last_lsn", e.last_lsn}});
    } else {
      std::printf(
          "%s: %u frames with data, %llu points (%llu buffered, %llu tombstones), %llu trees "
          "(%.1f MiB, leaves %.0f%% full), log %.1f MiB, last lsn %llu\n",
          e.name.c_str(), s.frames_with_data, static_cast<unsigned long long>(s.points),
          static_cast<unsigned long long>(s.buffered_points),
          static_cast<unsigned long long>(s.tombstones), static_cast<unsigned long long>(s.trees),
          static_cast<double>(s.tree_bytes) / (1 << 20), 100 * s.leaf_utilisation,
          static_cast<double>(s.wal_bytes) / (1 << 20),
          static_cast<unsigned long long>(e.last_lsn));
    }
  }
  json out = {{"datasets", list}};
  if (report->cache) {
    const CacheStats& c = *report->cache;
    uint64_t lookups = c.hits + c.misses;
    double hit_rate = lookups ? static_cast<double>(c.hits) / static_cast<double>(lookups) : 0;
    if (stats_.json) {
      out["cache"] = {{"capacity_bytes", c.capacity_bytes},
                      {"block_size", c.block_size},
                      {"hits", c.hits},
                      {"misses", c.misses},
                      {"hit_rate", hit_rate},
                      {"evictions", c.evictions},
                      {"resident_blocks", c.resident_blocks},
                      {"pinned_blocks", c.pinned_blocks}};
    } else {
      std::printf(
          "cache: %.0f MiB in %llu KiB blocks, %llu resident, %llu pinned; %llu hits, %llu "
          "misses, %llu evictions\n",
          static_cast<double>(c.capacity_bytes) / (1 << 20),
          static_cast<unsigned long long>(c.block_size >> 10),
          static_cast<unsigned long long>(c.resident_blocks),
          static_cast<unsigned long long>(c.pinned_blocks), static_cast<unsigned long long>(c.hits),
          static_cast<unsigned long long>(c.misses), static_cast<unsigned long long>(c.evictions));
    }
  }
  if (report->server) {
    const client::ServerCounters& v = *report->server;
    if (stats_.json) {
      out["cache"] = {{"capacity_bytes", v.cache_capacity_bytes}, {"hit_rate", v.cache_hit_rate}};
      json requests = json::array();
      for (const client::RequestLatency& l : v.requests) {
        requests.push_back({{"kind", l.kind},
                            {"count", l.count},
                            {"p50_ms", l.p50_ms},
                            {"p95_ms", l.p95_ms},
                            {"p99_ms", l.p99_ms}});
      }
      out["server"] = {{"address", db().where()},
                       {"role", v.role},
                       {"leader", v.leader},
                       {"connections_open", v.connections_open},
                       {"connections_total", v.connections_total},
                       {"bytes_in", v.bytes_in},
                       {"bytes_out", v.bytes_out},
                       {"requests", requests}};
    } else {
      std::printf("server %s: %llu connection%s open, %llu in all; %s in, %s out\n",
                  db().where().c_str(), static_cast<unsigned long long>(v.connections_open),
                  v.connections_open == 1 ? "" : "s",
                  static_cast<unsigned long long>(v.connections_total), Bytes(v.bytes_in).c_str(),
                  Bytes(v.bytes_out).c_str());
      if (!v.role.empty()) {
        std::printf("role: %s%s%s\n", v.role.c_str(), v.leader.empty() ? "" : "; the writer is at ",
                    v.leader.c_str());
      }
      std::printf("cache: %.0f MiB, hit rate %.1f%%\n",
                  static_cast<double>(v.cache_capacity_bytes) / (1 << 20),
                  100 * v.cache_hit_rate);
      if (!v.requests.empty()) {
        std::printf("  %-10s %10s %10s %10s %10s\n", "request", "count", "p50 ms", "p95 ms",
                    "p99 ms");
      }
      for (const client::RequestLatency& l : v.requests) {
        std::printf("  %-10s %10llu %10.3f %10.3f %10.3f\n", l.kind.c_str(),
                    static_cast<unsigned long long>(l.count), l.p50_ms, l.p95_ms, l.p99_ms);
      }
    }
  }
  if (stats_.json) PrintJson(out);
  return kExitOk;
}

int Cli::CmdCheck() {
  if (db().remote()) {
    return Usage("check",
                 "check reads the data directory's files and cannot run through --server; run "
                 "'hvdb --data DIR check' on the server's machine, with hvdb-server stopped");
  }
  std::vector<std::string> names;
  if (!check_.name.empty()) {
    names.push_back(check_.name);
  } else {
    Result<std::vector<std::string>> all = db().ListDatasets();
    if (!all.ok()) return Fail(all.status());
    names = std::move(all).value();
  }
  json problems = json::array();
  for (const std::string& name : names) {
    Result<std::vector<std::string>> found = db().Check(name);
    if (!found.ok()) return Fail(found.status());
    for (const std::string& p : *found) {
      problems.push_back({{"dataset", name}, {"problem", p}});
      if (!check_.json) std::printf("%s: %s\n", name.c_str(), p.c_str());
    }
  }
  if (check_.json) {
    PrintJson({{"ok", problems.empty()}, {"datasets", names.size()}, {"problems", problems}});
  } else if (problems.empty()) {
    std::printf("ok\n");
  }
  return problems.empty() ? kExitOk : kExitError;
}

int Cli::CmdDrop() {
  Status s = db().DropDataset(drop_.name);
  if (!s.ok()) return Fail(s);
  std::cout << "dropped dataset '" << drop_.name << "'\n";
  return kExitOk;
}

int Cli::CmdPing() {
  if (!db().remote()) {
    return Usage("ping", "ping needs --server HOST:PORT (there is no server on a data directory)");
  }
  std::vector<double> rtts;
  for (unsigned i = 0; i < ping_.count; ++i) {
    Result<double> ms = db().Ping();
    if (!ms.ok()) return Fail(ms.status());
    rtts.push_back(*ms);
    if (!ping_.json) {
      std::printf("pong from %s (%s) in %.3f ms\n", db().where().c_str(), db().transport().c_str(),
                  *ms);
    }
  }
  double lo = *std::min_element(rtts.begin(), rtts.end());
  double hi = *std::max_element(rtts.begin(), rtts.end());
  double sum = 0;
  for (double v : rtts) sum += v;
  double avg = sum / static_cast<double>(rtts.size());
  if (ping_.json) {
    PrintJson({{"server", db().where()},
               {"transport", db().transport()},
               {"count", rtts.size()},
               {"rtt_ms", rtts},
               {"min_ms", lo},
               {"avg_ms", avg},
               {"max_ms", hi}});
  } else if (rtts.size() > 1) {
    std::printf("%zu pings: min %.3f, avg %.3f, max %.3f ms\n", rtts.size(), lo, avg, hi);
  }
  return kExitOk;
}

}  // namespace
}  // namespace hvdb

int main(int argc, char** argv) {
  // Declared out here because the catch blocks still use them.
  std::optional<CLI::App> app;
  std::optional<hvdb::Cli> cli;
  // The only try/catch: CLI11 reports usage errors by exception; nothing below throws on
  // purpose (the storage and client APIs return Status), so anything else is a bug or out of
  // memory.
  try {
    app.emplace(
        "hvdb: a database for 3D video (point clouds over time), on a data directory or an "
        "hvdb-server",
        "hvdb");
    cli.emplace(*app);
    app->parse(argc, argv);
    return cli->Run();
  } catch (const CLI::ParseError& e) {
    int rc = app->exit(e);  // prints the help, or the message and a pointer to --help
    return rc == 0 ? hvdb::kExitOk : hvdb::kExitUsage;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hvdb: internal error: %s\n", e.what());
    return hvdb::kExitError;
  }
}
