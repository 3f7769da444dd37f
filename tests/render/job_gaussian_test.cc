// Render jobs in gaussian mode (render/job.h): a Gaussian-splat dataset is drawn by the 3DGS
// rasteriser by default, its PNG is the rasteriser's image clamped and rounded to 8 bits, a
// plain dataset draws its derived Gaussians when asked, the selection overlay and the
// background apply, and the options gaussian mode cannot honour are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <random>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "formats/gaussian_points.h"
#include "render/gaussian_raster.h"
#include "render/job.h"
#include "storage/database.h"

namespace hvdb::render {
namespace {

namespace fs = std::filesystem;

formats::GaussianCloud Cloud(uint64_t seed, size_t n) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0.f, 1.f);
  formats::GaussianCloud c;
  c.sh_degree = 3;
  c.Resize(n);
  for (float& v : c.position) v = 0.5f * g(rng);
  for (float& v : c.scale) v = -3.5f + 0.4f * g(rng);
  for (float& v : c.rotation) v = g(rng);
  for (float& v : c.opacity) v = 1 + g(rng);
  for (float& v : c.sh_dc) v = g(rng);
  for (float& v : c.sh_rest) v = 0.15f * g(rng);
  return c;
}

class GaussianJobTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_gauss_job_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
    auto db = Database::Open(dir_);
    ASSERT_TRUE(db.ok());
    db_ = std::move(db).value();
    cloud_ = Cloud(7, 4000);
    DatasetInfo info;
    info.name = "splats";
    info.fps = 10;
    info.gaussians = true;
    auto ds = db_->CreateDataset(info);
    ASSERT_TRUE(ds.ok());
    splats_ = *ds;
    std::vector<Point> pts;
    GaussianColumns recs;
    formats::CloudToPoints(cloud_, 0, &pts, &recs);
    ASSERT_TRUE(splats_->BulkLoadGaussians(0, pts, recs).ok());
    info.name = "plain";
    info.gaussians = false;
    auto plain = db_->CreateDataset(info);
    ASSERT_TRUE(plain.ok());
    plain_ = *plain;
    for (Point& p : pts) p.id = 0;
    ASSERT_TRUE(plain_->BulkLoad(0, pts).ok());
  }
  void TearDown() override {
    splats_.reset();
    plain_.reset();
    db_.reset();
    fs::remove_all(dir_);
  }
  static Camera View() { return Camera::LookAt({0.3, -0.2, -3}, {0, 0, 0}, {0, -1, 0}, 50, 200, 150); }
  static RenderRequest Request(const std::string& dataset) {
    RenderRequest r;
    r.dataset = dataset;
    Window w;
    w.lo = {-1e9, -1e9, -1e9, 0};
    w.hi = {1e9, 1e9, 1e9, 0};
    r.region = w;
    const Camera c = View();
    CameraInfo ci;
    ci.width = c.width;
    ci.height = c.height;
    ci.fx = c.fx, ci.fy = c.fy, ci.cx = c.cx, ci.cy = c.cy;
    ci.world_from_camera = c.world_from_camera;
    r.view = ci;
    return r;
  }
  Result<RenderReply> Run(std::shared_ptr<Dataset> ds, const RenderRequest& r,
                          RendererKind kind = RendererKind::kCpu) {
    HVDB_ASSIGN_OR_RETURN(auto job, RenderJob::Create(std::move(ds), r));
    std::string why;
    HVDB_ASSIGN_OR_RETURN(auto renderer, MakeRenderer(kind, &why));
    return job->Render(0, *renderer);
  }
  static cv::Mat Png(const RenderReply& reply) {
    std::vector<uint8_t> buf(reply.png.begin(), reply.png.end());
    cv::Mat m = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
    cv::cvtColor(m, m, m.channels() == 4 ? cv::COLOR_BGRA2RGBA : cv::COLOR_BGR2RGB);
    return m;
  }
  std::string dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> splats_, plain_;
  formats::GaussianCloud cloud_;
};

TEST_F(GaussianJobTest, AGaussianDatasetRendersAsTheRasteriserDraws) {
  auto reply = Run(splats_, Request("splats"));
  ASSERT_TRUE(reply.ok()) << reply.status().ToString();
  EXPECT_EQ(reply->mode_used, "gaussian");
  EXPECT_NE(reply->mode_choice.find("auto"), std::string::npos);
  EXPECT_NE(reply->renderer_used.find("3DGS"), std::string::npos);
  EXPECT_EQ(reply->points, cloud_.size());
  GaussianImage want;
  ASSERT_TRUE(RenderGaussians(cloud_, View(), {}, &want).ok());
  const std::vector<uint8_t> rgba = want.ToRgba8();
  cv::Mat got = Png(*reply);
  ASSERT_EQ(got.channels(), 3);  // opaque black behind: RGB
  ASSERT_EQ(got.cols, 200);
  int worst = 0, lit = 0;
  for (int y = 0; y < got.rows; ++y) {
    for (int x = 0; x < got.cols; ++x) {
      const cv::Vec3b v = got.at<cv::Vec3b>(y, x);
      const size_t i = 4 * (static_cast<size_t>(y) * 200 + static_cast<size_t>(x));
      for (int c = 0; c < 3; ++c) worst = std::max(worst, std::abs(v[c] - rgba[i + c]));
      lit += v[0] + v[1] + v[2] > 30;
    }
  }
  EXPECT_LE(worst, 1);  // the rounding of a value linearised and encoded back
  EXPECT_GT(lit, 2000);
}

// With the EGL renderer (asked for here; auto's choice on a GPU) gaussian mode draws with the
// GPU's 3DGS rasteriser (llvmpipe here): the picture of the CPU's within a few 8-bit steps.
TEST_F(GaussianJobTest, TheEglRendererDrawsGaussianModeOnTheGpu) {
  auto reply = Run(splats_, Request("splats"), RendererKind::kEgl);
  ASSERT_TRUE(reply.ok()) << reply.status().ToString();
  EXPECT_EQ(reply->mode_used, "gaussian");
  EXPECT_EQ(reply->renderer_used.rfind("egl: ", 0), 0u) << reply->renderer_used;
  EXPECT_NE(reply->renderer_choice.find("GPU's 3DGS rasteriser"), std::string::npos)
      << reply->renderer_choice;
  auto cpu = Run(splats_, Request("splats"));
  ASSERT_TRUE(cpu.ok());
  EXPECT_EQ(cpu->renderer_used.rfind("cpu: 3DGS", 0), 0u) << cpu->renderer_used;
  cv::Mat a = Png(*reply), b = Png(*cpu);
  ASSERT_EQ(a.size(), b.size());
  cv::Mat diff;
  cv::absdiff(a, b, diff);
  double worst = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &worst);
  EXPECT_LE(worst, 4);
  EXPECT_GE(cv::PSNR(a, b), 50);
}

TEST_F(GaussianJobTest, APlainDatasetDrawsDerivedGaussiansWhenAsked) {
  auto points = Run(plain_, Request("plain"));
  ASSERT_TRUE(points.ok());
  EXPECT_EQ(points->mode_used, "visibility");
  RenderRequest r = Request("plain");
  r.mode = Mode::kGaussian;
  auto g = Run(plain_, r);
  ASSERT_TRUE(g.ok()) << g.status().ToString();
  EXPECT_EQ(g->mode_used, "gaussian");
  EXPECT_EQ(g->mode_choice, "asked for");
  EXPECT_GT(cv::sum(Png(*g))[0], 1000);
  // And a Gaussian dataset in a point mode when asked.
  r = Request("splats");
  r.mode = Mode::kVisibility;
  auto v = Run(splats_, r);
  ASSERT_TRUE(v.ok());
  EXPECT_EQ(v->mode_used, "visibility");
}

TEST_F(GaussianJobTest, BackgroundAndOverlay) {
  RenderRequest r = Request("splats");
  r.background = std::array<float, 4>{SrgbToLinear(0.2f), SrgbToLinear(0.4f), SrgbToLinear(0.6f), 1};
  auto reply = Run(splats_, r);
  ASSERT_TRUE(reply.ok());
  cv::Mat m = Png(*reply);
  const cv::Vec3b corner = m.at<cv::Vec3b>(0, 0);  // nothing there: the background
  EXPECT_NEAR(corner[0], 51, 1);
  EXPECT_NEAR(corner[1], 102, 1);
  EXPECT_NEAR(corner[2], 153, 1);

  // The overlay: every splat selected (label bit 0 set) turns toward the highlight's green.
  Transaction t;
  Selection all;
  t.SetLabel(all, 1, true);
  ASSERT_TRUE(splats_->Commit(t).ok());
  r = Request("splats");
  r.highlight_mask = 1;
  r.highlight_color = std::array<float, 4>{0, 1, 0, 1};
  reply = Run(splats_, r);
  ASSERT_TRUE(reply.ok());
  const cv::Scalar sum = cv::sum(Png(*reply));
  EXPECT_GT(sum[1], 20 * (sum[0] + sum[2]) + 1000);
}

// A sequence over frames reserves each frame's cloud in place of the last one's: within a
// budget of a few clouds it renders every image.
TEST_F(GaussianJobTest, ASequenceKeepsToItsMemoryBudget) {
  std::vector<Point> pts;
  GaussianColumns recs;
  formats::CloudToPoints(cloud_, 0, &pts, &recs);
  for (uint32_t f = 1; f < 6; ++f) ASSERT_TRUE(splats_->BulkLoadGaussians(f, pts, recs).ok());
  RenderRequest r = Request("splats");
  r.region.reset();
  for (uint32_t f = 0; f < 6; ++f) {
    r.path.push_back(*r.view);
    r.frames.push_back(f);
  }
  r.view.reset();
  JobBudget budget(12u << 20, "--memory-budget");
  RenderLimits limits;
  limits.job.memory = &budget;
  auto job = RenderJob::Create(splats_, r, limits);
  ASSERT_TRUE(job.ok()) << job.status().ToString();
  std::string why;
  auto renderer = MakeRenderer(RendererKind::kCpu, &why);
  ASSERT_TRUE(renderer.ok());
  for (size_t i = 0; i < (*job)->size(); ++i) {
    auto reply = (*job)->Render(i, **renderer);
    ASSERT_TRUE(reply.ok()) << "image " << i << ": " << reply.status().ToString();
    EXPECT_EQ(reply->mode_used, "gaussian");
  }
  EXPECT_LE(budget.used(), 12u << 20);
}

TEST_F(GaussianJobTest, OptionsGaussianModeCannotHonourAreRefused) {
  RenderRequest r = Request("splats");
  r.mode = Mode::kGaussian;
  r.texture = true;
  auto job = RenderJob::Create(splats_, r);
  ASSERT_FALSE(job.ok());
  EXPECT_NE(job.status().message().find("render.mode"), std::string::npos);
  r = Request("splats");
  r.shadow_light = std::array<double, 3>{0, -3, 0};
  job = RenderJob::Create(splats_, r);
  ASSERT_FALSE(job.ok());
  EXPECT_NE(job.status().message().find("gaussian mode has none"), std::string::npos);
}

}  // namespace
}  // namespace hvdb::render
