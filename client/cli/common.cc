#include "client/cli/common.h"

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cerrno>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <iostream>
#include <iterator>
#include <stdexcept>

namespace hvdb::cli {

void Context::Add(CLI::App* cmd, Run run) {
  if (count_ == commands_.size()) throw std::length_error("more subcommands than Context holds");
  commands_[count_++] = {cmd, run};
}

std::optional<int> Context::RunParsed() {
  for (size_t i = 0; i < count_; ++i) {
    if (commands_[i].first->parsed()) return commands_[i].second(*this);
  }
  return std::nullopt;
}

double MsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

std::string Printf(const char* fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  int n = std::vsnprintf(buf, sizeof(buf), fmt, ap);
  va_end(ap);
  return std::string(buf, static_cast<size_t>(std::clamp(n, 0, static_cast<int>(sizeof(buf) - 1))));
}

namespace {

// "12.3k", "4.56M": for rates on the progress bar.
std::string Human(double v) {
  if (v >= 1e9) return Printf("%.2fG", v / 1e9);
  if (v >= 1e6) return Printf("%.2fM", v / 1e6);
  if (v >= 1e3) return Printf("%.1fk", v / 1e3);
  return Printf("%.0f", v);
}

std::string Duration(double seconds) {
  auto s = static_cast<long long>(std::llround(std::max(0.0, seconds)));
  if (s >= 3600) return Printf("%lldh%02lldm", s / 3600, s / 60 % 60);
  if (s >= 60) return Printf("%lldm%02llds", s / 60, s % 60);
  return Printf("%llds", s);
}

}  // namespace

std::string Bytes(uint64_t v) {
  auto d = static_cast<double>(v);
  if (v >= (uint64_t{1} << 30)) return Printf("%.2f GiB", d / (1 << 30));
  if (v >= (uint64_t{1} << 20)) return Printf("%.2f MiB", d / (1 << 20));
  if (v >= (uint64_t{1} << 10)) return Printf("%.1f KiB", d / (1 << 10));
  return Printf("%llu B", static_cast<unsigned long long>(v));
}

void PrintJson(const json& j) {
  // Messages from the engine may quote file bytes: replace what is not UTF-8, never throw.
  std::cout << j.dump(-1, ' ', false, json::error_handler_t::replace) << "\n";
}

int Fail(const Status& s) {
  std::cerr << "hvdb: " << s.ToString() << "\n";
  return kExitError;
}

int Usage(const std::string& command, const std::string& msg) {
  std::string cmd = command.empty() ? "hvdb" : "hvdb " + command;
  std::cerr << (command.empty() ? "hvdb: " : cmd + ": ") << msg << "\nRun '" << cmd
            << " --help' for usage.\n";
  return kExitUsage;
}

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

ProgressBar::ProgressBar(uint64_t total)
    : enabled_(isatty(STDERR_FILENO) != 0), total_(total), start_(Clock::now()) {}

void ProgressBar::Update(uint64_t done, uint64_t points) {
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

void ProgressBar::Clear() {
  if (drawn_) std::fputs("\r\033[K", stderr);
  drawn_ = false;
}

Result<std::vector<Point>> ReadPlyNoting(const std::string& path, const formats::ReadOptions& ro,
                                         uint64_t* skipped, ProgressBar* bar) {
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

CommitOutput Committed(const CommitInfo& ci) {
  CommitOutput out;
  out.lsn = ci.lsn;
  out.inserted = ci.inserted;
  out.removed = ci.removed;
  return out;
}

void PrintCommit(bool as_json, const CommitOutput& out) {
  if (as_json) {
    json j = out.fields;
    j["lsn"] = out.lsn;
    if (out.inserted) j["inserted"] = *out.inserted;
    if (out.removed) j["removed"] = *out.removed;
    PrintJson(j);
    return;
  }
  if (out.lsn == 0 && out.if_none == CommitOutput::IfNone::kQuiet) return;
  if (out.lsn == 0 && out.if_none == CommitOutput::IfNone::kSayNothingChanged) {
    std::printf("nothing changed (no commit, lsn 0)\n");
    return;
  }
  std::string counts;
  if (out.counts_in_text) {
    counts = Printf(" (inserted %llu, removed %llu)",
                    static_cast<unsigned long long>(out.inserted.value_or(0)),
                    static_cast<unsigned long long>(out.removed.value_or(0)));
  }
  std::printf("%scommitted lsn %llu%s%s\n", out.before.c_str(),
              static_cast<unsigned long long>(out.lsn), counts.c_str(), out.after.c_str());
}

std::optional<hvdb::Window> BoxToWindow(const std::vector<double>& v, const std::string& command,
                                        const std::string& option, int* rc) {
  if (v.size() != 8) {
    *rc = Usage(command, option + " takes 8 numbers X0 X1 Y0 Y1 Z0 Z1 T0 T1 (given once)");
    return std::nullopt;
  }
  hvdb::Window w;
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

CLI::Option* AddBit(CLI::App* cmd, const std::string& name, int* bit, const std::string& help) {
  return cmd->add_option(name, *bit, help)->check(CLI::Range(0, 31));
}

namespace {

using Vec3 = std::array<double, 3>;

Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

double Norm(const Vec3& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }

}  // namespace

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
    return bad(
        "\"world_from_camera\" is a reflection (x right, y down, z forward is a "
        "right-handed frame)");
  }
  return c;
}

}  // namespace hvdb::cli
