// PLY and CSV writing of Points (binary or ascii PLY with every hvdb property, so that
// reading gives each Point back bit for bit); the reader is ply_read.cc.
#include "formats/ply.h"

#include <sys/types.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cstdio>
#include <string_view>
#include <utility>

#include "storage/coding.h"

namespace hvdb::formats {
namespace {

constexpr std::string_view kPlyProperties =
    "property float x\n"
    "property float y\n"
    "property float z\n"
    "property float nx\n"
    "property float ny\n"
    "property float nz\n"
    "property uchar red\n"
    "property uchar green\n"
    "property uchar blue\n"
    "property uint id_lo\n"
    "property uint id_hi\n"
    "property uint frame\n"
    "property float cov_xx\n"
    "property float cov_xy\n"
    "property float cov_xz\n"
    "property float cov_yy\n"
    "property float cov_yz\n"
    "property float cov_zz\n"
    "property uint label\n"
    "property ushort camera\n"
    "property uchar flags\n"
    "end_header\n";
constexpr size_t kPlyRecordSize = 3 * 4 + 3 * 4 + 3 + 3 * 4 + 6 * 4 + 4 + 2 + 1;  // 70

// "element vertex N" plus a padding comment, always kCountBlock bytes, so Finish() can
// overwrite it in place whatever N turns out to be.
constexpr size_t kCountBlock = 48;
std::string CountBlock(uint64_t n) {
  std::string s = "element vertex " + std::to_string(n) + "\ncomment";
  s.append(kCountBlock - 1 - s.size(), ' ');
  s += '\n';
  return s;
}

constexpr size_t kWriteChunk = 16384;  // points encoded per fwrite

void AppendFloat(std::string* out, float v) {
  char tmp[32];
  // Shortest representation that reads back to the same float.
  auto res = std::to_chars(tmp, tmp + sizeof(tmp), v);
  out->append(tmp, res.ptr);
}

template <typename T>
void AppendInt(std::string* out, T v) {
  char tmp[24];
  auto res = std::to_chars(tmp, tmp + sizeof(tmp), v);
  out->append(tmp, res.ptr);
}

}  // namespace

std::array<float, 3> NormalForOct(std::array<int16_t, 2> oct) {
  std::array<float, 3> d = DecodeNormal(oct);
  if (EncodeNormal(d[0], d[1], d[2]) == oct) return d;
  // On the fold of the octahedron (a zero component in the lower hemisphere) two codes give
  // the same normal and EncodeNormal picks one by the sign of the zero. A tiny value with the
  // right sign selects the other; try each sign pattern of the zero components.
  constexpr float kTiny = 1e-30f;
  for (int pattern = 1; pattern < 27; ++pattern) {
    std::array<float, 3> c = d;
    bool usable = true;
    for (int i = 0, m = pattern; i < 3; ++i, m /= 3) {
      if (m % 3 == 0) continue;
      if (c[i] != 0.f) {
        usable = false;
        break;
      }
      c[i] = m % 3 == 1 ? kTiny : -kTiny;
    }
    if (usable && EncodeNormal(c[0], c[1], c[2]) == oct) return c;
  }
  return d;  // a code EncodeNormal never produces (e.g. -32768): the nearest normal
}

// ---------------------------------------------------------------------------------------------
// PlyWriter

PlyWriter::PlyWriter() = default;

PlyWriter::~PlyWriter() {
  if (file_) std::fclose(file_);
}

Status PlyWriter::Fail(const char* what) {
  int err = errno;
  if (file_) std::fclose(file_);
  file_ = nullptr;
  return Status::FromErrno(path_ + ": " + what, err);
}

Status PlyWriter::Open(const std::string& path, bool ascii) {
  if (file_) return Status::InvalidArgument(path + ": PlyWriter is already open on " + path_);
  path_ = path;
  ascii_ = ascii;
  count_ = 0;
  file_ = std::fopen(path.c_str(), "wb");
  if (!file_) return Status::FromErrno(path, errno);
  std::string header = "ply\nformat ";
  header += ascii ? "ascii" : "binary_little_endian";
  header +=
      " 1.0\ncomment hvdb points: positions in metres, covariances in m^2, "
      "id = id_lo + 2^32 id_hi\n";
  count_offset_ = static_cast<int64_t>(header.size());
  header += CountBlock(0);
  header += kPlyProperties;
  if (std::fwrite(header.data(), 1, header.size(), file_) != header.size()) return Fail("write");
  return Status::OK();
}

Status PlyWriter::Append(std::span<const Point> pts) {
  if (!file_) return Status::InvalidArgument(path_ + ": PlyWriter is not open");
  while (!pts.empty()) {
    std::span<const Point> chunk = pts.first(std::min(pts.size(), kWriteChunk));
    pts = pts.subspan(chunk.size());
    if (ascii_) {
      std::string text;
      text.reserve(chunk.size() * 160);
      for (const Point& p : chunk) {
        std::array<float, 3> n = NormalForOct(p.normal_oct);
        for (float v : {p.x, p.y, p.z, n[0], n[1], n[2]}) {
          AppendFloat(&text, v);
          text += ' ';
        }
        for (unsigned v : {unsigned{p.r}, unsigned{p.g}, unsigned{p.b},
                           static_cast<unsigned>(p.id & 0xffffffffu),
                           static_cast<unsigned>(p.id >> 32), unsigned{p.frame}}) {
          AppendInt(&text, v);
          text += ' ';
        }
        for (float v : p.cov) {
          AppendFloat(&text, v);
          text += ' ';
        }
        AppendInt(&text, p.label);
        text += ' ';
        AppendInt(&text, unsigned{p.camera});
        text += ' ';
        AppendInt(&text, unsigned{p.flags});
        text += '\n';
      }
      if (std::fwrite(text.data(), 1, text.size(), file_) != text.size()) return Fail("write");
    } else {
      buf_.resize(chunk.size() * kPlyRecordSize);
      auto* d = reinterpret_cast<uint8_t*>(buf_.data());
      for (const Point& p : chunk) {
        std::array<float, 3> n = NormalForOct(p.normal_oct);
        for (float v : {p.x, p.y, p.z, n[0], n[1], n[2]}) {
          EncodeLE(d, v);
          d += 4;
        }
        *d++ = p.r;
        *d++ = p.g;
        *d++ = p.b;
        for (uint32_t v :
             {static_cast<uint32_t>(p.id), static_cast<uint32_t>(p.id >> 32), p.frame}) {
          EncodeLE(d, v);
          d += 4;
        }
        for (float v : p.cov) {
          EncodeLE(d, v);
          d += 4;
        }
        EncodeLE(d, p.label);
        d += 4;
        EncodeLE(d, p.camera);
        d += 2;
        *d++ = p.flags;
      }
      if (std::fwrite(buf_.data(), 1, buf_.size(), file_) != buf_.size()) return Fail("write");
    }
    count_ += chunk.size();
  }
  return Status::OK();
}

Status PlyWriter::Finish() {
  if (!file_) return Status::InvalidArgument(path_ + ": PlyWriter is not open");
  std::string block = CountBlock(count_);
  if (std::fflush(file_) != 0) return Fail("write");
  if (fseeko(file_, static_cast<off_t>(count_offset_), SEEK_SET) != 0) return Fail("seek");
  if (std::fwrite(block.data(), 1, block.size(), file_) != block.size()) return Fail("write");
  std::FILE* f = file_;
  file_ = nullptr;
  if (std::fclose(f) != 0) return Status::FromErrno(path_ + ": close", errno);
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------
// CsvWriter

CsvWriter::CsvWriter() = default;

CsvWriter::~CsvWriter() {
  if (file_) std::fclose(file_);
}

Status CsvWriter::Open(const std::string& path, bool gaussians) {
  if (file_) return Status::InvalidArgument(path + ": CsvWriter is already open on " + path_);
  path_ = path;
  count_ = 0;
  gaussians_ = gaussians;
  file_ = std::fopen(path.c_str(), "wb");
  if (!file_) return Status::FromErrno(path, errno);
  std::string header =
      "id,frame,x,y,z,nx,ny,nz,red,green,blue,label,camera,flags,"
      "cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,cov_zz";
  if (gaussians) {
    header += ",opacity,scale_0,scale_1,scale_2,rot_0,rot_1,rot_2,rot_3,f_dc_0,f_dc_1,f_dc_2";
    for (size_t k = 0; k < GaussianRecordFloats(kMaxGaussianShDegree) - kGsRest; ++k) {
      header += ",f_rest_" + std::to_string(k);
    }
  }
  header += '\n';
  if (std::fwrite(header.data(), 1, header.size(), file_) != header.size()) {
    int err = errno;
    std::fclose(file_);
    file_ = nullptr;
    return Status::FromErrno(path_ + ": write", err);
  }
  return Status::OK();
}

Status CsvWriter::Append(std::span<const Point> pts) {
  if (gaussians_) {
    return Status::InvalidArgument(path_ + ": this CSV carries Gaussian records: AppendGaussians");
  }
  return Write(pts, nullptr);
}

Status CsvWriter::AppendGaussians(std::span<const Point> pts, const GaussianColumns& records) {
  if (!gaussians_) return Append(pts);
  if (records.sh_degree != kMaxGaussianShDegree || records.size() != pts.size()) {
    return Status::InvalidArgument(path_ + ": " + std::to_string(pts.size()) + " points need " +
                                   "as many Gaussian records of SH degree 3");
  }
  return Write(pts, &records);
}

Status CsvWriter::Write(std::span<const Point> all, const GaussianColumns* records) {
  if (!file_) return Status::InvalidArgument(path_ + ": CsvWriter is not open");
  std::span<const Point> pts = all;
  while (!pts.empty()) {
    const size_t first = all.size() - pts.size();  // index of the chunk's first point
    std::span<const Point> chunk = pts.first(std::min(pts.size(), kWriteChunk));
    pts = pts.subspan(chunk.size());
    buf_.clear();
    for (size_t i = 0; i < chunk.size(); ++i) {
      const Point& p = chunk[i];
      AppendInt(&buf_, p.id);
      buf_ += ',';
      AppendInt(&buf_, p.frame);
      for (float v : {p.x, p.y, p.z}) {
        buf_ += ',';
        AppendFloat(&buf_, v);
      }
      std::array<float, 3> n = DecodeNormal(p.normal_oct);
      for (float v : n) {
        buf_ += ',';
        if (p.flags & kFlagHasNormal) AppendFloat(&buf_, v);
      }
      for (unsigned v : {unsigned{p.r}, unsigned{p.g}, unsigned{p.b}, unsigned{p.label},
                         unsigned{p.camera}, unsigned{p.flags}}) {
        buf_ += ',';
        AppendInt(&buf_, v);
      }
      for (float v : p.cov) {
        buf_ += ',';
        AppendFloat(&buf_, v);
      }
      if (records) {
        const float* rec = records->record(first + i);
        for (size_t k = 0; k < records->stride(); ++k) {
          buf_ += ',';
          AppendFloat(&buf_, rec[k]);
        }
      }
      buf_ += '\n';
    }
    if (std::fwrite(buf_.data(), 1, buf_.size(), file_) != buf_.size()) {
      int err = errno;
      std::fclose(file_);
      file_ = nullptr;
      return Status::FromErrno(path_ + ": write", err);
    }
    count_ += chunk.size();
  }
  return Status::OK();
}

Status CsvWriter::Finish() {
  if (!file_) return Status::InvalidArgument(path_ + ": CsvWriter is not open");
  std::FILE* f = file_;
  file_ = nullptr;
  if (std::fclose(f) != 0) return Status::FromErrno(path_ + ": close", errno);
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------

Result<std::unique_ptr<PointWriter>> OpenPointWriter(const std::string& path, bool ascii_ply,
                                                     bool gaussians) {
  std::string ext;
  if (size_t dot = path.find_last_of('.');
      dot != std::string::npos && path.find('/', dot) == std::string::npos) {
    ext = path.substr(dot);
  }
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (ext == ".csv") {
    auto w = std::make_unique<CsvWriter>();
    HVDB_RETURN_IF_ERROR(w->Open(path, gaussians));
    return std::unique_ptr<PointWriter>(std::move(w));
  }
  if (ext == ".ply") {
    auto w = std::make_unique<PlyWriter>();
    HVDB_RETURN_IF_ERROR(w->Open(path, ascii_ply));
    return std::unique_ptr<PointWriter>(std::move(w));
  }
  return Status::InvalidArgument(path + ": unknown output format '" + ext +
                                 "' (name the file .ply or .csv)");
}

Status WritePly(const std::string& path, std::span<const Point> pts, bool ascii) {
  PlyWriter w;
  HVDB_RETURN_IF_ERROR(w.Open(path, ascii));
  HVDB_RETURN_IF_ERROR(w.Append(pts));
  return w.Finish();
}

Status WriteCsv(const std::string& path, std::span<const Point> pts) {
  CsvWriter w;
  HVDB_RETURN_IF_ERROR(w.Open(path));
  HVDB_RETURN_IF_ERROR(w.Append(pts));
  return w.Finish();
}

}  // namespace hvdb::formats
