#include "server/requests.h"

#include <optional>

#include "edit/operators.h"

namespace hvdb::server {

namespace {

Result<Affine4> AffineFromWire(const google::protobuf::RepeatedField<double>& m,
                               const google::protobuf::RepeatedField<double>& c) {
  Affine4 a;
  if (!m.empty()) {
    if (m.size() != 16) return Status::InvalidArgument("matrix: needs 16 values");
    for (int i = 0; i < 16; ++i) a.a[static_cast<size_t>(i)] = m[i];
  }
  if (!c.empty()) {
    if (c.size() != 4) return Status::InvalidArgument("offset: needs 4 values");
    for (int i = 0; i < 4; ++i) a.c[static_cast<size_t>(i)] = c[i];
  }
  return a;
}

}  // namespace

const char* KindOf(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kPing: return "ping";
    case wire::Request::kList: return "list";
    case wire::Request::kCreate: return "create";
    case wire::Request::kDrop: return "drop";
    case wire::Request::kDescribe: return "describe";
    case wire::Request::kQuery: return "query";
    case wire::Request::kCancel: return "cancel";
    case wire::Request::kEdit: return "edit";
    case wire::Request::kRevert: return "revert";
    case wire::Request::kIngest: return "ingest";
    case wire::Request::kStats: return "stats";
    case wire::Request::kRender: return "render";
    case wire::Request::kPutPhoto: return "put_photo";
    case wire::Request::kSelect: return "select";
    case wire::Request::kGraphCut: return "graph_cut";
    case wire::Request::kCopy: return "copy";
    case wire::Request::kPaste: return "paste";
    case wire::Request::kComposite: return "composite";
    case wire::Request::kRelease: return "release";
    default: return "unknown";
  }
}

bool Writes(const wire::Request& r) {
  switch (r.body_case()) {
    case wire::Request::kCreate:
    case wire::Request::kDrop:
    case wire::Request::kEdit:
    case wire::Request::kRevert:
    case wire::Request::kIngest:
    case wire::Request::kPutPhoto:
    case wire::Request::kSelect:
    case wire::Request::kGraphCut:
    case wire::Request::kCopy:
    case wire::Request::kPaste:
    case wire::Request::kComposite: return true;
    default: return false;
  }
}

wire::Response ErrorResponse(uint64_t id, const Status& st, wire::ErrorCode code) {
  wire::Response r;
  r.set_id(id);
  wire::ToWire(st, r.mutable_error());
  if (code != wire::ERROR_UNSPECIFIED) r.mutable_error()->set_code(code);
  return r;
}

Result<std::shared_ptr<Dataset>> FindDataset(Server* s, const std::string& name) {
  auto ds = s->db().GetDataset(name);
  // The engine's message names the data directory: not the client's business.
  if (!ds.ok() && ds.status().IsNotFound()) {
    return Status::NotFound("no dataset '" + name + "' on this server (list them with the "
                            "ListDatasets request, `hvdb --server ... datasets`)");
  }
  return ds;
}

wire::Response DatasetError(uint64_t id, const Status& st) {
  return ErrorResponse(id, st, st.IsNotFound() ? wire::UNKNOWN_DATASET : wire::ERROR_UNSPECIFIED);
}

wire::Response CommitResponse(uint64_t id, const CommitInfo& c) {
  wire::Response r;
  r.set_id(id);
  auto* cr = r.mutable_commit();
  cr->set_lsn(c.lsn);
  cr->set_inserted(c.inserted);
  cr->set_removed(c.removed);
  for (uint64_t a : c.assigned_ids) cr->add_assigned_ids(a);
  return r;
}

// The editing operators of edit/operators.h, on a worker.
wire::Response RunEditOperator(Server* s, uint64_t id, const wire::Request& req) {
  std::string name;
  switch (req.body_case()) {
    case wire::Request::kSelect: name = req.select().dataset(); break;
    case wire::Request::kGraphCut: name = req.graph_cut().dataset(); break;
    case wire::Request::kCopy: name = req.copy().dataset(); break;
    case wire::Request::kPaste: name = req.paste().dataset(); break;
    default: name = req.composite().dataset(); break;
  }
  auto ds = FindDataset(s, name);
  if (!ds.ok()) return DatasetError(id, ds.status());
  Dataset& d = **ds;
  wire::Response r;
  r.set_id(id);
  edit::ClipboardStore clipboards(s->config().data_dir, s->db().options().env);
  if (req.has_select()) {
    const wire::SelectRequest& q = req.select();
    edit::SelectRequest sr;
    auto region = wire::FromWire(q.region());
    if (!region.ok()) return ErrorResponse(id, region.status());
    sr.region = *region;
    sr.bit = static_cast<int>(std::min<uint32_t>(q.bit(), 999));
    if (!wire::SelectMode_IsValid(q.mode())) {
      return ErrorResponse(id, Status::InvalidArgument("select.mode: unknown value"));
    }
    sr.mode = static_cast<edit::SelectMode>(q.mode());
    if (q.has_lasso()) {
      edit::Lasso l;
      auto cam = wire::FromWire(q.lasso().camera());
      if (!cam.ok()) return ErrorResponse(id, cam.status());
      l.camera = *cam;
      if (q.lasso().polygon_size() % 2) {
        return ErrorResponse(id, Status::InvalidArgument("lasso.polygon: needs x y pairs"));
      }
      for (int i = 0; i + 1 < q.lasso().polygon_size(); i += 2) {
        l.polygon.push_back({q.lasso().polygon(i), q.lasso().polygon(i + 1)});
      }
      sr.shape = l;
    } else if (q.has_brush()) {
      edit::Brush b;
      auto cam = wire::FromWire(q.brush().camera());
      if (!cam.ok()) return ErrorResponse(id, cam.status());
      b.camera = *cam;
      b.u = q.brush().u();
      b.v = q.brush().v();
      b.pixel_radius = q.brush().pixel_radius();
      b.radius = q.brush().radius();
      b.depth = q.brush().nearest() ? edit::Brush::Depth::kNearest : edit::Brush::Depth::kMedian;
      sr.shape = b;
    }
    auto res = edit::Select(d, sr);
    if (!res.ok()) return ErrorResponse(id, res.status());
    auto* o = r.mutable_selected();
    o->set_matched(res->matched);
    o->set_selected(res->selected);
    o->set_lsn(res->lsn);
    if (res->brush_center) {
      for (double v : *res->brush_center) o->add_brush_center(v);
    }
  } else if (req.has_graph_cut()) {
    const wire::GraphCutRequest& q = req.graph_cut();
    edit::GraphCutRequest g;
    auto roi = wire::FromWire(q.roi());
    if (!roi.ok()) return ErrorResponse(id, roi.status());
    g.roi = *roi;
    g.foreground_bit = static_cast<int>(std::min<uint32_t>(q.foreground_bit(), 999));
    g.background_bit = static_cast<int>(std::min<uint32_t>(q.background_bit(), 999));
    g.out_bit = static_cast<int>(std::min<uint32_t>(q.out_bit(), 999));
    if (q.k() != 0) g.params.k = static_cast<int>(std::min<uint32_t>(q.k(), 64));
    if (q.intra_radius() != 0) g.params.intra_radius = q.intra_radius();
    if (q.inter_radius() != 0) g.params.inter_radius = q.inter_radius();
    g.params.use_normals = !q.colour_only();
    auto res = edit::GraphCutSelect(d, g, &s->graph_cuts());
    if (!res.ok()) return ErrorResponse(id, res.status());
    auto* o = r.mutable_graph_cut();
    o->set_roi_points(res->roi_points);
    o->set_selected(res->selected);
    o->set_lsn(res->lsn);
    o->set_energy(res->cut.energy);
    o->set_intra_edges(res->cut.intra_edges);
    o->set_inter_edges(res->cut.inter_edges);
    o->set_load_ms(res->load_ms);
    o->set_neighbours_ms(res->cut.neighbours_ms);
    o->set_gmm_ms(res->cut.gmm_ms);
    o->set_graph_ms(res->cut.graph_ms);
    o->set_maxflow_ms(res->cut.maxflow_ms);
    o->set_commit_ms(res->commit_ms);
    o->set_recut(res->cut.warm);
  } else if (req.has_copy()) {
    const wire::CopyRequest& q = req.copy();
    std::optional<hvdb::Region> region;
    if (q.has_region()) {
      auto rr = wire::FromWire(q.region());
      if (!rr.ok()) return ErrorResponse(id, rr.status());
      region = *rr;
    }
    auto res = edit::Copy(d, static_cast<int>(std::min<uint32_t>(q.bit(), 999)), region,
                          clipboards, q.clipboard(), q.cut());
    if (!res.ok()) return ErrorResponse(id, res.status());
    r.mutable_copied()->set_points(res->points);
    r.mutable_copied()->set_lsn(res->lsn);
  } else if (req.has_paste()) {
    const wire::PasteRequest& q = req.paste();
    auto map = AffineFromWire(q.matrix(), q.offset());
    if (!map.ok()) return ErrorResponse(id, map.status());
    auto clip = clipboards.Get(q.clipboard());
    if (!clip.ok()) return ErrorResponse(id, clip.status());
    auto c = edit::Paste(d, *clip, *map);
    if (!c.ok()) return ErrorResponse(id, c.status());
    return CommitResponse(id, *c);
  } else {
    const wire::CompositeRequest& q = req.composite();
    std::vector<Point> object;
    Status st = wire::DecodeColumns(q.object(), &object);
    if (!st.ok()) return ErrorResponse(id, st);
    if (q.trajectory_size() % 3) {
      return ErrorResponse(id, Status::InvalidArgument("composite.trajectory: needs x y z per frame"));
    }
    std::vector<std::array<double, 3>> path;
    for (int i = 0; i + 2 < q.trajectory_size(); i += 3) {
      path.push_back({q.trajectory(i), q.trajectory(i + 1), q.trajectory(i + 2)});
    }
    auto c = edit::Composite(d, object, q.first_frame(), q.frame_count(), path);
    if (!c.ok()) return ErrorResponse(id, c.status());
    return CommitResponse(id, *c);
  }
  return r;
}

}  // namespace hvdb::server
