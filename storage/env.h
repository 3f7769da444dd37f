// Env: the one seam between storage/ and the file system, after LevelDB's Env. Every open,
// read, write, sync, rename, remove and listing of storage/ goes through an Env, so that
//   - tests can inject faults (failed writes and syncs, short reads, ENOSPC, EIO, power loss)
//     with a wrapping Env (tests/storage/fault_env.h), and
//   - a second store (a distributed object store) can replace the POSIX one.
// Env::Default() is POSIX. Every errno becomes a Status here; callers never see errno.
//
// Paths are plain strings joined with '/'. Directories are namespaces: SyncDir makes the
// creations, renames and removals of names in `dir` durable (POSIX semantics; an object store
// may make it a no-op). File contents are durable once WritableFile::Sync returns.
#ifndef HVDB_STORAGE_ENV_H_
#define HVDB_STORAGE_ENV_H_

#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "storage/status.h"

namespace hvdb {

// One read of a batch: the bytes from `offset` on, scattered over `buffers` in order.
struct ReadRequest {
  uint64_t offset = 0;
  std::vector<std::span<uint8_t>> buffers;
  Status status;  // set by ReadBatch
};

// A range of a file image that holds data (see Env::WriteNewSparseFile).
struct FileExtent {
  uint64_t offset = 0, length = 0;
};

// A read-only file; Read and ReadBatch are safe for concurrent callers.
class RandomAccessFile {
 public:
  virtual ~RandomAccessFile() = default;
  // Reads exactly n bytes at offset; a short read is Corruption ("truncated").
  virtual Status Read(uint64_t offset, size_t n, void* dst) const = 0;
  // Reads every request, all issued before any is waited for (the device serves them in
  // parallel), and returns when all are done; each gets its own status, as Read's.
  virtual void ReadBatch(std::span<ReadRequest> requests) const = 0;
  // Drops the file's cached pages (for cold benchmarks). Only a hint.
  virtual void DropCache() const = 0;
  virtual uint64_t size() const = 0;
  virtual const std::string& path() const = 0;
};

// A file written by appending, plus positional writes for builders that fill in a header last.
class WritableFile {
 public:
  virtual ~WritableFile() = default;
  // On failure nothing of `data` stays: the file ends where it ended before.
  virtual Status Append(std::string_view data) = 0;
  // Writes at `offset` (which may lie past the end: the gap reads as zeros).
  virtual Status WriteAt(uint64_t offset, std::string_view data) = 0;
  virtual Status Sync() = 0;  // contents durable (fdatasync)
  virtual Status Truncate(uint64_t size) = 0;
  virtual uint64_t size() const = 0;
  virtual const std::string& path() const = 0;
};

// Held while a directory is in use by this process; released on destruction.
class FileLock {
 public:
  virtual ~FileLock() = default;
};

class Env {
 public:
  virtual ~Env() = default;
  // How the POSIX Env serves ReadBatch: io_uring (Debian's liburing; all requests in one
  // submission) or one preadv after another (bench/README.md compares them).
  enum class ReadEngine { kIoUring, kPreadv };
  // The process-wide POSIX Env: io_uring where the kernel allows it (else preadv, said once on
  // stderr). Never deleted.
  static Env* Default();
  static Env* Posix(ReadEngine engine);

  virtual Result<std::shared_ptr<RandomAccessFile>> OpenRead(const std::string& path) = 0;
  // Opens for writing at the end, creating it if absent (truncate: start empty).
  virtual Result<std::unique_ptr<WritableFile>> OpenWrite(const std::string& path,
                                                          bool truncate) = 0;
  // Replaces `to` if it exists.
  virtual Status Rename(const std::string& from, const std::string& to) = 0;
  virtual Status Remove(const std::string& path) = 0;  // an absent file is not an error
  virtual Status SyncDir(const std::string& dir) = 0;
  virtual Status CreateDirs(const std::string& dir) = 0;
  virtual Result<std::vector<std::string>> ListDir(const std::string& dir) = 0;  // no . / ..
  virtual Status RemoveTree(const std::string& dir) = 0;
  virtual bool Exists(const std::string& path) = 0;
  // An exclusive lock on `path` (created if absent); fails if another process holds it.
  virtual Result<std::unique_ptr<FileLock>> Lock(const std::string& path) = 0;
  // Whether Rename moves a directory (and all below it) atomically, as POSIX rename does. A
  // store without it (RADOS) gets datasets created in place and dropped by removing their
  // MANIFEST first (storage/database.cc).
  virtual bool AtomicDirRename() const { return true; }
  // Writes a whole new immutable file (a tree). sync: all or nothing and durable when it
  // returns (path.tmp, sync, rename, sync of the directory); else straight to `path`, unsynced.
  // The default does it with the calls above; the POSIX Env bypasses the page cache (O_DIRECT)
  // for a durable file whose data is 4 KiB-aligned, as the bytes must reach the device anyway.
  virtual Status WriteNewFile(const std::string& path, std::string_view data, bool sync);
  // As WriteNewFile, for an image that is zero outside `extents` (ascending, disjoint): a store
  // may write only the extents and leave holes that read as zeros (the POSIX Env does: a small
  // frame's mostly empty tree blocks then take no disk space). The default writes it all.
  virtual Status WriteNewSparseFile(const std::string& path, std::string_view data,
                                    std::span<const FileExtent> extents, bool sync) {
    (void)extents;
    return WriteNewFile(path, data, sync);
  }
};

// Writes `data` to path via path.tmp + sync + rename + sync(dir): all or nothing.
Status WriteFileAtomic(Env* env, const std::string& path, std::string_view data);
Result<std::string> ReadWholeFile(Env* env, const std::string& path);
std::string ParentDir(const std::string& path);  // "." when there is no '/'

}  // namespace hvdb

#endif  // HVDB_STORAGE_ENV_H_
