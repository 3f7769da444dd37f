// Render jobs (render/job.h): RenderJob against an embedded database, camera paths, and render
// requests through a real hvdb-server, whose sessions run them (single images, sequences, EXR,
// OVERLOADED).
#include "render/job.h"

#include <gtest/gtest.h>

#include <fstream>

#include "client/client.h"
#include "formats/image_io.h"
#include "render/metrics.h"
#include "tests/render/job_helpers.h"
#include "tests/render/test_scenes.h"
#include "tests/server/server_process.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using render::RenderJob;
using testing::TempDir;

using namespace render_test;  // FramePoints, Info, FrameRegion, SetLookAt, TheLookAt

class RenderJobTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = Database::Open(dir_.path());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(db).value();
    auto ds = db_->CreateDataset(Info("scene", true));
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    ds_ = *ds;
    for (uint32_t f = 0; f < 3; ++f) ASSERT_TRUE(ds_->BulkLoad(f, FramePoints(f)).ok());
    auto bare = db_->CreateDataset(Info("bare", false));
    ASSERT_TRUE(bare.ok());
    bare_ = *bare;
  }
  TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_, bare_;
};

TEST_F(RenderJobTest, RendersTheRegionLikeTheRendererDoes) {
  wire::Render req;
  req.set_dataset("scene");
  *req.mutable_region() = FrameRegion(1);
  SetLookAt(req.mutable_view());
  req.set_renderer(wire::RENDERER_CPU);
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  EXPECT_EQ((*job)->size(), 1u);
  EXPECT_EQ((*job)->renderer_kind(), render::RendererKind::kCpu);
  auto cpu = render::MakeCpuRenderer();
  auto img = (*job)->RenderImage(0, *cpu);
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  auto direct = cpu->Render(FramePoints(1), TheLookAt(), {});
  ASSERT_TRUE(direct.ok());
  // The query returns the points in its own order: sums may round differently.
  EXPECT_GE(render::Psnr(formats::ToSrgb8(*img), formats::ToSrgb8(*direct)), 50);
  auto reply = (*job)->Render(0, *cpu);
  ASSERT_TRUE(reply.ok());
  EXPECT_TRUE(reply->last);
  EXPECT_EQ(reply->width, 160u);
  EXPECT_EQ(reply->points, 3000u);
  EXPECT_EQ(reply->renderer_used, cpu->name());
  EXPECT_EQ(reply->png.substr(1, 3), "PNG");
}

// The selection as an overlay: the points carrying the highlighted bit are drawn in their
// colour blended toward the highlight colour, exactly as if they had that colour; the others
// as they are.
TEST_F(RenderJobTest, HighlightShowsASelection) {
  // Frame 0's upper half (y > 0) selected into bit 3.
  Selection upper;
  Window w;
  w.lo = {-1e9, 0, -1e9, 0};
  w.hi = {1e9, 1e9, 1e9, 0};
  upper.region = w;
  Transaction t;
  t.SetLabel(upper, 1u << 3, true);
  ASSERT_TRUE(ds_->Commit(t).ok());
  wire::Render req;
  req.set_dataset("scene");
  *req.mutable_region() = FrameRegion(0);
  SetLookAt(req.mutable_view());
  req.set_renderer(wire::RENDERER_CPU);
  req.set_highlight_mask(1u << 3);
  for (float v : {0.f, 0.f, 1.f, 1.f}) req.add_highlight_color(v);  // all blue
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  auto cpu = render::MakeCpuRenderer();
  auto img = (*job)->RenderImage(0, *cpu);
  ASSERT_TRUE(img.ok()) << img.status().ToString();
  auto pts = FramePoints(0);
  for (Point& p : pts) {
    if (p.y >= 0) p.r = 0, p.g = 0, p.b = 255;
  }
  auto want = cpu->Render(pts, TheLookAt(), {});
  ASSERT_TRUE(want.ok());
  EXPECT_GE(render::Psnr(formats::ToSrgb8(*img), formats::ToSrgb8(*want)), 50);
  auto plain = cpu->Render(FramePoints(0), TheLookAt(), {});
  EXPECT_LT(render::Psnr(formats::ToSrgb8(*img), formats::ToSrgb8(*plain)), 30);
  // Colours outside [0, 1], or not four of them, are refused naming the field.
  req.set_highlight_color(0, 2.f);
  EXPECT_EQ(CreateJob(ds_, req).status().message().rfind("render.highlight_color:", 0), 0u);
  req.clear_highlight_color();
  req.add_highlight_color(1.f);
  EXPECT_EQ(CreateJob(ds_, req).status().message().rfind("render.highlight_color:", 0), 0u);
}

TEST_F(RenderJobTest, SequencesFollowFramesAndCameras) {
  wire::Render req;
  req.set_dataset("scene");
  for (uint32_t f = 0; f < 3; ++f) {
    SetLookAt(req.add_path());
    req.add_frames(f);
  }
  auto dataset_view = req.add_path();
  dataset_view->set_dataset_camera(2);
  req.add_frames(0);
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  ASSERT_EQ((*job)->size(), 4u);
  auto cpu = render::MakeCpuRenderer();
  for (uint32_t i = 0; i < 4; ++i) {
    auto img = (*job)->RenderImage(i, *cpu);
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    size_t centre = size_t{img->height / 2} * img->width + img->width / 2;
    const float* p = &img->rgba[centre * 4];
    int brightest = p[0] > p[1] ? (p[0] > p[2] ? 0 : 2) : (p[1] > p[2] ? 1 : 2);
    EXPECT_EQ(brightest, static_cast<int>(i % 3)) << "image " << i;
  }
}

TEST_F(RenderJobTest, RejectsBadRequestsNamingTheField) {
  auto error = [&](const wire::Render& r, std::shared_ptr<Dataset> ds = nullptr) {
    auto job = CreateJob(ds ? ds : ds_, r);
    return job.ok() ? std::string("ok") : job.status().message();
  };
  wire::Render base;
  base.set_dataset("scene");
  *base.mutable_region() = FrameRegion(0);
  SetLookAt(base.mutable_view());
  EXPECT_EQ(error(base), "ok");
  wire::Render r = base;
  r.clear_view();
  EXPECT_EQ(error(r).rfind("render.view:", 0), 0u) << error(r);
  r = base;
  r.set_lod(40);  // storage's one rule for a level of detail (Dataset::CheckLod)
  EXPECT_EQ(error(r), "lod: 40 is out of range 0..5 for dataset 'scene' (its coarsest level)");
  r = base;
  r.add_background(1);
  EXPECT_EQ(error(r).rfind("render.background:", 0), 0u);
  r = base;
  r.mutable_view()->mutable_look_at()->set_width(5000);
  EXPECT_EQ(error(r).rfind("render.view: camera size", 0), 0u) << error(r);
  r = base;
  r.mutable_view()->set_dataset_camera(9);
  EXPECT_EQ(error(r).rfind("render.view.dataset_camera:", 0), 0u);
  r = base;
  r.add_frames(1);
  EXPECT_EQ(error(r).rfind("render.frames:", 0), 0u);
  r = base;
  r.set_view_dependent(true);
  EXPECT_EQ(error(r), "ok");
  EXPECT_EQ(error(r, bare_).rfind("render.view_dependent:", 0), 0u);
  r = base;
  r.clear_region();
  EXPECT_EQ(error(r).rfind("render.region:", 0), 0u);
  r = base;
  r.set_width(100);
  EXPECT_EQ(error(r).rfind("render.width:", 0), 0u);
  r = base;
  r.set_mode(static_cast<wire::RenderMode>(7));
  EXPECT_EQ(error(r).rfind("render.mode:", 0), 0u);
  render::RenderLimits few;
  few.max_points = 100;
  auto job = CreateJob(ds_, base, few);
  ASSERT_TRUE(job.ok());
  auto cpu = render::MakeCpuRenderer();
  const Status over = (*job)->RenderImage(0, *cpu).status();
  EXPECT_EQ(over.code(), StatusCode::kLimitExceeded) << over.ToString();
  std::atomic<bool> cancelled{true};
  auto job2 = CreateJob(ds_, base);
  EXPECT_EQ((*job2)->RenderImage(0, *cpu, &cancelled).status().code(), StatusCode::kCancelled);
}

// Findings of a probe of the render requests: a camera that looks nowhere, frames that do not
// exist, and jobs past their memory or time.
TEST_F(RenderJobTest, RequestsThatCannotRenderAreSaidInTheRequestsWords) {
  auto error = [&](const wire::Render& r, const render::RenderLimits& l = {}) {
    auto job = CreateJob(ds_, r, l);
    return job.ok() ? std::string("ok") : job.status().message();
  };
  wire::Render base;
  base.set_dataset("scene");
  *base.mutable_region() = FrameRegion(0);
  SetLookAt(base.mutable_view());
  wire::Render r = base;
  wire::LookAt* l = r.mutable_view()->mutable_look_at();
  for (int i = 0; i < 3; ++i) l->set_target(i, l->eye(i));
  EXPECT_NE(error(r).find("eye and target are the same point"), std::string::npos) << error(r);
  r = base;
  l = r.mutable_view()->mutable_look_at();
  l->clear_up();
  for (int i = 0; i < 3; ++i) l->add_up(l->target(i) - l->eye(i));
  EXPECT_NE(error(r).find("render.view.look_at.up"), std::string::npos) << error(r);
  // A path whose frame is past the dataset's three.
  wire::Render seq;
  seq.set_dataset("scene");
  SetLookAt(seq.add_path());
  seq.add_frames(0);
  SetLookAt(seq.add_path());
  seq.add_frames(4294967295u);
  EXPECT_EQ(error(seq).rfind("render.frames[1]: frame 4294967295 is past", 0), 0u) << error(seq);
  render::RenderRequest parsed;
  EXPECT_FALSE(render::ParseCameraPath(
                   R"({"cameras": [{"frame": -1, "dataset_camera": 2}]})", &parsed).ok());
  EXPECT_FALSE(render::ParseCameraPath(
                   R"({"cameras": [{"frame": 1000000000000, "dataset_camera": 2}]})", &parsed).ok());
  // Memory: the image's buffers come out of the job budget before anything is drawn.
  JobBudget small(512u << 10, "--memory-budget");  // under one 160 x 120 image
  render::RenderLimits tight;
  tight.job.memory = &small;
  const std::string m = error(base, tight);
  EXPECT_NE(m.find("--memory-budget"), std::string::npos) << m;
  EXPECT_EQ(small.used(), 0u);  // given back with the job
  // Time: a job past --max-job-seconds stops at its next image, saying so.
  render::RenderLimits late;
  late.job.max_seconds = 1;
  late.job.start = std::chrono::steady_clock::now() - std::chrono::seconds(2);
  auto job = CreateJob(ds_, base, late);
  ASSERT_TRUE(job.ok());
  auto cpu = render::MakeCpuRenderer();
  auto reply = (*job)->Render(0, *cpu);
  ASSERT_FALSE(reply.ok());
  EXPECT_EQ(reply.status().code(), StatusCode::kLimitExceeded);
  EXPECT_NE(reply.status().message().find("--max-job-seconds"), std::string::npos);
}

TEST_F(RenderJobTest, ProgressiveGivesACoarsePreviewFirst) {
  wire::Render req;
  req.set_dataset("scene");
  *req.mutable_region() = FrameRegion(1);
  SetLookAt(req.mutable_view());
  req.set_progressive(true);
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  ASSERT_EQ((*job)->size(), 2u);
  auto cpu = render::MakeCpuRenderer();
  auto preview = (*job)->Render(0, *cpu);
  auto full = (*job)->Render(1, *cpu);
  ASSERT_TRUE(preview.ok() && full.ok());
  EXPECT_TRUE(preview->preview);
  EXPECT_FALSE(preview->last);
  EXPECT_EQ(preview->lod, 4u);  // lod + 4 (the dataset has 5 levels)
  EXPECT_FALSE(full->preview);
  EXPECT_TRUE(full->last);
  EXPECT_EQ(full->lod, 0u);
  EXPECT_EQ(full->points, 3000u);
  EXPECT_LT(preview->points, full->points / 8);
  EXPECT_GT(preview->points, 0u);
  EXPECT_EQ(preview->index, 0u);
  EXPECT_EQ(full->index, 0u);
  EXPECT_EQ(preview->width, 80u);  // half the size
  EXPECT_EQ(preview->height, 60u);
  EXPECT_EQ(full->width, 160u);
  // The preview's grown splats still close the surface: it looks like the final image
  // rendered at its size.
  auto a = (*job)->RenderImage(0, *cpu);
  render::RenderOptions half;
  half.width = 80;
  half.height = 60;
  auto b = cpu->Render(FramePoints(1), TheLookAt(), half);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_GE(render::Psnr(formats::ToSrgb8(*a), formats::ToSrgb8(*b)), 18);
  // Near the coarsest level the preview is the coarsest level; at it, there is none.
  req.set_lod(3);
  auto near = CreateJob(ds_, req);
  ASSERT_TRUE(near.ok());
  ASSERT_EQ((*near)->size(), 2u);
  EXPECT_EQ((*near)->Render(0, *cpu)->lod, 5u);
  req.set_lod(5);
  auto coarsest = CreateJob(ds_, req);
  ASSERT_TRUE(coarsest.ok());
  EXPECT_EQ((*coarsest)->size(), 1u);
  // Not for sequences; and no level beyond the dataset's.
  req.set_lod(6);
  EXPECT_EQ(CreateJob(ds_, req).status().message().rfind("lod: 6 is out of range 0..5", 0), 0u);
  req.set_lod(0);
  req.clear_view();
  SetLookAt(req.add_path());
  req.add_frames(0);
  EXPECT_EQ(CreateJob(ds_, req).status().message().rfind("render.progressive:", 0), 0u);
}

TEST_F(RenderJobTest, ThePipelinedSequenceDrawsWhatEachFrameHolds) {
  // Image i + 1's points are queried while image i is drawn: repeated, alternating and
  // skipped frames must each show their own points.
  const std::vector<uint32_t> frames = {0, 1, 1, 2, 0, 2, 2, 1};
  wire::Render req;
  req.set_dataset("scene");
  for (uint32_t f : frames) {
    SetLookAt(req.add_path());
    req.add_frames(f);
  }
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok());
  auto cpu = render::MakeCpuRenderer();
  for (size_t i = 0; i < frames.size(); ++i) {
    auto img = (*job)->RenderImage(i, *cpu);
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    auto direct = cpu->Render(FramePoints(frames[i]), TheLookAt(), {});
    ASSERT_TRUE(direct.ok());
    EXPECT_GE(render::Psnr(formats::ToSrgb8(*img), formats::ToSrgb8(*direct)), 50) << "image " << i;
  }
  // Cancelled mid-sequence: the next image says so (its query may already have run).
  std::atomic<bool> cancelled{false};
  auto job2 = CreateJob(ds_, req);
  ASSERT_TRUE(job2.ok());
  ASSERT_TRUE((*job2)->RenderImage(0, *cpu, &cancelled).ok());
  cancelled = true;
  EXPECT_EQ((*job2)->RenderImage(1, *cpu, &cancelled).status().code(), StatusCode::kCancelled);
  // A failing query in the pipeline fails its own image, not the one before.
  render::RenderLimits few;
  few.max_points = 3000;
  wire::Render mixed = req;
  auto job3 = CreateJob(ds_, mixed, few);
  ASSERT_TRUE(job3.ok());
  EXPECT_TRUE((*job3)->RenderImage(0, *cpu).ok());
  few.max_points = 2999;
  auto job4 = CreateJob(ds_, mixed, few);
  ASSERT_TRUE(job4.ok());
  EXPECT_EQ((*job4)->RenderImage(0, *cpu).status().code(), StatusCode::kLimitExceeded);
}

TEST(CameraPathTest, ParsesTheThreeViewKinds) {
  render::RenderRequest req;
  Status st = render::ParseCameraPath(R"({"cameras": [
      {"frame": 3, "look_at": {"eye": [0, 0, -3], "target": [0, 0, 0], "up": [0, -1, 0],
                               "fov_y_deg": 40, "width": 320, "height": 240}},
      {"frame": 4, "camera": {"width": 64, "height": 48, "fx": 50, "fy": 50, "cx": 31.5,
                              "cy": 23.5, "world_from_camera": [1,0,0,0, 0,1,0,0, 0,0,1,0,
                                                                0,0,0,1]}},
      {"frame": 5, "dataset_camera": 2}]})",
                                      &req);
  ASSERT_TRUE(st.ok()) << st.ToString();
  ASSERT_EQ(req.path.size(), 3u);
  EXPECT_EQ(req.frames.size(), 3u);
  EXPECT_EQ(req.frames[2], 5u);
  EXPECT_EQ(std::get<render::LookAtView>(req.path[0]).fov_y_deg, 40);
  EXPECT_EQ((*std::get<render::LookAtView>(req.path[0]).up)[1], -1);
  EXPECT_EQ(std::get<CameraInfo>(req.path[1]).cx, 31.5);
  EXPECT_EQ(std::get<render::DatasetCameraView>(req.path[2]).id, 2u);
  EXPECT_FALSE(render::ParseCameraPath("{", &req).ok());
  EXPECT_FALSE(render::ParseCameraPath(R"({"cameras": [{"frame": 1, "dataset_camera": 1},
                                                       {"dataset_camera": 1}]})",
                                       &req)
                   .ok());
  Status bad = render::ParseCameraPath(R"({"cameras": [{"look_at": {"eye": [1, 2]}}]})", &req);
  EXPECT_NE(bad.message().find("entry 0"), std::string::npos) << bad.ToString();
}

// ---- Through hvdb-server ----

class RenderServerTest : public ::testing::Test {
 protected:
  void Start(std::vector<std::string> extra = {}) {
    server_ = std::make_unique<testing::ServerProcess>(dir_.path() + "/data", extra);
    ASSERT_TRUE(server_->running());
    client::Options o;
    o.port = server_->port();
    o.request_timeout = std::chrono::milliseconds(60000);
    auto c = client::Connection::Connect(o);
    ASSERT_TRUE(c.ok()) << c.status().ToString();
    conn_ = std::move(c).value();
    ASSERT_TRUE(conn_->CreateDataset(Info("scene", true)).ok());
    for (uint32_t f = 0; f < 3; ++f) {
      auto pts = FramePoints(f);
      ASSERT_TRUE(conn_->Ingest("scene", f, pts).ok());
    }
  }
  render::Srgb8Image Decode(const std::string& png) {
    std::string path = dir_.path() + "/reply.png";
    std::ofstream(path, std::ios::binary) << png;
    auto img = formats::ReadSrgb8(path);
    EXPECT_TRUE(img.ok()) << img.status().ToString();
    return img.ok() ? *img : render::Srgb8Image{};
  }
  TempDir dir_;
  std::unique_ptr<testing::ServerProcess> server_;
  std::unique_ptr<client::Connection> conn_;
};

TEST_F(RenderServerTest, RendersAnImage) {
  Start();
  wire::Render req;
  req.set_dataset("scene");
  *req.mutable_region() = FrameRegion(2);
  SetLookAt(req.mutable_view());
  req.set_renderer(wire::RENDERER_AUTO);
  auto reply = conn_->Render(req);
  ASSERT_TRUE(reply.ok()) << reply.status().ToString();
  EXPECT_EQ(reply->width(), 160u);
  EXPECT_EQ(reply->height(), 120u);
  EXPECT_EQ(reply->points(), 3000u);
  EXPECT_TRUE(reply->last());
  EXPECT_FALSE(reply->renderer_used().empty());
  std::printf("server rendered with %s%s in %.1f ms\n", reply->renderer_used().c_str(),
              reply->fallback() ? " (fallback)" : "", reply->render_ms());
  auto direct = render::MakeCpuRenderer()->Render(FramePoints(2), TheLookAt(), {});
  ASSERT_TRUE(direct.ok());
  EXPECT_GE(render::Psnr(Decode(reply->png()), formats::ToSrgb8(*direct)), 35);
  // EXR on request, at another size.
  req.set_format(wire::IMAGE_EXR);
  req.set_width(80);
  req.set_height(60);
  req.set_renderer(wire::RENDERER_CPU);
  reply = conn_->Render(req);
  ASSERT_TRUE(reply.ok()) << reply.status().ToString();
  EXPECT_EQ(reply->width(), 80u);
  EXPECT_TRUE(reply->png().empty());
  EXPECT_EQ(static_cast<uint8_t>(reply->exr()[0]), 0x76);
  // Errors keep their codes.
  req.set_dataset("nope");
  EXPECT_EQ(conn_->Render(req).status().code(), StatusCode::kNotFound);
  req.set_dataset("scene");
  req.clear_view();
  EXPECT_TRUE(conn_->Render(req).status().IsInvalidArgument());
  auto stats = conn_->Stats();
  ASSERT_TRUE(stats.ok());
  bool counted = false;
  for (const auto& l : stats->requests()) counted |= l.kind() == "render" && l.count() >= 2;
  EXPECT_TRUE(counted);
}

TEST_F(RenderServerTest, StreamsASequence) {
  Start();
  wire::Render req;
  req.set_dataset("scene");
  for (uint32_t f = 0; f < 3; ++f) {
    SetLookAt(req.add_path(), 96, 72);
    req.add_frames(f);
  }
  req.set_renderer(wire::RENDERER_CPU);
  std::vector<uint32_t> seen;
  Status st = conn_->RenderSequence(req, [&](const wire::RenderReply& r) {
    seen.push_back(r.index());
    EXPECT_EQ(r.last(), r.index() == 2);
    render::Srgb8Image img = Decode(r.png());
    size_t centre = (size_t{img.height / 2} * img.width + img.width / 2) * img.channels;
    EXPECT_GT(img.data[centre + r.index()], 150) << "frame " << r.index() << " colour";
    return Status::OK();
  });
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(seen, (std::vector<uint32_t>{0, 1, 2}));
  // Progressive: a preview, then the image; the choice of renderer is explained.
  wire::Render single;
  single.set_dataset("scene");
  *single.mutable_region() = FrameRegion(1);
  SetLookAt(single.mutable_view());
  single.set_progressive(true);
  EXPECT_TRUE(conn_->Render(single).status().IsInvalidArgument());
  std::vector<bool> previews;
  st = conn_->RenderSequence(single, [&](const wire::RenderReply& r) {
    previews.push_back(r.preview());
    EXPECT_EQ(r.last(), !r.preview());
    EXPECT_NE(r.renderer_choice().find("render service: "), std::string::npos)
        << r.renderer_choice();
    return Status::OK();
  });
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(previews, (std::vector<bool>{true, false}));
  // Stopping early cancels the rest.
  int calls = 0;
  st = conn_->RenderSequence(req, [&](const wire::RenderReply&) {
    ++calls;
    return Status::Cancelled("enough");
  });
  EXPECT_EQ(st.message(), "enough");
  EXPECT_EQ(calls, 1);
  EXPECT_TRUE(conn_->Ping().ok());  // the connection is still in step
}

TEST_F(RenderServerTest, RefusesRendersBeyondTheLimit) {
  Start({"--max-renders", "1"});
  wire::Request big;
  auto* r = big.mutable_render();
  r->set_dataset("scene");
  *r->mutable_region() = FrameRegion(0);
  SetLookAt(r->mutable_view(), 2048, 2048);
  r->set_renderer(wire::RENDERER_CPU);
  wire::Request small = big;
  small.mutable_render()->clear_view();
  SetLookAt(small.mutable_render()->mutable_view(), 16, 16);
  // Pipelined: the second arrives while the first holds the only slot.
  auto id1 = conn_->Send(&big);
  auto id2 = conn_->Send(&small);
  ASSERT_TRUE(id1.ok() && id2.ok());
  auto second = conn_->Receive(*id2);
  ASSERT_TRUE(second.ok());
  ASSERT_TRUE(second->has_error());
  EXPECT_EQ(second->error().code(), wire::OVERLOADED);
  auto first = conn_->Receive(*id1);
  ASSERT_TRUE(first.ok());
  EXPECT_TRUE(first->has_render()) << first->DebugString().substr(0, 200);
  // The slot is free again.
  auto again = conn_->Render(small.render());
  EXPECT_TRUE(again.ok()) << again.status().ToString();
}

}  // namespace
}  // namespace hvdb
