// POSIX file access for the engine, in one place: every errno becomes a Status here.
#ifndef HVDB_STORAGE_FILE_H_
#define HVDB_STORAGE_FILE_H_

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "storage/status.h"

namespace hvdb {

// A read-only file read with pread; safe for concurrent readers.
class RandomAccessFile {
 public:
  static Result<std::shared_ptr<RandomAccessFile>> Open(const std::string& path);
  ~RandomAccessFile();
  // Reads exactly n bytes at offset; a short read is Corruption ("truncated").
  Status Read(uint64_t offset, size_t n, void* dst) const;
  uint64_t size() const { return size_; }
  const std::string& path() const { return path_; }
  // Drops the file's pages from the OS page cache (for cold benchmarks).
  void DropCache() const;

 private:
  RandomAccessFile(std::string path, int fd, uint64_t size)
      : path_(std::move(path)), fd_(fd), size_(size) {}
  std::string path_;
  int fd_;
  uint64_t size_;
};

// An append-only file.
class AppendFile {
 public:
  // Opens for append, creating it if absent (truncate = start empty).
  static Result<std::unique_ptr<AppendFile>> Open(const std::string& path, bool truncate);
  ~AppendFile();
  Status Append(std::string_view data);
  Status Sync();  // fdatasync
  Status Truncate(uint64_t size);
  uint64_t size() const { return size_; }

 private:
  AppendFile(std::string path, int fd, uint64_t size)
      : path_(std::move(path)), fd_(fd), size_(size) {}
  std::string path_;
  int fd_;
  uint64_t size_;
};

// Writes `data` to path via path.tmp + fsync + rename + fsync(dir): all or nothing.
Status WriteFileAtomic(const std::string& path, std::string_view data);
Result<std::string> ReadWholeFile(const std::string& path);
Status SyncDir(const std::string& dir);
Status CreateDirs(const std::string& dir);
Result<std::vector<std::string>> ListDir(const std::string& dir);  // names, no . / ..
Status RemoveFile(const std::string& path);
Status RemoveTree(const std::string& dir);
bool FileExists(const std::string& path);

}  // namespace hvdb

#endif  // HVDB_STORAGE_FILE_H_
