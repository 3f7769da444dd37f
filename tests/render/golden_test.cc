// Golden images: small scenes rendered by both renderers and compared, with a tolerance, with
// PNGs stored under tests/render/golden/. On a mismatch the actual image and an amplified diff
// are written to the build directory (HVDB_RENDER_TEST_OUT). To (re)create the goldens after
// an intended change: HVDB_UPDATE_GOLDENS=1 build/tests/render_tests --gtest_filter='Golden*'
// and look at them before committing.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>

#include "formats/image_io.h"
#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

struct GoldenCase {
  std::string name;
  std::vector<Point> points;
  Camera camera;
  RenderOptions options;
};

std::vector<GoldenCase> Cases() {
  std::vector<GoldenCase> cases;
  auto sphere = testing::SphereScene(4000);
  auto planes = testing::PlanesScene(0.002f);
  std::vector<SourceCamera> sources;
  for (int i = 1; i <= 4; ++i) {
    Camera c = testing::ViewFrom(std::cos(i * 1.5708), 0.3, std::sin(i * 1.5708), 3, 10, 10);
    sources.push_back({static_cast<uint16_t>(i), c.world_from_camera});
  }
  Camera a = testing::ViewFrom(0.3, 0.4, 1, 3.5, 160, 120);
  Camera b = testing::ViewFrom(0.5, 0.2, 1, 3.2, 160, 120);
  RenderOptions o;
  cases.push_back({"sphere_visibility", sphere, a, o});
  o.mode = Mode::kProbabilistic;
  cases.push_back({"sphere_probabilistic", sphere, a, o});
  o = {};
  o.view_dependent = true;
  o.source_cameras = sources;
  cases.push_back(
      {"sphere_view_dependent", sphere, testing::ViewFrom(1, 0.3, 0.2, 3.5, 160, 120), o});
  o = {};
  o.background = {0.1f, 0.1f, 0.15f, 1};
  cases.push_back({"planes_visibility", planes, b, o});
  o.mode = Mode::kProbabilistic;
  cases.push_back({"planes_probabilistic", planes, b, o});
  o = {};
  o.splat_scale = 2;  // level of detail 2, on a quarter of the points
  std::vector<Point> quarter;
  for (size_t i = 0; i < sphere.size(); i += 4) quarter.push_back(sphere[i]);
  cases.push_back({"sphere_lod2", quarter, a, o});
  return cases;
}

// Passes when PSNR >= 40 dB and at most 0.5 % of the pixels differ by more than 8 levels.
void Compare(const Srgb8Image& actual, const std::string& name, const std::string& who) {
  const std::string golden_path = std::string(HVDB_RENDER_GOLDEN_DIR) + "/" + name + ".png";
  const char* update = std::getenv("HVDB_UPDATE_GOLDENS");
  if (update != nullptr && *update == '1' && who == "cpu") {
    ASSERT_TRUE(WriteSrgb8Png(actual, golden_path).ok());
    std::printf("wrote %s\n", golden_path.c_str());
    return;
  }
  auto golden = formats::ReadSrgb8(golden_path);
  ASSERT_TRUE(golden.ok()) << golden.status().ToString()
                           << " (create the goldens with HVDB_UPDATE_GOLDENS=1)";
  ASSERT_EQ(golden->width, actual.width);
  ASSERT_EQ(golden->height, actual.height);
  double psnr = Psnr(actual, *golden);
  size_t off = 0;
  const size_t n = size_t{actual.width} * actual.height;
  for (size_t i = 0; i < n; ++i) {
    for (uint32_t c = 0; c < 3; ++c) {
      if (std::abs(int(actual.data[i * actual.channels + c]) -
                   int(golden->data[i * golden->channels + c])) > 8) {
        ++off;
        break;
      }
    }
  }
  bool ok = psnr >= 40 && off <= n / 200;
  EXPECT_TRUE(ok) << name << " (" << who << "): PSNR " << psnr << " dB, " << off
                  << " pixels off by more than 8; see " << HVDB_RENDER_TEST_OUT;
  if (!ok) {
    std::filesystem::create_directories(HVDB_RENDER_TEST_OUT);
    std::string base = std::string(HVDB_RENDER_TEST_OUT) + "/" + name + "." + who;
    EXPECT_TRUE(WriteSrgb8Png(actual, base + ".actual.png").ok());
    EXPECT_TRUE(WriteSrgb8Png(AbsDiff(actual, *golden, 8), base + ".diff.png").ok());
  }
}

TEST(GoldenTest, CpuRendererMatchesGoldens) {
  auto r = MakeCpuRenderer();
  for (const GoldenCase& c : Cases()) {
    auto img = r->Render(c.points, c.camera, c.options);
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    Compare(ToSrgb8(*img), c.name, "cpu");
  }
}

TEST(GoldenTest, EglRendererMatchesGoldens) {
  auto r = MakeEglRenderer();
  ASSERT_TRUE(r.ok()) << "no EGL context: " << r.status().ToString();
  for (const GoldenCase& c : Cases()) {
    auto img = (*r)->Render(c.points, c.camera, c.options);
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    Compare(ToSrgb8(*img), c.name, "egl");
  }
}

TEST(GoldenTest, MismatchWritesADiff) {
  // The comparison itself: a changed image fails and leaves actual + diff PNGs behind.
  auto r = MakeCpuRenderer();
  GoldenCase c = Cases()[0];
  c.options.background = {1, 0, 1, 1};  // magenta instead of black
  auto img = r->Render(c.points, c.camera, c.options);
  ASSERT_TRUE(img.ok());
  auto golden = formats::ReadSrgb8(std::string(HVDB_RENDER_GOLDEN_DIR) + "/" + c.name + ".png");
  ASSERT_TRUE(golden.ok()) << "golden image missing: create it with HVDB_UPDATE_GOLDENS=1";
  Srgb8Image actual = ToSrgb8(*img);
  EXPECT_LT(Psnr(actual, *golden), 20);
  std::filesystem::create_directories(HVDB_RENDER_TEST_OUT);
  std::string path = std::string(HVDB_RENDER_TEST_OUT) + "/selftest.diff.png";
  ASSERT_TRUE(WriteSrgb8Png(AbsDiff(actual, *golden, 8), path).ok());
  auto back = formats::ReadSrgb8(path);
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->width, actual.width);
}

}  // namespace
}  // namespace hvdb::render
