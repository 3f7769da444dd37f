#include "client/cli/splat_files.h"

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "formats/gaussian_points.h"

namespace hvdb::cli {
namespace fs = std::filesystem;

namespace {

Result<std::string> ReadFile(const std::string& path, size_t limit) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::IOError(path + ": cannot open");
  std::string bytes;
  if (limit == SIZE_MAX) {
    std::error_code ec;
    const auto size = fs::file_size(path, ec);
    if (ec) return Status::IOError(path + ": " + ec.message());
    bytes.resize(size);
  } else {
    bytes.resize(limit);
  }
  in.read(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  bytes.resize(static_cast<size_t>(in.gcount()));
  return bytes;
}

// Natural order: runs of digits compare as numbers.
bool NaturalLess(const std::string& a, const std::string& b) {
  size_t i = 0, j = 0;
  while (i < a.size() && j < b.size()) {
    if (std::isdigit(static_cast<unsigned char>(a[i])) &&
        std::isdigit(static_cast<unsigned char>(b[j]))) {
      size_t i2 = i, j2 = j;
      while (i2 < a.size() && a[i2] == '0') ++i2;
      while (j2 < b.size() && b[j2] == '0') ++j2;
      size_t ie = i2, je = j2;
      while (ie < a.size() && std::isdigit(static_cast<unsigned char>(a[ie]))) ++ie;
      while (je < b.size() && std::isdigit(static_cast<unsigned char>(b[je]))) ++je;
      if (ie - i2 != je - j2) return ie - i2 < je - j2;
      const int c = a.compare(i2, ie - i2, b, j2, je - j2);
      if (c != 0) return c < 0;
      i = ie, j = je;
    } else {
      if (a[i] != b[j]) return a[i] < b[j];
      ++i, ++j;
    }
  }
  return a.size() - i < b.size() - j;
}

}  // namespace

formats::GaussianFormat SniffSplatFile(const std::string& path) {
  Result<std::string> head = ReadFile(path, 64 << 10);
  if (!head.ok() || head->empty()) return formats::GaussianFormat::kUnknown;
  const formats::GaussianFormat f = formats::DetectGaussianFormat(*head);
  // A prefix that happens to be whole 32-byte records says nothing: .splat needs the file.
  if (f == formats::GaussianFormat::kSplat) return formats::GaussianFormat::kUnknown;
  // A GLB is splats only if its JSON chunk (at the front) names the extension: a mesh is not.
  if (f == formats::GaussianFormat::kGlb &&
      head->find("KHR_gaussian_splatting") == std::string::npos) {
    return formats::GaussianFormat::kUnknown;
  }
  return f;
}

// A file mapped read-only: a splat file is read once, front to back, so mapping it spares the
// copy (and the zeroing of a buffer) of a few hundred MB.
class MappedFile {
 public:
  ~MappedFile() {
    if (data_ != nullptr && size_ > 0) ::munmap(data_, size_);
    if (fd_ >= 0) ::close(fd_);
  }
  Status Open(const std::string& path) {
    fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) return Status::IOError(path + ": cannot open: " + std::strerror(errno));
    struct stat st;
    if (::fstat(fd_, &st) != 0) return Status::IOError(path + ": " + std::strerror(errno));
    if (!S_ISREG(st.st_mode)) return Status::InvalidArgument(path + ": not a regular file");
    size_ = static_cast<size_t>(st.st_size);
    if (size_ == 0) return Status::OK();
    data_ = ::mmap(nullptr, size_, PROT_READ, MAP_PRIVATE | MAP_POPULATE, fd_, 0);
    if (data_ == MAP_FAILED) {
      data_ = nullptr;
      return Status::IOError(path + ": cannot map: " + std::strerror(errno));
    }
    return Status::OK();
  }
  std::string_view view() const {
    return data_ ? std::string_view(static_cast<const char*>(data_), size_) : std::string_view();
  }

 private:
  int fd_ = -1;
  void* data_ = nullptr;
  size_t size_ = 0;
};

Result<std::vector<Point>> ReadSplatFrame(const std::string& path, uint32_t frame,
                                          const formats::Similarity& move,
                                          GaussianColumns* records,
                                          std::vector<std::string>* ignored) {
  formats::GaussianCloud cloud;
  {
    MappedFile file;
    HVDB_RETURN_IF_ERROR(file.Open(path));
    HVDB_ASSIGN_OR_RETURN(cloud, formats::ReadGaussians(file.view(), path));
  }
  if (!move.IsIdentity()) HVDB_RETURN_IF_ERROR(formats::TransformCloud(&cloud, move, path));
  *ignored = cloud.ignored;
  std::vector<Point> points;
  formats::CloudToPoints(cloud, frame, &points, records);
  return points;
}

Result<std::vector<std::string>> ExpandSequence(const std::vector<std::string>& args) {
  std::vector<std::string> out;
  for (const std::string& a : args) {
    std::error_code ec;
    if (!fs::is_directory(a, ec)) {
      out.push_back(a);
      continue;
    }
    std::vector<std::string> names;
    for (const auto& e : fs::directory_iterator(a, ec)) {
      if (e.is_regular_file()) names.push_back(e.path().filename().string());
    }
    if (ec) return Status::IOError(a + ": " + ec.message());
    if (names.empty()) return Status::InvalidArgument(a + ": the directory holds no files");
    std::sort(names.begin(), names.end(), NaturalLess);
    for (const std::string& n : names) out.push_back((fs::path(a) / n).string());
  }
  return out;
}

}  // namespace hvdb::cli
