// Video export (render/video_encoder.h) and shadows through render jobs: the encoder's files
// decode (with libavformat, as a player would) to exactly the frames given at the size given;
// a Render request with format MP4/WebM streams a progress reply per image and the file in the
// last, in this process and through hvdb-server; bad requests are refused naming the field.
#include <gtest/gtest.h>

#include <fstream>

#include "client/client.h"
#include "render/job.h"
#include "render/video_encoder.h"
#include "tests/render/job_helpers.h"
#include "tests/render/video_probe.h"
#include "tests/server/server_process.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using namespace render_test;  // NOLINT: the shared scene
using render::RenderJob;
using testing::TempDir;
using testing::Decode;
using testing::Probe;

// A flat colour image.
render::Image Flat(uint32_t w, uint32_t h, float r, float g, float b) {
  render::Image img;
  img.width = w;
  img.height = h;
  img.rgba.resize(img.pixels() * 4);
  img.coverage.assign(img.pixels(), 1.f);
  img.depth.assign(img.pixels(), 1.f);
  for (size_t i = 0; i < img.pixels(); ++i) {
    img.rgba[4 * i] = r, img.rgba[4 * i + 1] = g, img.rgba[4 * i + 2] = b, img.rgba[4 * i + 3] = 1;
  }
  return img;
}

TEST(VideoEncoderTest, FilesDecodeToTheFramesGiven) {
  TempDir dir;
  for (auto [container, want_codec, want_format] :
       {std::tuple{render::VideoContainer::kMp4, "h264", "mov,mp4"},
        std::tuple{render::VideoContainer::kWebm, "vp9", "matroska,webm"}}) {
    auto enc = render::VideoEncoder::Create(container, 64, 48, 24);
    ASSERT_TRUE(enc.ok()) << enc.status().ToString();
    std::printf("%s: %s\n", render::VideoContainerName(container), (*enc)->codec().c_str());
    // 12 frames: red, green, blue, ...
    for (int i = 0; i < 12; ++i) {
      ASSERT_TRUE((*enc)->Add(Flat(64, 48, i % 3 == 0, i % 3 == 1, i % 3 == 2)).ok());
    }
    EXPECT_TRUE((*enc)->Add(Flat(32, 48, 1, 1, 1)).IsInvalidArgument());  // another size
    auto bytes = (*enc)->Finish();
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    Probe p = Decode(*bytes, dir.path());
    ASSERT_TRUE(p.error.empty()) << p.error;
    EXPECT_EQ(p.container.rfind(want_format, 0), 0u) << p.container;
    EXPECT_EQ(p.codec.find(want_codec) != std::string::npos || p.codec == "libvpx-vp9", true)
        << p.codec;
    EXPECT_EQ(p.frames, 12);
    EXPECT_EQ(p.width, 64);
    EXPECT_EQ(p.height, 48);
    EXPECT_NEAR(p.fps, 24, 0.01);
    for (int i = 0; i < p.frames; ++i) {
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(p.centre_rgb[size_t(i)][size_t(c)], c == i % 3 ? 255 : 0, 40)
            << "frame " << i << " channel " << c;
      }
    }
  }
  EXPECT_TRUE(render::VideoEncoder::Create(render::VideoContainer::kMp4, 63, 48, 24)
                  .status()
                  .IsInvalidArgument());
  EXPECT_TRUE(render::VideoEncoder::Create(render::VideoContainer::kMp4, 64, 48, 0)
                  .status()
                  .IsInvalidArgument());
}

class VideoJobTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = Database::Open(dir_.path() + "/db");
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(db).value();
    auto ds = db_->CreateDataset(Info("scene", true));
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    ds_ = *ds;
    for (uint32_t f = 0; f < 3; ++f) ASSERT_TRUE(ds_->BulkLoad(f, FramePoints(f)).ok());
  }
  // A video of `n` views cycling through the three frames.
  wire::Render VideoRequest(int n, wire::ImageFormat format = wire::IMAGE_MP4) {
    wire::Render req;
    req.set_dataset("scene");
    req.set_renderer(wire::RENDERER_CPU);
    req.set_format(format);
    req.set_video_fps(10);
    for (int i = 0; i < n; ++i) {
      SetLookAt(req.add_path(), 96, 72);
      req.add_frames(uint32_t(i % 3));
    }
    return req;
  }
  TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
};

TEST_F(VideoJobTest, APathBecomesOneVideoInTheLastReply) {
  for (wire::ImageFormat f : {wire::IMAGE_MP4, wire::IMAGE_WEBM}) {
    auto job = CreateJob(ds_, VideoRequest(7, f));
    ASSERT_TRUE(job.ok()) << job.status().ToString();
    ASSERT_EQ((*job)->size(), 7u);
    auto cpu = render::MakeCpuRenderer();
    std::string video;
    for (size_t i = 0; i < 7; ++i) {
      auto reply = (*job)->Render(i, *cpu);
      ASSERT_TRUE(reply.ok()) << reply.status().ToString();
      EXPECT_EQ(reply->index, i);
      EXPECT_EQ(reply->images, 7u);
      EXPECT_EQ(reply->last, i == 6);
      EXPECT_TRUE(reply->png.empty());
      EXPECT_FALSE(reply->video_codec.empty());
      EXPECT_EQ(reply->video.empty(), i != 6);
      video = reply->video;
    }
    Probe p = Decode(video, dir_.path());
    ASSERT_TRUE(p.error.empty()) << p.error;
    EXPECT_EQ(p.frames, 7);
    EXPECT_EQ(p.width, 96);
    EXPECT_EQ(p.height, 72);
    EXPECT_NEAR(p.fps, 10, 0.01);
    // Frame i shows frame i % 3: red, green, blue at the centre.
    for (int i = 0; i < p.frames; ++i) {
      const auto& c = p.centre_rgb[size_t(i)];
      const int brightest = c[0] > c[1] ? (c[0] > c[2] ? 0 : 2) : (c[1] > c[2] ? 1 : 2);
      EXPECT_EQ(brightest, i % 3) << "frame " << i;
    }
  }
}

TEST_F(VideoJobTest, BadVideoRequestsAreRefusedNamingTheField) {
  auto error = [&](const wire::Render& r) {
    auto job = CreateJob(ds_, r);
    EXPECT_FALSE(job.ok());
    return job.ok() ? std::string("ok") : job.status().ToString();
  };
  wire::Render none = VideoRequest(0);
  *none.mutable_region() = FrameRegion(0);
  EXPECT_NE(error(none).find("render.path: a video"), std::string::npos) << error(none);
  wire::Render odd = VideoRequest(2);
  odd.mutable_path(1)->mutable_look_at()->set_width(95);
  EXPECT_NE(error(odd).find("render.path[1]"), std::string::npos) << error(odd);
  wire::Render oddsize = VideoRequest(2);
  oddsize.set_width(95);
  oddsize.set_height(72);
  EXPECT_NE(error(oddsize).find("even width and height"), std::string::npos) << error(oddsize);
  wire::Render fps = VideoRequest(2);
  fps.set_video_fps(-1);
  EXPECT_NE(error(fps).find("render.video_fps"), std::string::npos) << error(fps);
  wire::Render png = VideoRequest(2, wire::IMAGE_PNG);
  EXPECT_NE(error(png).find("render.video_fps"), std::string::npos) << error(png);
}

TEST_F(VideoJobTest, ShadowFieldsReachTheRender) {
  // The upper half of frame 0 casts, from a lamp above the sphere (y up here).
  Selection upper;
  Window w;
  w.lo = {-1e9, 0.5, -1e9, 0};
  w.hi = {1e9, 1e9, 1e9, 0};
  upper.region = w;
  Transaction t;
  t.SetLabel(upper, 1u << 4, true);
  ASSERT_TRUE(ds_->Commit(t).ok());
  wire::Render req;
  req.set_dataset("scene");
  *req.mutable_region() = FrameRegion(0);
  SetLookAt(req.mutable_view());
  req.set_renderer(wire::RENDERER_CPU);
  auto cpu = render::MakeCpuRenderer();
  auto plain = (*CreateJob(ds_, req))->RenderImage(0, *cpu);
  ASSERT_TRUE(plain.ok());
  for (double v : {0.0, 3.0, 0.0}) req.add_shadow_light(v);
  req.set_shadow_casters(4);
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  auto lit = (*job)->RenderImage(0, *cpu);
  ASSERT_TRUE(lit.ok()) << lit.status().ToString();
  size_t darker = 0, brighter = 0;
  for (size_t i = 0; i < plain->pixels(); ++i) {
    darker += lit->rgba[4 * i] < plain->rgba[4 * i];
    brighter += lit->rgba[4 * i] > plain->rgba[4 * i];
  }
  EXPECT_GT(darker, 50u);  // the sphere's lower half, under its lit cap
  EXPECT_EQ(brighter, 0u);
  // Errors name the field.
  auto error = [&](const wire::Render& r) {
    auto j = CreateJob(ds_, r);
    return j.ok() ? std::string("ok") : j.status().ToString();
  };
  wire::Render bad = req;
  bad.set_shadow_casters(32);
  EXPECT_NE(error(bad).find("render.shadow_casters"), std::string::npos) << error(bad);
  bad = req;
  bad.set_shadow_strength(2);
  EXPECT_NE(error(bad).find("render.shadow_strength"), std::string::npos) << error(bad);
  bad = req;
  bad.clear_shadow_light();
  bad.add_shadow_light(1);
  EXPECT_NE(error(bad).find("render.shadow_light"), std::string::npos) << error(bad);
  bad.clear_shadow_light();
  EXPECT_NE(error(bad).find("render.shadow_light"), std::string::npos) << error(bad);
  // A lamp inside the casters: refused when the casters are known, at render time.
  bad = req;
  bad.set_shadow_light(1, 0.8);
  auto inside = CreateJob(ds_, bad);
  ASSERT_TRUE(inside.ok());
  auto img = (*inside)->RenderImage(0, *cpu);
  EXPECT_TRUE(img.status().IsInvalidArgument());
  EXPECT_NE(img.status().message().find("render.shadow_light"), std::string::npos);
}

TEST(VideoServerTest, TheServerStreamsProgressThenTheFile) {
  TempDir dir;
  testing::ServerProcess server(dir.path() + "/data", {});
  ASSERT_TRUE(server.running());
  client::Options o;
  o.port = server.port();
  o.request_timeout = std::chrono::milliseconds(60000);
  auto conn = client::Connection::Connect(o);
  ASSERT_TRUE(conn.ok()) << conn.status().ToString();
  ASSERT_TRUE((*conn)->CreateDataset(Info("scene", true)).ok());
  for (uint32_t f = 0; f < 3; ++f) ASSERT_TRUE((*conn)->Ingest("scene", f, FramePoints(f)).ok());
  wire::Render req;
  req.set_dataset("scene");
  req.set_renderer(wire::RENDERER_CPU);
  req.set_format(wire::IMAGE_WEBM);
  for (uint32_t i = 0; i < 5; ++i) {
    SetLookAt(req.add_path(), 96, 72);
    req.add_frames(i % 3);
  }
  std::vector<uint32_t> seen;
  std::string video;
  Status st = (*conn)->RenderSequence(req, [&](const wire::RenderReply& r) {
    seen.push_back(r.index());
    if (r.last()) video = r.video();
    return Status::OK();
  });
  ASSERT_TRUE(st.ok()) << st.ToString();
  EXPECT_EQ(seen, (std::vector<uint32_t>{0, 1, 2, 3, 4}));
  Probe p = Decode(video, dir.path());
  EXPECT_EQ(p.frames, 5);
  EXPECT_EQ(p.width, 96);
  EXPECT_NEAR(p.fps, 30, 0.01);  // video_fps 0: 30
  req.clear_path();
  req.clear_frames();
  EXPECT_TRUE((*conn)->RenderSequence(req, [](const wire::RenderReply&) { return Status::OK(); })
                  .IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb
