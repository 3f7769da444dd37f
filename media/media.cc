// An import request checked, its medium decoded and inserted in one transaction.
#include <algorithm>
#include <cctype>
#include <cmath>

#include "edit/operators.h"
#include "media/media.h"

namespace hvdb::media {
namespace {

std::string Lower(std::string s) {
  for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (!s.empty() && s[0] == '.') s.erase(0, 1);
  return s;
}

bool StartsWith(std::string_view data, std::string_view sig) {
  return data.size() >= sig.size() && data.substr(0, sig.size()) == sig;
}

bool Finite3(const std::array<double, 3>& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

}  // namespace

const char* KindName(Kind k) {
  switch (k) {
    case Kind::kImage: return "image";
    case Kind::kVideo: return "video";
    case Kind::kMesh: return "mesh";
    default: return "auto";
  }
}

Result<Kind> ParseKind(const std::string& s) {
  if (s.empty() || s == "auto") return Kind::kAuto;
  if (s == "image") return Kind::kImage;
  if (s == "video") return Kind::kVideo;
  if (s == "mesh") return Kind::kMesh;
  return Status::InvalidArgument("import_media.kind: '" + s +
                                 "' is not one of image, video, mesh (or empty: from the file)");
}

Kind DetectKind(std::string_view data, const std::string& format, Kind hint) {
  if (hint != Kind::kAuto) return hint;
  if (StartsWith(data, "\x89PNG\r\n\x1a\n") || StartsWith(data, "\xff\xd8\xff")) {
    return Kind::kImage;
  }
  if (StartsWith(data, "ply\n") || StartsWith(data, "ply\r") || StartsWith(data, "glTF")) {
    return Kind::kMesh;
  }
  const std::string f = Lower(format);
  for (const char* e : {"png", "jpg", "jpeg", "bmp", "tif", "tiff", "webp", "pnm", "ppm"}) {
    if (f == e) return Kind::kImage;
  }
  for (const char* e : {"obj", "ply", "gltf", "glb", "stl", "off", "fbx", "dae", "3ds"}) {
    if (f == e) return Kind::kMesh;
  }
  return Kind::kVideo;
}

Status TooManyPoints(uint64_t per_frame, uint64_t frames, Kind kind) {
  return Status::InvalidArgument(
      "import_media.frames: " + std::to_string(per_frame) + " points a frame in " +
      std::to_string(frames) + " frames is over the limit of " +
      std::to_string(kMaxImportPoints) + " points an import; give fewer frames" +
      (kind == Kind::kMesh ? " or a larger spacing" : " or fewer texels"));
}

Result<CommitInfo> Import(Dataset& ds, const ImportRequest& req, const JobLimits& limits) {
  JobLease lease = limits.Lease();
  const Budget budget{&limits, &lease};
  // The request's shape first: nothing is decoded for a request that cannot be served.
  if (req.data.empty()) {
    return Status::InvalidArgument("import_media.data: the file is empty (send its bytes)");
  }
  const Placement& pl = req.place;
  if (!Finite3(pl.at)) return Status::InvalidArgument("import_media.at: needs 3 finite metres");
  if (!Finite3(pl.rotate_deg)) {
    return Status::InvalidArgument("import_media.rotate: needs 3 finite angles in degrees");
  }
  if (!(pl.scale > 0) || !std::isfinite(pl.scale)) {
    return Status::InvalidArgument("import_media.scale: must be a finite number > 0");
  }
  if (!(pl.width > 0) || !std::isfinite(pl.width)) {
    return Status::InvalidArgument("import_media.width: must be a finite number of metres > 0");
  }
  if (req.label_bit && (*req.label_bit < 0 || *req.label_bit > 31)) {
    return Status::InvalidArgument("import_media.label_bit: " + std::to_string(*req.label_bit) +
                                   " is not a label bit (0..31)");
  }
  if (req.texels > kMaxTexels) {
    return Status::InvalidArgument("import_media.texels: at most " + std::to_string(kMaxTexels) +
                                   " (got " + std::to_string(req.texels) + ")");
  }
  if (!(req.spacing >= 0) || !std::isfinite(req.spacing)) {
    return Status::InvalidArgument("import_media.spacing: must be 0 (from the mesh's size) or "
                                   "a finite number of metres > 0");
  }
  if (req.first_frame.has_value() != req.last_frame.has_value()) {
    return Status::InvalidArgument("import_media.frames: give both the first and the last frame");
  }
  uint32_t first = 0, last = 0;
  if (req.first_frame) {
    first = *req.first_frame;
    last = *req.last_frame;
    if (first > last) {
      return Status::InvalidArgument("import_media.frames: the first frame (" +
                                     std::to_string(first) + ") is after the last (" +
                                     std::to_string(last) + ")");
    }
  } else {
    const uint32_t n = ds.Info().frame_count;
    last = n == 0 ? 0 : n - 1;
  }
  const uint64_t frames = uint64_t{last} - first + 1;
  const uint32_t label = req.label_bit ? 1u << *req.label_bit : 0;
  const Kind kind = DetectKind(req.data, req.format, req.kind);
  const std::string fmt = Lower(req.format);
  std::vector<Point> object;
  switch (kind) {
    case Kind::kImage: {
      HVDB_ASSIGN_OR_RETURN(
          Picture pic,
          DecodeImage(req.data, fmt, req.texels ? req.texels : kDefaultImageTexels, budget));
      object = PlaneSurfels(pic, pl, 0, label);
      break;
    }
    case Kind::kMesh: {
      HVDB_ASSIGN_OR_RETURN(object, SampleMesh(req.data, fmt, pl, req.spacing, label, budget));
      break;
    }
    case Kind::kVideo: {
      // Video frame k goes to dataset frame first + k; a shorter video holds its last frame.
      const uint32_t side = req.texels ? req.texels : kDefaultVideoTexels;
      HVDB_ASSIGN_OR_RETURN(
          std::vector<Picture> pics,
          DecodeVideo(req.data, fmt, static_cast<uint32_t>(frames), side, kMaxImportPoints, budget));
      // Every frame's texels, the last one's repeated to the end of the range.
      uint64_t total = 0;
      for (const Picture& pic : pics) total += static_cast<uint64_t>(pic.width) * pic.height;
      total += (frames - pics.size()) * static_cast<uint64_t>(pics.back().width) *
               static_cast<uint64_t>(pics.back().height);
      if (total > kMaxImportPoints) {
        const Picture& end = pics.back();
        return TooManyPoints(static_cast<uint64_t>(end.width) * end.height, frames, kind);
      }
      // The points, and the transaction's copy of them in the log record.
      HVDB_RETURN_IF_ERROR(budget.Reserve(total * sizeof(Point) * 2, "import_media: " +
                                          std::to_string(total) + " points"));
      std::vector<Point> pts;
      pts.reserve(total);
      for (uint64_t k = 0; k < frames; ++k) {
        if (k % 16 == 0) HVDB_RETURN_IF_ERROR(limits.CheckTime("import_media"));
        const Picture& pic = pics[std::min<size_t>(k, pics.size() - 1)];
        std::vector<Point> plane = PlaneSurfels(pic, pl, static_cast<uint32_t>(first + k), label);
        pts.insert(pts.end(), plane.begin(), plane.end());
      }
      if (pts.empty()) {
        return Status::InvalidArgument("import_media: the video has no opaque pixels");
      }
      Transaction t;
      t.Insert(std::move(pts));
      return ds.Commit(t);
    }
    default: break;
  }
  if (object.empty()) {
    return Status::InvalidArgument(std::string("import_media: the ") + KindName(kind) +
                                   " gave no points (every pixel is transparent)");
  }
  if (object.size() * frames > kMaxImportPoints) {
    return TooManyPoints(object.size(), frames, kind);
  }
  // The frames' copies in the transaction, and the log record that holds them.
  HVDB_RETURN_IF_ERROR(budget.Reserve(object.size() * frames * sizeof(Point) * 2,
                                      "import_media: " + std::to_string(object.size() * frames) +
                                          " points"));
  HVDB_RETURN_IF_ERROR(limits.CheckTime("import_media"));
  // A still medium is the same object in every frame: hvdb composite's insertion.
  return edit::Composite(ds, object, first, static_cast<uint32_t>(frames));
}

}  // namespace hvdb::media
