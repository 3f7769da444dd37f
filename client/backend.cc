#include "client/backend.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <filesystem>
#include <functional>
#include <span>
#include <system_error>
#include <utility>
#include <variant>

#include "client/client.h"
#include "protocol/convert.h"
#include "protocol/render_convert.h"
#include "service/service.h"
#include "render/job.h"
#include "render/renderer.h"

namespace hvdb::client {

namespace {

namespace fs = std::filesystem;

bool Contains(const std::vector<std::string>& names, const std::string& name) {
  return std::find(names.begin(), names.end(), name) != names.end();
}

// ---------------------------------------------------------------------------------------------
// Embedded: hvdb::Database on a data directory.

class EmbeddedResults final : public QueryResults {
 public:
  EmbeddedResults(std::shared_ptr<Dataset> ds, std::unique_ptr<Cursor> cursor)
      : ds_(std::move(ds)), cursor_(std::move(cursor)) {}
  Result<bool> Next(Batch* batch) override { return cursor_->Next(batch); }
  const std::vector<uint32_t>& frames() const override { return cursor_->frames(); }
  bool clipped() const override { return cursor_->clipped(); }

 private:
  std::shared_ptr<Dataset> ds_;  // outlives the cursor
  std::unique_ptr<Cursor> cursor_;
};

// Events from the storage callback, queued for Next. Bounded as a server connection is: a reader
// that falls kMaxQueued events behind gets kLagged (resume from the last LSN it was given).
class EmbeddedWatcher final : public Watcher {
 public:
  static constexpr size_t kMaxQueued = 65536;
  explicit EmbeddedWatcher(std::shared_ptr<Dataset> ds) : ds_(std::move(ds)) {}
  ChangeFn Fn() {
    return [this](const ChangeEvent& ev) {
      std::lock_guard<std::mutex> l(mu_);
      if (overflow_) return;
      if (q_.size() >= kMaxQueued) {
        overflow_ = true;
      } else {
        q_.push_back(ev);
      }
      cv_.notify_one();
    };
  }
  void Attach(std::unique_ptr<WatchHandle> h) { handle_ = std::move(h); }
  Result<bool> Next(ChangeEvent* ev, std::chrono::milliseconds timeout) override {
    std::unique_lock<std::mutex> l(mu_);
    if (ended_) return false;
    if (!cv_.wait_for(l, timeout, [&] { return !q_.empty() || overflow_; })) return false;
    if (q_.empty()) {  // overflowed, and everything before it was taken
      ChangeEvent lag;
      lag.kind = ChangeEvent::Kind::kLagged;
      lag.dataset = ds_->Info().name;
      lag.lsn = last_lsn_;
      *ev = lag;
      ended_ = true;
      l.unlock();
      handle_.reset();
      return true;
    }
    *ev = std::move(q_.front());
    q_.pop_front();
    if (ev->kind != ChangeEvent::Kind::kDropped) last_lsn_ = ev->lsn;
    if (ev->kind == ChangeEvent::Kind::kDropped) ended_ = true;
    return true;
  }
  ~EmbeddedWatcher() override { handle_.reset(); }  // before the queue it feeds

 private:
  std::shared_ptr<Dataset> ds_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<ChangeEvent> q_;
  bool overflow_ = false, ended_ = false;
  uint64_t last_lsn_ = 0;
  std::unique_ptr<WatchHandle> handle_;
};

// Runs every request through the executor (service/service.h), as hvdb-server does; what is
// left here is what only this mode has: the data directory opened on first use, its block
// cache's numbers, Check, and messages that name the directory.
class EmbeddedBackend final : public Backend {
 public:
  EmbeddedBackend(std::string dir, size_t cache_bytes)
      : dir_(std::move(dir)), cache_bytes_(cache_bytes) {}

  bool remote() const override { return false; }
  std::string where() const override { return dir_; }

  Result<std::vector<std::string>> ListDatasets() override {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/false));
    return x->ListDatasets();
  }

  Result<DatasetInfo> CreateDataset(const DatasetInfo& info) override {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/true));
    return x->CreateDataset(info);
  }

  Status DropDataset(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/false));
    return Explain(name, x->DropDataset(name));
  }

  Result<DatasetInfo> Describe(const std::string& name) override {
    return Do(name, [&](service::Service& x) { return x.Describe(name); });
  }

  Result<std::unique_ptr<QueryResults>> Query(const std::string& name, const Region& region,
                                              const QueryOptions& opts) override {
    HVDB_ASSIGN_OR_RETURN(service::OpenQuery q,
                          Do(name, [&](service::Service& x) { return x.Query(name, region, opts); }));
    return std::unique_ptr<QueryResults>(
        new EmbeddedResults(std::move(q.dataset), std::move(q.cursor)));
  }

  Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame, std::vector<Point> points,
                            const GaussianColumns* gaussians) override {
    return Do(name, [&](service::Service& x) {
      return x.BulkLoad(name, frame, std::move(points), gaussians);
    });
  }

  Result<service::GaussianRead> ReadGaussianRecords(const std::string& name,
                                                    std::vector<uint64_t> ids) override {
    return Do(name, [&](service::Service& x) { return x.ReadGaussians(name, ids); });
  }

  Result<CommitInfo> Commit(const std::string& name, const Transaction& txn) override {
    return Do(name, [&](service::Service& x) { return x.Commit(name, txn); });
  }

  Result<CommitInfo> Revert(const std::string& name, uint64_t lsn) override {
    return Do(name, [&](service::Service& x) { return x.Revert(name, lsn); });
  }

  Result<CompactInfo> Compact(const std::string& name, uint32_t first, uint32_t last,
                              bool photos) override {
    return Do(name, [&](service::Service& x) { return x.Compact(name, first, last, photos); });
  }

  Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) override {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/false));
    return Explain(name, x->PutPhoto(name, frame, photo));
  }

  Result<StatsReport> Stats(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/false));
    std::vector<std::string> names;
    if (!name.empty()) {
      names.push_back(name);
    } else {
      names = x->ListDatasets();
    }
    StatsReport report;
    for (const std::string& n : names) {
      HVDB_ASSIGN_OR_RETURN(service::DatasetReport d,
                            Do(n, [&](service::Service& s) { return s.Stats(n); }));
      report.datasets.push_back({n, d.stats, d.last_lsn});
    }
    report.cache = x->db().Cache();
    return report;
  }

  Result<double> Ping() override {
    return Status::Unsupported("ping needs --server HOST:PORT: there is no server to ping on " +
                               dir_);
  }

  Result<std::unique_ptr<Watcher>> Watch(const std::string& name,
                                         std::optional<uint64_t> from_lsn) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds,
                          Do(name, [&](service::Service& x) { return x.Find(name); }));
    auto w = std::make_unique<EmbeddedWatcher>(ds);
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<WatchHandle> h,
                          Do(name, [&](service::Service& x) { return x.Watch(name, from_lsn, w->Fn()); }));
    w->Attach(std::move(h));
    return std::unique_ptr<Watcher>(std::move(w));
  }

  Result<std::vector<std::string>> Check(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds,
                          Do(name, [&](service::Service& x) { return x.Find(name); }));
    return ds->Check();
  }

  Result<edit::SelectResult> Select(const std::string& name,
                                    const edit::SelectRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.Select(name, req); });
  }

  Result<edit::GraphCutReply> GraphCut(const std::string& name,
                                       const edit::GraphCutRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.GraphCut(name, req); });
  }

  Result<edit::CopyResult> Copy(const std::string& name, const edit::CopyRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.Copy(name, req); });
  }

  Result<CommitInfo> Paste(const std::string& name, const edit::PasteRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.Paste(name, req); });
  }

  Result<CommitInfo> Composite(const std::string& name,
                               const edit::CompositeRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.Composite(name, req); });
  }

  Result<CommitInfo> ImportMedia(const std::string& name,
                                 const media::ImportRequest& req) override {
    return Do(name, [&](service::Service& x) { return x.ImportMedia(name, req); });
  }

  Status Render(const render::RenderRequest& request,
                const std::function<Status(const render::RenderReply&)>& on_image) override {
    // What hvdb-server's sessions do, with a renderer of this process instead of one from the
    // server's pool: the request is checked before a renderer (an EGL context) is made.
    HVDB_ASSIGN_OR_RETURN(
        std::unique_ptr<render::RenderJob> job,
        Do(request.dataset, [&](service::Service& x) { return x.Render(request); }));
    std::string why;
    // Gaussian mode draws with the 3DGS rasteriser of the renderer's kind: the GPU's with EGL.
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<render::Renderer> renderer,
                          render::MakeRenderer(job->renderer_kind(), &why));
    // "fallback" keeps its meaning: auto found no EGL context (not: auto chose the CPU).
    const bool fallback = job->renderer_kind() == render::RendererKind::kAuto &&
                          why.rfind("no EGL context", 0) == 0;
    for (size_t i = 0; i < job->size(); ++i) {
      HVDB_ASSIGN_OR_RETURN(render::RenderReply reply, job->Render(i, *renderer));
      reply.fallback = fallback;
      if (reply.renderer_choice.empty()) reply.renderer_choice = why;
      HVDB_RETURN_IF_ERROR(on_image(reply));
    }
    return Status::OK();
  }

 private:
  // The executor over the database, opened on first use. Only `create` makes the directory,
  // so that a mistyped --data does not leave one behind.
  Result<service::Service*> Service(bool create) {
    if (service_) return service_.get();
    std::error_code ec;
    if (!fs::exists(dir_, ec)) {
      if (!create) {
        return Status::NotFound("data directory '" + dir_ + "' does not exist ('hvdb --data " +
                                dir_ + " create NAME --fps F' starts one)");
      }
      fs::create_directories(dir_, ec);
      if (ec) {
        return Status::IOError("cannot create data directory '" + dir_ + "': " + ec.message());
      }
    }
    hvdb::Options opts;
    opts.cache_bytes = cache_bytes_;
    HVDB_ASSIGN_OR_RETURN(db_, Database::Open(dir_, opts));
    // DIR/clipboards, the ones hvdb-server --data DIR keeps.
    service_ = std::make_unique<service::Service>(db_.get(), dir_);
    return service_.get();
  }

  // Runs fn on the executor; a dataset that does not exist is said the way every command says it.
  template <typename Fn>
  auto Do(const std::string& name, Fn fn) -> decltype(fn(std::declval<service::Service&>())) {
    HVDB_ASSIGN_OR_RETURN(service::Service * x, Service(/*create=*/false));
    auto r = fn(*x);
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Status Explain(const std::string& name, Status s) {
    if (!service::IsUnknownDataset(s)) return s;
    return Status::NotFound("no dataset '" + name + "' in " + dir_ + " ('hvdb --data " + dir_ +
                            " datasets' lists them)");
  }

  std::string dir_;
  size_t cache_bytes_;
  std::unique_ptr<Database> db_;
  std::unique_ptr<service::Service> service_;
};

// ---------------------------------------------------------------------------------------------
// Remote: an hvdb-server, through Client (which reconnects for requests safe to repeat).

class RemoteResults final : public QueryResults {
 public:
  RemoteResults(std::unique_ptr<QueryStream> stream, Batch first, bool first_more)
      : stream_(std::move(stream)), first_(std::move(first)), first_more_(first_more) {}
  Result<bool> Next(Batch* batch) override {
    if (have_first_) {
      have_first_ = false;
      if (!first_more_) return false;
      *batch = std::move(first_);
      return true;
    }
    return stream_->Next(batch);
  }
  const std::vector<uint32_t>& frames() const override { return stream_->frames(); }
  bool clipped() const override { return stream_->clipped(); }

 private:
  std::unique_ptr<QueryStream> stream_;
  Batch first_;  // read ahead by RemoteBackend::Query, so that setup errors surface there
  bool first_more_;
  bool have_first_ = true;
};

// A watch on a connection of its own: its events never wait behind other requests' answers.
class RemoteWatcher final : public Watcher {
 public:
  RemoteWatcher(std::unique_ptr<Connection> c, std::unique_ptr<WatchStream> s)
      : conn_(std::move(c)), stream_(std::move(s)) {}
  ~RemoteWatcher() override { stream_.reset(); }  // cancels it while the connection is open
  Result<bool> Next(ChangeEvent* ev, std::chrono::milliseconds timeout) override {
    return stream_->Next(ev, timeout);
  }

 private:
  std::unique_ptr<Connection> conn_;
  std::unique_ptr<WatchStream> stream_;
};

class RemoteBackend final : public Backend {
 public:
  RemoteBackend(std::string address, client::Options opts, bool follow_leader)
      : address_(std::move(address)), token_given_(!opts.token.empty()),
        follow_leader_(follow_leader), opts_(opts),
        client_(std::make_unique<Client>(std::move(opts))) {}

  Result<std::unique_ptr<Watcher>> Watch(const std::string& name,
                                         std::optional<uint64_t> from_lsn) override {
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<Connection> c, Connection::Connect(opts_));
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<WatchStream> s, c->Watch(name, from_lsn));
    return std::unique_ptr<Watcher>(new RemoteWatcher(std::move(c), std::move(s)));
  }

  bool remote() const override { return true; }
  std::string where() const override { return address_; }
  std::string transport() const override {
    auto* c = client_->connection();
    return c ? c->transport() : "not connected";
  }

  // The unary requests: each one generic call with the request table's pair (Call below).
  Result<std::vector<std::string>> ListDatasets() override {
    HVDB_ASSIGN_OR_RETURN(std::vector<std::string> names, Call<service::op::List>({}));
    std::sort(names.begin(), names.end());
    return names;
  }

  Result<DatasetInfo> CreateDataset(const DatasetInfo& info) override {
    return Call<service::op::Create>(info);
  }

  Status DropDataset(const std::string& name) override {
    return Call<service::op::Drop>(name).status();
  }

  Result<DatasetInfo> Describe(const std::string& name) override {
    return Call<service::op::Describe>(name);
  }

  Result<std::unique_ptr<QueryResults>> Query(const std::string& name, const Region& region,
                                              const QueryOptions& opts) override {
    Result<std::unique_ptr<QueryStream>> stream = Run<std::unique_ptr<QueryStream>>(
        true, [&](Connection& c) { return c.Query(name, region, opts); });
    if (!stream.ok()) return Explain(name, stream.status());
    // The server reports the query's setup errors as its first response: read it here.
    Batch first;
    Result<bool> more = (*stream)->Next(&first);
    if (!more.ok()) return Explain(name, more.status());
    return std::unique_ptr<QueryResults>(
        new RemoteResults(std::move(stream).value(), std::move(first), *more));
  }

  Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame, std::vector<Point> points,
                            const GaussianColumns* gaussians) override {
    Result<uint64_t> r = Run<uint64_t>(false, [&](Connection& c) {
      return c.Ingest(name, frame, std::span<const Point>(points), gaussians);
    });
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Result<service::GaussianRead> ReadGaussianRecords(const std::string& name,
                                                    std::vector<uint64_t> ids) override {
    return Call<service::op::ReadGaussians>({name, std::move(ids)});
  }

  Result<CommitInfo> Commit(const std::string& name, const Transaction& txn) override {
    return Call<service::op::Edit>({name, txn});
  }

  Result<CommitInfo> Revert(const std::string& name, uint64_t lsn) override {
    return Call<service::op::Revert>({name, lsn});
  }

  Result<CompactInfo> Compact(const std::string& name, uint32_t first, uint32_t last,
                              bool photos) override {
    return Call<service::op::Compact>({name, {first, last, photos}});
  }

  Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) override {
    return Call<service::op::PutPhoto>({name, {frame, photo}}).status();
  }

  Result<StatsReport> Stats(const std::string& name) override {
    std::vector<std::string> names;
    if (!name.empty()) {
      names.push_back(name);
    } else {
      HVDB_ASSIGN_OR_RETURN(names, ListDatasets());
    }
    StatsReport report;
    std::optional<service::ServerCounters> counters;
    for (const std::string& n : names) {
      HVDB_ASSIGN_OR_RETURN(service::StatsOut r, Call<service::op::Stats>(n));
      if (r.dataset) report.datasets.push_back({n, r.dataset->stats, r.dataset->last_lsn});
      counters = std::move(r.server);
    }
    if (!counters) {
      HVDB_ASSIGN_OR_RETURN(counters, Call<service::op::ServerStats>({}));
    }
    report.server = std::move(counters);
    return report;
  }

  Result<double> Ping() override {
    return Run<double>(true, [](Connection& c) -> Result<double> {
      auto start = std::chrono::steady_clock::now();
      HVDB_RETURN_IF_ERROR(c.Ping());
      return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
          .count();
    });
  }

  Result<std::vector<std::string>> Check(const std::string& /*name*/) override {
    return Status::Unsupported("check reads the data directory's files: run 'hvdb --data DIR "
                               "check' on the server's machine, with hvdb-server stopped");
  }

  // The editing operators travel as their values; the server's executor checks them as the
  // embedded one does.
  Result<edit::SelectResult> Select(const std::string& name,
                                    const edit::SelectRequest& req) override {
    return Call<service::op::Select>({name, req});
  }

  Result<edit::GraphCutReply> GraphCut(const std::string& name,
                                       const edit::GraphCutRequest& req) override {
    return Call<service::op::GraphCut>({name, req});
  }

  Result<edit::CopyResult> Copy(const std::string& name, const edit::CopyRequest& req) override {
    return Call<service::op::Copy>({name, req});
  }

  Result<CommitInfo> Paste(const std::string& name, const edit::PasteRequest& req) override {
    return Call<service::op::Paste>({name, req});
  }

  Result<CommitInfo> Composite(const std::string& name,
                               const edit::CompositeRequest& req) override {
    return Call<service::op::Composite>({name, req});
  }

  Result<CommitInfo> ImportMedia(const std::string& name,
                                 const media::ImportRequest& req) override {
    return Call<service::op::ImportMedia>({name, req});
  }

  Status Render(const render::RenderRequest& request,
                const std::function<Status(const render::RenderReply&)>& on_image) override {
    // The request travels as the wire's Render message, each reply back as a RenderReply.
    wire::Render msg;
    wire::ToWire(request, &msg);
    // A render only reads, so it is repeated after a lost connection; the images the caller
    // already has are not handed to it again.
    uint32_t delivered = 0;
    auto deliver = [&](const wire::RenderReply& reply) -> Status {
      if (reply.index() < delivered) return Status::OK();
      HVDB_RETURN_IF_ERROR(on_image(wire::FromWire(reply)));
      delivered = reply.index() + 1;
      return Status::OK();
    };
    Result<bool> r = Run<bool>(true, [&](Connection& c) -> Result<bool> {
      HVDB_RETURN_IF_ERROR(c.RenderSequence(msg, deliver));
      return true;
    });
    return r.ok() ? Status::OK() : Explain(request.dataset, r.status());
  }

 private:
  // A unary request of the table (service/requests.h): encoded with its op's pair, sent (again
  // after a lost connection only when the op says it is safe to repeat), its reply decoded, and
  // its error said the one way every request's is (Explain).
  template <typename Op>
  Result<typename Op::Out> Call(const typename Op::In& in) {
    wire::Request req;
    Op::Put(in, &req);
    Result<wire::Response> r = Run<wire::Response>(Op::Repeatable(in), [&req](Connection& c) {
      wire::Request q = req;
      return c.Call(&q);
    });
    if (!r.ok()) return Explain(Op::Kind(), Op::Dataset(in), req, r.status());
    return Op::TakeReply(*r);
  }

  // The first connection is tried once, so that a wrong address, a stopped server or a bad
  // token is reported at once; afterwards Client reconnects (with backoff) for requests that
  // are safe to repeat.
  template <typename T>
  Result<T> Run(bool idempotent, const std::function<Result<T>(Connection&)>& fn) {
    for (int hop = 0;; ++hop) {
      HVDB_RETURN_IF_ERROR(Connect());
      if (follow_leader_ && !leader_checked_) {
        // Reads go to the writer too: a reader that lags would show an ingest's last frames
        // as missing, and it would load them twice.
        leader_checked_ = true;
        Result<service::ServerCounters> s = client_->Run<service::ServerCounters>(
            true, [](Connection& c) { return c.Unary<service::op::ServerStats>({}); });
        if (s.ok() && s->role == "reader" && !s->leader.empty() && s->leader != address_) {
          HVDB_RETURN_IF_ERROR(MoveTo(s->leader));
          continue;
        }
      }
      Result<T> r = client_->Run<T>(idempotent, fn);
      // A reader refused it before applying anything: it goes to the writer as it is. A few
      // hops at most (a writer that was replaced while we moved).
      if (r.ok() || r.status().code() != StatusCode::kNotLeader || !follow_leader_ || hop == 3)
        return r;
      Status moved = MoveToLeader();
      if (!moved.ok())
        return Status::NotLeader(r.status().message() + " (not followed: " + moved.message() + ")");
    }
  }

  // follow_leader: asks the reader where the writer listens and connects there from now on.
  Status MoveToLeader() {
    Result<service::ServerCounters> s = client_->Run<service::ServerCounters>(
        true, [](Connection& c) { return c.Unary<service::op::ServerStats>({}); });
    if (!s.ok()) return Status(s.status().code(), "asking " + address_ + " for the writer: " + s.status().message());
    const std::string leader = s->leader;
    if (leader.empty()) return Status::NotLeader(address_ + " does not know the writer's address yet");
    if (leader == address_) return Status::NotLeader(address_ + " names itself as the writer");
    return MoveTo(leader);
  }

  Status MoveTo(const std::string& leader) {
    client::Options o = opts_;
    HVDB_RETURN_IF_ERROR(ParseAddress(leader, &o));
    // The old client stays: query streams opened on its connections may still be read.
    retired_clients_.push_back(std::move(client_));
    client_ = std::make_unique<Client>(o);
    opts_ = std::move(o);
    address_ = leader;
    connected_ = false;
    return Status::OK();
  }

  Status Connect() {
    if (!connected_) {
      Status st = client_->EnsureConnected();
      if (st.code() == StatusCode::kPermissionDenied) {
        return Status(st.code(), st.message() + (token_given_
                                                     ? " (" + address_ + " refused the token)"
                                                     : " (" + address_ +
                                                           " needs one: --token TOKEN or the "
                                                           "environment variable HVDB_TOKEN)"));
      }
      HVDB_RETURN_IF_ERROR(st);
      connected_ = true;
    }
    return Status::OK();
  }

  // A request's error: a dataset that does not exist, said as every command says it; for the
  // kinds that carry a file or an object whole (the table's if_too_large), what the server's
  // frame limit has to do with it.
  Status Explain(const service::RequestKind& kind, const std::string& name,
                 const wire::Request& req, Status s) {
    if (!name.empty()) s = Explain(name, std::move(s));
    if (kind.if_too_large == nullptr) return s;
    const size_t bytes = req.ByteSizeLong();
    // The server says so, or closes the connection while the request is still being sent.
    if (bytes >= wire::kDefaultMaxFrame - 4096 ||
        s.message().find("exceeds the limit") != std::string::npos) {
      return Status(s.code(), s.message() + " (the " + kind.name + " request is " +
                                  std::to_string(bytes) + " bytes; a server refuses one over " +
                                  "its --max-frame-bytes, " +
                                  std::to_string(wire::kDefaultMaxFrame) + " by default: " +
                                  kind.if_too_large + ")");
    }
    if (s.code() == StatusCode::kIOError && bytes > (64u << 10)) {
      // A lost connection is either: the size is not known to be the cause.
      return Status(s.code(), s.message() + " (the connection closed during the " + kind.name +
                                  " request: a server closes it for a request over its " +
                                  "--max-frame-bytes, which this one of " + std::to_string(bytes) +
                                  " bytes passes only where that is set below the default of " +
                                  std::to_string(wire::kDefaultMaxFrame) +
                                  ", or it stopped; its log says which)");
    }
    return s;
  }

  // A NotFound about a dataset that does not exist, said the same way by every command (the
  // wire maps the server's UNKNOWN_DATASET and NOT_FOUND both to NotFound: ask).
  Status Explain(const std::string& name, Status s) {
    if (!s.IsNotFound()) return s;
    Result<std::vector<std::string>> names = ListDatasets();
    if (!names.ok() || Contains(*names, name)) return s;
    return Status::NotFound("no dataset '" + name + "' on " + address_ + " ('hvdb --server " +
                            address_ + " datasets' lists them)");
  }

  std::string address_;
  bool token_given_;
  bool follow_leader_;
  client::Options opts_;  // for connections of their own (watches)
  std::unique_ptr<Client> client_;
  std::vector<std::unique_ptr<Client>> retired_clients_;
  bool connected_ = false;
  bool leader_checked_ = false;  // follow_leader: whether the first server was asked its role
};

}  // namespace

Result<GaussianColumns> Backend::ReadGaussians(const std::string& name,
                                               std::span<const Point> points, uint64_t* derived) {
  // Asked for in ascending id order, in requests of at most kMaxGaussianReadIds ids and 512
  // groups of 1024 consecutive ids (so at most kMaxGaussianReadBlocks blocks read each), and
  // put back in the points' order.
  std::vector<uint32_t> order(points.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<uint32_t>(i);
  std::sort(order.begin(), order.end(),
            [&](uint32_t a, uint32_t b) { return points[a].id < points[b].id; });
  std::vector<GaussianColumns> parts;
  std::vector<std::pair<size_t, size_t>> ranges;  // [begin, end) of `order` per part
  std::vector<bool> found(points.size(), false);
  int degree = 0;
  GaussianColumns out;
  // Many small segments (loads of a few splats each) can put more blocks in a group than two:
  // a request the server refuses as too many blocks is asked again in halves.
  size_t cap_ids = service::kMaxGaussianReadIds, cap_groups = service::kMaxGaussianReadBlocks / 2;
  for (size_t at = 0; at < order.size();) {
    std::vector<uint64_t> ids;
    size_t groups = 0;
    uint64_t last_group = UINT64_MAX;
    size_t end = at;
    for (; end < order.size() && ids.size() < cap_ids; ++end) {
      const uint64_t id = points[order[end]].id;
      if ((id >> 10) != last_group) {
        if (groups == cap_groups) break;
        ++groups;
        last_group = id >> 10;
      }
      ids.push_back(id);
    }
    const size_t n = ids.size();
    Result<service::GaussianRead> got = ReadGaussianRecords(name, std::move(ids));
    if (!got.ok() && got.status().code() == StatusCode::kLimitExceeded && n > 1) {
      cap_ids = n / 2;
      cap_groups = std::max<size_t>(1, groups / 2);
      continue;
    }
    HVDB_ASSIGN_OR_RETURN(service::GaussianRead r, std::move(got));
    if (r.found.size() != n || r.records.size() != n) {
      return Status::IOError("read_gaussians: " + std::to_string(r.records.size()) +
                             " records for " + std::to_string(n) + " ids");
    }
    degree = std::max(degree, r.records.sh_degree);
    out.antialiased = out.antialiased || r.records.antialiased;
    for (size_t k = 0; k < n; ++k) found[order[at + k]] = r.found[k];
    parts.push_back(std::move(r.records));
    ranges.emplace_back(at, end);
    at = end;
  }
  out.sh_degree = degree;
  const size_t stride = out.stride();
  out.values.assign(points.size() * stride, 0.f);
  for (size_t p = 0; p < parts.size(); ++p) {
    const GaussianColumns& part = parts[p];
    for (size_t k = 0; k < part.size(); ++k) {
      WidenRecord(part.record(k), part.sh_degree, out.record(order[ranges[p].first + k]), degree);
    }
  }
  const uint64_t n = DeriveMissing(points, found, &out);
  if (derived) *derived = n;
  return out;
}

std::unique_ptr<Backend> MakeEmbeddedBackend(std::string data_dir, size_t cache_bytes) {
  return std::make_unique<EmbeddedBackend>(std::move(data_dir), cache_bytes);
}

Result<std::unique_ptr<Backend>> MakeRemoteBackend(const RemoteOptions& options) {
  client::Options opts;
  HVDB_RETURN_IF_ERROR(ParseAddress(options.address, &opts));
  opts.token = options.token;
  if (options.wire == "columns") {
    opts.columns = true;
  } else if (options.wire == "draco") {
    opts.draco = true;
  } else if (options.wire == "hvdb7") {
    opts.hvdb7 = true;
  } else if (options.wire != "records") {
    return Status::InvalidArgument("wire encoding '" + options.wire +
                                   "': use records, columns, draco or hvdb7");
  }
  return std::unique_ptr<Backend>(
      new RemoteBackend(options.address, std::move(opts), options.follow_leader));
}

}  // namespace hvdb::client
