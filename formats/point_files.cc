#include "formats/point_files.h"

#include <cerrno>
#include <cstdio>
#include <fstream>
#include <iterator>

#include "protocol/wire.h"

namespace hvdb::formats {
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

class CompressedWriter : public PointWriter {
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

Result<std::unique_ptr<PointWriter>> OpenCompressedWriter(
    const std::string& path, FileCodec codec, const codec::EncodeOptions& options,
    const codec::Reference* reference) {
  if (codec == FileCodec::kRaw) return OpenPointWriter(path);
  // Fail now, not after the query, if the file cannot be created.
  std::FILE* f = std::fopen((path + ".tmp").c_str(), "wb");
  if (!f) return Status::FromErrno(path + ".tmp", errno);
  std::fclose(f);
  std::remove((path + ".tmp").c_str());
  return std::unique_ptr<PointWriter>(new CompressedWriter(path, codec, options, reference));
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

}  // namespace hvdb::formats
