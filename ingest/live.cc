// The pieces of live ingest that are not the follower's loop (ingest/follow.cc): which files a
// frame needs, whether a file is completely written, and replaying a recording at its rate.
#include "ingest/live.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <optional>
#include <sstream>
#include <thread>

#include <ImfInputFile.h>

namespace hvdb::ingest {

namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

int64_t NowMs() {
  return std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now().time_since_epoch()).count();
}

// Reads up to n bytes at offset; fewer at the end of the file.
std::string ReadAt(int fd, off_t offset, size_t n) {
  std::string out(n, '\0');
  size_t got = 0;
  while (got < n) {
    const ssize_t r = ::pread(fd, out.data() + got, n - got, offset + static_cast<off_t>(got));
    if (r <= 0) break;
    got += static_cast<size_t>(r);
  }
  out.resize(got);
  return out;
}

int PlyTypeSize(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

// A PLY file: "complete" when its binary body of fixed-size elements is all there; nullopt
// when that cannot be told from the size (ASCII, list properties): the caller falls back.
std::optional<FileCheck> PlyComplete(int fd, int64_t size) {
  const std::string head = ReadAt(fd, 0, static_cast<size_t>(std::min<int64_t>(size, 1 << 16)));
  const size_t end = head.find("end_header");
  if (end == std::string::npos) return FileCheck{false, "incomplete: the PLY header has no end_header yet"};
  const size_t body = head.find('\n', end);
  if (body == std::string::npos) return FileCheck{false, "incomplete: the PLY header is not finished"};
  std::istringstream in(head.substr(0, end));
  std::string line;
  bool binary = false;
  int64_t expected = static_cast<int64_t>(body + 1), count = 0, stride = 0;
  while (std::getline(in, line)) {
    std::istringstream l(line);
    std::string key, a, b;
    l >> key >> a >> b;
    if (key == "format") {
      binary = a.rfind("binary", 0) == 0;
    } else if (key == "element") {
      expected += count * stride;
      count = std::atoll(b.c_str());
      stride = 0;
    } else if (key == "property" && count > 0) {  // "element face 0" with a list: no bytes
      if (a == "list") return std::nullopt;
      const int s = PlyTypeSize(a);
      if (s == 0) return std::nullopt;
      stride += s;
    }
  }
  expected += count * stride;
  if (!binary) return std::nullopt;
  if (size < expected)
    return FileCheck{false, "incomplete: " + std::to_string(size) + " of the PLY's " +
                                std::to_string(expected) + " bytes"};
  return FileCheck{true, ""};
}

}  // namespace

std::vector<std::string> FrameFiles(const Recording& r, int i) {
  std::vector<std::string> out;
  if (r.kind == RecordingKind::kPly) {
    out.push_back(r.Path(r.ply, i));
    for (const CameraFiles& cf : r.files) out.push_back(r.Path(cf.colour, i, cf.camera));
    return out;
  }
  for (const CameraFiles& cf : r.files) {
    if (r.kind == RecordingKind::kStereo) {
      for (const std::string* p : {&cf.left, &cf.right, &cf.colour}) out.push_back(r.Path(*p, i));
    } else {
      out.push_back(r.Path(cf.colour, i, cf.camera));
      out.push_back(r.Path(cf.depth, i, cf.camera));
      if (!cf.pose.empty()) out.push_back(r.Path(cf.pose, i, cf.camera));
    }
  }
  return out;
}

FileCheck FileCompleteness::Check(const std::string& path, bool closed) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    seen_.erase(path);
    return {false, "missing"};
  }
  if (!S_ISREG(st.st_mode)) return {false, "not a regular file"};
  const int64_t size = st.st_size;
  const int64_t mtime = int64_t{st.st_mtim.tv_sec} * 1000000000 + st.st_mtim.tv_nsec;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return {false, std::string("cannot open: ") + std::strerror(errno)};
  const std::string magic = ReadAt(fd, 0, 4);
  std::optional<FileCheck> marker;
  if (magic.rfind("\x89PNG", 0) == 0) {
    static const char kIend[] = "\0\0\0\0IEND\xae\x42\x60\x82";
    const bool ok = size >= 20 && ReadAt(fd, size - 12, 12) == std::string(kIend, 12);
    marker = ok ? FileCheck{true, ""} : FileCheck{false, "incomplete: no IEND chunk at its end yet"};
  } else if (magic.rfind("\xff\xd8\xff", 0) == 0) {
    const bool ok = size >= 4 && ReadAt(fd, size - 2, 2) == "\xff\xd9";
    marker = ok ? FileCheck{true, ""} : FileCheck{false, "incomplete: no JPEG EOI marker at its end yet"};
  } else if (magic == std::string("\x76\x2f\x31\x01", 4)) {
    try {
      Imf::InputFile f(path.c_str());
      marker = f.isComplete() ? FileCheck{true, ""}
                              : FileCheck{false, "incomplete: OpenEXR misses some of its scanlines"};
    } catch (const std::exception& e) {
      marker = FileCheck{false, std::string("incomplete: OpenEXR cannot read it yet (") + e.what() + ")"};
    }
  } else if (magic.rfind("ply", 0) == 0) {
    marker = PlyComplete(fd, size);
  } else if (path.size() > 4 && path.compare(path.size() - 4, 4, ".txt") == 0 && size < (1 << 16)) {
    // A pose: whole once it holds 16 numbers and ends with a newline (a cut can only end in
    // one after a complete number). Otherwise the "other" rule below decides.
    const std::string text = ReadAt(fd, 0, static_cast<size_t>(size));
    std::istringstream in(text);
    std::string tok;
    int numbers = 0;
    while (in >> tok) {
      char* end = nullptr;
      std::strtod(tok.c_str(), &end);
      numbers += end != tok.c_str() && *end == '\0';
    }
    if (numbers >= 16 && !text.empty() && text.back() == '\n') marker = FileCheck{true, ""};
  }
  ::close(fd);
  if (marker) return *marker;
  // No end marker to look for: complete once the writer closed it, or when it has not
  // changed for settle_ms: by its mtime (a file already there when we first look), or between
  // two looks (a filesystem whose clock is not ours).
  Seen& s = seen_[path];
  const int64_t now = NowMs();
  if (s.size != size || s.mtime_ns != mtime) s = Seen{size, mtime, now};
  if (size == 0) return {false, "empty"};
  timespec real{};
  ::clock_gettime(CLOCK_REALTIME, &real);
  const int64_t age_ms = (int64_t{real.tv_sec} * 1000000000 + real.tv_nsec - mtime) / 1000000;
  if (closed || age_ms >= settle_ms_ || now - s.since_ms >= settle_ms_) return {true, ""};
  FileCheck c{false, "still being written (changed in the last " + std::to_string(settle_ms_) + " ms)"};
  c.settle_left_ms = static_cast<int>(std::max<int64_t>(1, settle_ms_ - std::max(age_ms, now - s.since_ms)));
  return c;
}

// ---------------------------------------------------------------- replay

namespace {

// Writes a file through a temporary name in its directory and renames it into place.
Status Publish(const std::string& tmp, const std::string& path) {
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) return Status::IOError(path + ": cannot rename into place: " + ec.message());
  return Status::OK();
}

std::string TempName(const std::string& path) {
  const fs::path p(path);
  std::string name = ".";  // appended piecewise: GCC 12 warns falsely on chained operator+
  name += p.filename().string();
  name += ".tmp";
  return (p.parent_path() / name).string();
}

}  // namespace

Result<ReplayReport> ReplayRecording(const std::string& src_dir, const std::string& out,
                                     const ReplayOptions& o,
                                     const std::function<void(int, int, double)>& progress) {
  if (!(o.fps >= 0 && o.fps <= 1000)) return Status::InvalidArgument("--realtime must be in [0, 1000] fps");
  if (o.loop < 1) return Status::InvalidArgument("--loop must be at least 1");
  HVDB_ASSIGN_OR_RETURN(Recording src, OpenRecording(src_dir));
  const int n = o.count > 0 ? std::min(o.count, src.frames) : src.frames;
  std::error_code ec;
  if (fs::exists(out, ec) && !fs::is_empty(out, ec))
    return Status::AlreadyExists(out + ": exists and is not empty; replay writes a new recording");
  fs::create_directories(out, ec);
  if (ec) return Status::IOError(out + ": cannot create: " + ec.message());

  // The copy's layout: frames/NNNNNN/<camera>[.<role>]<ext of the source file>.
  Recording dst = src;
  dst.dir = out;
  dst.frames = n * o.loop;
  dst.first_frame = 0;
  dst.frame_step = 1;
  auto ext = [&](const std::string& pattern, const std::string& camera) {
    return fs::path(src.Path(pattern, 0, camera)).extension().string();
  };
  const std::string fd = "frames/{frame:06d}/";
  if (src.kind == RecordingKind::kPly) {
    dst.ply = "frames/{frame:06d}" + ext(src.ply, "");
  }
  for (size_t k = 0; k < dst.files.size(); ++k) {
    CameraFiles& cf = dst.files[k];
    const CameraFiles& sf = src.files[k];
    if (src.kind == RecordingKind::kStereo) {
      const Brick& b = src.calibration.bricks[k];
      cf.left = fd + src.calibration.cameras[static_cast<size_t>(b.left)].name + ext(sf.left, "");
      cf.right = fd + src.calibration.cameras[static_cast<size_t>(b.right)].name + ext(sf.right, "");
      cf.colour = fd + src.calibration.cameras[static_cast<size_t>(b.colour)].name + ext(sf.colour, "");
    } else if (src.kind == RecordingKind::kPly) {
      cf.colour = fd + sf.camera + ".colour" + ext(sf.colour, sf.camera);
    } else {
      cf.colour = fd + sf.camera + ".colour" + ext(sf.colour, sf.camera);
      cf.depth = fd + sf.camera + ".depth" + ext(sf.depth, sf.camera);
      if (!sf.pose.empty()) cf.pose = fd + sf.camera + ".pose" + ext(sf.pose, sf.camera);
    }
  }
  // The description first, each renamed into place whole.
  if (src.kind != RecordingKind::kPly || !src.files.empty()) {
    const std::string cal = (fs::path(out) / "calibration.yml").string();
    const std::string tmp = (fs::path(out) / ".calibration.tmp.yml").string();
    HVDB_RETURN_IF_ERROR(SaveCalibration(src.calibration, tmp));
    HVDB_RETURN_IF_ERROR(Publish(tmp, cal));
  }
  {
    Recording staged = dst;
    staged.dir = (fs::path(out) / ".recording.tmp").string();
    fs::create_directories(staged.dir, ec);
    HVDB_RETURN_IF_ERROR(SaveRecording(staged));
    HVDB_RETURN_IF_ERROR(Publish((fs::path(staged.dir) / "recording.yml").string(),
                                 (fs::path(out) / "recording.yml").string()));
    fs::remove_all(staged.dir, ec);
  }
  ReplayReport rep;
  const auto start = Clock::now();
  for (int k = 0; k < dst.frames; ++k) {
    if (o.stop != nullptr && o.stop->load()) break;
    const int i = k % n;
    const std::vector<std::string> from = FrameFiles(src, i), to = FrameFiles(dst, k);
    std::vector<std::pair<std::string, std::string>> staged;
    for (size_t f = 0; f < from.size(); ++f) {
      fs::create_directories(fs::path(to[f]).parent_path(), ec);
      const std::string tmp = TempName(to[f]);
      fs::copy_file(from[f], tmp, fs::copy_options::overwrite_existing, ec);
      if (ec) return Status::IOError(from[f] + ": cannot copy to " + tmp + ": " + ec.message());
      staged.emplace_back(tmp, to[f]);
    }
    double late = 0;
    if (o.fps > 0) {
      const auto due = start + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(k / o.fps));
      if (Clock::now() < due) {
        std::this_thread::sleep_until(due);
      } else {
        late = std::chrono::duration<double>(Clock::now() - due).count();
        if (late > 0.5 / o.fps) ++rep.late;
        rep.max_late_s = std::max(rep.max_late_s, late);
      }
    }
    for (const auto& [tmp, path] : staged) HVDB_RETURN_IF_ERROR(Publish(tmp, path));
    ++rep.frames;
    if (progress) progress(rep.frames, dst.frames, late);
  }
  rep.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return rep;
}

}  // namespace hvdb::ingest
