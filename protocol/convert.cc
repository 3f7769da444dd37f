#include "protocol/convert.h"

#include <algorithm>
#include <limits>
#include <span>
#include <string>
#include <variant>

#include "storage/coding.h"

namespace hvdb::wire {

uint32_t BitToWire(int bit) { return static_cast<uint32_t>(bit); }
int BitFromWire(uint32_t bit) { return static_cast<int32_t>(bit); }

// ---- Select ----

void ToWire(const edit::SelectRequest& r, wire::SelectRequest* out) {
  ToWire(r.region, out->mutable_region());
  out->set_bit(BitToWire(r.bit));
  out->set_mode(static_cast<wire::SelectMode>(r.mode));
  if (const auto* lasso = std::get_if<edit::Lasso>(&r.shape)) {
    wire::LassoShape* l = out->mutable_lasso();
    ToWire(lasso->camera, l->mutable_camera());
    for (const auto& v : lasso->polygon) {
      l->add_polygon(v[0]);
      l->add_polygon(v[1]);
    }
  } else if (const auto* brush = std::get_if<edit::Brush>(&r.shape)) {
    wire::BrushShape* b = out->mutable_brush();
    ToWire(brush->camera, b->mutable_camera());
    b->set_u(brush->u);
    b->set_v(brush->v);
    b->set_pixel_radius(brush->pixel_radius);
    b->set_radius(brush->radius);
    b->set_nearest(brush->depth == edit::Brush::Depth::kNearest);
  }
  out->set_return_flips(r.return_flips);
}

Result<edit::SelectRequest> FromWire(const wire::SelectRequest& q) {
  edit::SelectRequest sr;
  HVDB_ASSIGN_OR_RETURN(sr.region, FromWire(q.region()));
  sr.bit = BitFromWire(q.bit());
  if (!wire::SelectMode_IsValid(q.mode())) {
    return Status::InvalidArgument("select.mode: unknown value " + std::to_string(q.mode()));
  }
  sr.mode = static_cast<edit::SelectMode>(q.mode());
  if (q.has_lasso()) {
    edit::Lasso l;
    HVDB_ASSIGN_OR_RETURN(l.camera, FromWire(q.lasso().camera()));
    if (q.lasso().polygon_size() % 2) {
      return Status::InvalidArgument("lasso.polygon: needs x y pairs");
    }
    for (int i = 0; i + 1 < q.lasso().polygon_size(); i += 2) {
      l.polygon.push_back({q.lasso().polygon(i), q.lasso().polygon(i + 1)});
    }
    sr.shape = std::move(l);
  } else if (q.has_brush()) {
    edit::Brush b;
    HVDB_ASSIGN_OR_RETURN(b.camera, FromWire(q.brush().camera()));
    b.u = q.brush().u();
    b.v = q.brush().v();
    b.pixel_radius = q.brush().pixel_radius();
    b.radius = q.brush().radius();
    b.depth = q.brush().nearest() ? edit::Brush::Depth::kNearest : edit::Brush::Depth::kMedian;
    sr.shape = std::move(b);
  }
  sr.return_flips = q.return_flips();
  return sr;
}

void ToWire(const edit::SelectResult& r, wire::SelectReply* out) {
  out->set_matched(r.matched);
  out->set_selected(r.selected);
  out->set_lsn(r.lsn);
  if (r.brush_center) {
    for (double v : *r.brush_center) out->add_brush_center(v);
  }
  for (const edit::LabelFlips& f : r.flips) {
    wire::LabelFlips* w = out->add_flips();
    w->set_frame(f.frame);
    w->set_set(f.set);
    w->set_count(static_cast<uint32_t>(f.ids.size()));
    std::string* ids = w->mutable_ids();
    ids->reserve(f.ids.size() * 2);
    uint64_t prev = 0;
    for (uint64_t id : f.ids) {
      PutVarint(ids, id - prev);
      prev = id;
    }
  }
}

Result<edit::SelectResult> FromWire(const wire::SelectReply& r) {
  edit::SelectResult out;
  out.matched = r.matched();
  out.selected = r.selected();
  out.lsn = r.lsn();
  if (r.brush_center_size() == 3) {
    out.brush_center = std::array<double, 3>{r.brush_center(0), r.brush_center(1), r.brush_center(2)};
  }
  for (const wire::LabelFlips& w : r.flips()) {
    edit::LabelFlips f{w.frame(), w.set(), {}};
    Reader rd(reinterpret_cast<const uint8_t*>(w.ids().data()), w.ids().size());
    // Each id takes at least a byte: a count beyond the bytes is malformed, not an allocation.
    if (w.count() > w.ids().size()) {
      return Status::InvalidArgument("select reply: flips of frame " + std::to_string(w.frame()) +
                                     " claim " + std::to_string(w.count()) + " ids in " +
                                     std::to_string(w.ids().size()) + " bytes");
    }
    f.ids.reserve(w.count());
    uint64_t prev = 0;
    for (uint32_t i = 0; i < w.count(); ++i) {
      uint64_t gap;
      if (!GetVarint(&rd, &gap) || (i > 0 && gap == 0) || gap > UINT64_MAX - prev) {
        return Status::InvalidArgument("select reply: flips of frame " + std::to_string(w.frame()) +
                                       ": id " + std::to_string(i) + " is not a valid ascending varint");
      }
      prev += gap;
      f.ids.push_back(prev);
    }
    if (rd.remaining() != 0) {
      return Status::InvalidArgument("select reply: flips of frame " + std::to_string(w.frame()) +
                                     " have bytes after their " + std::to_string(w.count()) + " ids");
    }
    out.flips.push_back(std::move(f));
  }
  return out;
}

// ---- Graph cut ----

void ToWire(const edit::GraphCutRequest& r, wire::GraphCutRequest* out) {
  ToWire(r.roi, out->mutable_roi());
  out->set_foreground_bit(BitToWire(r.foreground_bit));
  out->set_background_bit(BitToWire(r.background_bit));
  out->set_out_bit(BitToWire(r.out_bit));
  // Every parameter travels, so that the server judges the same values the embedded mode does;
  // k goes as a two's complement like the bits (a negative k is refused, not wrapped).
  const edit::GraphCutParams& p = r.params;
  out->set_k(static_cast<uint32_t>(p.k));
  out->set_intra_radius(p.intra_radius);
  out->set_inter_radius(p.inter_radius);
  out->set_colour_only(!p.use_normals);
  out->set_max_color_diff(p.max_color_diff);
  out->set_max_normal_diff(p.max_normal_diff);
  out->set_gmm_components(static_cast<uint32_t>(p.gmm_components));
  out->set_beta_c(p.beta_c);
  out->set_beta_n(p.beta_n);
  out->set_lambda_d(p.lambda_d);
  out->set_lambda_i(p.lambda_i);
  out->set_lambda_t(p.lambda_t);
}

Result<edit::GraphCutRequest> FromWire(const wire::GraphCutRequest& q) {
  edit::GraphCutRequest g;
  HVDB_ASSIGN_OR_RETURN(g.roi, FromWire(q.roi()));
  g.foreground_bit = BitFromWire(q.foreground_bit());
  g.background_bit = BitFromWire(q.background_bit());
  g.out_bit = BitFromWire(q.out_bit());
  edit::GraphCutParams& p = g.params;  // absent fields keep edit's defaults
  if (q.has_k()) p.k = static_cast<int32_t>(q.k());
  if (q.has_intra_radius()) p.intra_radius = q.intra_radius();
  if (q.has_inter_radius()) p.inter_radius = q.inter_radius();
  p.use_normals = !q.colour_only();
  if (q.has_max_color_diff()) p.max_color_diff = q.max_color_diff();
  if (q.has_max_normal_diff()) p.max_normal_diff = q.max_normal_diff();
  if (q.has_gmm_components()) p.gmm_components = static_cast<int32_t>(q.gmm_components());
  if (q.has_beta_c()) p.beta_c = q.beta_c();
  if (q.has_beta_n()) p.beta_n = q.beta_n();
  if (q.has_lambda_d()) p.lambda_d = q.lambda_d();
  if (q.has_lambda_i()) p.lambda_i = q.lambda_i();
  if (q.has_lambda_t()) p.lambda_t = q.lambda_t();
  return g;
}

void ToWire(const edit::GraphCutReply& r, wire::GraphCutReply* out) {
  out->set_roi_points(r.roi_points);
  out->set_selected(r.selected);
  out->set_lsn(r.lsn);
  out->set_energy(r.cut.energy);
  out->set_intra_edges(r.cut.intra_edges);
  out->set_inter_edges(r.cut.inter_edges);
  out->set_load_ms(r.load_ms);
  out->set_neighbours_ms(r.cut.neighbours_ms);
  out->set_gmm_ms(r.cut.gmm_ms);
  out->set_graph_ms(r.cut.graph_ms);
  out->set_maxflow_ms(r.cut.maxflow_ms);
  out->set_commit_ms(r.commit_ms);
  out->set_recut(r.cut.warm);
  out->set_labels_only(r.labels_only);
}

edit::GraphCutReply FromWire(const wire::GraphCutReply& r) {
  edit::GraphCutReply out;
  out.roi_points = r.roi_points();
  out.selected = r.selected();
  out.lsn = r.lsn();
  out.cut.energy = r.energy();
  out.cut.intra_edges = r.intra_edges();
  out.cut.inter_edges = r.inter_edges();
  out.cut.neighbours_ms = r.neighbours_ms();
  out.cut.gmm_ms = r.gmm_ms();
  out.cut.graph_ms = r.graph_ms();
  out.cut.maxflow_ms = r.maxflow_ms();
  out.cut.warm = r.recut();
  out.labels_only = r.labels_only();
  out.load_ms = r.load_ms();
  out.commit_ms = r.commit_ms();
  return out;
}

// ---- Clipboards and compositing ----

void ToWire(const edit::CopyRequest& r, wire::CopyRequest* out) {
  out->set_bit(BitToWire(r.bit));
  if (r.region) ToWire(*r.region, out->mutable_region());
  out->set_clipboard(r.clipboard);
  out->set_cut(r.cut);
}

Result<edit::CopyRequest> FromWire(const wire::CopyRequest& q) {
  edit::CopyRequest c;
  c.bit = BitFromWire(q.bit());
  if (q.has_region()) {
    HVDB_ASSIGN_OR_RETURN(hvdb::Region region, FromWire(q.region()));
    c.region = std::move(region);
  }
  c.clipboard = q.clipboard();
  c.cut = q.cut();
  return c;
}

void ToWire(const edit::CopyResult& r, wire::CopyReply* out) {
  out->set_points(r.points);
  out->set_lsn(r.lsn);
}

edit::CopyResult FromWire(const wire::CopyReply& r) { return {r.points(), r.lsn()}; }

void ToWire(const edit::PasteRequest& r, wire::PasteRequest* out) {
  out->set_clipboard(r.clipboard);
  for (double v : r.map.a) out->add_matrix(v);
  for (double v : r.map.c) out->add_offset(v);
}

Result<edit::PasteRequest> FromWire(const wire::PasteRequest& q) {
  edit::PasteRequest p;
  p.clipboard = q.clipboard();
  if (!q.matrix().empty()) {  // empty: the identity
    if (q.matrix_size() != 16) return Status::InvalidArgument("matrix: needs 16 values");
    std::copy(q.matrix().begin(), q.matrix().end(), p.map.a.begin());
  }
  if (!q.offset().empty()) {  // empty: zero
    if (q.offset_size() != 4) return Status::InvalidArgument("offset: needs 4 values");
    std::copy(q.offset().begin(), q.offset().end(), p.map.c.begin());
  }
  return p;
}

void ToWire(const edit::CompositeRequest& r, wire::CompositeRequest* out) {
  EncodeColumns(std::span<const Point>(r.object), out->mutable_object());
  out->set_first_frame(r.first_frame);
  out->set_frame_count(r.frame_count);
  for (const auto& d : r.trajectory) {
    for (double v : d) out->add_trajectory(v);
  }
  if (r.gaussians) {
    EncodeGaussians(*r.gaussians, 0, r.gaussians->size(), out->mutable_gaussians());
  }
}

Result<edit::CompositeRequest> FromWire(const wire::CompositeRequest& q) {
  edit::CompositeRequest c;
  HVDB_RETURN_IF_ERROR(DecodeColumns(q.object(), &c.object));
  c.first_frame = q.first_frame();
  c.frame_count = q.frame_count();
  if (q.trajectory_size() % 3) {
    return Status::InvalidArgument("composite.trajectory: needs x y z per frame");
  }
  for (int i = 0; i + 2 < q.trajectory_size(); i += 3) {
    c.trajectory.push_back({q.trajectory(i), q.trajectory(i + 1), q.trajectory(i + 2)});
  }
  if (q.has_gaussians()) {
    auto g = std::make_shared<GaussianColumns>();
    HVDB_RETURN_IF_ERROR(DecodeGaussians(q.gaussians(), g.get()));
    if (g->size() != c.object.size()) {
      return Status::InvalidArgument("composite.gaussians: " + std::to_string(g->size()) +
                                     " records for " + std::to_string(c.object.size()) +
                                     " object points");
    }
    c.gaussians = std::move(g);
  }
  return c;
}

void ToWire(const media::ImportRequest& r, wire::ImportMediaRequest* out) {
  out->set_data(r.data);
  out->set_kind(r.kind == media::Kind::kAuto ? "" : media::KindName(r.kind));
  out->set_format(r.format);
  if (r.first_frame) out->set_first_frame(*r.first_frame);
  if (r.last_frame) out->set_last_frame(*r.last_frame);
  for (double v : r.place.at) out->add_at(v);
  out->set_scale(r.place.scale);
  for (double v : r.place.rotate_deg) out->add_rotate(v);
  out->set_width(r.place.width);
  if (r.label_bit) out->set_label_bit(BitToWire(*r.label_bit));
  out->set_texels(r.texels);
  out->set_spacing(r.spacing);
}

Result<media::ImportRequest> FromWire(const wire::ImportMediaRequest& q) {
  media::ImportRequest m;
  m.data = q.data();
  HVDB_ASSIGN_OR_RETURN(m.kind, media::ParseKind(q.kind()));
  m.format = q.format();
  if (q.has_first_frame()) m.first_frame = q.first_frame();
  if (q.has_last_frame()) m.last_frame = q.last_frame();
  if (q.at_size() != 0 && q.at_size() != 3) {
    return Status::InvalidArgument("import_media.at: needs x y z (3 values) or none");
  }
  if (q.rotate_size() != 0 && q.rotate_size() != 3) {
    return Status::InvalidArgument("import_media.rotate: needs rx ry rz (3 values) or none");
  }
  for (int i = 0; i < q.at_size(); ++i) m.place.at[i] = q.at(i);
  for (int i = 0; i < q.rotate_size(); ++i) m.place.rotate_deg[i] = q.rotate(i);
  if (q.has_scale()) m.place.scale = q.scale();
  if (q.has_width()) m.place.width = q.width();
  if (q.has_label_bit()) m.label_bit = BitFromWire(q.label_bit());
  m.texels = q.texels();
  m.spacing = q.spacing();
  return m;
}

// ---- Commits, statistics, query options ----

void ToWire(const CommitInfo& c, wire::CommitReply* out) {
  out->set_lsn(c.lsn);
  out->set_inserted(c.inserted);
  out->set_removed(c.removed);
  for (uint64_t a : c.assigned_ids) out->add_assigned_ids(a);
}

CommitInfo FromWire(const wire::CommitReply& c) {
  CommitInfo info;
  info.lsn = c.lsn();
  info.inserted = c.inserted();
  info.removed = c.removed();
  info.assigned_ids.assign(c.assigned_ids().begin(), c.assigned_ids().end());
  return info;
}

void ToWire(const hvdb::DatasetStats& s, wire::DatasetStats* out) {
  out->set_frames_with_data(s.frames_with_data);
  out->set_points(s.points);
  out->set_tombstones(s.tombstones);
  out->set_buffered_points(s.buffered_points);
  out->set_trees(s.trees);
  out->set_tree_bytes(s.tree_bytes);
  out->set_wal_bytes(s.wal_bytes);
  out->set_leaf_utilisation(s.leaf_utilisation);
  out->set_merges(s.merges);
  out->set_checkpoints(s.checkpoints);
  out->set_cold_frames(s.cold_frames);
  out->set_cold_trees(s.cold_trees);
  out->set_cold_tree_bytes(s.cold_tree_bytes);
  out->set_cold_points(s.cold_points);
  out->set_gaussian_segments(s.gaussian_segments);
  out->set_gaussian_records(s.gaussian_records);
  out->set_gaussian_bytes(s.gaussian_bytes);
}

void ToWire(const hvdb::CompactInfo& c, wire::CompactReply* out) {
  out->set_frames(c.frames);
  out->set_already(c.already);
  out->set_points(c.points);
  out->set_bytes_before(c.bytes_before);
  out->set_bytes_after(c.bytes_after);
  out->set_photo_runs(c.photo_runs);
  out->set_photo_pictures(c.photo_pictures);
  out->set_photo_already(c.photo_already);
  out->set_photo_bytes_before(c.photo_bytes_before);
  out->set_photo_bytes_after(c.photo_bytes_after);
  out->set_photo_min_psnr(c.photo_min_psnr);
}

hvdb::CompactInfo FromWire(const wire::CompactReply& c) {
  hvdb::CompactInfo d;
  d.frames = c.frames();
  d.already = c.already();
  d.points = c.points();
  d.bytes_before = c.bytes_before();
  d.bytes_after = c.bytes_after();
  d.photo_runs = c.photo_runs();
  d.photo_pictures = c.photo_pictures();
  d.photo_already = c.photo_already();
  d.photo_bytes_before = c.photo_bytes_before();
  d.photo_bytes_after = c.photo_bytes_after();
  d.photo_min_psnr = c.photo_min_psnr();
  return d;
}

Result<CompactArgs> FromWire(const wire::CompactRequest& c) {
  // The range is judged by the engine (Dataset::Compact), as for an embedded caller.
  if (c.all()) return CompactArgs{0, UINT32_MAX, c.photos()};
  return CompactArgs{c.first(), c.last(), c.photos()};
}

hvdb::DatasetStats FromWire(const wire::DatasetStats& s) {
  hvdb::DatasetStats d;
  d.frames_with_data = s.frames_with_data();
  d.points = s.points();
  d.tombstones = s.tombstones();
  d.buffered_points = s.buffered_points();
  d.trees = s.trees();
  d.tree_bytes = s.tree_bytes();
  d.wal_bytes = s.wal_bytes();
  d.leaf_utilisation = s.leaf_utilisation();
  d.merges = s.merges();
  d.checkpoints = s.checkpoints();
  d.cold_frames = s.cold_frames();
  d.cold_trees = s.cold_trees();
  d.cold_tree_bytes = s.cold_tree_bytes();
  d.cold_points = s.cold_points();
  d.gaussian_segments = s.gaussian_segments();
  d.gaussian_records = s.gaussian_records();
  d.gaussian_bytes = s.gaussian_bytes();
  return d;
}

void ToWire(const hvdb::DatasetInfo& info, wire::CreateDataset* out) {
  out->set_name(info.name);
  out->set_fps(info.fps);
  out->set_space_time_scale(info.space_time_scale);
  out->set_frame_count(info.frame_count);
  out->set_gaussians(info.gaussians);
  for (const CameraInfo& cam : info.cameras) ToWire(cam, out->add_cameras());
}

Result<hvdb::DatasetInfo> FromWire(const wire::CreateDataset& c) {
  hvdb::DatasetInfo info;
  info.name = c.name();
  info.fps = c.fps();
  info.space_time_scale = c.space_time_scale() == 0 ? 1.0 : c.space_time_scale();
  info.frame_count = c.frame_count();
  info.gaussians = c.gaussians();
  for (const auto& cam : c.cameras()) {
    HVDB_ASSIGN_OR_RETURN(CameraInfo ci, FromWire(cam));
    info.cameras.push_back(std::move(ci));
  }
  return info;
}

void ToWire(const Photo& photo, wire::PutPhoto* out) {
  ToWire(photo.camera, out->mutable_camera());
  out->set_image(photo.image);
  if (photo.billboard.scale != 0) {
    auto* b = out->mutable_billboard();
    b->set_scale(photo.billboard.scale);
    for (double v : photo.billboard.plane) b->add_plane(v);
    b->set_displacement(photo.billboard.displacement);
    b->set_alpha(photo.billboard.alpha);
  }
}

Result<Photo> FromWire(const wire::PutPhoto& p) {
  Photo photo;
  HVDB_ASSIGN_OR_RETURN(photo.camera, FromWire(p.camera()));
  photo.image = p.image();
  if (p.has_billboard()) {
    const wire::Billboard& b = p.billboard();
    if (b.plane_size() != 3) {
      return Status::InvalidArgument("put_photo.billboard.plane: needs 3 values, got " +
                                     std::to_string(b.plane_size()));
    }
    photo.billboard = {b.scale(), {b.plane(0), b.plane(1), b.plane(2)}, b.displacement(), b.alpha()};
  }
  return photo;
}

void ToWire(const QueryOptions& o, wire::Query* out) {
  out->set_lod(static_cast<uint32_t>(o.lod));  // two's complement: a negative level is refused
  out->set_progressive(o.progressive);
  out->set_no_temporal_lod(!o.temporal_lod);
  out->set_batch_points(static_cast<uint32_t>(std::min<size_t>(o.batch_points, UINT32_MAX)));
  out->set_label_mask(o.label_mask);
}

Result<QueryOptions> QueryOptionsFromWire(const wire::Query& q) {
  QueryOptions o;
  o.lod = static_cast<int32_t>(q.lod());
  o.progressive = q.progressive();
  o.temporal_lod = !q.no_temporal_lod();
  o.label_mask = q.label_mask();
  if (q.batch_points() != 0) o.batch_points = q.batch_points();
  return o;
}

void ToWire(const ChangeEvent& e, wire::WatchEvent* out) {
  static_assert(static_cast<int>(ChangeEvent::Kind::kCommit) == wire::WATCH_COMMIT &&
                static_cast<int>(ChangeEvent::Kind::kRevert) == wire::WATCH_REVERT &&
                static_cast<int>(ChangeEvent::Kind::kBulk) == wire::WATCH_BULK &&
                static_cast<int>(ChangeEvent::Kind::kDropped) == wire::WATCH_DROPPED &&
                static_cast<int>(ChangeEvent::Kind::kLive) == wire::WATCH_LIVE &&
                static_cast<int>(ChangeEvent::Kind::kLagged) == wire::WATCH_LAGGED);
  out->set_dataset(e.dataset);
  out->set_lsn(e.lsn);
  out->set_kind(static_cast<wire::WatchEventKind>(e.kind));
  out->mutable_frames()->Assign(e.frames.begin(), e.frames.end());
  out->set_points(e.points);
  out->set_removed(e.removed);
  out->set_reverts(e.reverts);
}

Result<ChangeEvent> FromWire(const wire::WatchEvent& e) {
  if (e.kind() < wire::WATCH_COMMIT || e.kind() > wire::WATCH_LAGGED) {
    return Status::InvalidArgument("event.kind: unknown value " + std::to_string(e.kind()));
  }
  ChangeEvent out;
  out.kind = static_cast<ChangeEvent::Kind>(e.kind());
  out.dataset = e.dataset();
  out.lsn = e.lsn();
  out.frames.assign(e.frames().begin(), e.frames().end());
  out.points = e.points();
  out.removed = e.removed();
  out.reverts = e.reverts();
  return out;
}

}  // namespace hvdb::wire
