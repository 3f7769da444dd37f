// The POSIX Env: pread/pwrite/fdatasync on file descriptors.
#include "storage/env.h"
#include "storage/log.h"

#include <dirent.h>
#include <fcntl.h>
#include <liburing.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/uio.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>

namespace hvdb {

namespace {

// Reads the rest of a request after `done` bytes with preadv, to the end or an error.
Status FinishRead(int fd, const std::string& path, uint64_t file_size, ReadRequest* r,
                  size_t done) {
  size_t total = 0;
  for (auto b : r->buffers) total += b.size();
  while (done < total) {
    iovec iov[64];
    int n = 0;
    size_t skip = done;
    for (auto b : r->buffers) {
      if (skip >= b.size()) {
        skip -= b.size();
        continue;
      }
      if (n == 64) break;
      iov[n++] = {b.data() + skip, b.size() - skip};
      skip = 0;
    }
    ssize_t got = ::preadv(fd, iov, n, static_cast<off_t>(r->offset + done));
    if (got < 0) {
      if (errno == EINTR) continue;
      return Status::FromErrno("read " + path, errno);
    }
    if (got == 0) {
      return Status::Corruption(path + ": truncated: wanted " + std::to_string(total) +
                                " bytes at offset " + std::to_string(r->offset) +
                                ", file has " + std::to_string(file_size));
    }
    done += static_cast<size_t>(got);
  }
  return Status::OK();
}

// One io_uring per thread that reads batches (the buffer pool's loader threads, mostly).
class Ring {
 public:
  static constexpr unsigned kDepth = 64;
  Ring() { ok_ = io_uring_queue_init(kDepth, &ring_, 0) == 0; }
  ~Ring() {
    if (ok_) io_uring_queue_exit(&ring_);
  }
  bool ok() const { return ok_; }
  io_uring* get() { return &ring_; }

 private:
  io_uring ring_{};
  bool ok_ = false;
};

bool UringAvailable() {
  static const bool ok = [] {
    Ring probe;
    if (!probe.ok()) {
      LogNote("io_uring is not available here; batched reads use preadv");
    }
    return probe.ok();
  }();
  return ok;
}

class PosixRandomAccessFile final : public RandomAccessFile {
 public:
  PosixRandomAccessFile(std::string path, int fd, uint64_t size, Env::ReadEngine engine)
      : path_(std::move(path)), fd_(fd), size_(size), engine_(engine) {}
  ~PosixRandomAccessFile() override { ::close(fd_); }

  Status Read(uint64_t offset, size_t n, void* dst) const override {
    auto* p = static_cast<char*>(dst);
    size_t done = 0;
    while (done < n) {
      ssize_t r = ::pread(fd_, p + done, n - done, static_cast<off_t>(offset + done));
      if (r < 0) {
        if (errno == EINTR) continue;
        return Status::FromErrno("read " + path_, errno);
      }
      if (r == 0) {
        return Status::Corruption(path_ + ": truncated: wanted " + std::to_string(n) +
                                  " bytes at offset " + std::to_string(offset) + ", file has " +
                                  std::to_string(size_));
      }
      done += static_cast<size_t>(r);
    }
    return Status::OK();
  }
  void ReadBatch(std::span<ReadRequest> reqs) const override {
    if (engine_ == Env::ReadEngine::kIoUring && UringBatch(reqs)) return;
    for (ReadRequest& r : reqs) r.status = FinishRead(fd_, path_, size_, &r, 0);
  }
  void DropCache() const override { ::posix_fadvise(fd_, 0, 0, POSIX_FADV_DONTNEED); }
  uint64_t size() const override { return size_; }
  const std::string& path() const override { return path_; }

 private:
  // All requests in flight at once (up to the ring's depth); a short completion is finished
  // with preadv. False if this thread has no ring.
  bool UringBatch(std::span<ReadRequest> reqs) const {
    thread_local Ring ring;
    if (!ring.ok()) return false;
    std::vector<std::vector<iovec>> iovs(reqs.size());
    for (size_t i = 0; i < reqs.size(); ++i) {
      for (auto b : reqs[i].buffers) iovs[i].push_back({b.data(), b.size()});
    }
    for (size_t first = 0; first < reqs.size(); first += Ring::kDepth) {
      const size_t n = std::min<size_t>(Ring::kDepth, reqs.size() - first);
      for (size_t i = first; i < first + n; ++i) {
        io_uring_sqe* sqe = io_uring_get_sqe(ring.get());
        io_uring_prep_readv(sqe, fd_, iovs[i].data(), static_cast<unsigned>(iovs[i].size()),
                            reqs[i].offset);
        io_uring_sqe_set_data64(sqe, i);
      }
      int submitted = io_uring_submit(ring.get());
      if (submitted < 0) {
        for (size_t i = first; i < reqs.size(); ++i) {
          reqs[i].status = FinishRead(fd_, path_, size_, &reqs[i], 0);
        }
        return true;
      }
      for (size_t k = 0; k < n; ++k) {
        io_uring_cqe* cqe = nullptr;
        int rc = io_uring_wait_cqe(ring.get(), &cqe);
        if (rc < 0) {  // cannot happen with requests in flight, but never leave one unread
          if (rc == -EINTR) {
            --k;
            continue;
          }
          for (size_t i = first; i < first + n; ++i) {
            reqs[i].status = Status::FromErrno("io_uring wait " + path_, -rc);
          }
          break;
        }
        const size_t i = io_uring_cqe_get_data64(cqe);
        const int res = cqe->res;
        io_uring_cqe_seen(ring.get(), cqe);
        if (res < 0) {
          reqs[i].status = Status::FromErrno("read " + path_, -res);
        } else {
          reqs[i].status = FinishRead(fd_, path_, size_, &reqs[i], static_cast<size_t>(res));
        }
      }
    }
    return true;
  }

  std::string path_;
  int fd_;
  uint64_t size_;
  Env::ReadEngine engine_;
};

class PosixWritableFile final : public WritableFile {
 public:
  PosixWritableFile(std::string path, int fd, uint64_t size)
      : path_(std::move(path)), fd_(fd), size_(size) {}
  ~PosixWritableFile() override { ::close(fd_); }

  Status Append(std::string_view data) override {
    Status s = WriteAt(size_, data);
    if (!s.ok()) {
      // Leave no partial record behind: a log must end on a record boundary.
      (void)::ftruncate(fd_, static_cast<off_t>(size_));
    }
    return s;
  }
  Status WriteAt(uint64_t offset, std::string_view data) override {
    size_t done = 0;
    while (done < data.size()) {
      ssize_t w = ::pwrite(fd_, data.data() + done, data.size() - done,
                           static_cast<off_t>(offset + done));
      if (w < 0) {
        if (errno == EINTR) continue;
        return Status::FromErrno("write " + path_, errno);
      }
      done += static_cast<size_t>(w);
    }
    size_ = std::max<uint64_t>(size_, offset + data.size());
    return Status::OK();
  }
  Status Sync() override {
    if (::fdatasync(fd_) != 0) return Status::FromErrno("fsync " + path_, errno);
    return Status::OK();
  }
  Status Truncate(uint64_t size) override {
    if (::ftruncate(fd_, static_cast<off_t>(size)) != 0) {
      return Status::FromErrno("truncate " + path_, errno);
    }
    size_ = size;
    return Status::OK();
  }
  uint64_t size() const override { return size_; }
  const std::string& path() const override { return path_; }

 private:
  std::string path_;
  int fd_;
  uint64_t size_;
};

class PosixFileLock final : public FileLock {
 public:
  explicit PosixFileLock(int fd) : fd_(fd) {}
  ~PosixFileLock() override { ::close(fd_); }  // closing releases the flock

 private:
  int fd_;
};

class PosixEnv final : public Env {
 public:
  explicit PosixEnv(ReadEngine engine) : engine_(engine) {}
  Result<std::shared_ptr<RandomAccessFile>> OpenRead(const std::string& path) override {
    int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) return Status::FromErrno("open " + path, errno);
    struct stat st;
    if (::fstat(fd, &st) != 0) {
      int err = errno;
      ::close(fd);
      return Status::FromErrno("stat " + path, err);
    }
    return std::shared_ptr<RandomAccessFile>(
        new PosixRandomAccessFile(path, fd, static_cast<uint64_t>(st.st_size), engine_));
  }

  Result<std::unique_ptr<WritableFile>> OpenWrite(const std::string& path,
                                                  bool truncate) override {
    int flags = O_WRONLY | O_CREAT | O_CLOEXEC | (truncate ? O_TRUNC : 0);
    int fd = ::open(path.c_str(), flags, 0644);
    if (fd < 0) return Status::FromErrno("open " + path, errno);
    off_t end = ::lseek(fd, 0, SEEK_END);
    if (end < 0) {
      int err = errno;
      ::close(fd);
      return Status::FromErrno("seek " + path, err);
    }
    return std::unique_ptr<WritableFile>(
        new PosixWritableFile(path, fd, static_cast<uint64_t>(end)));
  }

  Status Rename(const std::string& from, const std::string& to) override {
    if (::rename(from.c_str(), to.c_str()) != 0) return Status::FromErrno("rename " + from, errno);
    return Status::OK();
  }

  Status Remove(const std::string& path) override {
    if (::unlink(path.c_str()) != 0 && errno != ENOENT) {
      return Status::FromErrno("remove " + path, errno);
    }
    return Status::OK();
  }

  Status SyncDir(const std::string& dir) override {
    int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) return Status::FromErrno("open dir " + dir, errno);
    int rc = ::fsync(fd);
    int err = errno;
    ::close(fd);
    if (rc != 0) return Status::FromErrno("fsync dir " + dir, err);
    return Status::OK();
  }

  Status CreateDirs(const std::string& dir) override {
    std::error_code ec;
    std::filesystem::create_directories(dir, ec);
    if (ec) return Status::IOError("create directory " + dir + ": " + ec.message());
    return Status::OK();
  }

  Result<std::vector<std::string>> ListDir(const std::string& dir) override {
    DIR* d = ::opendir(dir.c_str());
    if (d == nullptr) return Status::FromErrno("list " + dir, errno);
    std::vector<std::string> names;
    while (dirent* e = ::readdir(d)) {
      std::string n = e->d_name;
      if (n != "." && n != "..") names.push_back(n);
    }
    ::closedir(d);
    return names;
  }

  Status RemoveTree(const std::string& dir) override {
    std::error_code ec;
    std::filesystem::remove_all(dir, ec);
    if (ec) return Status::IOError("remove " + dir + ": " + ec.message());
    return Status::OK();
  }

  bool Exists(const std::string& path) override { return ::access(path.c_str(), F_OK) == 0; }

  Status WriteNewFile(const std::string& path, std::string_view data, bool sync) override {
    const FileExtent all{0, data.size()};
    return WriteNewSparseFile(path, data, std::span<const FileExtent>(&all, 1), sync);
  }

  // Writes the extents with pwrite and sizes the file with ftruncate: the gaps stay holes
  // (zeros that take no blocks). Durable: written as path.tmp, synced, renamed, the directory
  // synced; its data bypasses the page cache (O_DIRECT) when all of it is 4 KiB-aligned, as
  // the bytes must reach the device anyway.
  Status WriteNewSparseFile(const std::string& path, std::string_view data,
                            std::span<const FileExtent> extents, bool sync) override {
    bool aligned = reinterpret_cast<uintptr_t>(data.data()) % 4096 == 0;
    for (const FileExtent& e : extents) {
      if (e.offset > data.size() || e.length > data.size() - e.offset) {
        return Status::InvalidArgument("write " + path + ": extent past the end of the data");
      }
      aligned = aligned && e.offset % 4096 == 0 && e.length % 4096 == 0;
    }
    const std::string target = sync ? path + ".tmp" : path;
    const int flags = O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC;
    int fd = sync && aligned ? ::open(target.c_str(), flags | O_DIRECT, 0644) : -1;
    // File systems without direct I/O (tmpfs) refuse the flag: write through the cache there.
    if (fd < 0) fd = ::open(target.c_str(), flags, 0644);
    if (fd < 0) return Status::FromErrno("open " + target, errno);
    Status st;
    for (const FileExtent& e : extents) {
      for (uint64_t done = 0; done < e.length && st.ok();) {
        const size_t n = static_cast<size_t>(std::min<uint64_t>(e.length - done, 64u << 20));
        ssize_t w = ::pwrite(fd, data.data() + e.offset + done, n,
                             static_cast<off_t>(e.offset + done));
        if (w < 0 && errno == EINTR) continue;
        if (w <= 0) {
          st = Status::FromErrno("write " + target, w < 0 ? errno : EIO);
          break;
        }
        done += static_cast<uint64_t>(w);
      }
    }
    if (st.ok() && ::ftruncate(fd, static_cast<off_t>(data.size())) != 0) {
      st = Status::FromErrno("truncate " + target, errno);
    }
    if (st.ok() && sync && ::fdatasync(fd) != 0) st = Status::FromErrno("fsync " + target, errno);
    ::close(fd);
    if (st.ok() && sync) st = Rename(target, path);
    if (!st.ok()) {
      (void)Remove(target);
      return st;
    }
    return sync ? SyncDir(ParentDir(path)) : Status::OK();
  }

  Result<std::unique_ptr<FileLock>> Lock(const std::string& path) override {
    int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) return Status::FromErrno("open " + path, errno);
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      ::close(fd);
      return Status::IOError(path + " is locked by another process");
    }
    return std::unique_ptr<FileLock>(new PosixFileLock(fd));
  }

 private:
  const ReadEngine engine_;
};

}  // namespace

Env* Env::Posix(ReadEngine engine) {
  // Never destroyed: datasets may outlive static teardown.
  static Env* uring = new PosixEnv(ReadEngine::kIoUring);
  static Env* preadv = new PosixEnv(ReadEngine::kPreadv);
  return engine == ReadEngine::kIoUring ? uring : preadv;
}

Env* Env::Default() {
  static Env* env = Posix(UringAvailable() ? ReadEngine::kIoUring : ReadEngine::kPreadv);
  return env;
}

std::string ParentDir(const std::string& path) {
  size_t slash = path.find_last_of('/');
  if (slash == std::string::npos) return ".";
  if (slash == 0) return "/";
  return path.substr(0, slash);
}

Status Env::WriteNewFile(const std::string& path, std::string_view data, bool sync) {
  if (sync) return WriteFileAtomic(this, path, data);
  HVDB_ASSIGN_OR_RETURN(auto f, OpenWrite(path, /*truncate=*/true));
  return f->Append(data);
}

Status WriteFileAtomic(Env* env, const std::string& path, std::string_view data) {
  std::string tmp = path + ".tmp";
  {
    HVDB_ASSIGN_OR_RETURN(auto f, env->OpenWrite(tmp, /*truncate=*/true));
    Status s = f->Append(data);
    if (s.ok()) s = f->Sync();
    if (!s.ok()) {
      (void)env->Remove(tmp);
      return s;
    }
  }
  Status s = env->Rename(tmp, path);
  if (!s.ok()) {
    (void)env->Remove(tmp);
    return s;
  }
  return env->SyncDir(ParentDir(path));
}

Result<std::string> ReadWholeFile(Env* env, const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(auto f, env->OpenRead(path));
  std::string data(f->size(), '\0');
  HVDB_RETURN_IF_ERROR(f->Read(0, data.size(), data.data()));
  return data;
}

}  // namespace hvdb
