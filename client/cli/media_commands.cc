// `hvdb import-media`: an image, video or mesh file composited into a dataset. The file's bytes
// go to the executor (in this process with --data, hvdb-server with --server), which decodes
// them (media/media.h) and commits one transaction.
#include <cerrno>
#include <cstring>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/common.h"
#include "media/media.h"

namespace hvdb::cli {
namespace {

struct ImportMediaArgs {
  std::string name;
  std::string file;
  std::vector<uint32_t> frames;
  std::vector<double> at, rotate;
  double scale = 1, width = 1;
  std::optional<int> label_bit;
  std::string kind;
  uint32_t texels = 0;
  double spacing = 0;
  bool json = false;
} media_args;

Result<std::string> ReadMediaFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return Status::InvalidArgument("cannot read '" + path + "': " + std::strerror(errno));
  }
  std::ostringstream ss;
  ss << in.rdbuf();
  if (in.bad()) return Status::IOError("reading '" + path + "' failed");
  return std::move(ss).str();
}

// The extension, without the dot ("" when the name has none).
std::string Extension(const std::string& path) {
  const size_t slash = path.find_last_of('/');
  const size_t dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  return path.substr(dot + 1);
}

int CmdImportMedia(Context& ctx, const ImportMediaArgs& a) {
  const std::string cmd = "import-media";
  media::ImportRequest req;
  Result<media::Kind> kind = media::ParseKind(a.kind);
  if (!kind.ok()) return Usage(cmd, "--kind '" + a.kind + "': give image, video or mesh");
  req.kind = *kind;
  if (!a.frames.empty()) {
    if (a.frames[0] > a.frames[1]) {
      return Usage(cmd, "--frames " + std::to_string(a.frames[0]) + " " +
                            std::to_string(a.frames[1]) + ": A must not be after B");
    }
    req.first_frame = a.frames[0];
    req.last_frame = a.frames[1];
  }
  if (!a.at.empty()) req.place.at = {a.at[0], a.at[1], a.at[2]};
  if (!a.rotate.empty()) req.place.rotate_deg = {a.rotate[0], a.rotate[1], a.rotate[2]};
  req.place.scale = a.scale;
  req.place.width = a.width;
  req.label_bit = a.label_bit;
  req.texels = a.texels;
  req.spacing = a.spacing;
  req.format = Extension(a.file);
  // An unknown dataset is reported before the file is read.
  Result<DatasetInfo> info = ctx.db().Describe(a.name);
  if (!info.ok()) return Fail(info.status());
  Result<std::string> data = ReadMediaFile(a.file);
  if (!data.ok()) return Fail(data.status());
  req.data = std::move(data).value();
  const size_t file_bytes = req.data.size();
  const media::Kind k = media::DetectKind(req.data, req.format, req.kind);
  Result<CommitInfo> ci = ctx.db().ImportMedia(a.name, req);
  if (!ci.ok()) return Fail(ci.status());
  const uint32_t first = req.first_frame.value_or(0);
  const uint32_t last = req.last_frame.value_or(
      std::max<uint32_t>(info->frame_count, 1) - 1);
  CommitOutput out = Committed(*ci);
  out.fields = {{"dataset", a.name},   {"file", a.file},         {"kind", media::KindName(k)},
                {"bytes", file_bytes}, {"first_frame", first}, {"last_frame", last}};
  // Not Printf: the path may be longer than its buffer.
  out.before = "imported " + std::string(media::KindName(k)) + " " + a.file + " into frames " +
               std::to_string(first) + ".." + std::to_string(last) + " (" +
               std::to_string(ci->inserted) + " points): ";
  PrintCommit(a.json, out);
  return kExitOk;
}

}  // namespace

void AddMediaCommands(CLI::App& app, Context& ctx) {
  ImportMediaArgs& m = media_args;
  CLI::App* c = app.add_subcommand(
      "import-media",
      "Composite an image, video or mesh file into frames: a textured plane, or mesh surfels");
  c->add_option("name", m.name, "Dataset")->required();
  c->add_option("file", m.file, "FILE: PNG/JPEG image, video (mp4, webm, ...), or mesh "
                                "(OBJ, PLY, glTF/GLB, STL)")
      ->required();
  c->add_option("--frames", m.frames, "Frames A B, inclusive (default: every frame of the "
                                      "dataset; frame 0 if it has none)")
      ->expected(2);
  c->add_option("--at", m.at, "X Y Z: where the plane's / mesh's centre goes (metres; default "
                              "0 0 0)")
      ->expected(3);
  c->add_option("--scale", m.scale, "Scale factor (planes: of --width; meshes: of the file's "
                                    "units)")
      ->capture_default_str()
      ->check(Positive());
  c->add_option("--rotate", m.rotate, "RX RY RZ: degrees about X, then Y, then Z (default 0 0 0)")
      ->expected(3);
  c->add_option("--label-bit", m.label_bit, "Set label bit B (0..31) on every inserted point")
      ->check(CLI::Range(0, 31));
  c->add_option("--width", m.width, "Images and videos: the plane's width in metres before "
                                    "--scale")
      ->capture_default_str()
      ->check(Positive());
  c->add_option("--kind", m.kind, "image, video or mesh (default: from the file's bytes and "
                                  "extension)");
  c->add_option("--texels", m.texels,
                "Images and videos: surfels along the longer side (default 512 for images, 256 "
                "for videos; a larger picture is area-averaged down)")
      ->check(CLI::Range(1u, media::kMaxTexels));
  c->add_option("--spacing", m.spacing,
                "Meshes: metres between samples (default 2 mm, coarser past 200 000 points)")
      ->check(Positive());
  c->add_flag("--json", m.json, "Print JSON");
  c->footer(
      "An image is a plane in its local XY plane (image up = +y, facing +z), one surfel per\n"
      "texel with the texel's colour; --width (1 m) times --scale wide, centred on --at, rotated\n"
      "by --rotate (p' = at + Rz Ry Rx (scale p)). Transparent pixels (alpha < 128) are left out.\n"
      "A video is such a plane whose frame A+k shows video frame k; past the video's end its\n"
      "last frame is held. A mesh is sampled area-uniformly (a fixed seed: the same file gives\n"
      "the same points), its bounding box centred on --at, with its triangles' normals and its\n"
      "embedded texture's, vertex or material colours. The file travels in one request: over\n"
      "--server it must fit the server's --max-frame-bytes (16 MiB by default). One\n"
      "transaction: prints its lsn ('hvdb undo NAME LSN' removes everything it inserted).");
  ctx.Add(c, [](Context& cx) { return CmdImportMedia(cx, media_args); });
}

}  // namespace hvdb::cli
