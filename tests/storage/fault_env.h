// FaultEnv: an Env that wraps the POSIX one and injects faults, after LevelDB's
// FaultInjectionTestEnv.
//
//   - Errors: fail the n-th write (Append/WriteAt), the n-th sync (file or directory), or the
//     n-th read (EIO, or a short read), with the error given.
//   - Crash: after `crash_after` mutating calls (open for write, write, sync, truncate, rename,
//     remove, create directory, sync directory) every further mutating call fails, as if the
//     process had died between two system calls; reads still work.
//   - Power loss: PowerLoss() drops what was never synced: each written file is cut back to
//     its size at its last sync (a file never synced loses everything), and the creations,
//     renames and removals of names in a directory since its last SyncDir are undone (newest
//     first; removed and replaced files are kept aside for that until the directory is synced).
//     Limitation: data overwritten in place after a sync is not restored (the engine writes
//     only fresh files and appends).
#ifndef HVDB_TESTS_STORAGE_FAULT_ENV_H_
#define HVDB_TESTS_STORAGE_FAULT_ENV_H_

#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "storage/env.h"

namespace hvdb::testing {

class FaultEnv : public Env {
 public:
  // `aside`: a directory on the same file system for files kept to undo removals.
  explicit FaultEnv(std::string aside, Env* base = Env::Default());

  // 1-based counts from now; 0 disables. Each fault fires once.
  void FailWrite(uint64_t nth, Status error);
  void FailSync(uint64_t nth, Status error);
  // The n-th read and the `count` - 1 after it (a device that keeps failing).
  void FailRead(uint64_t nth, Status error, uint64_t count = 1);
  void ShortRead(uint64_t nth, uint64_t count = 1);
  void CrashAfter(uint64_t mutating_calls);
  void CrashNow();
  bool crashed() const;
  uint64_t mutating_calls() const;
  uint64_t faults_fired() const;
  uint64_t syncs() const;  // file and directory syncs so far
  // Drops unsynced data and directory changes (see above); then the env works normally again.
  void PowerLoss();
  void Reset();  // clears all pending faults (not the sync tracking)

  // Env
  Result<std::shared_ptr<RandomAccessFile>> OpenRead(const std::string& path) override;
  Result<std::unique_ptr<WritableFile>> OpenWrite(const std::string& path, bool truncate) override;
  Status Rename(const std::string& from, const std::string& to) override;
  Status Remove(const std::string& path) override;
  Status SyncDir(const std::string& dir) override;
  Status CreateDirs(const std::string& dir) override;
  Result<std::vector<std::string>> ListDir(const std::string& dir) override;
  Status RemoveTree(const std::string& dir) override;
  bool Exists(const std::string& path) override;
  Result<std::unique_ptr<FileLock>> Lock(const std::string& path) override;

  // For the wrapped files.
  Status BeforeMutation(const std::string& what);  // crash check + count
  Status BeforeWrite(const std::string& path);
  Status BeforeSync(const std::string& path);
  Status BeforeRead(const std::string& path, bool* short_read);
  void Synced(const std::string& path, uint64_t size);
  void Written(const std::string& path);

 private:
  struct DirOp {
    enum Kind { kCreate, kRename, kRemove } kind;
    std::string path, from;  // kRename: from -> path
    std::string aside;       // kRemove / kRename over a file: where the old file is kept
    std::string dir;         // the directory whose sync makes it durable
  };
  std::string KeepAside(const std::string& path);  // REQUIRES: mu_ held
  Status Fire(uint64_t* count, uint64_t* at, Status* error);

  const std::string aside_dir_;
  Env* const base_;
  mutable std::mutex mu_;
  uint64_t writes_ = 0, syncs_ = 0, reads_ = 0, mutations_ = 0, fired_ = 0, aside_seq_ = 0;
  uint64_t fail_write_at_ = 0, fail_sync_at_ = 0, fail_read_at_ = 0, short_read_at_ = 0;
  uint64_t fail_read_left_ = 0, short_read_left_ = 0;
  uint64_t crash_after_ = 0;
  bool crashed_ = false;
  Status write_error_, sync_error_, read_error_;
  std::map<std::string, uint64_t> synced_;  // written files: size at their last sync
  std::vector<DirOp> pending_;  // not yet durable, oldest first
};

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_STORAGE_FAULT_ENV_H_
