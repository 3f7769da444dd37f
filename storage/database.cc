#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <random>

#include "storage/buffer_pool.h"
#include "storage/log.h"
#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/dataset_impl.h"
#include "storage/env.h"

namespace hvdb {

// DIR/clipboards holds the editing operators' clipboards (edit::ClipboardStore), not a dataset.
static constexpr char kClipboardsDir[] = "clipboards";

Status ValidateDatasetName(const std::string& name) {
  if (name.empty() || name.size() > 64 || name[0] == '.') {
    return Status::InvalidArgument("dataset name '" + name +
                                   "' must be 1-64 characters and not start with '.'");
  }
  for (char c : name) {
    bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
              c == '_' || c == '-' || c == '.';
    if (!ok) {
      return Status::InvalidArgument("dataset name '" + name +
                                     "' may only use letters, digits, '_', '-' and '.'");
    }
  }
  return Status::OK();
}

static Status ValidateOptions(const Options& o) {
  if (o.block_size < 4096 || o.block_size > (1u << 20) || (o.block_size & (o.block_size - 1))) {
    return Status::InvalidArgument("block size must be a power of two in [4 KiB, 1 MiB], got " +
                                   std::to_string(o.block_size));
  }
  if (o.cache_bytes < (8u << 20)) {
    return Status::InvalidArgument("cache must be at least 8 MiB, got " +
                                   std::to_string(o.cache_bytes >> 20) + " MiB");
  }
  if (o.lod_levels < 0 || o.lod_levels > 8) {
    return Status::InvalidArgument("lod_levels must be in 0..8, got " +
                                   std::to_string(o.lod_levels));
  }
  if (o.merge_fanout < 2 || o.merge_fanout > 16) {
    return Status::InvalidArgument("merge_fanout must be in [2, 16], got " +
                                   std::to_string(o.merge_fanout));
  }
  if (o.t0_points < 64 || o.t0_points > (4u << 20)) {
    return Status::InvalidArgument("t0_points must be in [64, 4194304], got " +
                                   std::to_string(o.t0_points));
  }
  return Status::OK();
}

Database::Database(std::string dir, Options opts)
    : dir_(std::move(dir)), opts_(opts), env_(opts.env ? opts.env : Env::Default()) {
  opts_.env = env_;
}

Database::~Database() {
  open_.clear();  // datasets stop their mergers and checkpoint on close
  pool_.reset();
  lock_.reset();
}

Result<std::unique_ptr<Database>> Database::Open(const std::string& dir, const Options& opts) {
  HVDB_RETURN_IF_ERROR(ValidateOptions(opts));
  std::unique_ptr<Database> db(new Database(dir, opts));
  Env* env = db->env_;
  HVDB_RETURN_IF_ERROR(env->CreateDirs(dir));
  std::string lock = dir + "/LOCK";
  auto locked = env->Lock(lock);
  if (!locked.ok() && opts.follow) {
    db->follower_ = true;
    HVDB_RETURN_IF_ERROR(db->Refresh());  // reads LEADER
  } else if (!locked.ok()) {
    return Status::IOError(dir + " is in use by another hvdb process (" + lock +
                           " is locked); stop it or use its server");
  } else {
    db->lock_ = std::move(locked).value();
    HVDB_RETURN_IF_ERROR(db->RemoveLeftovers());
    HVDB_RETURN_IF_ERROR(db->WriteLeader(""));
  }
  db->pool_ = std::make_unique<BufferPool>(opts.cache_bytes, opts.block_size);
  return db;
}

Status Database::RemoveLeftovers() {
  HVDB_ASSIGN_OR_RETURN(auto names, env_->ListDir(dir_));
  for (const std::string& n : names) {
    // Leftovers of a create or drop cut short by a crash (without atomic directory renames:
    // a dataset's directory without its MANIFEST).
    const std::string sub = dir_ + "/" + n;
    if (n == kClipboardsDir) continue;  // the editing operators' clipboards (edit/)
    if (n.ends_with(".creating") || n.ends_with(".dropping") ||
        (!env_->AtomicDirRename() && ValidateDatasetName(n).ok() &&
         !env_->Exists(sub + "/MANIFEST") && env_->ListDir(sub).ok())) {
      HVDB_RETURN_IF_ERROR(env_->RemoveTree(sub));
    }
  }
  return Status::OK();
}

// ---------------------------------------------------------------------------------------------
// Writer and followers (docs/FORMAT.md, "LEADER")

namespace {

constexpr char kLeaderMagic[8] = {'H', 'V', 'D', 'B', 'L', 'D', 'R', '\0'};

struct LeaderRecord {
  uint64_t epoch = 0;
  std::string address;
};

Result<LeaderRecord> DecodeLeader(const std::string& data, const std::string& what) {
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (data.size() < 28 || std::memcmp(p, kLeaderMagic, 8) != 0 ||
      crc32c::Unmask(DecodeLE<uint32_t>(p + data.size() - 4)) !=
          crc32c::Value(p, data.size() - 4)) {
    return Status::Corruption(what + ": not a LEADER file, or damaged");
  }
  Reader r(p + 8, data.size() - 12);
  uint32_t version = 0;
  LeaderRecord rec;
  if (!r.Get(&version) || version != 1 || !r.Get(&rec.epoch) || !r.GetString(&rec.address)) {
    return Status::Corruption(what + ": unsupported version or bad fields");
  }
  return rec;
}

}  // namespace

Status Database::WriteLeader(const std::string& address) {
  std::lock_guard<std::mutex> l(mu_);
  if (epoch_ == 0) {
    // A new epoch per writer: followers that see it change reload everything, as a new
    // writer's recovery may have cut a torn log tail or removed unlisted trees.
    std::random_device rd;
    epoch_ = (uint64_t{rd()} << 32 | rd()) ^
             static_cast<uint64_t>(std::chrono::steady_clock::now().time_since_epoch().count());
    epoch_ |= 1;
  }
  Writer w;
  w.PutBytes(kLeaderMagic, 8);
  w.Put<uint32_t>(1);
  w.Put<uint64_t>(epoch_);
  w.PutString(address);
  w.Put<uint32_t>(crc32c::Mask(crc32c::Value(w.data().data(), w.data().size())));
  HVDB_RETURN_IF_ERROR(WriteFileAtomic(env_, dir_ + "/LEADER", w.data()));
  leader_ = address;
  return Status::OK();
}

Status Database::SetLeaderAddress(const std::string& address) {
  if (follower_) return Status::NotLeader("a follower cannot publish itself as the writer");
  return WriteLeader(address);
}

std::string Database::Leader() const {
  std::lock_guard<std::mutex> l(mu_);
  return leader_;
}

Status Database::Refresh() {
  if (!follower_) return Status::OK();
  bool full = false;
  const std::string path = dir_ + "/LEADER";
  // One read per look; absent (no writer yet) or mid-replacement: the next call reads it.
  if (auto data = ReadWholeFile(env_, path); data.ok()) {
    HVDB_ASSIGN_OR_RETURN(LeaderRecord rec, DecodeLeader(*data, path));
    std::lock_guard<std::mutex> l(mu_);
    full = rec.epoch != epoch_;
    epoch_ = rec.epoch;
    leader_ = rec.address;
  }
  std::vector<std::pair<std::string, std::shared_ptr<Dataset>>> open;
  {
    std::lock_guard<std::mutex> l(mu_);
    open = open_;
  }
  Status first;
  for (const auto& entry : open) {
    const std::shared_ptr<Dataset>& ds = entry.second;
    if (!env_->Exists(dir_ + "/" + entry.first + "/MANIFEST")) {  // dropped by the writer
      {
        std::lock_guard<std::mutex> l(mu_);
        std::erase_if(open_, [&](const auto& e) { return e.second == ds; });
      }
      ds->impl()->EndWatches();
      continue;
    }
    Status st = ds->impl()->Refresh(full);
    if (!st.ok() && first.ok()) first = st;
  }
  return first;
}

Result<bool> Database::TryPromote() {
  if (!follower_) return true;
  auto locked = env_->Lock(dir_ + "/LOCK");
  if (!locked.ok()) return false;
  lock_ = std::move(locked).value();
  HVDB_RETURN_IF_ERROR(RemoveLeftovers());
  {
    std::lock_guard<std::mutex> l(mu_);
    epoch_ = 0;  // ours is new
  }
  HVDB_RETURN_IF_ERROR(WriteLeader(""));
  std::lock_guard<std::mutex> l(mu_);
  for (auto it = open_.begin(); it != open_.end();) {
    Status st = it->second->impl()->Promote();
    if (!st.ok()) {
      // Reopened (and its recovery error reported) by the next GetDataset.
      LogWarning(it->first + ": taking over as the writer: " + st.ToString());
      it = open_.erase(it);
    } else {
      ++it;
    }
  }
  follower_ = false;
  return true;
}

std::vector<std::string> Database::ListDatasets() const {
  std::vector<std::string> out;
  auto names = env_->ListDir(dir_);
  if (!names.ok()) return out;
  for (const std::string& n : *names) {
    if (ValidateDatasetName(n).ok() && env_->Exists(dir_ + "/" + n + "/MANIFEST")) out.push_back(n);
  }
  std::sort(out.begin(), out.end());
  return out;
}

static Status FollowerRefuses(const std::string& what) {
  return Status::NotLeader(what + ": this process only reads the data directory; another "
                                  "process holds it and is the one that writes it");
}

Result<std::shared_ptr<Dataset>> Database::CreateDataset(const DatasetInfo& info) {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(info.name));
  if (follower_) return FollowerRefuses("create of dataset '" + info.name + "'");
  if (info.name == kClipboardsDir) {
    return Status::InvalidArgument("dataset name 'clipboards' is reserved (the folder of the "
                                   "editing operators' clipboards)");
  }
  std::lock_guard<std::mutex> l(mu_);
  HVDB_ASSIGN_OR_RETURN(auto impl,
                        DatasetImpl::Create(dir_ + "/" + info.name, info, opts_, pool_.get()));
  impl->SetParentHub(all_);
  auto ds = std::make_shared<Dataset>(std::move(impl));
  open_.emplace_back(info.name, ds);
  return ds;
}

Result<std::shared_ptr<Dataset>> Database::GetDataset(const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));
  std::lock_guard<std::mutex> l(mu_);
  for (auto& [n, ds] : open_) {
    if (n == name) return ds;
  }
  std::string path = dir_ + "/" + name;
  if (!env_->Exists(path + "/MANIFEST")) {
    return Status::NotFound("no dataset '" + name + "' in " + dir_ +
                            " (list them with `hvdb datasets`)");
  }
  HVDB_ASSIGN_OR_RETURN(auto impl, DatasetImpl::Open(path, opts_, pool_.get(), follower_));
  impl->SetParentHub(all_);
  auto ds = std::make_shared<Dataset>(std::move(impl));
  open_.emplace_back(name, ds);
  return ds;
}

Status Database::DropDataset(const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateDatasetName(name));
  if (follower_) return FollowerRefuses("drop of dataset '" + name + "'");
  std::lock_guard<std::mutex> l(mu_);
  std::string path = dir_ + "/" + name;
  if (!env_->Exists(path + "/MANIFEST")) return Status::NotFound("no dataset '" + name + "'");
  for (const auto& [n, ds] : open_) {
    if (n == name) ds->impl()->EndWatches();
  }
  std::erase_if(open_, [&](const auto& e) { return e.first == name; });
  if (!env_->AtomicDirRename()) {
    // Its MANIFEST first: the dataset is gone at that step, the rest is deleted after.
    HVDB_RETURN_IF_ERROR(env_->Remove(path + "/MANIFEST"));
    return env_->RemoveTree(path);
  }
  // Rename first: the drop is atomic, and a crash mid-delete leaves only a .dropping folder.
  std::string gone = path + ".dropping";
  HVDB_RETURN_IF_ERROR(env_->Rename(path, gone));
  HVDB_RETURN_IF_ERROR(env_->SyncDir(dir_));
  return env_->RemoveTree(gone);
}

CacheStats Database::Cache() const { return pool_->Stats(); }

std::unique_ptr<WatchHandle> Database::WatchAll(ChangeFn fn) {
  auto sub = all_->Subscribe(std::move(fn), /*hold=*/true);
  sub->Go(0, "");  // a kLive event first, as a dataset's watch has
  return sub;
}

Dataset::Dataset(std::unique_ptr<DatasetImpl> impl) : impl_(std::move(impl)) {}
Dataset::~Dataset() = default;
DatasetInfo Dataset::Info() const { return impl_->Info(); }
int Dataset::lod_levels() const { return impl_->levels(); }
Status Dataset::CheckLod(int64_t lod) const {
  return CheckLodRange(lod, impl_->levels(), impl_->Info().name);
}
Result<std::unique_ptr<Cursor>> Dataset::Query(const Region& region, const QueryOptions& opts) {
  return impl_->Query(region, opts);
}
Result<uint64_t> Dataset::BulkLoad(uint32_t frame, std::vector<Point> points) {
  return impl_->BulkLoad(frame, std::move(points));
}
Result<uint64_t> Dataset::BulkLoadGaussians(uint32_t frame, std::vector<Point> points,
                                           const GaussianColumns& attrs) {
  return impl_->BulkLoadGaussians(frame, std::move(points), attrs);
}
Result<GaussianColumns> Dataset::ReadGaussians(std::span<const Point> points,
                                               uint64_t* derived) const {
  return impl_->ReadGaussians(points, derived);
}
Status Dataset::ReadGaussianRecords(std::span<const uint64_t> ids, GaussianColumns* out,
                                    std::vector<bool>* found, size_t max_blocks) const {
  return impl_->ReadGaussianRecords(ids, out, found, max_blocks);
}
Result<CommitInfo> Dataset::Commit(const Transaction& txn) { return impl_->Commit(txn); }
Result<CommitInfo> Dataset::Revert(uint64_t lsn) { return impl_->Revert(lsn); }
DatasetStats Dataset::Stats() const { return impl_->Stats(); }
std::vector<std::string> Dataset::Check() const { return impl_->Check(); }
Status Dataset::Checkpoint() { return impl_->Checkpoint(); }
Result<CompactInfo> Dataset::Compact(uint32_t first, uint32_t last) {
  return impl_->Compact(first, last);
}
Result<CompactInfo> Dataset::CompactPhotos(uint32_t first, uint32_t last) {
  return impl_->CompactPhotos(first, last);
}
Status Dataset::WaitForMerges() { return impl_->WaitForMerges(); }
Result<std::unique_ptr<WatchHandle>> Dataset::Watch(std::optional<uint64_t> from_lsn, ChangeFn fn) {
  return impl_->Watch(from_lsn, std::move(fn));
}
Status Dataset::PutPhoto(uint32_t frame, const Photo& photo) { return impl_->PutPhoto(frame, photo); }
Result<std::vector<Photo>> Dataset::Photos(uint32_t frame) const { return impl_->Photos(frame); }

}  // namespace hvdb
