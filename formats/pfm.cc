#include "formats/pfm.h"

#include <bit>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <iterator>
#include <vector>

namespace hvdb::formats {

namespace {

// Reads one whitespace-delimited header token starting at *pos; false at end of data.
bool NextToken(const std::string& data, size_t* pos, std::string* token) {
  size_t p = *pos;
  while (p < data.size() && std::isspace(static_cast<unsigned char>(data[p]))) ++p;
  size_t start = p;
  while (p < data.size() && !std::isspace(static_cast<unsigned char>(data[p])) && p - start < 64) ++p;
  if (p == start) return false;
  *token = data.substr(start, p - start);
  *pos = p;
  return true;
}

bool ParseInt(const std::string& s, long* out) {
  if (s.empty() || s.size() > 10) return false;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
  }
  *out = std::stol(s);
  return true;
}

}  // namespace

Status WritePfm(const std::string& path, const cv::Mat& image) {
  if (image.empty()) return Status::InvalidArgument("WritePfm " + path + ": empty image");
  if (image.depth() != CV_32F || (image.channels() != 1 && image.channels() != 3)) {
    return Status::InvalidArgument("WritePfm " + path +
                                   ": image must be CV_32F with 1 or 3 channels");
  }
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  if (!f) return Status::FromErrno("WritePfm: cannot create " + path, errno);
  f << (image.channels() == 3 ? "PF" : "Pf") << "\n"
    << image.cols << " " << image.rows << "\n-1\n";
  const size_t row_bytes = static_cast<size_t>(image.cols) * image.elemSize();
  std::vector<char> row(row_bytes);
  for (int y = image.rows - 1; y >= 0; --y) {  // bottom-to-top
    std::memcpy(row.data(), image.ptr(y), row_bytes);
    if constexpr (std::endian::native == std::endian::big) {
      for (size_t i = 0; i < row_bytes; i += 4) {
        std::swap(row[i], row[i + 3]);
        std::swap(row[i + 1], row[i + 2]);
      }
    }
    f.write(row.data(), static_cast<std::streamsize>(row_bytes));
  }
  f.flush();
  if (!f) return Status::FromErrno("WritePfm: write failed for " + path, errno);
  return Status::OK();
}

Result<cv::Mat> ReadPfm(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) return Status::NotFound("ReadPfm: cannot open " + path);
  std::string data((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  auto bad = [&](const std::string& why) {
    return Status::Corruption("ReadPfm " + path + ": " + why);
  };
  size_t pos = 0;
  std::string magic, ws, hs, ss;
  if (!NextToken(data, &pos, &magic) || (magic != "Pf" && magic != "PF")) {
    return bad("not a PFM file (header must start with 'Pf' or 'PF')");
  }
  const int channels = magic == "PF" ? 3 : 1;
  long w = 0, h = 0;
  if (!NextToken(data, &pos, &ws) || !NextToken(data, &pos, &hs) || !ParseInt(ws, &w) ||
      !ParseInt(hs, &h) || w <= 0 || h <= 0 || w > (1 << 20) || h > (1 << 20)) {
    return bad("malformed width/height in header");
  }
  if (!NextToken(data, &pos, &ss)) return bad("missing scale in header");
  char* end = nullptr;
  const double scale = std::strtod(ss.c_str(), &end);
  if (end != ss.c_str() + ss.size() || scale == 0 || !std::isfinite(scale)) {
    return bad("malformed scale '" + ss + "' in header (must be a non-zero number)");
  }
  // Exactly one whitespace character separates the header from the raster.
  if (pos >= data.size() || !std::isspace(static_cast<unsigned char>(data[pos]))) {
    return bad("header not terminated");
  }
  ++pos;
  const size_t row_bytes = static_cast<size_t>(w) * channels * 4;
  const size_t need = row_bytes * static_cast<size_t>(h);
  if (data.size() - pos < need) {
    return bad("truncated: " + std::to_string(data.size() - pos) + " bytes of raster, expected " +
               std::to_string(need));
  }
  const bool little = scale < 0;
  cv::Mat img(static_cast<int>(h), static_cast<int>(w), CV_MAKETYPE(CV_32F, channels));
  for (int y = 0; y < img.rows; ++y) {
    // Row 0 of the file is the bottom row of the image.
    char* dst = reinterpret_cast<char*>(img.ptr(img.rows - 1 - y));
    std::memcpy(dst, data.data() + pos + static_cast<size_t>(y) * row_bytes, row_bytes);
    if (little != (std::endian::native == std::endian::little)) {
      for (size_t i = 0; i < row_bytes; i += 4) {
        std::swap(dst[i], dst[i + 3]);
        std::swap(dst[i + 1], dst[i + 2]);
      }
    }
  }
  return img;
}

}  // namespace hvdb::formats
