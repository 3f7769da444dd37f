// The executor: the one place a request runs against a Database. hvdb-server's sessions
// (server/session.cc: every transport decodes its bytes into a wire::Request, whose body
// protocol/convert.h turns into these values) and the embedded mode (client/backend.cc: the
// `hvdb --data` command line, Python's hvdb.open) both call it, so that the same request gets
// the same result and the same error, word for word, whichever way it came.
//
// Typed values in, typed values or a Status out. Each request is validated once, on this path:
// here what no engine call checks (levels of detail, photos before they are stored), in the
// engine what it must refuse anyway (regions and transactions in storage/, label bits and
// graph-cut parameters in edit/). The transports check only the shape of their messages. What only a transport has (flow control, ring slots, ingest chunks,
// cancellation) stays in the transport; what only a process has (the server's counters, a
// block cache's numbers) stays with it.
//
// Thread safety: as the Database's. hvdb-server calls it from many workers at once; the
// embedded backend from one thread.
#ifndef HVDB_SERVICE_SERVICE_H_
#define HVDB_SERVICE_SERVICE_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "edit/operators.h"
#include "media/media.h"
#include "render/job.h"
#include "service/requests.h"
#include "storage/database.h"
#include "storage/job_limits.h"

namespace hvdb::service {

// The bounds of the jobs that decode what a client sends (import-media) and of render jobs
// (docs/PROTOCOL.md, "Limits"): memory they may hold together, and seconds each may run.
struct JobConfig {
  uint64_t memory_budget = 0;  // 0: DefaultMemoryBudget()
  uint32_t max_job_seconds = 0;  // 0: no deadline (the embedded mode's default)
  std::string memory_flag = "--memory-budget";  // named in errors
};

// An open query: the cursor and the dataset it reads (kept alive while the cursor is).
struct OpenQuery {
  std::shared_ptr<Dataset> dataset;
  std::unique_ptr<Cursor> cursor;
};

class Service {
 public:
  // `db` outlives the service. Clipboards are kept in DIR/clipboards of `data_dir` through `env`
  // (null: the POSIX files). `graph_cuts`: the cache of the last cut (hvdb-server keeps one, so
  // that a cut after one more stroke is a re-cut); null: none.
  // `jobs`: the memory and time bounds of import and render jobs.
  Service(Database* db, std::string data_dir, Env* env = nullptr,
          edit::GraphCutCache* graph_cuts = nullptr, const JobConfig& jobs = {});

  Database& db() { return *db_; }

  // Names of the datasets, sorted.
  std::vector<std::string> ListDatasets();
  Result<DatasetInfo> CreateDataset(const DatasetInfo& info);
  Status DropDataset(const std::string& name);
  Result<DatasetInfo> Describe(const std::string& name);
  Result<std::shared_ptr<Dataset>> Find(const std::string& name);

  Result<OpenQuery> Query(const std::string& name, const Region& region, const QueryOptions& opts);
  // gaussians: a Gaussian-splat dataset's records of the points (Dataset::BulkLoadGaussians).
  Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame, std::vector<Point> points,
                            const GaussianColumns* gaussians = nullptr);
  Result<GaussianRead> ReadGaussians(const std::string& name, std::span<const uint64_t> ids);
  Result<CommitInfo> Commit(const std::string& name, const Transaction& txn);
  Result<CommitInfo> Revert(const std::string& name, uint64_t lsn);
  // The cold tier: frames [first, last] compressed now (Dataset::Compact); with `photos`,
  // instead their photos coded as video per camera (Dataset::CompactPhotos).
  Result<CompactInfo> Compact(const std::string& name, uint32_t first, uint32_t last,
                              bool photos = false);
  // The photo (and its billboard) is checked before it is stored: a bad one is refused here, not
  // left to fail renders.
  Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo);
  Result<DatasetReport> Stats(const std::string& name);
  // What the process reports of itself: hvdb-server's counters through the source it sets
  // (SetCounters); without one (the embedded mode), this process's block cache only.
  ServerCounters Counters();
  void SetCounters(std::function<ServerCounters()> source) { counters_ = std::move(source); }
  // The dataset's changes (storage/watch.h: replay from `from_lsn`, then live), or, for name "",
  // every dataset's changes from now on (from_lsn must be absent). fn runs on the writing thread
  // and must only hand the event on; destroy the handle to stop.
  Result<std::unique_ptr<WatchHandle>> Watch(const std::string& name,
                                             std::optional<uint64_t> from_lsn, ChangeFn fn);

  // ---- The editing operators (edit/operators.h).
  Result<edit::SelectResult> Select(const std::string& name, const edit::SelectRequest& req);
  Result<edit::GraphCutReply> GraphCut(const std::string& name, const edit::GraphCutRequest& req);
  Result<edit::CopyResult> Copy(const std::string& name, const edit::CopyRequest& req);
  Result<CommitInfo> Paste(const std::string& name, const edit::PasteRequest& req);
  Result<CommitInfo> Composite(const std::string& name, const edit::CompositeRequest& req);
  // An image, video or mesh file decoded here (media/media.h) and inserted in one transaction,
  // within the job bounds.
  Result<CommitInfo> ImportMedia(const std::string& name, const media::ImportRequest& req);

  // ---- Rendering: the request checked and the job made; the caller brings a renderer (the
  // server's pool, or one made in this process) and asks for the images one by one. The job
  // holds its points and images within the job bounds (limits.job is set here).
  Result<std::unique_ptr<render::RenderJob>> Render(const render::RenderRequest& request,
                                                    const render::RenderLimits& limits = {});

 private:
  Database* db_;
  std::string data_dir_;
  Env* env_;
  edit::GraphCutCache* graph_cuts_;
  JobConfig jobs_;
  JobBudget job_memory_;
  std::function<ServerCounters()> counters_;
  // A job's bounds, starting now.
  JobLimits NewJob();
};

}  // namespace hvdb::service

#endif  // HVDB_SERVICE_SERVICE_H_
