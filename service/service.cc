#include "service/service.h"

#include <algorithm>
#include <utility>

namespace hvdb::service {

Service::Service(Database* db, std::string data_dir, Env* env, edit::GraphCutCache* graph_cuts,
                 const JobConfig& jobs)
    : db_(db),
      data_dir_(std::move(data_dir)),
      env_(env),
      graph_cuts_(graph_cuts),
      jobs_(jobs),
      job_memory_(jobs.memory_budget != 0 ? jobs.memory_budget : DefaultMemoryBudget(),
                  jobs.memory_flag) {
  // Every transport and the embedded mode read photos through here: those coded as video
  // (storage/photo_video.h) need the codec, which storage/ cannot link.
  media::InstallPhotoVideoCodec();
}

std::vector<std::string> Service::ListDatasets() {
  std::vector<std::string> names = db_->ListDatasets();
  std::sort(names.begin(), names.end());
  return names;
}

Result<DatasetInfo> Service::CreateDataset(const DatasetInfo& info) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, db_->CreateDataset(info));
  return ds->Info();
}

Result<std::shared_ptr<Dataset>> Service::Find(const std::string& name) {
  Result<std::shared_ptr<Dataset>> ds = db_->GetDataset(name);
  // The engine's message names the data directory's files: not the caller's business.
  if (!ds.ok() && ds.status().IsNotFound()) return UnknownDataset(name);
  return ds;
}

Status Service::DropDataset(const std::string& name) {
  Status st = db_->DropDataset(name);
  if (st.IsNotFound()) return UnknownDataset(name);
  return st;
}

Result<DatasetInfo> Service::Describe(const std::string& name) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return ds->Info();
}

Result<OpenQuery> Service::Query(const std::string& name, const Region& region,
                                 const QueryOptions& opts) {
  // The level of detail is storage's to check (Dataset::CheckLod), when the query opens.
  OpenQuery q;
  HVDB_ASSIGN_OR_RETURN(q.dataset, Find(name));
  HVDB_ASSIGN_OR_RETURN(q.cursor, q.dataset->Query(region, opts));
  return q;
}

Result<uint64_t> Service::BulkLoad(const std::string& name, uint32_t frame,
                                   std::vector<Point> points, const GaussianColumns* gaussians) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  if (gaussians) return ds->BulkLoadGaussians(frame, std::move(points), *gaussians);
  if (ds->Info().gaussians) {
    return Status::InvalidArgument("dataset '" + name +
                                   "' holds Gaussian splats: load splat files (3DGS PLY, SPZ, "
                                   ".splat) into it, with their Gaussian attributes");
  }
  return ds->BulkLoad(frame, std::move(points));
}

Result<GaussianRead> Service::ReadGaussians(const std::string& name,
                                            std::span<const uint64_t> ids) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  GaussianRead out;
  HVDB_RETURN_IF_ERROR(
      ds->ReadGaussianRecords(ids, &out.records, &out.found, kMaxGaussianReadBlocks));
  return out;
}

Result<CommitInfo> Service::Commit(const std::string& name, const Transaction& txn) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return ds->Commit(txn);
}

Result<CommitInfo> Service::Revert(const std::string& name, uint64_t lsn) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return ds->Revert(lsn);
}

Result<CompactInfo> Service::Compact(const std::string& name, uint32_t first, uint32_t last,
                                     bool photos) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return photos ? ds->CompactPhotos(first, last) : ds->Compact(first, last);
}

Status Service::PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  HVDB_RETURN_IF_ERROR(render::CheckPhoto(photo));
  return ds->PutPhoto(frame, photo);
}

Result<DatasetReport> Service::Stats(const std::string& name) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return DatasetReport{ds->Stats(), ds->Info().last_lsn};
}

ServerCounters Service::Counters() {
  if (counters_) return counters_();
  ServerCounters c;
  CacheStats cache = db_->Cache();
  c.cache_capacity_bytes = cache.capacity_bytes;
  const uint64_t lookups = cache.hits + cache.misses;
  c.cache_hit_rate = lookups ? static_cast<double>(cache.hits) / lookups : 0;
  return c;
}

Result<edit::SelectResult> Service::Select(const std::string& name,
                                           const edit::SelectRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return edit::Select(*ds, req);
}

Result<edit::GraphCutReply> Service::GraphCut(const std::string& name,
                                              const edit::GraphCutRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return edit::GraphCutSelect(*ds, req, graph_cuts_);
}

Result<edit::CopyResult> Service::Copy(const std::string& name, const edit::CopyRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  edit::ClipboardStore store(data_dir_, env_);  // DIR/clipboards, shared by server and CLI
  return edit::Copy(*ds, req.bit, req.region, store, req.clipboard, req.cut);
}

Result<CommitInfo> Service::Paste(const std::string& name, const edit::PasteRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  edit::ClipboardStore store(data_dir_, env_);
  HVDB_ASSIGN_OR_RETURN(edit::Clip clip, store.Get(req.clipboard));
  return edit::Paste(*ds, clip, req.map);
}

Result<CommitInfo> Service::Composite(const std::string& name, const edit::CompositeRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return edit::Composite(*ds, req.object, req.first_frame, req.frame_count, req.trajectory,
                         req.gaussians.get());
}

Result<CommitInfo> Service::ImportMedia(const std::string& name,
                                       const media::ImportRequest& req) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(name));
  return media::Import(*ds, req, NewJob());
}

JobLimits Service::NewJob() {
  JobLimits l;
  l.memory = &job_memory_;
  l.max_seconds = jobs_.max_job_seconds;
  return l;
}

Result<std::unique_ptr<render::RenderJob>> Service::Render(const render::RenderRequest& request,
                                                           const render::RenderLimits& limits) {
  HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Find(request.dataset));
  render::RenderLimits l = limits;
  l.job = NewJob();
  return render::RenderJob::Create(std::move(ds), request, l);
}

Result<std::unique_ptr<WatchHandle>> Service::Watch(const std::string& name,
                                                    std::optional<uint64_t> from_lsn,
                                                    ChangeFn fn) {
  if (name.empty()) {
    if (from_lsn) {
      return Status::InvalidArgument("watch.from_lsn: a watch of every dataset is live only "
                                     "(name a dataset to resume from an LSN)");
    }
    return db_->WatchAll(std::move(fn));
  }
  HVDB_ASSIGN_OR_RETURN(auto ds, Find(name));
  return ds->Watch(from_lsn, std::move(fn));
}

}  // namespace hvdb::service
