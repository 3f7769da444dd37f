#include "client/backend.h"

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <functional>
#include <span>
#include <system_error>
#include <utility>
#include <variant>

#include <nlohmann/json.hpp>

#include "client/client.h"
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

class EmbeddedBackend final : public Backend {
 public:
  EmbeddedBackend(std::string dir, size_t cache_bytes)
      : dir_(std::move(dir)), cache_bytes_(cache_bytes) {}

  bool remote() const override { return false; }
  std::string where() const override { return dir_; }

  Result<std::vector<std::string>> ListDatasets() override {
    HVDB_ASSIGN_OR_RETURN(Database * db, Db(/*create=*/false));
    std::vector<std::string> names = db->ListDatasets();
    std::sort(names.begin(), names.end());
    return names;
  }

  Result<DatasetInfo> CreateDataset(const DatasetInfo& info) override {
    HVDB_ASSIGN_OR_RETURN(Database * db, Db(/*create=*/true));
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, db->CreateDataset(info));
    return ds->Info();
  }

  Status DropDataset(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(Database * db, Db(/*create=*/false));
    return Explain(name, db->DropDataset(name));
  }

  Result<DatasetInfo> Describe(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return ds->Info();
  }

  Result<std::unique_ptr<QueryResults>> Query(const std::string& name, const Region& region,
                                              const QueryOptions& opts) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<Cursor> cursor, ds->Query(region, opts));
    return std::unique_ptr<QueryResults>(new EmbeddedResults(std::move(ds), std::move(cursor)));
  }

  Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame,
                            std::vector<Point> points) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return ds->BulkLoad(frame, std::move(points));
  }

  Result<CommitInfo> Commit(const std::string& name, const Transaction& txn) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return ds->Commit(txn);
  }

  Result<CommitInfo> Revert(const std::string& name, uint64_t lsn) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return ds->Revert(lsn);
  }

  Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    HVDB_RETURN_IF_ERROR(render::CheckPhoto(photo));
    return ds->PutPhoto(frame, photo);
  }

  Result<StatsReport> Stats(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(Database * db, Db(/*create=*/false));
    std::vector<std::string> names;
    if (!name.empty()) {
      names.push_back(name);
    } else {
      HVDB_ASSIGN_OR_RETURN(names, ListDatasets());
    }
    StatsReport report;
    for (const std::string& n : names) {
      HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(n));
      report.datasets.push_back({n, ds->Stats(), ds->Info().last_lsn});
    }
    report.cache = db->Cache();
    return report;
  }

  Result<double> Ping() override {
    return Status::Unsupported("ping needs --server HOST:PORT: there is no server to ping on " +
                               dir_);
  }

  Result<std::vector<std::string>> Check(const std::string& name) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return ds->Check();
  }

  Result<edit::SelectResult> Select(const std::string& name,
                                    const edit::SelectRequest& req) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return edit::Select(*ds, req);
  }

  Result<edit::GraphCutReply> GraphCut(const std::string& name,
                                       const edit::GraphCutRequest& req) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return edit::GraphCutSelect(*ds, req);
  }

  Result<edit::CopyResult> Copy(const std::string& name, int bit,
                                const std::optional<Region>& region, const std::string& clipboard,
                                bool cut) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    edit::ClipboardStore store(dir_);  // DIR/clipboards, as hvdb-server --data DIR keeps them
    return edit::Copy(*ds, bit, region, store, clipboard, cut);
  }

  Result<CommitInfo> Paste(const std::string& name, const std::string& clipboard,
                           const Affine4& map) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    edit::ClipboardStore store(dir_);
    HVDB_ASSIGN_OR_RETURN(std::vector<Point> clip, store.Get(clipboard));
    return edit::Paste(*ds, clip, map);
  }

  Result<CommitInfo> Composite(const std::string& name, const std::vector<Point>& object,
                               uint32_t first_frame, uint32_t frame_count,
                               const std::vector<std::array<double, 3>>& trajectory) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(name));
    return edit::Composite(*ds, object, first_frame, frame_count, trajectory);
  }

  Status Render(const wire::Render& request,
                const std::function<Status(const wire::RenderReply&)>& on_image) override {
    HVDB_ASSIGN_OR_RETURN(std::shared_ptr<Dataset> ds, Open(request.dataset()));
    // What hvdb-server's sessions do, with a renderer of this process instead of one from the
    // server's pool: the request is checked before a renderer (an EGL context) is made.
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<render::RenderJob> job,
                          render::RenderJob::Create(std::move(ds), request));
    std::string why;
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<render::Renderer> renderer,
                          render::MakeRenderer(job->renderer_kind(), &why));
    // "fallback" keeps its meaning: auto found no EGL context (not: auto chose the CPU).
    const bool fallback = job->renderer_kind() == render::RendererKind::kAuto &&
                          why.rfind("no EGL context", 0) == 0;
    for (size_t i = 0; i < job->size(); ++i) {
      HVDB_ASSIGN_OR_RETURN(wire::RenderReply reply, job->Render(i, *renderer));
      reply.set_fallback(fallback);
      reply.set_renderer_choice(why);
      HVDB_RETURN_IF_ERROR(on_image(reply));
    }
    return Status::OK();
  }

 private:
  // The database, opened on first use. Only `create` makes the directory, so that a mistyped
  // --data does not leave one behind.
  Result<Database*> Db(bool create) {
    if (db_) return db_.get();
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
    return db_.get();
  }

  Result<std::shared_ptr<Dataset>> Open(const std::string& name) {
    HVDB_ASSIGN_OR_RETURN(Database * db, Db(/*create=*/false));
    Result<std::shared_ptr<Dataset>> ds = db->GetDataset(name);
    if (ds.ok()) return ds;
    return Explain(name, ds.status());
  }

  // A NotFound about a dataset that does not exist, said the same way by every command.
  Status Explain(const std::string& name, Status s) {
    if (!s.IsNotFound() || !db_ || Contains(db_->ListDatasets(), name)) return s;
    return Status::NotFound("no dataset '" + name + "' in " + dir_ + " ('hvdb --data " + dir_ +
                            " datasets' lists them)");
  }

  std::string dir_;
  size_t cache_bytes_;
  std::unique_ptr<Database> db_;
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

uint64_t U64(const nlohmann::json& j, const char* key) {
  auto it = j.find(key);
  return it != j.end() && it->is_number_unsigned() ? it->get<uint64_t>() : 0;
}

double F64(const nlohmann::json& j, const char* key) {
  auto it = j.find(key);
  return it != j.end() && it->is_number() ? it->get<double>() : 0;
}

// A label bit outside 0..31, refused here with the engine's words (the wire carries bits
// unsigned, so a negative one would otherwise reach the server as another number).
Status CheckBit(int bit, const char* what) {
  if (bit < 0 || bit > 31) {
    return Status::InvalidArgument(std::string(what) + ": label bit must be 0..31, got " +
                                   std::to_string(bit));
  }
  return Status::OK();
}

// The graph-cut parameters that have no field in GraphCutRequest must keep their defaults.
Status CheckWireParams(const edit::GraphCutParams& p) {
  const edit::GraphCutParams d;
  if (p.max_color_diff != d.max_color_diff || p.max_normal_diff != d.max_normal_diff ||
      p.gmm_components != d.gmm_components || p.beta_c != d.beta_c || p.beta_n != d.beta_n ||
      p.lambda_d != d.lambda_d || p.lambda_i != d.lambda_i || p.lambda_t != d.lambda_t) {
    return Status::Unsupported(
        "graph cut: only k, the intra/inter-frame radii and colour-only can be sent to "
        "hvdb-server; the other parameters keep their defaults there");
  }
  return Status::OK();
}

class RemoteBackend final : public Backend {
 public:
  RemoteBackend(std::string address, client::Options opts)
      : address_(std::move(address)), token_given_(!opts.token.empty()), client_(std::move(opts)) {}

  bool remote() const override { return true; }
  std::string where() const override { return address_; }
  std::string transport() const override {
    auto* c = const_cast<Client&>(client_).connection();
    return c ? c->transport() : "not connected";
  }

  Result<std::vector<std::string>> ListDatasets() override {
    HVDB_ASSIGN_OR_RETURN(std::vector<std::string> names,
                          Run<std::vector<std::string>>(
                              true, [](Connection& c) { return c.ListDatasets(); }));
    std::sort(names.begin(), names.end());
    return names;
  }

  Result<DatasetInfo> CreateDataset(const DatasetInfo& info) override {
    return Run<DatasetInfo>(false, [&info](Connection& c) { return c.CreateDataset(info); });
  }

  Status DropDataset(const std::string& name) override {
    Result<bool> r = Run<bool>(false, [&name](Connection& c) -> Result<bool> {
      HVDB_RETURN_IF_ERROR(c.DropDataset(name));
      return true;
    });
    return r.ok() ? Status::OK() : Explain(name, r.status());
  }

  Result<DatasetInfo> Describe(const std::string& name) override {
    Result<DatasetInfo> r =
        Run<DatasetInfo>(true, [&name](Connection& c) { return c.Describe(name); });
    if (!r.ok()) return Explain(name, r.status());
    return r;
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

  Result<uint64_t> BulkLoad(const std::string& name, uint32_t frame,
                            std::vector<Point> points) override {
    Result<uint64_t> r = Run<uint64_t>(false, [&](Connection& c) {
      return c.Ingest(name, frame, std::span<const Point>(points));
    });
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Result<CommitInfo> Commit(const std::string& name, const Transaction& txn) override {
    Result<CommitInfo> r =
        Run<CommitInfo>(false, [&](Connection& c) { return c.Commit(name, txn); });
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Result<CommitInfo> Revert(const std::string& name, uint64_t lsn) override {
    Result<CommitInfo> r =
        Run<CommitInfo>(false, [&](Connection& c) { return c.Revert(name, lsn); });
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Status PutPhoto(const std::string& name, uint32_t frame, const Photo& photo) override {
    // Safe to repeat: the same photo replaces itself.
    Result<bool> r = Run<bool>(true, [&](Connection& c) -> Result<bool> {
      HVDB_RETURN_IF_ERROR(c.PutPhoto(name, frame, photo));
      return true;
    });
    if (!r.ok()) return Explain(name, r.status());
    return Status::OK();
  }

  Result<StatsReport> Stats(const std::string& name) override {
    std::vector<std::string> names;
    if (!name.empty()) {
      names.push_back(name);
    } else {
      HVDB_ASSIGN_OR_RETURN(names, ListDatasets());
    }
    StatsReport report;
    std::optional<wire::StatsReply> last;
    for (const std::string& n : names) {
      Result<wire::StatsReply> r =
          Run<wire::StatsReply>(true, [&n](Connection& c) { return c.Stats(n); });
      if (!r.ok()) return Explain(n, r.status());
      nlohmann::json j = nlohmann::json::parse(r->dataset_json(), nullptr,
                                               /*allow_exceptions=*/false);
      if (!j.is_object()) {
        return Status::IOError("hvdb-server sent unreadable statistics for dataset '" + n +
                               "': " + r->dataset_json());
      }
      StatsReport::Entry e;
      e.name = n;
      e.last_lsn = r->last_lsn();
      e.stats.frames_with_data = static_cast<uint32_t>(U64(j, "frames_with_data"));
      e.stats.points = U64(j, "points");
      e.stats.tombstones = U64(j, "tombstones");
      e.stats.buffered_points = U64(j, "buffered_points");
      e.stats.trees = U64(j, "trees");
      e.stats.tree_bytes = U64(j, "tree_bytes");
      e.stats.wal_bytes = U64(j, "wal_bytes");
      e.stats.leaf_utilisation = F64(j, "leaf_utilisation");
      report.datasets.push_back(std::move(e));
      last = std::move(r).value();
    }
    if (!last) {
      HVDB_ASSIGN_OR_RETURN(
          last, Run<wire::StatsReply>(true, [](Connection& c) { return c.Stats(""); }));
    }
    ServerCounters s;
    s.connections_open = last->connections_open();
    s.connections_total = last->connections_total();
    s.bytes_in = last->bytes_in();
    s.bytes_out = last->bytes_out();
    s.cache_hit_rate = last->cache_hit_rate();
    s.cache_capacity_bytes = last->cache_capacity_bytes();
    s.role = last->role();
    s.leader = last->leader();
    for (const wire::LatencySummary& l : last->requests()) {
      s.requests.push_back({l.kind(), l.count(), l.p50_ms(), l.p95_ms(), l.p99_ms()});
    }
    std::sort(s.requests.begin(), s.requests.end(),
              [](const RequestLatency& a, const RequestLatency& b) { return a.kind < b.kind; });
    report.server = std::move(s);
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

  Result<edit::SelectResult> Select(const std::string& name,
                                    const edit::SelectRequest& req) override {
    HVDB_RETURN_IF_ERROR(CheckBit(req.bit, "select"));
    wire::SelectRequest q;
    q.set_dataset(name);
    wire::ToWire(req.region, q.mutable_region());
    q.set_bit(static_cast<uint32_t>(req.bit));
    q.set_mode(static_cast<wire::SelectMode>(req.mode));
    if (const auto* lasso = std::get_if<edit::Lasso>(&req.shape)) {
      wire::LassoShape* l = q.mutable_lasso();
      wire::ToWire(lasso->camera, l->mutable_camera());
      for (const auto& v : lasso->polygon) {
        l->add_polygon(v[0]);
        l->add_polygon(v[1]);
      }
    } else if (const auto* brush = std::get_if<edit::Brush>(&req.shape)) {
      wire::BrushShape* b = q.mutable_brush();
      wire::ToWire(brush->camera, b->mutable_camera());
      b->set_u(brush->u);
      b->set_v(brush->v);
      b->set_pixel_radius(brush->pixel_radius);
      b->set_radius(brush->radius);
      b->set_nearest(brush->depth == edit::Brush::Depth::kNearest);
    }
    // Not repeated after a lost connection: it may have been committed.
    Result<wire::SelectReply> r =
        Run<wire::SelectReply>(false, [&q](Connection& c) { return c.Select(q); });
    if (!r.ok()) return Explain(name, r.status());
    edit::SelectResult out;
    out.matched = r->matched();
    out.selected = r->selected();
    out.lsn = r->lsn();
    if (r->brush_center_size() == 3) {
      out.brush_center =
          std::array<double, 3>{r->brush_center(0), r->brush_center(1), r->brush_center(2)};
    }
    return out;
  }

  Result<edit::GraphCutReply> GraphCut(const std::string& name,
                                       const edit::GraphCutRequest& req) override {
    HVDB_RETURN_IF_ERROR(CheckBit(req.foreground_bit, "graph cut foreground"));
    HVDB_RETURN_IF_ERROR(CheckBit(req.background_bit, "graph cut background"));
    HVDB_RETURN_IF_ERROR(CheckBit(req.out_bit, "graph cut output"));
    HVDB_RETURN_IF_ERROR(CheckWireParams(req.params));
    if (req.params.k < 1 || !(req.params.intra_radius > 0) || !(req.params.inter_radius > 0)) {
      // 0 means "the default" on the wire: refuse what the engine would refuse.
      return Status::InvalidArgument("graph cut: k, radii, betas and components must be positive");
    }
    if (req.params.k > 64) {  // hvdb-server caps k at 64
      return Status::InvalidArgument("graph cut: k must be at most 64 through hvdb-server, got " +
                                     std::to_string(req.params.k));
    }
    wire::GraphCutRequest q;
    q.set_dataset(name);
    wire::ToWire(req.roi, q.mutable_roi());
    q.set_foreground_bit(static_cast<uint32_t>(req.foreground_bit));
    q.set_background_bit(static_cast<uint32_t>(req.background_bit));
    q.set_out_bit(static_cast<uint32_t>(req.out_bit));
    q.set_k(static_cast<uint32_t>(req.params.k));
    q.set_intra_radius(req.params.intra_radius);
    q.set_inter_radius(req.params.inter_radius);
    q.set_colour_only(!req.params.use_normals);
    Result<wire::GraphCutReply> r =
        Run<wire::GraphCutReply>(false, [&q](Connection& c) { return c.GraphCut(q); });
    if (!r.ok()) return Explain(name, r.status());
    edit::GraphCutReply out;
    out.roi_points = r->roi_points();
    out.selected = r->selected();
    out.lsn = r->lsn();
    out.cut.energy = r->energy();
    out.cut.intra_edges = r->intra_edges();
    out.cut.inter_edges = r->inter_edges();
    out.cut.neighbours_ms = r->neighbours_ms();
    out.cut.gmm_ms = r->gmm_ms();
    out.cut.graph_ms = r->graph_ms();
    out.cut.maxflow_ms = r->maxflow_ms();
    out.cut.warm = r->recut();
    out.load_ms = r->load_ms();
    out.commit_ms = r->commit_ms();
    return out;
  }

  Result<edit::CopyResult> Copy(const std::string& name, int bit,
                                const std::optional<Region>& region, const std::string& clipboard,
                                bool cut) override {
    HVDB_RETURN_IF_ERROR(CheckBit(bit, "copy"));
    wire::CopyRequest q;
    q.set_dataset(name);
    q.set_bit(static_cast<uint32_t>(bit));
    if (region) wire::ToWire(*region, q.mutable_region());
    q.set_clipboard(clipboard);
    q.set_cut(cut);
    // A copy only rewrites the clipboard: safe to repeat. A cut deletes: not.
    Result<wire::CopyReply> r =
        Run<wire::CopyReply>(!cut, [&q](Connection& c) { return c.Copy(q); });
    if (!r.ok()) return Explain(name, r.status());
    return edit::CopyResult{r->points(), r->lsn()};
  }

  Result<CommitInfo> Paste(const std::string& name, const std::string& clipboard,
                           const Affine4& map) override {
    wire::PasteRequest q;
    q.set_dataset(name);
    q.set_clipboard(clipboard);
    for (double v : map.a) q.add_matrix(v);
    for (double v : map.c) q.add_offset(v);
    Result<CommitInfo> r = Run<CommitInfo>(false, [&q](Connection& c) { return c.Paste(q); });
    if (!r.ok()) return Explain(name, r.status());
    return r;
  }

  Result<CommitInfo> Composite(const std::string& name, const std::vector<Point>& object,
                               uint32_t first_frame, uint32_t frame_count,
                               const std::vector<std::array<double, 3>>& trajectory) override {
    wire::CompositeRequest q;
    q.set_dataset(name);
    wire::EncodeColumns(std::span<const Point>(object), q.mutable_object());
    q.set_first_frame(first_frame);
    q.set_frame_count(frame_count);
    for (const auto& d : trajectory) {
      for (double v : d) q.add_trajectory(v);
    }
    Result<CommitInfo> r = Run<CommitInfo>(false, [&q](Connection& c) { return c.Composite(q); });
    if (!r.ok()) {
      Status s = Explain(name, r.status());
      const size_t bytes = q.ByteSizeLong();
      if (bytes >= wire::kDefaultMaxFrame / 2) {
        // The object travels in one request, which the server bounds (--max-frame-bytes).
        s = Status(s.code(), s.message() + " (the object's " + std::to_string(object.size()) +
                                 " points make one request of " + std::to_string(bytes >> 20) +
                                 " MiB, and hvdb-server takes at most 16 MiB unless started "
                                 "with a larger --max-frame-bytes; thin the object out, or "
                                 "composite it in parts)");
      }
      return s;
    }
    return r;
  }

  Status Render(const wire::Render& request,
                const std::function<Status(const wire::RenderReply&)>& on_image) override {
    // A render only reads, so it is repeated after a lost connection; the images the caller
    // already has are not handed to it again.
    uint32_t delivered = 0;
    auto deliver = [&](const wire::RenderReply& reply) -> Status {
      if (reply.index() < delivered) return Status::OK();
      HVDB_RETURN_IF_ERROR(on_image(reply));
      delivered = reply.index() + 1;
      return Status::OK();
    };
    Result<bool> r = Run<bool>(true, [&](Connection& c) -> Result<bool> {
      HVDB_RETURN_IF_ERROR(c.RenderSequence(request, deliver));
      return true;
    });
    return r.ok() ? Status::OK() : Explain(request.dataset(), r.status());
  }

 private:
  // The first connection is tried once, so that a wrong address, a stopped server or a bad
  // token is reported at once; afterwards Client reconnects (with backoff) for requests that
  // are safe to repeat.
  template <typename T>
  Result<T> Run(bool idempotent, const std::function<Result<T>(Connection&)>& fn) {
    if (!connected_) {
      Status st = client_.EnsureConnected();
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
    return client_.Run<T>(idempotent, fn);
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
  Client client_;
  bool connected_ = false;
};

}  // namespace

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
  return std::unique_ptr<Backend>(new RemoteBackend(options.address, std::move(opts)));
}

}  // namespace hvdb::client
