#include "tests/storage/fault_env.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>

namespace hvdb::testing {

namespace {

class FaultWritableFile final : public WritableFile {
 public:
  FaultWritableFile(FaultEnv* env, std::unique_ptr<WritableFile> base)
      : env_(env), base_(std::move(base)) {}
  Status Append(std::string_view data) override {
    HVDB_RETURN_IF_ERROR(env_->BeforeWrite(path()));
    return base_->Append(data);
  }
  Status WriteAt(uint64_t offset, std::string_view data) override {
    HVDB_RETURN_IF_ERROR(env_->BeforeWrite(path()));
    return base_->WriteAt(offset, data);
  }
  Status Sync() override {
    HVDB_RETURN_IF_ERROR(env_->BeforeSync(path()));
    HVDB_RETURN_IF_ERROR(base_->Sync());
    env_->Synced(path(), base_->size());
    return Status::OK();
  }
  Status Truncate(uint64_t size) override {
    HVDB_RETURN_IF_ERROR(env_->BeforeMutation("truncate " + path()));
    return base_->Truncate(size);
  }
  uint64_t size() const override { return base_->size(); }
  const std::string& path() const override { return base_->path(); }

 private:
  FaultEnv* env_;
  std::unique_ptr<WritableFile> base_;
};

class FaultRandomAccessFile final : public RandomAccessFile {
 public:
  FaultRandomAccessFile(FaultEnv* env, std::shared_ptr<RandomAccessFile> base)
      : env_(env), base_(std::move(base)) {}
  Status Read(uint64_t offset, size_t n, void* dst) const override {
    bool short_read = false;
    HVDB_RETURN_IF_ERROR(env_->BeforeRead(path(), &short_read));
    if (!short_read) return base_->Read(offset, n, dst);
    // As the POSIX Env reports a file that ends early.
    HVDB_RETURN_IF_ERROR(base_->Read(offset, n / 2, dst));
    return Status::Corruption(path() + ": truncated: wanted " + std::to_string(n) +
                              " bytes at offset " + std::to_string(offset) + " (injected)");
  }
  void ReadBatch(std::span<ReadRequest> reqs) const override {
    std::vector<ReadRequest*> pass;
    for (ReadRequest& r : reqs) {
      bool short_read = false;
      r.status = env_->BeforeRead(path(), &short_read);
      if (r.status.ok() && short_read) {
        r.status = Status::Corruption(path() + ": truncated: wanted more bytes at offset " +
                                      std::to_string(r.offset) + " (injected)");
      }
      if (r.status.ok()) pass.push_back(&r);
    }
    std::vector<ReadRequest> batch;
    for (ReadRequest* r : pass) batch.push_back(*r);
    base_->ReadBatch(batch);
    for (size_t i = 0; i < pass.size(); ++i) pass[i]->status = batch[i].status;
  }
  void DropCache() const override { base_->DropCache(); }
  uint64_t size() const override { return base_->size(); }
  const std::string& path() const override { return base_->path(); }

 private:
  FaultEnv* env_;
  std::shared_ptr<RandomAccessFile> base_;
};

uint64_t SizeOf(const std::string& path) {
  struct stat st;
  return ::stat(path.c_str(), &st) == 0 ? static_cast<uint64_t>(st.st_size) : 0;
}

}  // namespace

FaultEnv::FaultEnv(std::string aside, Env* base) : aside_dir_(std::move(aside)), base_(base) {
  (void)base_->CreateDirs(aside_dir_);
}

void FaultEnv::FailWrite(uint64_t nth, Status error) {
  std::lock_guard<std::mutex> l(mu_);
  fail_write_at_ = nth ? writes_ + nth : 0;
  write_error_ = std::move(error);
}
void FaultEnv::FailSync(uint64_t nth, Status error) {
  std::lock_guard<std::mutex> l(mu_);
  fail_sync_at_ = nth ? syncs_ + nth : 0;
  sync_error_ = std::move(error);
}
void FaultEnv::FailRead(uint64_t nth, Status error, uint64_t count) {
  std::lock_guard<std::mutex> l(mu_);
  fail_read_at_ = nth ? reads_ + nth : 0;
  fail_read_left_ = count;
  read_error_ = std::move(error);
}
void FaultEnv::ShortRead(uint64_t nth, uint64_t count) {
  std::lock_guard<std::mutex> l(mu_);
  short_read_at_ = nth ? reads_ + nth : 0;
  short_read_left_ = count;
}
void FaultEnv::CrashAfter(uint64_t calls) {
  std::lock_guard<std::mutex> l(mu_);
  crash_after_ = calls ? mutations_ + calls : 0;
}
void FaultEnv::CrashNow() {
  std::lock_guard<std::mutex> l(mu_);
  crashed_ = true;
}
bool FaultEnv::crashed() const {
  std::lock_guard<std::mutex> l(mu_);
  return crashed_;
}
uint64_t FaultEnv::mutating_calls() const {
  std::lock_guard<std::mutex> l(mu_);
  return mutations_;
}
uint64_t FaultEnv::syncs() const {
  std::lock_guard<std::mutex> l(mu_);
  return syncs_;
}
uint64_t FaultEnv::faults_fired() const {
  std::lock_guard<std::mutex> l(mu_);
  return fired_;
}
void FaultEnv::Reset() {
  std::lock_guard<std::mutex> l(mu_);
  fail_write_at_ = fail_sync_at_ = fail_read_at_ = short_read_at_ = crash_after_ = 0;
  fail_read_left_ = short_read_left_ = 0;
  crashed_ = false;
}

Status FaultEnv::BeforeMutation(const std::string& what) {
  std::lock_guard<std::mutex> l(mu_);
  if (!crashed_ && crash_after_ != 0 && mutations_ >= crash_after_) crashed_ = true;
  if (crashed_) return Status::IOError(what + ": the process has crashed (injected)");
  ++mutations_;
  return Status::OK();
}

Status FaultEnv::Fire(uint64_t* count, uint64_t* at, Status* error) {
  ++*count;
  if (*at != 0 && *count == *at) {
    *at = 0;
    ++fired_;
    return *error;
  }
  return Status::OK();
}

Status FaultEnv::BeforeWrite(const std::string& path) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("write " + path));
  std::lock_guard<std::mutex> l(mu_);
  return Fire(&writes_, &fail_write_at_, &write_error_);
}

Status FaultEnv::BeforeSync(const std::string& path) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("sync " + path));
  std::lock_guard<std::mutex> l(mu_);
  return Fire(&syncs_, &fail_sync_at_, &sync_error_);
}

Status FaultEnv::BeforeRead(const std::string&, bool* short_read) {
  std::lock_guard<std::mutex> l(mu_);
  ++reads_;
  if (fail_read_at_ != 0 && reads_ >= fail_read_at_ && fail_read_left_ > 0) {
    --fail_read_left_;
    ++fired_;
    return read_error_;
  }
  if (short_read_at_ != 0 && reads_ >= short_read_at_ && short_read_left_ > 0) {
    --short_read_left_;
    ++fired_;
    *short_read = true;
  }
  return Status::OK();
}

void FaultEnv::Synced(const std::string& path, uint64_t size) {
  std::lock_guard<std::mutex> l(mu_);
  synced_[path] = size;
}

std::string FaultEnv::KeepAside(const std::string& path) {
  std::string to = aside_dir_ + "/" + std::to_string(++aside_seq_);
  return ::link(path.c_str(), to.c_str()) == 0 ? to : std::string();
}

Result<std::shared_ptr<RandomAccessFile>> FaultEnv::OpenRead(const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(auto f, base_->OpenRead(path));
  return std::shared_ptr<RandomAccessFile>(new FaultRandomAccessFile(this, std::move(f)));
}

Result<std::unique_ptr<WritableFile>> FaultEnv::OpenWrite(const std::string& path,
                                                          bool truncate) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("open " + path));
  const bool existed = base_->Exists(path);
  HVDB_ASSIGN_OR_RETURN(auto f, base_->OpenWrite(path, truncate));
  std::lock_guard<std::mutex> l(mu_);
  if (!existed) {
    pending_.push_back({DirOp::kCreate, path, "", "", ParentDir(path)});
    synced_[path] = 0;
  } else if (truncate) {
    synced_[path] = 0;
  } else if (!synced_.count(path)) {
    synced_[path] = f->size();  // from before this env: durable as found
  }
  return std::unique_ptr<WritableFile>(new FaultWritableFile(this, std::move(f)));
}

Status FaultEnv::Rename(const std::string& from, const std::string& to) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("rename " + from));
  std::lock_guard<std::mutex> l(mu_);
  std::string aside = base_->Exists(to) ? KeepAside(to) : "";
  Status s = base_->Rename(from, to);
  if (!s.ok()) {
    if (!aside.empty()) ::unlink(aside.c_str());
    return s;
  }
  pending_.push_back({DirOp::kRename, to, from, aside, ParentDir(to)});
  auto it = synced_.find(from);
  if (it != synced_.end()) {
    synced_[to] = it->second;
    synced_.erase(it);
  } else {
    synced_.erase(to);
  }
  return s;
}

Status FaultEnv::Remove(const std::string& path) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("remove " + path));
  std::lock_guard<std::mutex> l(mu_);
  if (!base_->Exists(path)) return Status::OK();
  std::string aside = KeepAside(path);
  HVDB_RETURN_IF_ERROR(base_->Remove(path));
  pending_.push_back({DirOp::kRemove, path, "", aside, ParentDir(path)});
  synced_.erase(path);
  return Status::OK();
}

Status FaultEnv::SyncDir(const std::string& dir) {
  HVDB_RETURN_IF_ERROR(BeforeSync(dir));
  HVDB_RETURN_IF_ERROR(base_->SyncDir(dir));
  std::lock_guard<std::mutex> l(mu_);
  std::erase_if(pending_, [&dir](const DirOp& op) {
    if (op.dir != dir) return false;
    if (!op.aside.empty()) ::unlink(op.aside.c_str());
    return true;
  });
  return Status::OK();
}

Status FaultEnv::CreateDirs(const std::string& dir) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("create directory " + dir));
  return base_->CreateDirs(dir);
}

Result<std::vector<std::string>> FaultEnv::ListDir(const std::string& dir) {
  return base_->ListDir(dir);
}

Status FaultEnv::RemoveTree(const std::string& dir) {
  HVDB_RETURN_IF_ERROR(BeforeMutation("remove " + dir));
  return base_->RemoveTree(dir);
}

bool FaultEnv::Exists(const std::string& path) { return base_->Exists(path); }

Result<std::unique_ptr<FileLock>> FaultEnv::Lock(const std::string& path) {
  return base_->Lock(path);
}

void FaultEnv::PowerLoss() {
  std::lock_guard<std::mutex> l(mu_);
  // Contents first (by the names files have now), then the names, newest change first.
  for (const auto& [path, size] : synced_) {
    if (base_->Exists(path) && SizeOf(path) > size) (void)::truncate(path.c_str(), static_cast<off_t>(size));
  }
  synced_.clear();
  std::vector<DirOp> ops = std::move(pending_);
  pending_.clear();
  std::reverse(ops.begin(), ops.end());  // newest first
  for (const DirOp& op : ops) {
    switch (op.kind) {
      case DirOp::kCreate: (void)::unlink(op.path.c_str()); break;
      case DirOp::kRename:
        (void)::rename(op.path.c_str(), op.from.c_str());
        if (!op.aside.empty()) (void)::rename(op.aside.c_str(), op.path.c_str());
        break;
      case DirOp::kRemove:
        if (!op.aside.empty()) (void)::rename(op.aside.c_str(), op.path.c_str());
        break;
    }
  }
  fail_write_at_ = fail_sync_at_ = fail_read_at_ = short_read_at_ = crash_after_ = 0;
  crashed_ = false;
}

}  // namespace hvdb::testing
