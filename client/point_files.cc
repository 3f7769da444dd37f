#include "client/point_files.h"

#include <cerrno>
#include <cstdio>
#include <fstream>
#include <filesystem>
#include <iterator>
#include <limits>

#include "client/backend.h"
#include "protocol/wire.h"

namespace hvdb::client {
namespace {

Status WriteWhole(const std::string& path, const std::string& data) {
  const std::string tmp = path + ".tmp";
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return Status::FromErrno(tmp, errno);
  bool ok = std::fwrite(data.data(), 1, data.size(), f) == data.size();
  ok = (std::fflush(f) == 0) && ok;
  ok = (std::fclose(f) == 0) && ok;
  if (!ok) {
    std::remove(tmp.c_str());
    return Status::IOError(tmp + ": write failed");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) return Status::FromErrno(path, errno);
  return Status::OK();
}

class CompressedWriter : public ply::PointWriter {
 public:
  CompressedWriter(std::string path, FileCodec codec, const codec::EncodeOptions& o,
                   const codec::Reference* ref)
      : path_(std::move(path)), codec_(codec), options_(o), ref_(ref) {}
  Status Append(std::span<const Point> pts) override {
    points_.insert(points_.end(), pts.begin(), pts.end());
    count_ += pts.size();
    return Status::OK();
  }
  Status Finish() override {
    std::string data;
    Status st = codec_ == FileCodec::kHvdb7
                    ? codec::Encode(points_, options_, &data, nullptr, ref_)
                    : wire::EncodeDraco(points_, options_.qp == 0 ? 30 : options_.qp, &data);
    if (!st.ok()) return Status(st.code(), path_ + ": " + st.message());
    return WriteWhole(path_, data);
  }

 private:
  std::string path_;
  FileCodec codec_;
  codec::EncodeOptions options_;
  const codec::Reference* ref_;
  std::vector<Point> points_;
};

}  // namespace

Status ParseFileCodec(const std::string& name, FileCodec* out) {
  if (name == "raw") *out = FileCodec::kRaw;
  else if (name == "hvdb7") *out = FileCodec::kHvdb7;
  else if (name == "draco") *out = FileCodec::kDraco;
  else return Status::InvalidArgument("--codec '" + name + "': use hvdb7, draco or raw");
  return Status::OK();
}

Result<std::unique_ptr<ply::PointWriter>> OpenCompressedWriter(
    const std::string& path, FileCodec codec, const codec::EncodeOptions& options,
    const codec::Reference* reference) {
  if (codec == FileCodec::kRaw) return ply::OpenPointWriter(path);
  // Fail now, not after the query, if the file cannot be created.
  std::FILE* f = std::fopen((path + ".tmp").c_str(), "wb");
  if (!f) return Status::FromErrno(path + ".tmp", errno);
  std::fclose(f);
  std::remove((path + ".tmp").c_str());
  return std::unique_ptr<ply::PointWriter>(new CompressedWriter(path, codec, options, reference));
}

namespace {

bool StartsWith(const std::string& path, const std::string& magic) {
  std::ifstream f(path, std::ios::binary);
  std::string head(magic.size(), '\0');
  return f.read(head.data(), static_cast<std::streamsize>(head.size())) && head == magic;
}

Status ReadWhole(const std::string& path, std::string* data) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Status::IOError(path + ": cannot open for reading");
  data->assign((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (f.bad()) return Status::IOError(path + ": read failed");
  return Status::OK();
}

}  // namespace

bool IsHvdb7File(const std::string& path) { return StartsWith(path, "HV7C"); }
bool IsDracoFile(const std::string& path) { return StartsWith(path, "DRACO"); }

Result<std::vector<Point>> ReadDracoFile(const std::string& path) {
  std::string data;
  HVDB_RETURN_IF_ERROR(ReadWhole(path, &data));
  std::vector<Point> pts;
  Status st = wire::DecodeDraco(data, &pts);
  if (!st.ok()) return Status(st.code(), path + ": " + st.message());
  return pts;
}

Result<std::vector<Point>> ReadHvdb7File(const std::string& path,
                                         const codec::Reference* reference) {
  std::string data;
  HVDB_RETURN_IF_ERROR(ReadWhole(path, &data));
  std::vector<Point> pts;
  codec::DecodeOptions o;
  o.reference = reference;
  Status st = codec::Decode(data, &pts, o);
  if (!st.ok()) return Status(st.code(), path + ": " + st.message());
  return pts;
}

Result<std::vector<std::string>> ExportFrames(Backend& db, const std::string& name,
                                              const std::string& dir, const ExportOptions& o,
                                              const std::function<void(size_t, size_t)>& progress) {
  HVDB_ASSIGN_OR_RETURN(DatasetInfo info, db.Describe(name));
  if (o.first >= info.frame_count && info.frame_count > 0) {
    return Status::InvalidArgument("--first " + std::to_string(o.first) + ": '" + name +
                                   "' has frames 0.." + std::to_string(info.frame_count - 1));
  }
  const uint32_t last = o.count == 0 ? info.frame_count
                                     : std::min<uint64_t>(info.frame_count, uint64_t{o.first} + o.count);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Status::IOError(dir + ": " + ec.message());
  const char* ext = o.codec == FileCodec::kHvdb7 ? "hv7" : o.codec == FileCodec::kDraco ? "drc" : "ply";
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
      HVDB_ASSIGN_OR_RETURN(bool more, q->Next(&b));
      pts.insert(pts.end(), b.points.begin(), b.points.end());
      if (!more) break;
    }
    char file[64];
    std::snprintf(file, sizeof file, "_%06u.%s", f, ext);
    const std::string path = dir + "/" + name + file;
    const bool temporal = o.temporal && have_ref && !pts.empty() && !ref.points.empty();
    HVDB_ASSIGN_OR_RETURN(auto writer,
                          OpenCompressedWriter(path, o.codec, o.encode, temporal ? &ref : nullptr));
    HVDB_RETURN_IF_ERROR(writer->Append(pts));
    HVDB_RETURN_IF_ERROR(writer->Finish());
    if (o.temporal && o.codec == FileCodec::kHvdb7) {
      // The next frame is coded against this one as a decoder will see it.
      HVDB_ASSIGN_OR_RETURN(ref.points, ReadHvdb7File(path, temporal ? &ref : nullptr));
      have_ref = true;
    }
    files.push_back(path);
    if (progress) progress(f - o.first + 1, last - o.first);
  }
  return files;
}

}  // namespace hvdb::client
