// Shadows (render/shadow.h): a labelled blob above a plane darkens the plane under it and
// nothing else; the Panoptic person's head and shoulders shadow the body below; CPU and EGL
// renders get the same shadows; bad options are refused.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "render/shadow.h"
#include "tests/render/panoptic_data.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

using testing::Surfel;
constexpr uint32_t kBit = 3;

// A 2 x 2 m grey floor at y = 0 (world y up) and a blob of radius 0.2 at height 0.5 carrying
// label bit kBit.
std::vector<Point> BlobOverPlane() {
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 0, 1}, n[3] = {0, 1, 0};
  const float step = 0.02f;
  for (float z = -1; z <= 1; z += step) {
    for (float x = -1; x <= 1; x += step) {
      pts.push_back(Surfel(x, 0, z, t1, t2, n, step * 0.6f, 180, 180, 180));
    }
  }
  for (Point p : testing::SphereScene(3000)) {
    p.x *= 0.2f, p.y = 0.5f + 0.2f * p.y, p.z *= 0.2f;
    for (float& c : p.cov) c *= 0.04f;
    p.label = 1u << kBit;
    pts.push_back(p);
  }
  return pts;
}

Camera View() { return Camera::LookAt({0, 2.5, 2.5}, {0, 0, 0}, {0, 1, 0}, 50, 320, 240); }

// The pixel index world point (x, y, z) falls on.
size_t PixelOf(const Camera& c, double x, double y, double z) {
  const auto& m = c.world_from_camera;
  const double d[3] = {x - m[3], y - m[7], z - m[11]};
  double pc[3];
  for (int k = 0; k < 3; ++k) pc[k] = m[k] * d[0] + m[4 + k] * d[1] + m[8 + k] * d[2];
  const long u = std::lround(c.fx * pc[0] / pc[2] + c.cx), v = std::lround(c.fy * pc[1] / pc[2] + c.cy);
  EXPECT_TRUE(u >= 0 && v >= 0 && u < long(c.width) && v < long(c.height));
  return size_t(v) * c.width + size_t(u);
}

float Luma(const Image& img, size_t i) {
  return img.rgba[4 * i] + img.rgba[4 * i + 1] + img.rgba[4 * i + 2];
}

class ShadowTest : public ::testing::TestWithParam<bool> {};

TEST_P(ShadowTest, BlobShadowsThePlaneUnderItAndNothingElse) {
  const bool directional = GetParam();
  const std::vector<Point> pts = BlobOverPlane();
  auto cpu = MakeCpuRenderer();
  RenderOptions o;
  auto plain = cpu->Render(pts, View(), o);
  ASSERT_TRUE(plain.ok()) << plain.status().ToString();
  Image shadowed = *plain;
  ShadowOptions s;
  s.light = directional ? std::array<double, 3>{0, 1, 0} : std::array<double, 3>{0, 2, 0};
  s.directional = directional;
  s.caster_bit = kBit;
  ShadowStats stats;
  ASSERT_TRUE(ApplyShadows(pts, View(), o, s, &shadowed, &stats).ok());
  EXPECT_EQ(stats.casters, 3000u);
  EXPECT_GT(stats.shadowed_pixels, 200u);
  // Under the blob (the shadow is 0.2 m wide for the sun, 0.27 m for the lamp at 2 m): 60%
  // darker, the full strength.
  for (auto [x, z] : {std::pair{0.0, 0.0}, {0.1, 0.0}, {-0.08, 0.08}, {0.0, -0.1}}) {
    const size_t i = PixelOf(View(), x, 0, z);
    EXPECT_NEAR(Luma(shadowed, i), 0.4f * Luma(*plain, i), 1e-4) << x << " " << z;
  }
  // Away from it: exactly the same.
  for (auto [x, z] : {std::pair{0.8, 0.8}, {-0.7, -0.5}, {0.5, 0.0}, {0.0, 0.6}}) {
    const size_t i = PixelOf(View(), x, 0, z);
    EXPECT_EQ(Luma(shadowed, i), Luma(*plain, i)) << x << " " << z;
  }
  // The blob's lit top is not in its own shadow.
  const size_t top = PixelOf(View(), 0, 0.7, 0);
  EXPECT_EQ(Luma(shadowed, top), Luma(*plain, top));
  // Nothing gets brighter; background pixels are untouched; alpha and depth are kept.
  for (size_t i = 0; i < plain->pixels(); ++i) {
    ASSERT_LE(Luma(shadowed, i), Luma(*plain, i));
    ASSERT_EQ(shadowed.rgba[4 * i + 3], plain->rgba[4 * i + 3]);
  }
  EXPECT_EQ(shadowed.depth, plain->depth);
}

INSTANTIATE_TEST_SUITE_P(PointAndDirectional, ShadowTest, ::testing::Bool());

TEST(ShadowErrors, BadOptionsAreRefusedAndChangeNothing) {
  const std::vector<Point> pts = BlobOverPlane();
  auto cpu = MakeCpuRenderer();
  auto plain = cpu->Render(pts, View(), {});
  ASSERT_TRUE(plain.ok());
  auto expect = [&](ShadowOptions s, const std::string& field) {
    Image img = *plain;
    Status st = ApplyShadows(pts, View(), {}, s, &img);
    EXPECT_EQ(st.code(), StatusCode::kInvalidArgument) << st.ToString();
    EXPECT_NE(st.message().find(field), std::string::npos) << st.ToString();
    EXPECT_EQ(img.rgba, plain->rgba);
  };
  ShadowOptions s;
  s.light = {0, 0.5, 0};  // inside the blob
  s.caster_bit = kBit;
  expect(s, "render.shadow_light");
  s.light = {0, 2, 0};
  s.caster_bit = 32;
  expect(s, "render.shadow_casters");
  s.caster_bit = kBit;
  s.strength = 1.5f;
  expect(s, "render.shadow_strength");
  s.strength = 0.6f;
  s.directional = true;
  s.light = {0, 0, 0};
  expect(s, "render.shadow_light");
  // No point carries the bit: nothing to cast, the image is left alone.
  s.light = {0, 1, 0};
  s.caster_bit = 7;
  Image img = *plain;
  ASSERT_TRUE(ApplyShadows(pts, View(), {}, s, &img).ok());
  EXPECT_EQ(img.rgba, plain->rgba);
}

// The pixels a shadow pass darkened.
std::vector<bool> Darkened(const Image& plain, const Image& shadowed) {
  std::vector<bool> d(plain.pixels());
  for (size_t i = 0; i < d.size(); ++i) d[i] = Luma(shadowed, i) < Luma(plain, i);
  return d;
}

TEST(ShadowEgl, CpuAndEglRendersGetTheSameShadows) {
  auto egl = MakeEglRenderer();
  // scripts/setup.sh installs Mesa's EGL: a missing context is a broken install, not a skip.
  ASSERT_TRUE(egl.ok()) << egl.status().ToString();
  const std::vector<Point> pts = BlobOverPlane();
  auto cpu = MakeCpuRenderer();
  ShadowOptions s;
  s.light = {0.3, 2, 0.2};
  s.caster_bit = kBit;
  std::vector<bool> masks[2];
  int k = 0;
  for (Renderer* r : {cpu.get(), egl->get()}) {
    auto plain = r->Render(pts, View(), {});
    ASSERT_TRUE(plain.ok()) << plain.status().ToString();
    Image img = *plain;
    ASSERT_TRUE(ApplyShadows(pts, View(), {}, s, &img).ok());
    masks[k++] = Darkened(*plain, img);
  }
  size_t both = 0, either = 0;
  for (size_t i = 0; i < masks[0].size(); ++i) {
    both += masks[0][i] && masks[1][i];
    either += masks[0][i] || masks[1][i];
  }
  ASSERT_GT(either, 200u);
  EXPECT_GE(double(both) / either, 0.97) << both << " of " << either;
}

TEST(ShadowPanoptic, HeadAndShouldersShadowTheBodyFromAbove) {
  namespace pan = testing::panoptic;
  const std::string dir = std::string(HVDB_SHARED_DATA) + "/" + pan::kSubdir;
  ASSERT_TRUE(std::filesystem::exists(dir)) << dir << " is not there (../shared/data)";
  auto cams = pan::LoadCameras(dir);
  auto cloud = pan::LoadCloud(dir, 380);
  ASSERT_TRUE(cams.ok() && cloud.ok());
  // y points down: the top 30% of the person's height casts.
  float ymin = 1e9f, ymax = -1e9f;
  for (const Point& p : *cloud) ymin = std::min(ymin, p.y), ymax = std::max(ymax, p.y);
  for (Point& p : *cloud) {
    if (p.y < ymin + 0.3f * (ymax - ymin)) p.label |= 1u << kBit;
  }
  auto cpu = MakeCpuRenderer();
  RenderOptions o;
  o.depth_threshold = 0.05f;
  const Camera& cam = (*cams)[3].camera;
  auto plain = cpu->Render(*cloud, cam, o);
  ASSERT_TRUE(plain.ok());
  Image img = *plain;
  ShadowOptions s;
  s.light = {0.2, -1, 0.1};  // the sun, high up and a little to the side
  s.directional = true;
  s.caster_bit = kBit;
  ShadowStats stats;
  ASSERT_TRUE(ApplyShadows(*cloud, cam, o, s, &img, &stats).ok());
  EXPECT_GT(stats.shadowed_pixels, 2000u);
  size_t darker = 0, same = 0, empty = 0;
  for (size_t i = 0; i < img.pixels(); ++i) {
    ASSERT_LE(Luma(img, i), Luma(*plain, i));
    if (!std::isfinite(plain->depth[i])) {
      ++empty;
      ASSERT_EQ(Luma(img, i), Luma(*plain, i));  // the background stays as it was
    }
    darker += Luma(img, i) < Luma(*plain, i);
    same += Luma(img, i) == Luma(*plain, i);
  }
  std::printf("panoptic: %zu pixels shadowed, %zu unchanged (%zu empty) in %.1f ms\n", darker,
              same, empty, stats.milliseconds);
  EXPECT_GT(same, darker);  // the lit head and most of the view are left alone
}

}  // namespace
}  // namespace hvdb::render
