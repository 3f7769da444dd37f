// The tiled CPU renderer against the brute-force reference (the former band renderer, kept in
// reference_renderer.h): the same images (PSNR >= 45 dB, depth to rounding) on generated and
// random scenes, every mode, odd image sizes, lens distortion, splats larger than a tile and
// splats crossing the image border; and the same image for any thread count.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/render/reference_renderer.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

constexpr double kMinPsnr = 45.0;

struct Case {
  const char* name;
  Mode mode;
  bool view_dependent;
};
const Case kCases[] = {{"visibility", Mode::kVisibility, false},
                       {"probabilistic", Mode::kProbabilistic, false},
                       {"visibility+view_dependent", Mode::kVisibility, true},
                       {"probabilistic+view_dependent", Mode::kProbabilistic, true}};

RenderOptions OptionsFor(const Case& c) {
  RenderOptions o;
  o.mode = c.mode;
  o.view_dependent = c.view_dependent;
  for (int i = 1; i <= 4; ++i) {
    Camera s = testing::ViewFrom(std::cos(i * 1.5708), 0.3, std::sin(i * 1.5708), 3, 10, 10);
    o.source_cameras.push_back({static_cast<uint16_t>(i), s.world_from_camera});
  }
  return o;
}

// Compares both renderers' images: colour PSNR, coverage and depth per pixel.
void ExpectSame(const std::vector<Point>& pts, const Camera& cam, const RenderOptions& o,
                const std::string& what) {
  auto fast = MakeCpuRenderer(2)->Render(pts, cam, o);
  auto ref = testing::ReferenceRenderer(2).Render(pts, cam, o);
  ASSERT_TRUE(fast.ok()) << fast.status().ToString();
  ASSERT_TRUE(ref.ok()) << ref.status().ToString();
  ASSERT_EQ(fast->pixels(), ref->pixels());
  double psnr = Psnr(ToSrgb8(*fast), ToSrgb8(*ref));
  EXPECT_GE(psnr, kMinPsnr) << what;
  size_t coverage_off = 0, depth_off = 0, covered = 0;
  for (size_t i = 0; i < fast->pixels(); ++i) {
    float a = fast->depth[i], b = ref->depth[i];
    covered += std::isfinite(b);
    if (std::isinf(a) != std::isinf(b) || (std::isfinite(a) && std::abs(a - b) > 1e-4f * b)) {
      ++depth_off;
    }
    coverage_off += std::abs(fast->coverage[i] - ref->coverage[i]) > 1e-3f;
  }
  // A pixel on the cutoff ellipse's very edge may fall either side of it by rounding.
  EXPECT_LE(depth_off, fast->pixels() / 2000) << what;
  EXPECT_LE(coverage_off, fast->pixels() / 1000) << what;
  EXPECT_GT(covered, 0u) << what;
  std::printf("%-44s PSNR(tiled, reference) = %6.1f dB, %zu covered pixels\n", what.c_str(),
              std::min(psnr, 999.0), covered);
}

TEST(TileRasterTest, SphereMatchesTheReferenceInEveryMode) {
  auto pts = testing::SphereScene(20000);
  // 333 x 250: neither side a multiple of the tile.
  Camera cam = testing::ViewFrom(0.3, 0.4, 1, 3.5, 333, 250);
  for (const Case& c : kCases) ExpectSame(pts, cam, OptionsFor(c), std::string("sphere ") + c.name);
}

TEST(TileRasterTest, OcclusionAndFuzzyDepthMatchTheReference) {
  auto pts = testing::PlanesScene(0.01f);
  Camera cam = testing::ViewFrom(0.2, -0.1, 1, 2.5, 301, 177);
  for (const Case& c : kCases) ExpectSame(pts, cam, OptionsFor(c), std::string("planes ") + c.name);
}

// Random Gaussians of every size, from sub-pixel to larger than several tiles, some crossing
// the image border and some behind the camera, seen through a distorting lens.
std::vector<Point> RandomScene(uint32_t seed, size_t n) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> pos(-1.5f, 1.5f), unit(0, 1);
  std::vector<Point> pts;
  for (size_t i = 0; i < n; ++i) {
    Point p;
    p.x = pos(rng);
    p.y = pos(rng);
    p.z = pos(rng);
    float sigma = 0.002f * std::pow(100.0f, unit(rng));  // 2 mm .. 20 cm
    float a[3] = {sigma * (unit(rng) - 0.5f), sigma * (unit(rng) - 0.5f), sigma * unit(rng)};
    float b[3] = {sigma * unit(rng), sigma * (unit(rng) - 0.5f), 0.1f * sigma * unit(rng)};
    float c[3] = {0.05f * sigma, 0.05f * sigma * unit(rng), 0.02f * sigma};
    p.cov = CovarianceFromSpanning(a, b, c);
    p.flags = unit(rng) < 0.9f ? kFlagHasCovariance : 0;
    p.r = static_cast<uint8_t>(rng());
    p.g = static_cast<uint8_t>(rng());
    p.b = static_cast<uint8_t>(rng());
    p.camera = static_cast<uint16_t>(rng() % 6);
    pts.push_back(p);
  }
  return pts;
}

TEST(TileRasterTest, RandomScenesMatchTheReference) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    auto pts = RandomScene(seed, 3000);
    Camera cam = testing::ViewFrom(0.5, 0.2, 1, 2.2, 257 + seed * 31, 193 + seed * 17);
    if (seed == 2) cam.distortion = {-0.12, 0.03, 0.001, -0.0005, 0};
    for (const Case& c : kCases) {
      RenderOptions o = OptionsFor(c);
      o.depth_threshold = 0.05f;
      if (seed == 3) o.splat_scale = 2.0f;
      ExpectSame(pts, cam, o, "random seed " + std::to_string(seed) + " " + c.name);
    }
  }
}

TEST(TileRasterTest, ImagesDoNotDependOnTheThreadCount) {
  auto pts = RandomScene(9, 4000);
  Camera cam = testing::ViewFrom(0.1, 0.3, 1, 2.5, 200, 150);
  for (const Case& c : kCases) {
    auto one = MakeCpuRenderer(1)->Render(pts, cam, OptionsFor(c));
    auto many = MakeCpuRenderer(3)->Render(pts, cam, OptionsFor(c));
    ASSERT_TRUE(one.ok() && many.ok());
    EXPECT_EQ(one->rgba, many->rgba) << c.name;
    EXPECT_EQ(one->coverage, many->coverage) << c.name;
    EXPECT_EQ(one->depth, many->depth) << c.name;
  }
}

TEST(TileRasterTest, ARendererIsReusedAcrossSizesAndScenes) {
  // Buffers kept between renders (splats, tile lists) must not leak one image into the next.
  auto r = MakeCpuRenderer(2);
  auto big = testing::SphereScene(30000);
  auto small = testing::PlanesScene();
  Camera a = testing::ViewFrom(0.3, 0.4, 1, 3.5, 320, 240);
  Camera b = testing::ViewFrom(0.2, -0.1, 1, 2.5, 97, 61);
  ASSERT_TRUE(r->Render(big, a, {}).ok());
  auto again = r->Render(small, b, {});
  auto fresh = MakeCpuRenderer(2)->Render(small, b, {});
  ASSERT_TRUE(again.ok() && fresh.ok());
  EXPECT_EQ(again->rgba, fresh->rgba);
  EXPECT_EQ(again->depth, fresh->depth);
}

}  // namespace
}  // namespace hvdb::render

namespace hvdb::render {
namespace {

TEST(TileRasterTest, SplatsThatWouldNeedTooMuchMemoryAreRefusedClearly) {
  // 6000 splats, each covering all 16384 tiles of a 4096 x 4096 image (a camera inside a
  // cloud of huge Gaussians): ~98 M tile entries, beyond what the renderer holds. Refused
  // with LimitExceeded, and the renderer works afterwards.
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 1, 0}, n[3] = {0, 0, 1};
  for (int i = 0; i < 6000; ++i) {
    pts.push_back(testing::Surfel(0.001f * static_cast<float>(i % 10), 0, 1, t1, t2, n, 5.0f,
                                  200, 100, 50));
  }
  Camera cam;
  cam.width = cam.height = 4096;
  cam.fx = cam.fy = 2000;
  cam.cx = cam.cy = 2047.5;
  auto r = MakeCpuRenderer(2);
  auto img = r->Render(pts, cam, {});
  ASSERT_FALSE(img.ok());
  EXPECT_EQ(img.status().code(), StatusCode::kLimitExceeded) << img.status().ToString();
  EXPECT_NE(img.status().message().find("move the camera back"), std::string::npos);
  auto small = r->Render(testing::SphereScene(2000), testing::ViewFrom(0, 0, 1, 3, 64, 48), {});
  EXPECT_TRUE(small.ok());
}

}  // namespace
}  // namespace hvdb::render
