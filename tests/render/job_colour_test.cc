// The render job's default colour (render/job.h, RenderJob::Colour): a frame with photos is
// drawn textured unless the request asks otherwise, and every reply says what drew it.
#include <gtest/gtest.h>

#include "formats/image_io.h"
#include "media/media.h"
#include "render/job.h"
#include "render/metrics.h"
#include "tests/render/job_helpers.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using render::RenderJob;
using namespace render_test;  // FramePoints, Info, FrameRegion, SetLookAt

// Frame 0 of the sphere with a photo from each of the dataset's four cameras; frame 1 without
// photos. The photos show a pattern the points' (uniform) colour lacks: stripes across the
// sphere, so that a textured view is told apart from the points' at a glance.
class RenderColourTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto db = Database::Open(dir_.path());
    ASSERT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(db).value();
    const DatasetInfo info = Info("scene", true);
    auto ds = db_->CreateDataset(info);
    ASSERT_TRUE(ds.ok()) << ds.status().ToString();
    ds_ = *ds;
    for (uint32_t f = 0; f < 2; ++f) ASSERT_TRUE(ds_->BulkLoad(f, FramePoints(f)).ok());
    std::vector<Point> striped = FramePoints(0);
    for (Point& p : striped) {
      const bool light = static_cast<int>(std::floor(p.y * 8)) % 2 == 0;
      p.r = light ? 240 : 30;
      p.g = light ? 240 : 30;
      p.b = light ? 60 : 200;
    }
    auto cpu = render::MakeCpuRenderer();
    for (const CameraInfo& c : info.cameras) {
      auto seen = cpu->Render(striped, render::CameraFromInfo(c), {});
      ASSERT_TRUE(seen.ok()) << seen.status().ToString();
      auto png = formats::EncodePng(*seen);
      ASSERT_TRUE(png.ok());
      Photo photo;
      photo.camera = c;
      photo.image = *png;
      ASSERT_TRUE(ds_->PutPhoto(0, photo).ok());
    }
  }

  wire::Render Request(uint32_t frame) const {
    wire::Render req;
    req.set_dataset("scene");
    *req.mutable_region() = FrameRegion(frame);
    SetLookAt(req.mutable_view());
    req.set_renderer(wire::RENDERER_CPU);
    return req;
  }

  // The request's one image and its reply.
  std::pair<formats::Srgb8Image, render::RenderReply> Draw(const wire::Render& req) {
    auto job = CreateJob(ds_, req);
    EXPECT_TRUE(job.ok()) << job.status().ToString();
    if (!job.ok()) return {};
    auto reply = (*job)->Render(0, *cpu_);
    EXPECT_TRUE(reply.ok()) << reply.status().ToString();
    if (!reply.ok()) return {};
    auto img = (*job)->RenderImage(0, *cpu_);
    EXPECT_TRUE(img.ok());
    return {formats::ToSrgb8(*img), *reply};
  }

  testing::TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
  std::unique_ptr<render::Renderer> cpu_ = render::MakeCpuRenderer();
};

TEST_F(RenderColourTest, ADefaultRenderOfAFrameWithPhotosIsTheTexturedPicture) {
  auto [by_default, reply] = Draw(Request(0));
  wire::Render textured_req = Request(0);
  textured_req.set_texture(true);
  auto [textured, textured_reply] = Draw(textured_req);
  wire::Render points_req = Request(0);
  points_req.set_mode(wire::RENDER_VISIBILITY);
  auto [points, points_reply] = Draw(points_req);

  EXPECT_EQ(reply.mode_used, "textured");
  EXPECT_EQ(reply.mode_choice, "auto: 4 photos of frame 0");
  EXPECT_EQ(textured_reply.mode_used, "textured");
  EXPECT_EQ(textured_reply.mode_choice, "asked for");
  EXPECT_EQ(points_reply.mode_used, "visibility");
  EXPECT_EQ(points_reply.mode_choice, "asked for");
  ASSERT_EQ(by_default.data.size(), textured.data.size());
  EXPECT_EQ(by_default.data, textured.data);  // the same job, the same image, bit for bit
  EXPECT_EQ(reply.png, textured_reply.png);
  // And not the points' picture: the stripes come from the photos.
  EXPECT_LT(render::Psnr(by_default, points), 25);

  // texture: false asks for the points as explicitly as a mode does.
  wire::Render untextured = Request(0);
  untextured.set_texture(false);
  auto [plain, plain_reply] = Draw(untextured);
  EXPECT_EQ(plain_reply.mode_used, "visibility");
  EXPECT_EQ(plain.data, points.data);
  // An explicit probabilistic mode draws the points in it.
  wire::Render prob = Request(0);
  prob.set_mode(wire::RENDER_PROBABILISTIC);
  EXPECT_EQ(Draw(prob).second.mode_used, "probabilistic");
}

// Photos coded as video (Dataset::CompactPhotos, storage/photo_video.h) texture the same
// picture: the render reads them through Dataset::Photos as before, decoded.
TEST_F(RenderColourTest, PhotosCodedAsVideoTextureTheSamePicture) {
  media::InstallPhotoVideoCodec();
  wire::Render req = Request(0);
  req.set_texture(true);
  auto [before, before_reply] = Draw(req);
  auto info = ds_->CompactPhotos(0, 1);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 4u);  // one per camera
  EXPECT_GE(info->photo_min_psnr, kPhotoVideoMinPsnr);
  auto [after, after_reply] = Draw(Request(0));
  EXPECT_EQ(after_reply.mode_used, "textured");
  EXPECT_EQ(after_reply.mode_choice, "auto: 4 photos of frame 0");
  ASSERT_EQ(after.data.size(), before.data.size());
  EXPECT_GE(render::Psnr(after, before), 38) << "the textured picture moved";
}

TEST_F(RenderColourTest, AutoDrawsThePointsWhereTextureCannotHelp) {
  // A frame without photos: the points, no error.
  auto [img, reply] = Draw(Request(1));
  EXPECT_EQ(reply.mode_used, "visibility");
  EXPECT_EQ(reply.mode_choice, "auto: no photos of frame 1");
  // A sequence over the frame with photos, even of one view: the points (texture is refused
  // for a path, auto does not try it).
  wire::Render seq = Request(0);
  seq.clear_view();
  seq.clear_region();
  SetLookAt(seq.add_path());
  seq.add_frames(0);
  auto job = CreateJob(ds_, seq);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  auto r = (*job)->Render(0, *cpu_);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->mode_used, "visibility");
  EXPECT_EQ(r->mode_choice.rfind("auto: a sequence", 0), 0u) << r->mode_choice;
  // A selection overlay shows on the points' colours.
  wire::Render lit = Request(0);
  lit.set_highlight_mask(1);
  EXPECT_EQ(Draw(lit).second.mode_used, "visibility");
  // A progressive request: the preview is the points, the final image textured.
  wire::Render prog = Request(0);
  prog.set_progressive(true);
  auto pj = CreateJob(ds_, prog);
  ASSERT_TRUE(pj.ok());
  ASSERT_EQ((*pj)->size(), 2u);
  EXPECT_EQ((*pj)->Render(0, *cpu_)->mode_used, "visibility");
  EXPECT_EQ((*pj)->Render(1, *cpu_)->mode_used, "textured");
  // Asked for, texture on a frame without photos stays an error naming the field.
  wire::Render missing = Request(1);
  missing.set_texture(true);
  auto mj = CreateJob(ds_, missing);
  ASSERT_TRUE(mj.ok());
  auto bad = (*mj)->Render(0, *cpu_);
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(bad.status().IsNotFound());
  EXPECT_EQ(bad.status().message().rfind("render.texture:", 0), 0u) << bad.status().message();
}

TEST_F(RenderColourTest, ADamagedStoredPhotoFailsTheTexturedRenderEveryTimeNamingIt) {
  // Storage takes any bytes (hvdb-server's PutPhoto checks them first): a photo damaged on
  // disk fails the textured render with Corruption naming the camera and frame, on every try
  // of the same job (no half-made texture is kept), and the points still draw.
  const CameraInfo camera = Info("scene", true).cameras[1];
  Photo damaged;
  damaged.camera = camera;
  damaged.image = "\x89PNG\r\n\x1a\n but not a picture";
  ASSERT_TRUE(ds_->PutPhoto(0, damaged).ok());
  wire::Render req = Request(0);
  req.set_texture(true);
  auto job = CreateJob(ds_, req);
  ASSERT_TRUE(job.ok());
  const std::string named = "render.texture: the photo of camera " + std::to_string(camera.id) +
                            " of frame 0";
  for (int attempt = 0; attempt < 2; ++attempt) {
    auto bad = (*job)->Render(0, *cpu_);
    ASSERT_FALSE(bad.ok()) << attempt;
    EXPECT_TRUE(bad.status().IsCorruption()) << bad.status().ToString();
    EXPECT_NE(bad.status().message().find(named), std::string::npos) << bad.status().message();
  }
  wire::Render points = Request(0);
  points.set_mode(wire::RENDER_VISIBILITY);
  EXPECT_EQ(Draw(points).second.mode_used, "visibility");
}

}  // namespace
}  // namespace hvdb
