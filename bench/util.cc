#include "bench/util.h"

#include <fcntl.h>
#include <sys/resource.h>
#include <liburing.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <sys/statfs.h>
#include <sys/sysmacros.h>
#include <sys/sysinfo.h>
#include <sys/utsname.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

namespace hvdb::bench {

namespace fs = std::filesystem;

namespace {
const Clock::time_point g_start = Clock::now();
}

void Log(const char* fmt, ...) {
  char buf[1024];
  va_list ap;
  va_start(ap, fmt);
  std::vsnprintf(buf, sizeof(buf), fmt, ap);
  va_end(ap);
  std::fprintf(stderr, "[%7.1fs] %s\n", MsBetween(g_start, Clock::now()) / 1000.0, buf);
}

void Die(const std::string& what) {
  std::fprintf(stderr, "hvdb-bench: %s\n", what.c_str());
  std::exit(1);
}

void Check(const Status& s, const std::string& what) {
  if (!s.ok()) Die(what + ": " + s.ToString());
}

std::vector<Point> UniformPoints(size_t n, uint64_t seed, uint32_t frame) {
  std::vector<Point> pts(n);
  Rng rng(seed);
  for (Point& p : pts) {
    p.x = rng.UniformF();
    p.y = rng.UniformF();
    p.z = rng.UniformF();
    p.frame = frame;
    const float s = 1e-6f * (1.f + rng.UniformF());  // ~1 mm splats
    p.cov = {s, 0, 0, s, 0, s};
    p.normal_oct = EncodeNormal(rng.UniformF() - 0.5f, rng.UniformF() - 0.5f, rng.UniformF() - 0.5f);
    const uint64_t c = rng.Next();
    p.r = static_cast<uint8_t>(c);
    p.g = static_cast<uint8_t>(c >> 8);
    p.b = static_cast<uint8_t>(c >> 16);
    p.flags = kFlagHasNormal | kFlagHasCovariance;
    p.camera = static_cast<uint16_t>((c >> 24) % 8);
  }
  return pts;
}

// --- files -------------------------------------------------------------------------------------

std::vector<std::string> FilesUnder(const std::string& path) {
  std::vector<std::string> out;
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) return {path};
  if (!fs::is_directory(path, ec)) return out;
  for (auto it = fs::recursive_directory_iterator(path, ec); !ec && it != fs::end(it);
       it.increment(ec)) {
    if (it->is_regular_file(ec)) out.push_back(it->path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

uint64_t DiskBytes(const std::string& path) {
  uint64_t total = 0;
  for (const std::string& f : FilesUnder(path)) {
    struct stat st;
    if (::stat(f.c_str(), &st) == 0) total += static_cast<uint64_t>(st.st_blocks) * 512;
  }
  return total;
}

uint64_t FileBytes(const std::string& path) {
  uint64_t total = 0;
  for (const std::string& f : FilesUnder(path)) {
    struct stat st;
    if (::stat(f.c_str(), &st) == 0) total += static_cast<uint64_t>(st.st_size);
  }
  return total;
}

void RemoveAll(const std::string& path) {
  std::error_code ec;
  fs::remove_all(path, ec);
  if (ec) Die("remove " + path + ": " + ec.message());
}

void MakeDirs(const std::string& path) {
  std::error_code ec;
  fs::create_directories(path, ec);
  if (ec) Die("create " + path + ": " + ec.message());
}

ProcCounters ReadProcCounters() {
  ProcCounters c;
  rusage ru{};
  if (::getrusage(RUSAGE_SELF, &ru) == 0) c.minor_faults = static_cast<uint64_t>(ru.ru_minflt);
  std::ifstream io("/proc/self/io");
  std::string key;
  uint64_t v = 0;
  while (io >> key >> v) {
    if (key == "read_bytes:") c.read_bytes = v;
  }
  return c;
}

void Evict(const std::string& path) {
  // fdatasync first: DONTNEED cannot drop dirty pages. (Per file, not syncfs: on a shared
  // machine syncfs would wait for everybody else's writeback too.)
  for (const std::string& f : FilesUnder(path)) {
    int fd = ::open(f.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) continue;  // a file deleted meanwhile (an obsolete tree)
    ::fdatasync(fd);
    ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
    ::close(fd);
  }
}

void SyncFiles(const std::string& path) {
  std::vector<std::string> paths = FilesUnder(path);
  std::error_code ec;
  if (fs::is_directory(path, ec)) {
    paths.push_back(path);
    for (auto it = fs::recursive_directory_iterator(path, ec); !ec && it != fs::end(it);
         it.increment(ec)) {
      if (it->is_directory(ec)) paths.push_back(it->path().string());
    }
  }
  for (const std::string& f : paths) {
    int fd = ::open(f.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) continue;
    ::fdatasync(fd);
    ::close(fd);
  }
}

double ResidentFraction(const std::string& path) {
  const long page = ::sysconf(_SC_PAGESIZE);
  uint64_t pages = 0, resident = 0;
  std::vector<unsigned char> vec;
  for (const std::string& f : FilesUnder(path)) {
    int fd = ::open(f.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) continue;
    struct stat st;
    if (::fstat(fd, &st) == 0 && st.st_size > 0) {
      const auto size = static_cast<size_t>(st.st_size);
      void* m = ::mmap(nullptr, size, PROT_READ, MAP_SHARED, fd, 0);
      if (m != MAP_FAILED) {
        const size_t n = (size + static_cast<size_t>(page) - 1) / static_cast<size_t>(page);
        vec.assign(n, 0);
        if (::mincore(m, size, vec.data()) == 0) {
          pages += n;
          for (unsigned char c : vec) resident += (c & 1);
        }
        ::munmap(m, size);
      }
    }
    ::close(fd);
  }
  return pages ? static_cast<double>(resident) / static_cast<double>(pages) : 0.0;
}

// --- physical limits -------------------------------------------------------------------------

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

Limits::Limits(std::string scratch_dir, int reps)
    : dir_(std::move(scratch_dir)), file_(dir_ + "/limit.bin"), reps_(reps) {
  MakeDirs(dir_);
}

Limits::~Limits() { ::unlink(file_.c_str()); }

void Limits::EnsureFile(uint64_t bytes) {
  constexpr uint64_t kChunk = 4u << 20;
  uint64_t want = std::max<uint64_t>((bytes + kChunk - 1) / kChunk * kChunk, 64u << 20);
  if (file_bytes_ >= want) return;
  int fd = ::open(file_.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) Die("create " + file_ + ": " + std::strerror(errno));
  std::vector<uint8_t> buf(kChunk);
  Rng rng(42);
  for (uint64_t done = 0; done < want; done += kChunk) {
    for (size_t i = 0; i < buf.size(); i += 8) {
      uint64_t r = rng.Next();
      std::memcpy(buf.data() + i, &r, 8);
    }
    if (::write(fd, buf.data(), buf.size()) != static_cast<ssize_t>(buf.size())) {
      Die("write " + file_ + ": " + std::strerror(errno));
    }
  }
  ::fsync(fd);
  ::close(fd);
  file_bytes_ = want;
}

double Limits::Cold::direct_ms() const { return Median(direct); }
double Limits::Cold::buffered_ms() const { return Median(buffered); }

const std::vector<double>& Limits::Warm(uint64_t bytes) {
  if (auto it = warm_.find(bytes); it != warm_.end()) return it->second;
  // The bytes come from a resident source of their full size; they go, batch by batch, into a
  // reused destination of one batch (16384 records, hvdb's default batch), as a consumer of a
  // cursor receives them: the limit is the memory's read bandwidth, not a cold destination.
  constexpr size_t kBatch = 16384 * kPointRecordSize;
  if (src_.size() < bytes) src_.assign(bytes, 0x5a);
  if (dst_.size() < kBatch) dst_.assign(kBatch, 0);
  std::vector<double> t;
  volatile uint8_t sink = 0;
  for (int r = 0; r < reps_ + 1; ++r) {
    Timer tm;
    for (uint64_t at = 0; at < bytes; at += kBatch) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>(kBatch, bytes - at));
      std::memcpy(dst_.data(), src_.data() + at, n);
      sink = sink + dst_[n / 2];
    }
    double ms = tm.Ms();
    if (r > 0) t.push_back(ms);  // the first pass warms the caches and TLB
  }
  (void)sink;
  return warm_[bytes] = t;
}

std::vector<double> RandomBlocksMs(const std::string& file, size_t blocks, size_t block_bytes,
                                   int reps, uint64_t seed) {
  std::vector<double> out;
  int fd = ::open(file.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) Die("open " + file + ": " + std::strerror(errno));
  const uint64_t nblocks = static_cast<uint64_t>(::lseek(fd, 0, SEEK_END)) / block_bytes;
  blocks = std::min<size_t>(blocks, nblocks);
  std::vector<uint8_t> buf(blocks * block_bytes);
  io_uring ring;
  if (io_uring_queue_init(static_cast<unsigned>(std::max<size_t>(blocks, 1)), &ring, 0) != 0) {
    Die("io_uring_queue_init failed");
  }
  Rng rng(seed);
  for (int r = 0; r < reps; ++r) {
    std::vector<uint64_t> pick;
    while (pick.size() < blocks) {
      uint64_t b = rng.Next() % nblocks;
      if (std::find(pick.begin(), pick.end(), b) == pick.end()) pick.push_back(b);
    }
    std::sort(pick.begin(), pick.end());
    Evict(file);
    Timer tm;
    for (size_t i = 0; i < blocks; ++i) {
      io_uring_sqe* sqe = io_uring_get_sqe(&ring);
      io_uring_prep_read(sqe, fd, buf.data() + i * block_bytes, static_cast<unsigned>(block_bytes),
                         pick[i] * block_bytes);
    }
    io_uring_submit(&ring);
    for (size_t i = 0; i < blocks; ++i) {
      io_uring_cqe* cqe = nullptr;
      if (io_uring_wait_cqe(&ring, &cqe) != 0) Die("io_uring wait failed");
      if (cqe->res < 0) Die("read " + file + ": " + std::strerror(-cqe->res));
      io_uring_cqe_seen(&ring, cqe);
    }
    out.push_back(tm.Ms());
  }
  io_uring_queue_exit(&ring);
  ::close(fd);
  return out;
}

const Limits::Cold& Limits::ColdRead(uint64_t bytes) {
  if (auto it = cold_.find(bytes); it != cold_.end()) return it->second;
  EnsureFile(bytes);
  constexpr size_t kDirectChunk = 4u << 20, kAlign = 4096;
  const uint64_t aligned = std::max<uint64_t>((bytes + kAlign - 1) / kAlign * kAlign, kAlign);
  void* raw = std::aligned_alloc(kAlign, kDirectChunk);
  auto* buf = static_cast<uint8_t*>(raw);
  std::memset(buf, 0, kDirectChunk);
  Cold c;
  for (int r = 0; r < reps_; ++r) {
    for (int mode = 0; mode < 2; ++mode) {
      Evict(file_);
      int fd = ::open(file_.c_str(), O_RDONLY | O_CLOEXEC | (mode == 0 ? O_DIRECT : 0));
      if (fd < 0) Die("open " + file_ + ": " + std::strerror(errno));
      const uint64_t total = mode == 0 ? aligned : bytes;
      const size_t chunk = mode == 0 ? kDirectChunk : (1u << 20);
      Timer tm;
      uint64_t done = 0;
      while (done < total) {
        size_t n = static_cast<size_t>(std::min<uint64_t>(chunk, total - done));
        ssize_t got = ::pread(fd, buf, n, static_cast<off_t>(done));
        if (got <= 0) Die("read " + file_ + ": " + std::strerror(errno));
        done += static_cast<uint64_t>(got);
      }
      double ms = tm.Ms();
      ::close(fd);
      (mode == 0 ? c.direct : c.buffered).push_back(ms);
    }
  }
  std::free(raw);
  return cold_[bytes] = c;
}

double Limits::LimitMs(uint64_t bytes, bool cold) {
  return cold ? ColdRead(bytes).best_ms() : Median(Warm(bytes));
}

std::vector<double> Limits::Samples(uint64_t bytes, bool cold) {
  return cold ? ColdRead(bytes).best() : Warm(bytes);
}

nlohmann::json Limits::Describe(uint64_t bytes, bool cold) {
  nlohmann::json j;
  j["bytes"] = bytes;
  j["reps"] = reps_;
  if (cold) {
    const Cold& c = ColdRead(bytes);
    j["kind"] = "sequential read after eviction (faster of O_DIRECT 4 MiB and buffered read)";
    j["o_direct_ms"] = c.direct_ms();
    j["buffered_ms"] = c.buffered_ms();
    j["ms"] = c.best_ms();
  } else {
    j["kind"] = "memcpy from a resident buffer into a reused 1 MiB batch buffer";
    j["ms"] = Median(Warm(bytes));
  }
  return j;
}

double AppendSyncMs(const std::string& scratch_dir, uint64_t bytes, int reps) {
  std::string path = scratch_dir + "/append.bin";
  int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0) Die("create " + path + ": " + std::strerror(errno));
  std::vector<uint8_t> buf(bytes, 0x33);
  std::vector<double> t;
  for (int r = 0; r < reps + 1; ++r) {
    Timer tm;
    if (::write(fd, buf.data(), buf.size()) != static_cast<ssize_t>(buf.size())) {
      Die("write " + path + ": " + std::strerror(errno));
    }
    ::fdatasync(fd);
    if (r > 0) t.push_back(tm.Ms());
  }
  ::close(fd);
  ::unlink(path.c_str());
  return Median(t);
}

std::vector<double> WriteSyncMs(const std::string& scratch_dir, uint64_t bytes, int reps) {
  const std::string path = scratch_dir + "/write.bin";
  std::vector<uint8_t> buf(4u << 20, 0x77);
  std::vector<double> t;
  for (int r = 0; r < reps; ++r) {
    Timer tm;
    int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) Die("create " + path + ": " + std::strerror(errno));
    for (uint64_t done = 0; done < bytes;) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>(buf.size(), bytes - done));
      if (::write(fd, buf.data(), n) != static_cast<ssize_t>(n)) {
        Die("write " + path + ": " + std::strerror(errno));
      }
      done += n;
    }
    ::fdatasync(fd);
    ::close(fd);
    t.push_back(tm.Ms());
    ::unlink(path.c_str());
  }
  return t;
}

// --- hvdb ------------------------------------------------------------------------------------

Db Db::Create(const std::string& dir, const std::string& name, const Options& opts, double fps) {
  RemoveAll(dir);
  Db d;
  d.dir = dir;
  d.name = name;
  d.opts = opts;
  d.db = Check(Database::Open(dir, opts), "open " + dir);
  DatasetInfo info;
  info.name = name;
  info.fps = fps;
  d.ds = Check(d.db->CreateDataset(info), "create dataset " + name);
  return d;
}

void Db::Close() {
  ds.reset();
  db.reset();
}

void Db::Reopen(bool cold) {
  Close();
  if (cold) Evict(dir);
  db = Check(Database::Open(dir, opts), "open " + dir);
  ds = Check(db->GetDataset(name), "open dataset " + name);
  if (cold) {
    Evict(dir);
    last_resident = ResidentFraction(DatasetDir());
  }
}

QueryRun RunQuery(Dataset& ds, const Region& region, const QueryOptions& qo) {
  QueryRun run;
  Timer tm;
  auto cursor = Check(ds.Query(region, qo), "query");
  run.frames = static_cast<uint32_t>(cursor->frames().size());
  Batch batch;
  while (true) {
    bool more = Check(cursor->Next(&batch), "query next");
    run.points += batch.points.size();
    if (qo.progressive && batch.level_done) {
      run.level_ms.push_back(tm.Ms());
      run.level_points.push_back(run.points);
    }
    if (!more) break;
  }
  run.ms = tm.Ms();
  return run;
}

Window FrameWindow(uint32_t frame, double fps) {
  Window w;
  w.lo = {-1e9, -1e9, -1e9, (frame - 0.25) / fps};
  w.hi = {1e9, 1e9, 1e9, (frame + 0.25) / fps};
  return w;
}

std::vector<std::string> FrameTreeFiles(const Db& db, uint32_t frame) {
  char prefix[16];
  std::snprintf(prefix, sizeof(prefix), "%08u-", frame);
  std::vector<std::string> out;
  for (const std::string& f : FilesUnder(db.DatasetDir() + "/trees")) {
    if (fs::path(f).filename().string().rfind(prefix, 0) == 0) out.push_back(f);
  }
  return out;
}

// --- machine ---------------------------------------------------------------------------------

namespace {

std::string Trim(std::string s) {
  while (!s.empty() && (s.back() == '\n' || s.back() == ' ' || s.back() == '\t')) s.pop_back();
  size_t i = 0;
  while (i < s.size() && (s[i] == ' ' || s[i] == '\t')) ++i;
  return s.substr(i);
}

std::string ReadSmall(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return Trim(ss.str());
}

std::string CpuInfoField(const std::string& key) {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(key, 0) == 0) {
      auto c = line.find(':');
      if (c != std::string::npos) return Trim(line.substr(c + 1));
    }
  }
  return "unknown";
}

}  // namespace

nlohmann::json MachineInfo(const std::string& scratch_dir) {
  nlohmann::json m;
  m["nproc"] = std::thread::hardware_concurrency();
  m["cpu_model"] = CpuInfoField("model name");
  struct sysinfo si;
  if (::sysinfo(&si) == 0) {
    m["memory_bytes"] = static_cast<uint64_t>(si.totalram) * si.mem_unit;
  }
  struct utsname u;
  if (::uname(&u) == 0) {
    m["kernel"] = std::string(u.sysname) + " " + u.release + " " + u.version;
    m["arch"] = u.machine;
  }
  m["os"] = "unknown";
  {
    std::ifstream in("/etc/os-release");
    std::string line;
    while (std::getline(in, line)) {
      if (line.rfind("PRETTY_NAME=", 0) == 0) {
        std::string v = line.substr(12);
        if (v.size() >= 2 && v.front() == '"') v = v.substr(1, v.size() - 2);
        m["os"] = v;
      }
    }
  }
  // The file system and block device the scratch directory is on.
  struct stat st;
  if (::stat(scratch_dir.c_str(), &st) == 0) {
    unsigned maj = major(st.st_dev), min = minor(st.st_dev);
    std::ifstream mi("/proc/self/mountinfo");
    std::string line;
    while (std::getline(mi, line)) {
      std::istringstream ls(line);
      std::string id, parent, devno, root, mnt;
      ls >> id >> parent >> devno >> root >> mnt;
      if (devno != std::to_string(maj) + ":" + std::to_string(min)) continue;
      auto dash = line.find(" - ");
      if (dash == std::string::npos) continue;
      std::istringstream rest(line.substr(dash + 3));
      std::string fstype, source;
      rest >> fstype >> source;
      m["disk"]["mount"] = mnt;
      m["disk"]["fs"] = fstype;
      m["disk"]["device"] = source;
      break;
    }
    std::string sys = "/sys/dev/block/" + std::to_string(maj) + ":" + std::to_string(min);
    std::error_code ec;
    std::string dev = fs::canonical(sys, ec).filename().string();
    if (!ec) {
      std::string q = "/sys/block/" + dev + "/queue/";
      m["disk"]["block_device"] = dev;
      m["disk"]["rotational"] = ReadSmall(q + "rotational");
      m["disk"]["scheduler"] = ReadSmall(q + "scheduler");
      std::string sectors = ReadSmall("/sys/block/" + dev + "/size");
      if (!sectors.empty()) m["disk"]["size_bytes"] = std::stoull(sectors) * 512;
      std::string model = ReadSmall("/sys/block/" + dev + "/device/model");
      if (!model.empty()) m["disk"]["model"] = model;
      std::string vendor = ReadSmall("/sys/block/" + dev + "/device/vendor");
      if (!vendor.empty()) m["disk"]["vendor"] = vendor;
    }
  }
  struct statfs sf;
  if (::statfs(scratch_dir.c_str(), &sf) == 0) {
    m["disk"]["free_bytes"] = static_cast<uint64_t>(sf.f_bavail) * sf.f_bsize;
  }
  bool vm = CpuInfoField("flags").find("hypervisor") != std::string::npos;
  m["virtual_machine"] = vm;
  double load[3] = {0, 0, 0};
  if (::getloadavg(load, 3) == 3) m["loadavg_at_start"] = {load[0], load[1], load[2]};
  return m;
}

}  // namespace hvdb::bench
