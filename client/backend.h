// Backend: what the `hvdb` command line does to a database, whether it runs embedded on a data
// directory (EmbeddedBackend, over hvdb::Database) or talks to an hvdb-server (RemoteBackend,
// over hvdb::client::Client). The subcommands call this one API; the two implementations give
// the same results and the same errors for the same data, so the output does not depend on the
// mode (apart from what only one mode has: `check` is embedded-only, `ping` remote-only, and
// `stats` reports the block cache of this process or the server's counters).
//
// Nothing is opened or connected until the first call, so usage errors can be reported before
// touching a file or the network. Errors are Status values; nothing here throws on purpose.
//
// The editing operators (Select ... Composite) run next to the data: in this process on a data
// directory, whose clipboards (DIR/clipboards) are the ones hvdb-server uses when it serves that
// directory, or in the server (the editing requests of docs/PROTOCOL.md). So does Render: the
// same render::RenderJob (render/job.h) runs in this process or in hvdb-server's sessions.
#ifndef HVDB_CLIENT_BACKEND_H_
#define HVDB_CLIENT_BACKEND_H_

#include <array>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "edit/operators.h"
#include "media/media.h"
#include "protocol/wire.h"
#include "render/request.h"
#include "service/requests.h"
#include "storage/database.h"
#include "storage/status.h"

namespace hvdb::client {

// The results of one query, batch by batch.
class QueryResults {
 public:
  virtual ~QueryResults() = default;
  // Next batch into *batch (its points replaced); false at the end.
  virtual Result<bool> Next(Batch* batch) = 0;
  // Valid after Next() returned false: the frames read, and whether a slice was clipped.
  virtual const std::vector<uint32_t>& frames() const = 0;
  virtual bool clipped() const = 0;
};

// A watch of a dataset's changes (storage/watch.h): the same events in both modes. Embedded, it
// sees the changes this process makes (and, on a follower, the writer's as it refreshes);
// remote, every change the server publishes.
class Watcher {
 public:
  virtual ~Watcher() = default;
  // The next event, waiting at most `timeout`: false if none came in time. After a kDropped or
  // kLagged event the watch has ended, and Next returns false at once.
  virtual Result<bool> Next(ChangeEvent* ev, std::chrono::milliseconds timeout) = 0;
};

// What an hvdb-server reports about itself (the request table's server_stats).
using RequestLatency = service::RequestLatency;
using ServerCounters = service::ServerCounters;

struct StatsReport {
  struct Entry {
    std::string name;
    DatasetStats stats;
    uint64_t last_lsn = 0;
  };
  std::vector<Entry> datasets;
  std::optional<CacheStats> cache;       // embedded: this process's block cache
  std::optional<ServerCounters> server;  // remote: the server's counters
};

class Backend {
 public:
  virtual ~Backend() = default;

  virtual bool remote() const = 0;
  // Where the data is, for messages: the data directory, or HOST:PORT of the server.
  virtual std::string where() const = 0;
  // Remote: what the connection runs on ("tcp HOST:PORT", "unix PATH + shared memory").
  virtual std::string transport() const { return "embedded"; }

  // Names of the datasets, sorted.
  virtual Result<std::vector<std::string>> ListDatasets() = 0;
  // Creates a dataset (embedded: and the data directory, if it does not exist yet).
  virtual Result<DatasetInfo> CreateDataset(const DatasetInfo& info) = 0;
  virtual Status DropDataset(const std::string& name) = 0;
  virtual Result<DatasetInfo> Describe(const std::string& name) = 0;
  // Errors of the query's setup (unknown dataset, bad region, too many frames) are returned
  // here in both modes, not by the first Next().
  virtual Result<std::unique_ptr<QueryResults>> Query(const std::string& name,
                                                      const Region& region,
                                                      const QueryOptions& opts) = 0;
  // Bulk-loads one frame (atomic per frame); returns the number of points loaded.
  // gaussians: a Gaussian-splat dataset's records of the points, in their order.
  virtual Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame,
                                    std::vector<Point> points,
                                    const GaussianColumns* gaussians = nullptr) = 0;
  // The Gaussian records of points (by id) of a Gaussian-splat dataset, in their order, those
  // of points without one derived from the point (DeriveMissing; *derived counts them).
  Result<GaussianColumns> ReadGaussians(const std::string& name, std::span<const Point> points,
                                        uint64_t* derived = nullptr);
  // One request's worth of ReadGaussians (service::kMaxGaussianReadIds at most).
  virtual Result<service::GaussianRead> ReadGaussianRecords(const std::string& name,
                                                            std::vector<uint64_t> ids) = 0;
  virtual Result<CommitInfo> Commit(const std::string& name, const Transaction& txn) = 0;
  virtual Result<CommitInfo> Revert(const std::string& name, uint64_t lsn) = 0;
  // The cold tier: frames [first, last] compressed now.
  // photos: the video tier of photos instead of the points' cold tier (Service::Compact).
  virtual Result<CompactInfo> Compact(const std::string& name, uint32_t first, uint32_t last,
                                      bool photos = false) = 0;
  // Stores a camera's photo of a frame (Dataset::PutPhoto), for textured renders.
  virtual Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) = 0;
  // Storage statistics of one dataset, or of all ("" ), plus the cache or server counters.
  virtual Result<StatsReport> Stats(const std::string& name) = 0;
  // Subscribes to the dataset's changes; with from_lsn, the changes after it come first (from
  // the log). Errors (unknown dataset, from_lsn past the last LSN) are returned here.
  virtual Result<std::unique_ptr<Watcher>> Watch(const std::string& name,
                                                 std::optional<uint64_t> from_lsn) = 0;
  // Remote only: one round trip to the server, in milliseconds.
  virtual Result<double> Ping() = 0;
  // Embedded only: the problems Dataset::Check finds in one dataset.
  virtual Result<std::vector<std::string>> Check(const std::string& name) = 0;

  // ---- Editing operators (edit/operators.h). Each change is one transaction of the dataset:
  // Revert(lsn) undoes it, and reverting that undo's lsn redoes it.

  // Sets, adds to, subtracts from or intersects the selection held in label bit req.bit.
  virtual Result<edit::SelectResult> Select(const std::string& name,
                                            const edit::SelectRequest& req) = 0;
  // 4D graph cut inside req.roi, seeded by the stroke bits; the result goes to req.out_bit.
  // Only k, intra_radius, inter_radius and use_normals of req.params reach a server (the
  // protocol's fields): a request that changes the others is Unsupported there.
  virtual Result<edit::GraphCutReply> GraphCut(const std::string& name,
                                               const edit::GraphCutRequest& req) = 0;
  // Copies the points carrying req.bit (within req.region, if given) to the clipboard
  // req.clipboard; with req.cut, deletes them in the same step (CopyResult::lsn, else 0).
  virtual Result<edit::CopyResult> Copy(const std::string& name, const edit::CopyRequest& req) = 0;
  // Inserts the clipboard's points moved by req.map, as new points.
  virtual Result<CommitInfo> Paste(const std::string& name, const edit::PasteRequest& req) = 0;
  // Inserts req.object into frames first_frame .. first_frame + frame_count - 1, offset by
  // trajectory[i] (metres) in frame first_frame + i (static if the trajectory is empty).
  virtual Result<CommitInfo> Composite(const std::string& name,
                                       const edit::CompositeRequest& req) = 0;
  // Inserts an image, video or mesh file (req.data: its bytes), decoded next to the data
  // (media/media.h), in one transaction.
  virtual Result<CommitInfo> ImportMedia(const std::string& name,
                                         const media::ImportRequest& req) = 0;

  // ---- Rendering (docs/PROTOCOL.md, "Rendering"): a render request (render/request.h), as
  // render::RenderJob takes it in both modes (request.dataset names the dataset); remote, it
  // travels as the wire's Render message (protocol/render_convert.h). on_image gets each
  // image's reply (encoded PNG or EXR, renderer used, points, render time, `fallback` when
  // RendererKind::kAuto found no EGL context), in order; a non-OK status from it stops the rest
  // and is returned. Embedded, the renderer is made in this process with render::MakeRenderer
  // (a fallback is logged through render::SetLogHandler's handler, stderr by default); remote,
  // hvdb-server renders and logs it.
  virtual Status Render(const render::RenderRequest& request,
                        const std::function<Status(const render::RenderReply&)>& on_image) = 0;
};

// On a data directory, opened (with an advisory lock) on first use.
std::unique_ptr<Backend> MakeEmbeddedBackend(std::string data_dir, size_t cache_bytes);

struct RemoteOptions {
  std::string address;  // HOST:PORT or unix:PATH (a loopback server's Unix socket is used by itself)
  std::string token;    // "" for servers that need none
  // How query results travel: "records", "columns", "draco" or "hvdb7" (codec/).
  std::string wire = "records";
  // A write refused with NOT_LEADER (the server is a reader that follows the writer) is sent
  // again to the writer, whose address the reader publishes (its StatsReply.leader), and the
  // backend stays on the writer from then on. Off by default: the `hvdb` CLI and the Python
  // module report the refusal (they name the writer); hvdb-ingest turns it on, so ingest tasks
  // given any server of a cluster commit to its writer.
  bool follow_leader = false;
};
// Validates the address (InvalidArgument if it is neither HOST:PORT nor unix:PATH); connects on
// first use.
Result<std::unique_ptr<Backend>> MakeRemoteBackend(const RemoteOptions& options);

}  // namespace hvdb::client

#endif  // HVDB_CLIENT_BACKEND_H_
