// The CPU reference renderer: the behaviour of fig. 5.2 (fuzzy depth test, blending,
// normalisation), 5.4.1 (saturation), eqs. 5.15-5.17 (view-dependent weights) and 8.4 (LOD).
#include <gtest/gtest.h>

#include <cmath>

#include "render/renderer.h"
#include "render/splat.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

// A camera at the origin looking along +z, 200 x 150, f = 200.
Camera Front() {
  Camera c;
  c.width = 200;
  c.height = 150;
  c.fx = c.fy = 200;
  c.cx = 99.5;
  c.cy = 74.5;
  return c;
}

// A square layer of surfels parallel to the image plane at depth z, side `half` * 2.
std::vector<Point> Layer(float z, uint8_t r, uint8_t g, uint8_t b, uint16_t camera = 0,
                         float half = 0.5f, float step = 0.02f, float sigma_scale = 0.6f) {
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 1, 0}, n[3] = {0, 0, 1};
  for (float y = -half; y <= half + 1e-6f; y += step) {
    for (float x = -half; x <= half + 1e-6f; x += step) {
      pts.push_back(testing::Surfel(x, y, z, t1, t2, n, step * sigma_scale, r, g, b, camera));
    }
  }
  return pts;
}

std::vector<Point> Concat(std::vector<Point> a, const std::vector<Point>& b) {
  a.insert(a.end(), b.begin(), b.end());
  return a;
}

struct Pixel {
  float r, g, b, a, coverage, depth;
};
Pixel At(const Image& img, uint32_t x, uint32_t y) {
  size_t i = size_t{y} * img.width + x;
  return {img.rgba[i * 4],     img.rgba[i * 4 + 1], img.rgba[i * 4 + 2],
          img.rgba[i * 4 + 3], img.coverage[i],     img.depth[i]};
}

Image RenderCpu(const std::vector<Point>& pts, const Camera& cam, const RenderOptions& o,
                unsigned threads = 2) {
  auto r = MakeCpuRenderer(threads);
  auto img = r->Render(pts, cam, o);
  EXPECT_TRUE(img.ok()) << img.status().ToString();
  return img.ok() ? *img : Image{};
}

TEST(CpuRendererTest, EmptySceneIsTheBackground) {
  RenderOptions o;
  o.background = {0.25f, 0.5f, 0.75f, 1};
  Image img = RenderCpu({}, Front(), o);
  ASSERT_EQ(img.pixels(), 200u * 150u);
  Pixel p = At(img, 10, 20);
  EXPECT_FLOAT_EQ(p.r, 0.25f);
  EXPECT_FLOAT_EQ(p.b, 0.75f);
  EXPECT_FLOAT_EQ(p.a, 1);
  EXPECT_EQ(p.coverage, 0);
  EXPECT_TRUE(std::isinf(p.depth));
  auto r = MakeCpuRenderer(1);
  EXPECT_EQ(r->kind(), RendererKind::kCpu);
  EXPECT_EQ(r->name(), "cpu (1 thread)");
}

TEST(CpuRendererTest, NormalisationGivesTheSurfaceColour) {
  // Fig. 5.2 lines 15-18: inside a densely sampled surface the blended colour, divided by the
  // accumulated weight, is the points' colour, and the surface is opaque.
  Image img = RenderCpu(Layer(2, 200, 100, 50), Front(), {});
  Pixel p = At(img, 100, 75);
  const auto& lin = internal::SrgbTable();
  EXPECT_NEAR(p.r, lin[200], 1e-5);
  EXPECT_NEAR(p.g, lin[100], 1e-5);
  EXPECT_NEAR(p.b, lin[50], 1e-5);
  EXPECT_FLOAT_EQ(p.coverage, 1);
  EXPECT_NEAR(p.depth, 2, 1e-4);
  // Outside the square: background, antialiased at the edge.
  EXPECT_EQ(At(img, 2, 2).coverage, 0);
}

TEST(CpuRendererTest, VisibilityResolvesOcclusion) {
  // Red in front (z = 2) of blue (z = 2.5): only red shows, both modes.
  auto pts = Concat(Layer(2.5f, 0, 0, 255, 0, 0.8f), Layer(2, 255, 0, 0));
  for (Mode m : {Mode::kVisibility, Mode::kProbabilistic}) {
    RenderOptions o;
    o.mode = m;
    Image img = RenderCpu(pts, Front(), o);
    Pixel p = At(img, 100, 75);
    EXPECT_GT(p.r, 0.99f);
    EXPECT_LT(p.b, 0.01f);
    EXPECT_NEAR(p.depth, 2, 1e-3);
    // Beside the red square, the blue one behind it shows.
    Pixel side = At(img, 100 + 58, 75);
    EXPECT_GT(side.b, 0.99f);
    EXPECT_NEAR(side.depth, 2.5, 1e-3);
  }
}

TEST(CpuRendererTest, FuzzyDepthTestBlendsWithinThreshold) {
  // Two layers 1 cm apart: within dz = 2 cm they blend (same surface, lines 9-11), with
  // dz = 2 mm the nearer one occludes (lines 4-7).
  auto pts = Concat(Layer(2.01f, 0, 0, 255), Layer(2, 255, 0, 0));
  RenderOptions o;
  o.depth_threshold = 0.02f;
  Pixel blended = At(RenderCpu(pts, Front(), o), 100, 75);
  EXPECT_NEAR(blended.r, 0.5f, 0.05f);
  EXPECT_NEAR(blended.b, 0.5f, 0.05f);
  o.depth_threshold = 0.002f;
  Pixel front = At(RenderCpu(pts, Front(), o), 100, 75);
  EXPECT_GT(front.r, 0.99f);
  EXPECT_LT(front.b, 0.01f);
}

TEST(CpuRendererTest, ProbabilisticStopsWhenAlphaSaturates) {
  // 5.4.1: front to back, accumulation stops once alpha reaches one: the dense front layer
  // 1 cm ahead wins although the fuzzy depth test would have blended them.
  auto pts = Concat(Layer(2.01f, 0, 0, 255), Layer(2, 255, 0, 0));
  RenderOptions o;
  o.mode = Mode::kProbabilistic;
  Pixel p = At(RenderCpu(pts, Front(), o), 100, 75);
  EXPECT_FLOAT_EQ(p.coverage, 1);
  EXPECT_GT(p.r, 0.9f);
  EXPECT_LT(p.b, 0.1f);
  // A sparse front layer (small splats, far apart) does not saturate: the back shows through.
  auto sparse = Concat(Layer(2.2f, 0, 0, 255), Layer(2, 255, 0, 0, 0, 0.5f, 0.05f, 0.15f));
  Image img = RenderCpu(sparse, Front(), o);
  float blue = 0;
  for (uint32_t x = 60; x < 140; ++x) blue += At(img, x, 75).b;
  EXPECT_GT(blue / 80, 0.3f);
}

TEST(CpuRendererTest, ViewDependentWeightsFavourTheAlignedCamera) {
  // The same surface seen by two source cameras with different colours: red from camera 1
  // (along the view), green from camera 2 (60 degrees off). Eqs. 5.15-5.17.
  Camera cam1 = Front();
  Camera cam2 = Camera::LookAt({2 * std::sin(M_PI / 3), 0, 2 - 2 * std::cos(M_PI / 3)}, {0, 0, 2},
                               {0, -1, 0}, 60, 200, 150);
  auto pts = Concat(Layer(2, 255, 0, 0, 1), Layer(2, 0, 255, 0, 2));
  RenderOptions o;
  o.source_cameras = {{1, cam1.world_from_camera}, {2, cam2.world_from_camera}};
  Pixel plain = At(RenderCpu(pts, cam1, o), 100, 75);
  EXPECT_NEAR(plain.r, plain.g, 0.1f);
  o.view_dependent = true;
  Pixel from1 = At(RenderCpu(pts, cam1, o), 100, 75);
  EXPECT_GT(from1.r, 0.95f);
  EXPECT_LT(from1.g, 0.05f);
  EXPECT_FLOAT_EQ(from1.coverage, 1);  // weights change the blend, not the coverage
  Pixel from2 = At(RenderCpu(pts, cam2, o), 100, 75);
  EXPECT_GT(from2.g, 0.95f);
  EXPECT_LT(from2.r, 0.05f);
}

TEST(CpuRendererTest, LevelOfDetailSplatsCoverMoreArea) {
  // Isolated splats: the covered area grows with the variance, 2^i at level i (8.4).
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 1, 0}, n[3] = {0, 0, 1};
  for (int i = 0; i < 4; ++i) {
    pts.push_back(testing::Surfel(-0.6f + 0.4f * i, 0, 2, t1, t2, n, 0.03f, 255, 255, 255));
  }
  RenderOptions o;
  o.filter_variance = 0;
  auto covered = [&](int level) {
    o.splat_scale = static_cast<float>(std::pow(2.0, level / 2.0));
    Image img = RenderCpu(pts, Front(), o);
    double sum = 0;
    for (float c : img.coverage) sum += c;
    return sum;
  };
  // Four splats of sigma 3 px: each kernel sums to 2 pi sigma^2 (less the cut-off tail).
  double base = covered(0);
  EXPECT_NEAR(base, 4 * 2 * M_PI * 9 * (1 - std::exp(-2.5 * 2.5 / 2)), 0.05 * base);
  for (int level = 1; level <= 3; ++level) {
    EXPECT_NEAR(covered(level) / base, std::pow(2.0, level), 0.1 * std::pow(2.0, level))
        << "level " << level;
  }
}

TEST(CpuRendererTest, ThreadCountDoesNotChangeTheImage) {
  auto pts = testing::SphereScene(3000);
  Camera cam = testing::ViewFrom(0.3, 0.4, 1, 3.5, 160, 120);
  for (Mode m : {Mode::kVisibility, Mode::kProbabilistic}) {
    RenderOptions o;
    o.mode = m;
    Image a = RenderCpu(pts, cam, o, 1), b = RenderCpu(pts, cam, o, 3);
    EXPECT_EQ(a.rgba, b.rgba);
    EXPECT_EQ(a.depth, b.depth);
  }
}

TEST(CpuRendererTest, DepthOnlyIsTheFullRendersDepth) {
  // Both modes report the nearest fragment's depth; depth_only computes just that, bit for bit,
  // and leaves the colour buffers empty (texturing's source views take nothing else).
  auto pts = Concat(testing::SphereScene(3000), Layer(4.0f, 10, 200, 30, 0, 0.15f));
  Camera cam = testing::ViewFrom(0.3, 0.4, 1, 6, 171, 97);
  for (Mode m : {Mode::kVisibility, Mode::kProbabilistic}) {
    RenderOptions o;
    o.mode = m;
    Image full = RenderCpu(pts, cam, o);
    o.depth_only = true;
    Image depth = RenderCpu(pts, cam, o);
    EXPECT_EQ(depth.width, full.width);
    EXPECT_EQ(depth.height, full.height);
    EXPECT_EQ(depth.depth, full.depth);
    EXPECT_TRUE(depth.rgba.empty());
    EXPECT_TRUE(depth.coverage.empty());
    size_t finite = 0;
    for (float z : depth.depth) finite += std::isfinite(z);
    EXPECT_GT(finite, depth.pixels() / 40);
    EXPECT_LT(finite, depth.pixels());  // the background stays +inf
  }
  // The same renderer alternating: the colour buffers come back for a full render.
  auto r = MakeCpuRenderer(2);
  Image img;
  RenderOptions o;
  o.depth_only = true;
  ASSERT_TRUE(r->RenderInto(pts, cam, o, &img).ok());
  o.depth_only = false;
  ASSERT_TRUE(r->RenderInto(pts, cam, o, &img).ok());
  EXPECT_EQ(img.rgba.size(), 4 * img.pixels());
  EXPECT_EQ(img.coverage.size(), img.pixels());
}

TEST(CpuRendererTest, SizeOptionScalesTheCamera) {
  RenderOptions o;
  o.width = 100;
  o.height = 75;
  Image img = RenderCpu(Layer(2, 255, 255, 255, 0, 0.2f), Front(), o);
  EXPECT_EQ(img.width, 100u);
  EXPECT_EQ(img.height, 75u);
  EXPECT_FLOAT_EQ(At(img, 50, 37).coverage, 1);
  EXPECT_EQ(At(img, 50 + 30, 37).coverage, 0);  // 0.2 m at 2 m, f 100: 10 px (+ splat size)
}

TEST(CpuRendererTest, TransparentBackgroundKeepsCoverageInAlpha) {
  RenderOptions o;
  o.background = {0, 0, 0, 0};
  Image img = RenderCpu(Layer(2, 255, 255, 255, 0, 0.2f), Front(), o);
  EXPECT_FLOAT_EQ(At(img, 100, 75).a, 1);
  EXPECT_EQ(At(img, 5, 5).a, 0);
}

TEST(CpuRendererTest, RejectsBadArguments) {
  auto r = MakeCpuRenderer();
  Camera c = Front();
  c.width = 5000;
  EXPECT_TRUE(r->Render({}, c, {}).status().IsInvalidArgument());
  RenderOptions o;
  o.splat_scale = 0;
  EXPECT_TRUE(r->Render({}, Front(), o).status().IsInvalidArgument());
  EXPECT_TRUE(ParseRendererKind("vulkan").status().IsInvalidArgument());
  EXPECT_EQ(*ParseRendererKind("egl"), RendererKind::kEgl);
}

}  // namespace
}  // namespace hvdb::render
