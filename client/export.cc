#include "client/export.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

#include "client/backend.h"
#include "formats/gaussian_points.h"

namespace hvdb::client {

using formats::FileCodec;

Status WriteSplatFile(Backend& db, const std::string& name, const std::string& path,
                      formats::GaussianFormat format, int spz_version, std::vector<Point>* pts) {
  using formats::GaussianFormat;
  std::sort(pts->begin(), pts->end(), [](const Point& a, const Point& b) { return a.id < b.id; });
  HVDB_ASSIGN_OR_RETURN(GaussianColumns records, db.ReadGaussians(name, *pts));
  const formats::GaussianCloud cloud = formats::PointsToCloud(*pts, records);
  formats::SpzWriteOptions spz;
  spz.version = spz_version;
  Result<std::string> bytes =
      format == GaussianFormat::kSpz     ? formats::WriteSpz(cloud, path, spz)
      : format == GaussianFormat::kSplat ? formats::WriteSplat(cloud, path)
      : format == GaussianFormat::kGlb   ? formats::WriteGlb(cloud, path)
                                         : formats::WriteGaussianPly(cloud, path);
  HVDB_RETURN_IF_ERROR(bytes.status());
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(bytes->data(), static_cast<std::streamsize>(bytes->size()));
    out.flush();
    if (!out) {
      std::filesystem::remove(tmp);
      return Status::IOError(tmp + ": write failed (disk full?)");
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) return Status::IOError(path + ": " + ec.message());
  return Status::OK();
}

Result<std::vector<std::string>> ExportFrames(Backend& db, const std::string& name,
                                              const std::string& dir, const ExportOptions& o,
                                              const std::function<void(size_t, size_t)>& progress) {
  HVDB_ASSIGN_OR_RETURN(DatasetInfo info, db.Describe(name));
  if (o.first >= info.frame_count && info.frame_count > 0) {
    return Status::InvalidArgument("--first " + std::to_string(o.first) + ": '" + name +
                                   "' has frames 0.." + std::to_string(info.frame_count - 1));
  }
  const uint32_t last = o.count == 0
                            ? info.frame_count
                            : std::min<uint64_t>(info.frame_count, uint64_t{o.first} + o.count);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Status::IOError(dir + ": " + ec.message());
  using formats::GaussianFormat;
  const bool splats = o.splats != GaussianFormat::kUnknown;
  const char* ext = splats ? (o.splats == GaussianFormat::kSpz     ? "spz"
                              : o.splats == GaussianFormat::kSplat ? "splat"
                              : o.splats == GaussianFormat::kGlb   ? "glb"
                                                                   : "ply")
                    : o.codec == FileCodec::kHvdb7 ? "hv7"
                    : o.codec == FileCodec::kDraco ? "drc"
                                                   : "ply";
  std::vector<std::string> files;
  codec::Reference ref;
  bool have_ref = false;
  for (uint32_t f = o.first; f < last; ++f) {
    Window w;
    for (int a = 0; a < 3; ++a) {
      w.lo[a] = -std::numeric_limits<double>::infinity();
      w.hi[a] = std::numeric_limits<double>::infinity();
    }
    w.lo[3] = w.hi[3] = f / info.fps;
    HVDB_ASSIGN_OR_RETURN(auto q, db.Query(name, Region(w), QueryOptions{}));
    std::vector<Point> pts;
    Batch b;
    while (true) {
      // The batch a last Next (false) leaves is not a batch: a remote query leaves the one
      // before it there.
      HVDB_ASSIGN_OR_RETURN(bool more, q->Next(&b));
      if (!more) break;
      pts.insert(pts.end(), b.points.begin(), b.points.end());
    }
    char file[64];
    std::snprintf(file, sizeof file, "_%06u.%s", f, ext);
    const std::string path = dir + "/" + name + file;
    if (splats) {
      HVDB_RETURN_IF_ERROR(WriteSplatFile(db, name, path, o.splats, o.spz_version, &pts));
      files.push_back(path);
      if (progress) progress(f - o.first + 1, last - o.first);
      continue;
    }
    const bool temporal = o.temporal && have_ref && !pts.empty() && !ref.points.empty();
    HVDB_ASSIGN_OR_RETURN(auto writer, formats::OpenCompressedWriter(path, o.codec, o.encode,
                                                                     temporal ? &ref : nullptr));
    HVDB_RETURN_IF_ERROR(writer->Append(pts));
    HVDB_RETURN_IF_ERROR(writer->Finish());
    if (o.temporal && o.codec == FileCodec::kHvdb7) {
      // The next frame is coded against this one as a decoder will see it.
      HVDB_ASSIGN_OR_RETURN(ref.points, formats::ReadHvdb7File(path, temporal ? &ref : nullptr));
      // And on its grid, so that what did not move is coded as such (docs/CODEC.md).
      std::ifstream in(path, std::ios::binary);
      std::string head(4096, '\0');
      in.read(head.data(), static_cast<std::streamsize>(head.size()));
      head.resize(static_cast<size_t>(in.gcount()));
      codec::StreamInfo si;
      if (codec::ReadInfo(head, &si).ok() && si.qp > 0) {
        for (int a = 0; a < 3; ++a) ref.origin[a] = si.origin[a];
        ref.step = si.step;
        ref.qp = si.qp;
      }
      have_ref = true;
    }
    files.push_back(path);
    if (progress) progress(f - o.first + 1, last - o.first);
  }
  return files;
}

}  // namespace hvdb::client
