// The render request and reply (render/request.h) round-trip through the wire's Render and
// RenderReply messages (protocol/render_convert.h): what the command line or Python asks of a
// server is what the server's render job gets, and its replies what the embedded mode returns.
// FromWire refuses a malformed shape naming the field, as the render job always has.
#include "protocol/render_convert.h"

#include <google/protobuf/io/coded_stream.h>
#include <google/protobuf/io/zero_copy_stream_impl_lite.h>
#include <gtest/gtest.h>

#include <optional>
#include <string>
#include <variant>

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

std::string Bytes(const render::RenderRequest& r) {
  wire::Render w;
  wire::ToWire(r, &w);
  std::string out;
  google::protobuf::io::StringOutputStream s(&out);
  google::protobuf::io::CodedOutputStream c(&s);
  c.SetSerializationDeterministic(true);
  w.SerializeToCodedStream(&c);
  return out;
}

render::RenderRequest RoundTrip(const render::RenderRequest& r) {
  wire::Render w;
  wire::ToWire(r, &w);
  Result<render::RenderRequest> back = wire::FromWire(w);
  EXPECT_TRUE(back.ok()) << back.status().ToString();
  return back.ok() ? *back : render::RenderRequest{};
}

TEST(RenderConvertTest, ADefaultRequestKeepsItsUnsetFields) {
  render::RenderRequest r;
  r.dataset = "d";
  render::RenderRequest b = RoundTrip(r);
  EXPECT_EQ(b.dataset, "d");
  EXPECT_FALSE(b.region);
  EXPECT_FALSE(b.view);
  EXPECT_FALSE(b.mode);  // auto colour: mode, texture and billboards all unset
  EXPECT_FALSE(b.texture);
  EXPECT_FALSE(b.billboards);
  EXPECT_FALSE(b.background);
  EXPECT_FALSE(b.highlight_color);
  EXPECT_FALSE(b.shadow_light);
  EXPECT_EQ(b.renderer, render::RendererKind::kAuto);
  EXPECT_EQ(b.format, render::ImageFormat::kPng);
  EXPECT_EQ(b.lod, 0u);
  EXPECT_TRUE(b.path.empty());
  EXPECT_EQ(Bytes(b), Bytes(r));
}

TEST(RenderConvertTest, EveryFieldRoundTrips) {
  render::RenderRequest r;
  r.dataset = "scene";
  Slice s;
  s.normal = {0, 0, 1, 0.5};
  s.offset = 0.25;
  s.thickness = 0.02;
  s.max_frames = 7;
  r.region = Region(s);
  r.lod = 3;
  render::LookAtView l;
  l.eye = {1, 2, 3};
  l.target = {0, 0.5, 0};
  l.up = std::array<double, 3>{0, -1, 0};
  l.fov_y_deg = 40;
  l.width = 320;
  l.height = 240;
  r.view = l;
  r.mode = render::Mode::kProbabilistic;
  r.view_dependent = true;
  r.width = 64;
  r.height = 48;
  r.background = std::array<float, 4>{0.1f, 0.2f, 0.3f, 1};
  r.renderer = render::RendererKind::kEgl;
  r.depth_threshold = 0.05f;
  r.cutoff_radius = 3;
  r.format = render::ImageFormat::kWebm;
  render::LookAtView no_up = l;
  no_up.up.reset();
  r.path = {Camera(4), no_up, render::DatasetCameraView{2}};
  r.frames = {5, 6, 7};
  r.no_temporal_lod = true;
  r.label_mask = 0x30;
  r.progressive = true;
  r.highlight_mask = 8;
  r.highlight_color = std::array<float, 4>{0, 0, 1, 0.75f};
  r.texture = false;
  r.billboards = true;
  r.shadow_light = std::array<double, 3>{0, -3, 1};
  r.shadow_directional = true;
  r.shadow_casters = 4;
  r.shadow_strength = 0.5f;
  r.shadow_map_size = 512;
  r.video_fps = 12.5;

  render::RenderRequest b = RoundTrip(r);
  EXPECT_EQ(b.dataset, "scene");
  ASSERT_TRUE(b.region && std::holds_alternative<Slice>(*b.region));
  EXPECT_EQ(std::get<Slice>(*b.region).normal, s.normal);
  EXPECT_EQ(std::get<Slice>(*b.region).max_frames, 7u);
  EXPECT_EQ(b.lod, 3u);
  ASSERT_TRUE(b.view && std::holds_alternative<render::LookAtView>(*b.view));
  const auto& bl = std::get<render::LookAtView>(*b.view);
  EXPECT_EQ(bl.eye, l.eye);
  EXPECT_EQ(bl.target, l.target);
  EXPECT_EQ(bl.up, l.up);
  EXPECT_EQ(bl.fov_y_deg, 40);
  EXPECT_EQ(bl.width, 320u);
  EXPECT_EQ(bl.height, 240u);
  EXPECT_EQ(b.mode, render::Mode::kProbabilistic);
  EXPECT_TRUE(b.view_dependent);
  EXPECT_EQ(b.width, 64u);
  EXPECT_EQ(b.height, 48u);
  EXPECT_EQ(b.background, r.background);
  EXPECT_EQ(b.renderer, render::RendererKind::kEgl);
  EXPECT_EQ(b.depth_threshold, 0.05f);
  EXPECT_EQ(b.cutoff_radius, 3.f);
  EXPECT_EQ(b.format, render::ImageFormat::kWebm);
  ASSERT_EQ(b.path.size(), 3u);
  ASSERT_TRUE(std::holds_alternative<CameraInfo>(b.path[0]));
  const CameraInfo& c = std::get<CameraInfo>(b.path[0]);
  EXPECT_EQ(c.id, 4);
  EXPECT_EQ(c.name, "cam4");
  EXPECT_EQ(c.fx, 500.5);
  EXPECT_EQ(c.distortion, Camera(4).distortion);
  EXPECT_EQ(c.world_from_camera, Camera(4).world_from_camera);
  ASSERT_TRUE(std::holds_alternative<render::LookAtView>(b.path[1]));
  EXPECT_FALSE(std::get<render::LookAtView>(b.path[1]).up);  // none: 0 1 0
  ASSERT_TRUE(std::holds_alternative<render::DatasetCameraView>(b.path[2]));
  EXPECT_EQ(std::get<render::DatasetCameraView>(b.path[2]).id, 2u);
  EXPECT_EQ(b.frames, r.frames);
  EXPECT_TRUE(b.no_temporal_lod);
  EXPECT_EQ(b.label_mask, 0x30u);
  EXPECT_TRUE(b.progressive);
  EXPECT_EQ(b.highlight_mask, 8u);
  EXPECT_EQ(b.highlight_color, r.highlight_color);
  EXPECT_EQ(b.texture, std::optional<bool>(false));  // given false: not auto
  EXPECT_EQ(b.billboards, std::optional<bool>(true));
  EXPECT_EQ(b.shadow_light, r.shadow_light);
  EXPECT_TRUE(b.shadow_directional);
  EXPECT_EQ(b.shadow_casters, 4u);
  EXPECT_EQ(b.shadow_strength, 0.5f);
  EXPECT_EQ(b.shadow_map_size, 512u);
  EXPECT_EQ(b.video_fps, 12.5);
  // And every byte of the message: nothing is lost or added on the way.
  EXPECT_EQ(Bytes(b), Bytes(r));
  // Each enum value maps both ways.
  for (auto k : {render::RendererKind::kAuto, render::RendererKind::kEgl, render::RendererKind::kCpu}) {
    r.renderer = k;
    EXPECT_EQ(RoundTrip(r).renderer, k);
  }
  for (auto f : {render::ImageFormat::kPng, render::ImageFormat::kExr, render::ImageFormat::kMp4,
                 render::ImageFormat::kWebm}) {
    r.format = f;
    EXPECT_EQ(RoundTrip(r).format, f);
  }
  r.mode = render::Mode::kVisibility;
  EXPECT_EQ(RoundTrip(r).mode, render::Mode::kVisibility);
}

TEST(RenderConvertTest, TheReplyRoundTrips) {
  render::RenderReply r;
  r.png = std::string("\x89PNG\0\1", 6);
  r.exr = "exr";
  r.video = "video";
  r.video_codec = "libx264";
  r.width = 160;
  r.height = 120;
  r.renderer_used = "cpu (4 threads)";
  r.renderer_choice = "asked for";
  r.fallback = true;
  r.points = 3000;
  r.render_ms = 12.5;
  r.index = 2;
  r.images = 3;
  r.last = true;
  r.preview = true;
  r.lod = 4;
  r.mode_used = "textured";
  r.mode_choice = "auto: 4 photos of frame 0";
  wire::RenderReply w;
  wire::ToWire(r, &w);
  render::RenderReply b = wire::FromWire(w);
  EXPECT_EQ(b.png, r.png);
  EXPECT_EQ(b.exr, r.exr);
  EXPECT_EQ(b.video, r.video);
  EXPECT_EQ(b.video_codec, r.video_codec);
  EXPECT_EQ(b.width, 160u);
  EXPECT_EQ(b.height, 120u);
  EXPECT_EQ(b.renderer_used, r.renderer_used);
  EXPECT_EQ(b.renderer_choice, r.renderer_choice);
  EXPECT_TRUE(b.fallback);
  EXPECT_EQ(b.points, 3000u);
  EXPECT_EQ(b.render_ms, 12.5);
  EXPECT_EQ(b.index, 2u);
  EXPECT_EQ(b.images, 3u);
  EXPECT_TRUE(b.last);
  EXPECT_TRUE(b.preview);
  EXPECT_EQ(b.lod, 4u);
  EXPECT_EQ(b.mode_used, r.mode_used);
  EXPECT_EQ(b.mode_choice, r.mode_choice);
  // Moved out (hvdb-server's way): the same message.
  wire::RenderReply moved;
  render::RenderReply copy = r;
  wire::ToWire(std::move(copy), &moved);
  EXPECT_EQ(moved.SerializeAsString(), w.SerializeAsString());
}

// The shape is FromWire's to refuse, in the words the render job always used.
TEST(RenderConvertTest, AMalformedShapeIsRefusedNamingTheField) {
  wire::Render base;
  base.set_dataset("d");
  base.mutable_view()->set_dataset_camera(1);
  ASSERT_TRUE(wire::FromWire(base).ok());
  auto error = [](const wire::Render& r) {
    Result<render::RenderRequest> b = wire::FromWire(r);
    EXPECT_FALSE(b.ok());
    EXPECT_TRUE(b.ok() || b.status().IsInvalidArgument()) << b.status().ToString();
    return b.ok() ? std::string("ok") : b.status().message();
  };
  wire::Render r = base;
  r.set_renderer(static_cast<wire::RendererKind>(7));
  EXPECT_EQ(error(r), "render.renderer: unknown value 7");
  r = base;
  r.set_format(static_cast<wire::ImageFormat>(9));
  EXPECT_EQ(error(r), "render.format: unknown value 9");
  r = base;
  r.set_mode(static_cast<wire::RenderMode>(5));
  EXPECT_EQ(error(r), "render.mode: unknown value 5");
  r = base;
  r.add_background(1);
  EXPECT_EQ(error(r), "render.background: needs 4 values (linear RGBA) or none");
  r = base;
  r.add_highlight_color(1);
  EXPECT_EQ(error(r).rfind("render.highlight_color: needs 4 values", 0), 0u);
  r = base;
  r.add_shadow_light(1);
  EXPECT_EQ(error(r).rfind("render.shadow_light: needs 3 values", 0), 0u);
  r = base;
  r.mutable_view()->Clear();
  EXPECT_EQ(error(r), "render.view: needs a camera, a look_at or a dataset_camera");
  r = base;
  r.mutable_view()->mutable_look_at()->add_eye(1);
  EXPECT_EQ(error(r), "render.view.look_at: eye and target need 3 values each");
  r = base;
  r.clear_view();
  r.add_path()->set_dataset_camera(1);
  wire::Camera* c = r.add_path()->mutable_camera();
  wire::ToWire(Camera(1), c);
  c->mutable_intrinsics()->RemoveLast();
  EXPECT_EQ(error(r), "render.path[1]: camera.intrinsics: needs fx fy cx cy");
  r.mutable_path(1)->Clear();
  auto* l = r.mutable_path(1)->mutable_look_at();
  for (double v : {1.0, 2.0, 3.0}) l->add_eye(v), l->add_target(-v);
  l->add_up(1);
  EXPECT_EQ(error(r), "render.path[1].look_at.up: needs 3 values (or none for 0 1 0)");
  r = base;
  r.mutable_region();  // present, of no kind
  EXPECT_EQ(error(r), "region: must be a window or a slice");
}

}  // namespace
}  // namespace hvdb
