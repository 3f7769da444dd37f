// The EGL renderer against the CPU reference: the same algorithm, so the same images (PSNR
// >= 35 dB, all modes), plus the factory's fallback to the CPU renderer.
#include <gtest/gtest.h>

#include <cstdlib>

#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

constexpr double kMinPsnr = 35.0;

class EglRendererTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto r = MakeEglRenderer();
    if (r.ok()) {
      egl_ = std::move(r).value().release();
    } else {
      why_ = r.status().ToString();
    }
  }
  static void TearDownTestSuite() {
    delete egl_;
    egl_ = nullptr;
  }
  void SetUp() override {
    // scripts/setup.sh installs Mesa's EGL: a missing context is a broken install, not a skip.
    ASSERT_NE(egl_, nullptr) << "no EGL context on this machine: " << why_;
  }

  // Renders with both and compares the 8-bit images (and coverage).
  void ExpectAgreement(const std::vector<Point>& pts, const Camera& cam, const RenderOptions& o,
                       const std::string& what) {
    auto cpu = MakeCpuRenderer();
    auto a = cpu->Render(pts, cam, o);
    auto b = egl_->Render(pts, cam, o);
    ASSERT_TRUE(a.ok()) << a.status().ToString();
    ASSERT_TRUE(b.ok()) << b.status().ToString();
    ASSERT_EQ(a->width, b->width);
    ASSERT_EQ(a->height, b->height);
    Srgb8Image sa = ToSrgb8(*a), sb = ToSrgb8(*b);
    double psnr = Psnr(sa, sb);
    EXPECT_GE(psnr, kMinPsnr) << what;
    size_t covered_a = 0, covered_b = 0, depth_off = 0;
    for (size_t i = 0; i < a->pixels(); ++i) {
      covered_a += a->coverage[i] > 0.5f;
      covered_b += b->coverage[i] > 0.5f;
      if (std::isfinite(a->depth[i]) != std::isfinite(b->depth[i]) ||
          (std::isfinite(a->depth[i]) && std::abs(a->depth[i] - b->depth[i]) > 1e-3f)) {
        ++depth_off;
      }
    }
    EXPECT_NEAR(static_cast<double>(covered_a), static_cast<double>(covered_b),
                0.002 * a->pixels() + 2)
        << what;
    EXPECT_LE(depth_off, a->pixels() / 500 + 2) << what;
    EXPECT_GT(covered_a, a->pixels() / 20) << what << ": the scene should fill the view";
    std::printf("%-40s PSNR(cpu, egl) = %.1f dB\n", what.c_str(), psnr);
  }

  static Renderer* egl_;
  static std::string why_;
};
Renderer* EglRendererTest::egl_ = nullptr;
std::string EglRendererTest::why_;

std::vector<SourceCamera> FourSourceCameras() {
  std::vector<SourceCamera> s;
  for (int i = 1; i <= 4; ++i) {
    Camera c = testing::ViewFrom(std::cos(i * 1.5708), 0.3, std::sin(i * 1.5708), 3, 10, 10);
    s.push_back({static_cast<uint16_t>(i), c.world_from_camera});
  }
  return s;
}

TEST_F(EglRendererTest, AgreesWithCpuInEveryMode) {
  auto sphere = testing::SphereScene(6000);
  auto planes = testing::PlanesScene(0.003f);
  Camera a = testing::ViewFrom(0.3, 0.4, 1, 3.5, 240, 180);
  Camera b = testing::ViewFrom(0.5, 0.2, 1, 3.2, 240, 180);
  for (Mode mode : {Mode::kVisibility, Mode::kProbabilistic}) {
    for (bool vd : {false, true}) {
      RenderOptions o;
      o.mode = mode;
      o.view_dependent = vd;
      o.source_cameras = FourSourceCameras();
      std::string name = std::string(mode == Mode::kVisibility ? "visibility" : "probabilistic") +
                         (vd ? " + view-dependent" : "");
      ExpectAgreement(sphere, a, o, "sphere, " + name);
      ExpectAgreement(planes, b, o, "planes, " + name);
    }
  }
}

TEST_F(EglRendererTest, AgreesWithDistortionLodAndBackground) {
  auto sphere = testing::SphereScene(6000);
  Camera cam = testing::ViewFrom(-0.2, 0.3, 1, 3.0, 320, 180, 60);
  cam.distortion = {0.05, -0.06, 0.0007, -0.0005, 0.017};
  RenderOptions o;
  o.background = {0.2f, 0.3f, 0.4f, 1};
  o.splat_scale = 2;  // level of detail 2
  ExpectAgreement(sphere, cam, o, "distorted, lod 2, background");
  o.mode = Mode::kProbabilistic;
  o.background = {0, 0, 0, 0};
  o.width = 160;
  o.height = 90;
  ExpectAgreement(sphere, cam, o, "probabilistic, resized, transparent");
}

TEST_F(EglRendererTest, DepthOnlyAgreesWithItsFullRenderAndTheCpu) {
  auto sphere = testing::SphereScene(6000);
  Camera cam = testing::ViewFrom(0.3, 0.4, 1, 3.5, 240, 180);
  auto cpu = MakeCpuRenderer();
  for (Mode mode : {Mode::kVisibility, Mode::kProbabilistic}) {
    RenderOptions o;
    o.mode = mode;
    auto full = egl_->Render(sphere, cam, o);
    o.depth_only = true;
    auto depth = egl_->Render(sphere, cam, o);
    auto reference = cpu->Render(sphere, cam, o);
    ASSERT_TRUE(full.ok() && depth.ok() && reference.ok());
    EXPECT_TRUE(depth->rgba.empty());
    EXPECT_TRUE(depth->coverage.empty());
    ASSERT_EQ(depth->depth.size(), full->depth.size());
    size_t off_full = 0, off_cpu = 0, finite = 0;
    for (size_t i = 0; i < depth->pixels(); ++i) {
      const float z = depth->depth[i];
      finite += std::isfinite(z);
      off_full += !(z == full->depth[i]);  // (inf == inf)
      off_cpu += std::isfinite(z) != std::isfinite(reference->depth[i]) ||
                 (std::isfinite(z) && std::abs(z - reference->depth[i]) > 1e-3f);
    }
    EXPECT_GT(finite, depth->pixels() / 10);
    EXPECT_EQ(off_full, 0u);
    EXPECT_LE(off_cpu, depth->pixels() / 500 + 2);
  }
}

TEST_F(EglRendererTest, RendersLargeAndRepeatedly) {
  // Different sizes one after the other reuse the context; more points than one upload chunk
  // would need a big scene, so check many small renders and a big image instead.
  auto sphere = testing::SphereScene(2000);
  for (uint32_t w : {64u, 1024u, 97u}) {
    Camera cam = testing::ViewFrom(0, 0, 1, 3, w, w * 3 / 4);
    auto img = egl_->Render(sphere, cam, {});
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    EXPECT_EQ(img->width, w);
  }
  EXPECT_EQ(egl_->kind(), RendererKind::kEgl);
  EXPECT_NE(egl_->name().find("egl"), std::string::npos);
  EXPECT_EQ(egl_->last_stats().points, 2000u);
  EXPECT_TRUE(egl_->Render(sphere, testing::ViewFrom(0, 0, 1, 3, 5000, 10), {})
                  .status()
                  .IsInvalidArgument());
}

TEST(RendererFactoryTest, FallsBackToCpuWithAWarning) {
  std::vector<std::string> warnings;
  SetLogHandler([&](const std::string& m) { warnings.push_back(m); });
  ::setenv("HVDB_RENDER_NO_EGL", "1", 1);
  auto r = MakeRenderer(RendererKind::kAuto);
  auto strict = MakeRenderer(RendererKind::kEgl);
  ::unsetenv("HVDB_RENDER_NO_EGL");
  SetLogHandler(nullptr);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ((*r)->kind(), RendererKind::kCpu);
  ASSERT_EQ(warnings.size(), 1u);
  EXPECT_NE(warnings[0].find("CPU renderer"), std::string::npos);
  EXPECT_NE(warnings[0].find("HVDB_RENDER_NO_EGL"), std::string::npos);
  EXPECT_EQ(strict.status().code(), StatusCode::kUnsupported);
  auto cpu = MakeRenderer(RendererKind::kCpu);
  ASSERT_TRUE(cpu.ok());
  EXPECT_EQ((*cpu)->kind(), RendererKind::kCpu);
}

// A renderer that only says what it is: ChooseAuto's input where no GPU is at hand.
class FakeRenderer final : public Renderer {
 public:
  explicit FakeRenderer(bool hardware) : hardware_(hardware) {}
  RendererKind kind() const override { return RendererKind::kEgl; }
  std::string name() const override { return hardware_ ? "egl: NVIDIA H100" : "egl: llvmpipe"; }
  Result<Image> Render(std::span<const Point>, const Camera&, const RenderOptions&) override {
    return Status::Unsupported("fake");
  }
  RenderStats last_stats() const override { return {}; }
  bool hardware() const override { return hardware_; }

 private:
  bool hardware_;
};

TEST(RendererFactoryTest, AutoTakesAGpuAndPassesOverASoftwareRasteriser) {
  std::vector<std::string> notes;
  SetLogHandler([&](const std::string& m) { notes.push_back(m); });
  std::string why;
  auto gpu = std::make_unique<FakeRenderer>(true);
  Renderer* gpu_ptr = gpu.get();
  auto chosen = ChooseAuto(std::move(gpu), &why);
  EXPECT_EQ(chosen.get(), gpu_ptr);
  EXPECT_NE(why.find("GPU"), std::string::npos) << why;
  auto soft = ChooseAuto(std::make_unique<FakeRenderer>(false), &why);
  SetLogHandler(nullptr);
  EXPECT_EQ(soft->kind(), RendererKind::kCpu);
  EXPECT_NE(why.find("software rasteriser"), std::string::npos) << why;
  EXPECT_NE(why.find("llvmpipe"), std::string::npos) << why;
  ASSERT_EQ(notes.size(), 1u);  // the choice is logged
  EXPECT_EQ(notes[0].rfind("note: ", 0), 0u) << notes[0];

  EXPECT_TRUE(IsSoftwareRasteriser("llvmpipe (LLVM 15.0.6, 256 bits)"));
  EXPECT_TRUE(IsSoftwareRasteriser("softpipe"));
  EXPECT_TRUE(IsSoftwareRasteriser("Software Rasterizer"));
  EXPECT_FALSE(IsSoftwareRasteriser("NVIDIA H100 80GB HBM3/PCIe/SSE2"));
  EXPECT_FALSE(IsSoftwareRasteriser("Mesa Intel(R) UHD Graphics 620 (KBL GT2)"));
  EXPECT_FALSE(IsSoftwareRasteriser("AMD Radeon RX 6800 (navi21, LLVM 15.0.6, DRM 3.49)"));
}

TEST(RendererFactoryTest, AutoOnThisMachineSaysWhichAndWhy) {
  // Whatever this machine has, auto's choice follows it and says why: a GPU gives EGL, a
  // software rasteriser (Mesa's llvmpipe on CI) or no EGL at all gives the CPU renderer.
  auto egl = MakeEglRenderer();
  SetLogHandler([](const std::string&) {});
  std::string why;
  auto r = MakeRenderer(RendererKind::kAuto, &why);
  SetLogHandler(nullptr);
  ASSERT_TRUE(r.ok());
  if (!egl.ok()) {
    EXPECT_EQ((*r)->kind(), RendererKind::kCpu);
    EXPECT_EQ(why.rfind("no EGL context", 0), 0u) << why;
  } else if ((*egl)->hardware()) {
    EXPECT_EQ((*r)->kind(), RendererKind::kEgl);
    EXPECT_NE(why.find("GPU"), std::string::npos) << why;
  } else {
    EXPECT_EQ((*r)->kind(), RendererKind::kCpu);
    EXPECT_NE(why.find("software rasteriser"), std::string::npos) << why;
  }
  std::printf("auto: %s -> %s\n", why.c_str(), (*r)->name().c_str());
}

}  // namespace
}  // namespace hvdb::render
