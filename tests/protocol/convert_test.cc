// Every ToWire/FromWire pair of protocol/convert.h round-trips: a value sent over the wire is
// the value the server's executor gets, and a reply is the value the embedded mode returns.
#include "protocol/convert.h"

#include <gtest/gtest.h>

#include <random>

namespace hvdb {
namespace {

CameraInfo Camera(uint16_t id) {
  CameraInfo c;
  c.id = id;
  c.name = "cam" + std::to_string(id);
  c.width = 640;
  c.height = 480;
  c.fx = 500.5;
  c.fy = 501.25;
  c.cx = 320.5;
  c.cy = 240.25;
  c.distortion = {0.1, -0.01, 0.001, 0.002, 0.0001};
  for (size_t i = 0; i < 16; ++i) c.world_from_camera[i] = (i % 5 == 0) ? 1.0 : 0.01 * i;
  return c;
}

Region SliceRegion() {
  Slice s;
  s.normal = {0, 0, 1, 0.5};
  s.offset = 0.25;
  s.thickness = 0.02;
  Window clip;
  clip.lo = {-1, -2, -3, 0};
  clip.hi = {1, 2, 3, 4};
  s.clip = clip;
  s.on_too_many_frames = Slice::FrameBound::kClip;
  s.max_frames = 7;
  return s;
}

void ExpectSameCamera(const CameraInfo& a, const CameraInfo& b) {
  EXPECT_EQ(a.id, b.id);
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.width, b.width);
  EXPECT_EQ(a.fx, b.fx);
  EXPECT_EQ(a.cy, b.cy);
  EXPECT_EQ(a.distortion, b.distortion);
  EXPECT_EQ(a.world_from_camera, b.world_from_camera);
}

void ExpectSameRegion(const Region& a, const Region& b) {
  wire::Region wa, wb;
  ToWire(a, &wa);
  ToWire(b, &wb);
  EXPECT_EQ(wa.SerializeAsString(), wb.SerializeAsString());
}

TEST(ConvertTest, SelectRequestWithEachShape) {
  edit::SelectRequest r;
  r.region = SliceRegion();
  r.bit = -3;  // a bad bit comes back as itself, for the executor to refuse
  r.mode = edit::SelectMode::kIntersect;
  edit::Lasso l{Camera(2), {{1, 2}, {3, 4}, {5, 6.5}}};
  r.shape = l;
  wire::SelectRequest w;
  ToWire(r, &w);
  auto back = FromWire(w);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->bit, -3);
  EXPECT_EQ(back->mode, edit::SelectMode::kIntersect);
  ExpectSameRegion(back->region, r.region);
  const auto* bl = std::get_if<edit::Lasso>(&back->shape);
  ASSERT_NE(bl, nullptr);
  EXPECT_EQ(bl->polygon, l.polygon);
  ExpectSameCamera(bl->camera, l.camera);

  edit::Brush b;
  b.camera = Camera(3);
  b.u = 10.5;
  b.v = 20.25;
  b.pixel_radius = 7;
  b.radius = 0.03;
  b.depth = edit::Brush::Depth::kNearest;
  r.shape = b;
  r.bit = 31;
  w.Clear();
  ToWire(r, &w);
  back = FromWire(w);
  ASSERT_TRUE(back.ok());
  const auto* bb = std::get_if<edit::Brush>(&back->shape);
  ASSERT_NE(bb, nullptr);
  EXPECT_EQ(bb->u, b.u);
  EXPECT_EQ(bb->v, b.v);
  EXPECT_EQ(bb->pixel_radius, b.pixel_radius);
  EXPECT_EQ(bb->radius, b.radius);
  EXPECT_EQ(bb->depth, b.depth);
  EXPECT_EQ(back->bit, 31);

  r.shape = std::monostate{};
  wire::SelectRequest whole;
  ToWire(r, &whole);
  back = FromWire(whole);
  ASSERT_TRUE(back.ok());
  EXPECT_TRUE(std::holds_alternative<std::monostate>(back->shape));
}

TEST(ConvertTest, SelectReply) {
  edit::SelectResult r{12, 34, 56, std::array<double, 3>{1.5, -2, 3}, {}};
  r.flips = {{3, false, {1, 2, 300}}, {3, true, {7, UINT64_MAX}}, {9, true, {1ull << 40}}};
  wire::SelectReply w;
  ToWire(r, &w);
  EXPECT_EQ(w.flips(0).ids().size(), 4u);  // gaps 1, 1, 298: a byte, a byte, two bytes
  auto back = FromWire(w);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->matched, 12u);
  EXPECT_EQ(back->selected, 34u);
  EXPECT_EQ(back->lsn, 56u);
  ASSERT_TRUE(back->brush_center.has_value());
  EXPECT_EQ(*back->brush_center, *r.brush_center);
  ASSERT_EQ(back->flips.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    EXPECT_EQ(back->flips[i].frame, r.flips[i].frame);
    EXPECT_EQ(back->flips[i].set, r.flips[i].set);
    EXPECT_EQ(back->flips[i].ids, r.flips[i].ids);
  }
  // A reply's flips that do not decode are an error, never a shorter list.
  for (auto [count, bytes] : std::vector<std::pair<uint32_t, std::string>>{
           {4, std::string("\x01\x01\x01", 3)},             // fewer ids than the count
           {2, std::string("\x01\x00", 2)},                 // a repeated id (gap 0)
           {1, std::string("\x01\x01", 2)},                 // bytes after the ids
           {1000000, std::string("\x01", 1)},                // a count no bytes could hold
           {1, std::string(10, '\xff')}}) {                  // a varint past 64 bits
    wire::SelectReply bad = w;
    bad.mutable_flips(0)->set_count(count);
    bad.mutable_flips(0)->set_ids(bytes);
    EXPECT_FALSE(FromWire(bad).ok()) << count;
  }
}

// Every graph-cut parameter travels, including values the server will refuse: the executor, not
// the wire, judges them, so embedded and remote callers get the same answer.
TEST(ConvertTest, GraphCutRequestCarriesEveryParameter) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 100);
  for (int round = 0; round < 20; ++round) {
    edit::GraphCutRequest r;
    Window w;
    w.lo = {u(rng), u(rng), u(rng), 0};
    w.hi = {u(rng), u(rng), u(rng), 1};
    r.roi = w;
    r.foreground_bit = static_cast<int>(rng() % 40) - 4;
    r.background_bit = static_cast<int>(rng() % 40);
    r.out_bit = static_cast<int>(rng() % 40);
    edit::GraphCutParams& p = r.params;
    p.k = static_cast<int>(rng() % 200) - 10;
    p.intra_radius = u(rng);
    p.inter_radius = u(rng);
    p.max_color_diff = u(rng);
    p.max_normal_diff = u(rng);
    p.gmm_components = static_cast<int>(rng() % 20) - 2;
    p.beta_c = u(rng);
    p.beta_n = u(rng);
    p.lambda_d = u(rng);
    p.lambda_i = u(rng);
    p.lambda_t = u(rng);
    p.use_normals = round % 2 == 0;
    wire::GraphCutRequest q;
    ToWire(r, &q);
    auto back = FromWire(q);
    ASSERT_TRUE(back.ok());
    EXPECT_EQ(back->foreground_bit, r.foreground_bit);
    EXPECT_EQ(back->background_bit, r.background_bit);
    EXPECT_EQ(back->out_bit, r.out_bit);
    const edit::GraphCutParams& b = back->params;
    EXPECT_EQ(b.k, p.k);
    EXPECT_EQ(b.intra_radius, p.intra_radius);
    EXPECT_EQ(b.inter_radius, p.inter_radius);
    EXPECT_EQ(b.max_color_diff, p.max_color_diff);
    EXPECT_EQ(b.max_normal_diff, p.max_normal_diff);
    EXPECT_EQ(b.gmm_components, p.gmm_components);
    EXPECT_EQ(b.beta_c, p.beta_c);
    EXPECT_EQ(b.beta_n, p.beta_n);
    EXPECT_EQ(b.lambda_d, p.lambda_d);
    EXPECT_EQ(b.lambda_i, p.lambda_i);
    EXPECT_EQ(b.lambda_t, p.lambda_t);
    EXPECT_EQ(b.use_normals, p.use_normals);
    ExpectSameRegion(back->roi, r.roi);
  }
}

// A client that sends none of the parameters (the browser) gets edit's defaults.
TEST(ConvertTest, AbsentGraphCutParametersTakeTheDefaults) {
  wire::GraphCutRequest q;
  ToWire(Region(Window{}), q.mutable_roi());
  auto back = FromWire(q);
  ASSERT_TRUE(back.ok());
  const edit::GraphCutParams d;
  EXPECT_EQ(back->params.k, d.k);
  EXPECT_EQ(back->params.intra_radius, d.intra_radius);
  EXPECT_EQ(back->params.lambda_i, d.lambda_i);
  EXPECT_EQ(back->params.gmm_components, d.gmm_components);
  EXPECT_TRUE(back->params.use_normals);
}

TEST(ConvertTest, GraphCutReply) {
  edit::GraphCutReply r;
  r.roi_points = 1000;
  r.selected = 400;
  r.lsn = 9;
  r.cut.energy = 12.5;
  r.cut.intra_edges = 7000;
  r.cut.inter_edges = 3000;
  r.cut.neighbours_ms = 1.5;
  r.cut.gmm_ms = 2.5;
  r.cut.graph_ms = 3.5;
  r.cut.maxflow_ms = 4.5;
  r.cut.warm = true;
  r.load_ms = 5.5;
  r.commit_ms = 6.5;
  wire::GraphCutReply w;
  ToWire(r, &w);
  edit::GraphCutReply b = FromWire(w);
  EXPECT_EQ(b.roi_points, r.roi_points);
  EXPECT_EQ(b.selected, r.selected);
  EXPECT_EQ(b.lsn, r.lsn);
  EXPECT_EQ(b.cut.energy, r.cut.energy);
  EXPECT_EQ(b.cut.intra_edges, r.cut.intra_edges);
  EXPECT_EQ(b.cut.inter_edges, r.cut.inter_edges);
  EXPECT_EQ(b.cut.neighbours_ms, r.cut.neighbours_ms);
  EXPECT_EQ(b.cut.gmm_ms, r.cut.gmm_ms);
  EXPECT_EQ(b.cut.graph_ms, r.cut.graph_ms);
  EXPECT_EQ(b.cut.maxflow_ms, r.cut.maxflow_ms);
  EXPECT_EQ(b.cut.warm, r.cut.warm);
  EXPECT_EQ(b.load_ms, r.load_ms);
  EXPECT_EQ(b.commit_ms, r.commit_ms);
}

TEST(ConvertTest, CopyPasteAndComposite) {
  edit::CopyRequest c{-1, SliceRegion(), "clip", true};
  wire::CopyRequest wc;
  ToWire(c, &wc);
  auto cb = FromWire(wc);
  ASSERT_TRUE(cb.ok());
  EXPECT_EQ(cb->bit, -1);
  ASSERT_TRUE(cb->region.has_value());
  ExpectSameRegion(*cb->region, *c.region);
  EXPECT_EQ(cb->clipboard, "clip");
  EXPECT_TRUE(cb->cut);
  c.region.reset();
  wc.Clear();
  ToWire(c, &wc);
  cb = FromWire(wc);
  ASSERT_TRUE(cb.ok());
  EXPECT_FALSE(cb->region.has_value());

  edit::CopyResult cr{77, 88};
  wire::CopyReply wcr;
  ToWire(cr, &wcr);
  EXPECT_EQ(FromWire(wcr).points, 77u);
  EXPECT_EQ(FromWire(wcr).lsn, 88u);

  edit::PasteRequest p;
  p.clipboard = "clip";
  for (size_t i = 0; i < 16; ++i) p.map.a[i] = 0.5 * static_cast<double>(i);
  p.map.c = {1, 2, 3, 0.25};
  wire::PasteRequest wp;
  ToWire(p, &wp);
  auto pb = FromWire(wp);
  ASSERT_TRUE(pb.ok());
  EXPECT_EQ(pb->clipboard, "clip");
  EXPECT_EQ(pb->map.a, p.map.a);
  EXPECT_EQ(pb->map.c, p.map.c);
  wp.add_matrix(1);  // 17 values: the shape is wrong
  EXPECT_TRUE(FromWire(wp).status().IsInvalidArgument());

  edit::CompositeRequest k;
  for (int i = 0; i < 5; ++i) {
    Point pt{};
    pt.x = static_cast<float>(i);
    pt.y = 2.f;
    pt.z = -1.f;
    pt.r = static_cast<uint8_t>(10 * i);
    pt.frame = static_cast<uint32_t>(i);
    pt.id = static_cast<uint64_t>(100 + i);
    k.object.push_back(pt);
  }
  k.first_frame = 3;
  k.frame_count = 2;
  k.trajectory = {{0.1, 0.2, 0.3}, {0.4, 0.5, 0.6}};
  wire::CompositeRequest wk;
  ToWire(k, &wk);
  auto kb = FromWire(wk);
  ASSERT_TRUE(kb.ok());
  ASSERT_EQ(kb->object.size(), k.object.size());
  for (size_t i = 0; i < k.object.size(); ++i) {
    EXPECT_EQ(kb->object[i].x, k.object[i].x);
    EXPECT_EQ(kb->object[i].r, k.object[i].r);
    EXPECT_EQ(kb->object[i].id, k.object[i].id);
  }
  EXPECT_EQ(kb->first_frame, 3u);
  EXPECT_EQ(kb->frame_count, 2u);
  EXPECT_EQ(kb->trajectory, k.trajectory);
}

TEST(ConvertTest, CommitStatsPhotoCreateAndQueryOptions) {
  CommitInfo c{5, 6, 7, {8, 9}};
  wire::CommitReply wc;
  ToWire(c, &wc);
  CommitInfo cb = FromWire(wc);
  EXPECT_EQ(cb.lsn, 5u);
  EXPECT_EQ(cb.inserted, 6u);
  EXPECT_EQ(cb.removed, 7u);
  EXPECT_EQ(cb.assigned_ids, c.assigned_ids);

  DatasetStats s;
  s.frames_with_data = 3;
  s.points = 4;
  s.tombstones = 5;
  s.buffered_points = 6;
  s.trees = 7;
  s.tree_bytes = 8;
  s.wal_bytes = 9;
  s.merges = 10;
  s.checkpoints = 11;
  s.leaf_utilisation = 0.75;
  wire::DatasetStats ws;
  ToWire(s, &ws);
  DatasetStats sb = FromWire(ws);
  EXPECT_EQ(sb.frames_with_data, 3u);
  EXPECT_EQ(sb.points, 4u);
  EXPECT_EQ(sb.tombstones, 5u);
  EXPECT_EQ(sb.buffered_points, 6u);
  EXPECT_EQ(sb.trees, 7u);
  EXPECT_EQ(sb.tree_bytes, 8u);
  EXPECT_EQ(sb.wal_bytes, 9u);
  EXPECT_EQ(sb.merges, 10u);
  EXPECT_EQ(sb.checkpoints, 11u);
  EXPECT_EQ(sb.leaf_utilisation, 0.75);

  Photo ph{Camera(4), "jpegbytes", {}};
  ph.billboard = {0.5, {1, 2, 3}, "disp", "alpha"};
  wire::PutPhoto wp;
  ToWire(ph, &wp);
  auto pb = FromWire(wp);
  ASSERT_TRUE(pb.ok());
  ExpectSameCamera(pb->camera, ph.camera);
  EXPECT_EQ(pb->image, ph.image);
  EXPECT_EQ(pb->billboard.scale, 0.5);
  EXPECT_EQ(pb->billboard.plane, ph.billboard.plane);
  EXPECT_EQ(pb->billboard.displacement, "disp");
  EXPECT_EQ(pb->billboard.alpha, "alpha");
  wp.mutable_billboard()->add_plane(4);
  EXPECT_TRUE(FromWire(wp).status().IsInvalidArgument());

  DatasetInfo info;
  info.name = "d";
  info.fps = 29.97;
  info.space_time_scale = 2.5;
  info.frame_count = 16;
  info.cameras = {Camera(1), Camera(2)};
  wire::CreateDataset wcd;
  ToWire(info, &wcd);
  auto ib = FromWire(wcd);
  ASSERT_TRUE(ib.ok());
  EXPECT_EQ(ib->name, "d");
  EXPECT_EQ(ib->fps, 29.97);
  EXPECT_EQ(ib->space_time_scale, 2.5);
  EXPECT_EQ(ib->frame_count, 16u);
  ASSERT_EQ(ib->cameras.size(), 2u);
  ExpectSameCamera(ib->cameras[1], info.cameras[1]);

  QueryOptions o;
  o.lod = -2;
  o.progressive = true;
  o.temporal_lod = false;
  o.batch_points = 999;
  o.label_mask = 0x10;
  wire::Query wq;
  ToWire(o, &wq);
  auto ob = wire::QueryOptionsFromWire(wq);
  ASSERT_TRUE(ob.ok());
  EXPECT_EQ(ob->lod, -2);
  EXPECT_TRUE(ob->progressive);
  EXPECT_FALSE(ob->temporal_lod);
  EXPECT_EQ(ob->batch_points, 999u);
  EXPECT_EQ(ob->label_mask, 0x10u);
}

TEST(ConvertTest, ImportMedia) {
  media::ImportRequest m;
  m.data = std::string("\x89PNG\0bytes", 11);
  m.kind = media::Kind::kVideo;
  m.format = "webm";
  m.first_frame = 3;
  m.last_frame = 9;
  m.place.at = {1, -2, 3.5};
  m.place.scale = 0.25;
  m.place.rotate_deg = {10, 20, -30};
  m.place.width = 1.5;
  m.label_bit = -1;  // refused by the executor, with the caller's number
  m.texels = 64;
  m.spacing = 0.004;
  wire::ImportMediaRequest w;
  ToWire(m, &w);
  auto b = FromWire(w);
  ASSERT_TRUE(b.ok()) << b.status().ToString();
  EXPECT_EQ(b->data, m.data);
  EXPECT_EQ(b->kind, media::Kind::kVideo);
  EXPECT_EQ(b->format, "webm");
  EXPECT_EQ(b->first_frame, 3u);
  EXPECT_EQ(b->last_frame, 9u);
  EXPECT_EQ(b->place.at, m.place.at);
  EXPECT_EQ(b->place.scale, 0.25);
  EXPECT_EQ(b->place.rotate_deg, m.place.rotate_deg);
  EXPECT_EQ(b->place.width, 1.5);
  EXPECT_EQ(b->label_bit, -1);
  EXPECT_EQ(b->texels, 64u);
  EXPECT_EQ(b->spacing, 0.004);
  // Absent fields take the defaults.
  wire::ImportMediaRequest bare;
  bare.set_data("x");
  b = FromWire(bare);
  ASSERT_TRUE(b.ok());
  EXPECT_EQ(b->kind, media::Kind::kAuto);
  EXPECT_FALSE(b->first_frame.has_value());
  EXPECT_FALSE(b->label_bit.has_value());
  EXPECT_EQ(b->place.scale, 1);
  EXPECT_EQ(b->place.width, 1);
  // The shape: a known kind, 3 values or none.
  w.set_kind("sound");
  EXPECT_NE(FromWire(w).status().message().find("import_media.kind"), std::string::npos);
  w.set_kind("");
  w.add_at(1);
  EXPECT_NE(FromWire(w).status().message().find("import_media.at"), std::string::npos);
}

}  // namespace
}  // namespace hvdb
