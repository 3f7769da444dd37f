// render/projective_texture.h on a scene with an exact answer: a finely textured plane with a
// red square in front of it, three source cameras whose photos are ray-cast, coarse points.
// Texturing the splats' depth from the photos must come close to the ray-cast truth (far closer
// than the points alone), and a source that sees the red square where the virtual camera sees
// the plane must not lend it its colour.
#include "render/projective_texture.h"

#include <gtest/gtest.h>

#include <cmath>

#include "render/job/internal.h"
#include "render/metrics.h"
#include "tests/render/test_scenes.h"

namespace hvdb::render {
namespace {

constexpr double kPlaneZ = 2.0, kSquareZ = 1.0;
constexpr double kSquare[4] = {-0.25, -0.15, -0.05, 0.05};  // x0 x1 y0 y1 at z = 1

// The plane's texture: smooth waves of 12 cm (9 pixels at the plane), different per channel,
// so that sampling the photos between pixels is exact enough and the points' blur is not.
std::array<uint8_t, 3> Texture(double x, double y) {
  const double k = 2 * M_PI / 0.12;
  auto c = [](double v) { return static_cast<uint8_t>(std::clamp(std::lround(v), 0L, 255L)); };
  return {c(128 + 100 * std::sin(k * x)), c(128 + 100 * std::sin(k * y)), c(128 + 90 * std::cos(k * (x + y)))};
}

Camera At(double x) {
  Camera c;
  c.width = 160;
  c.height = 120;
  c.fx = c.fy = 150;
  c.cx = 79.5;
  c.cy = 59.5;
  c.world_from_camera[3] = x;  // looking along +z from (x, 0, 0)
  return c;
}

// The ray-cast photo of camera c (and its depth).
std::vector<uint8_t> Photo(const Camera& c) {
  std::vector<uint8_t> rgb(size_t{c.width} * c.height * 3);
  const double ox = c.world_from_camera[3];
  for (uint32_t v = 0; v < c.height; ++v) {
    for (uint32_t u = 0; u < c.width; ++u) {
      const double dx = (u - c.cx) / c.fx, dy = (v - c.cy) / c.fy;
      std::array<uint8_t, 3> col;
      const double sx = ox + dx * kSquareZ, sy = dy * kSquareZ;
      if (sx >= kSquare[0] && sx <= kSquare[1] && sy >= kSquare[2] && sy <= kSquare[3]) {
        col = {255, 0, 0};
      } else {
        col = Texture(ox + dx * kPlaneZ, dy * kPlaneZ);
      }
      std::copy(col.begin(), col.end(), &rgb[3 * (size_t{v} * c.width + u)]);
    }
  }
  return rgb;
}

std::vector<Point> Points() {
  std::vector<Point> pts;
  const float t1[3] = {1, 0, 0}, t2[3] = {0, 1, 0}, n[3] = {0, 0, -1};
  const double step = 0.03;  // coarser than a pixel (1.3 cm at the plane): the points alone blur
  for (double y = -0.9; y <= 0.9; y += step) {
    for (double x = -1.5; x <= 1.5; x += step) {
      const auto c = Texture(x, y);
      pts.push_back(testing::Surfel(static_cast<float>(x), static_cast<float>(y), static_cast<float>(kPlaneZ),
                                    t1, t2, n, static_cast<float>(step * 0.6), c[0], c[1], c[2]));
    }
  }
  for (double y = kSquare[2]; y <= kSquare[3] + 1e-9; y += 0.004) {
    for (double x = kSquare[0]; x <= kSquare[1] + 1e-9; x += 0.004) {
      pts.push_back(testing::Surfel(static_cast<float>(x), static_cast<float>(y), static_cast<float>(kSquareZ),
                                    t1, t2, n, 0.0025f, 255, 0, 0));
    }
  }
  return pts;
}

Srgb8Image Rgb(const Image& im) {
  Srgb8Image s = ToSrgb8(im);
  if (s.channels == 4) {
    Srgb8Image rgb{s.width, s.height, 3, {}};
    for (size_t p = 0; p < s.data.size(); p += 4) rgb.data.insert(rgb.data.end(), &s.data[p], &s.data[p + 3]);
    return rgb;
  }
  return s;
}

TEST(ProjectiveTextureTest, SharperThanThePointsAndOnlyFromSourcesThatSeeThePoint) {
  auto renderer = MakeCpuRenderer(2);
  const std::vector<Point> pts = Points();
  const std::vector<Camera> cams = {At(-0.3), At(0), At(0.3)};
  std::vector<std::vector<uint8_t>> photos;
  std::vector<Image> seen;
  std::vector<TextureView> views;
  for (const Camera& c : cams) {
    photos.push_back(Photo(c));
    auto im = renderer->Render(pts, c, RenderOptions{});
    ASSERT_TRUE(im.ok()) << im.status().ToString();
    seen.push_back(std::move(*im));
  }
  for (size_t i = 0; i < cams.size(); ++i) views.push_back({cams[i], photos[i], seen[i].depth});

  // The virtual camera near the first source, which sees the red square where it sees the plane.
  const Camera target = At(-0.2);
  auto points_only = renderer->Render(pts, target, RenderOptions{});
  ASSERT_TRUE(points_only.ok());
  Image textured = *points_only;
  TextureStats stats;
  ASSERT_TRUE(ProjectiveTexture(target, views, TextureOptions{}, &textured, &stats).ok());
  EXPECT_EQ(stats.pixels, target.width * target.height);
  EXPECT_GT(stats.textured, stats.pixels * 95 / 100);

  const std::vector<uint8_t> truth_rgb = Photo(target);
  Srgb8Image truth{target.width, target.height, 3, truth_rgb};
  const double p_points = Psnr(Rgb(*points_only), truth), p_tex = Psnr(Rgb(textured), truth);
  std::printf("[ texture ] PSNR points only %.2f dB, textured %.2f dB\n", p_points, p_tex);
  EXPECT_GT(p_tex, p_points + 5);
  EXPECT_GT(p_tex, 30);

  // Plane points at x in [-0.06, -0.01] (near y = 0): the virtual camera sees them directly
  // (clear of the square's silhouette, where its splats spill over), the first source sees the
  // red square in front of them. No red may come through.
  const Srgb8Image out = Rgb(textured);
  int checked = 0;
  for (uint32_t v = 0; v < target.height; ++v) {
    for (uint32_t u = 0; u < target.width; ++u) {
      const double x = -0.2 + (u - target.cx) / target.fx * kPlaneZ, y = (v - target.cy) / target.fy * kPlaneZ;
      if (x < -0.06 || x > -0.01 || std::abs(y) > 0.03) continue;
      const uint8_t* o = &out.data[3 * (size_t{v} * target.width + u)];
      const uint8_t* t = &truth.data[3 * (size_t{v} * target.width + u)];
      EXPECT_LT(std::abs(int(o[0]) - int(t[0])) + std::abs(int(o[1]) - int(t[1])) + std::abs(int(o[2]) - int(t[2])), 90)
          << "pixel " << u << "," << v;
      ++checked;
    }
  }
  EXPECT_GT(checked, 8);
}

TEST(ProjectiveTextureTest, RejectsMismatchedBuffers) {
  const Camera c = At(0);
  Image im;
  std::vector<uint8_t> rgb(10);
  std::vector<float> depth(10);
  std::vector<TextureView> views = {{c, rgb, depth}};
  EXPECT_TRUE(ProjectiveTexture(c, views, {}, &im).IsInvalidArgument());  // image not rendered from c
  auto renderer = MakeCpuRenderer(1);
  auto ok = renderer->Render(Points(), c, RenderOptions{});
  ASSERT_TRUE(ok.ok());
  EXPECT_TRUE(ProjectiveTexture(c, views, {}, &*ok).IsInvalidArgument());  // view buffers wrong
  TextureOptions bad;
  bad.max_views = 0;
  EXPECT_TRUE(ProjectiveTexture(c, {}, bad, &*ok).IsInvalidArgument());
}

TEST(ProjectiveTextureTest, SourceDepthIsDrawnSmallerOnlyWhereSplatsSpanPixels) {
  // The same points seen by a small camera (splats about a pixel) and a 1080p one (several):
  // only the second's depth is drawn smaller, and the size the view is drawn at does not
  // change which (it is measured in the source camera's own pixels).
  const auto sphere = testing::SphereScene(6000);
  const Camera small = testing::ViewFrom(0.3, 0.4, 1, 3.5, 160, 120);
  const Camera large = testing::ViewFrom(0.3, 0.4, 1, 3.5, 1920, 1080);
  RenderOptions o;
  EXPECT_EQ(internal::SourceDepthScale(sphere, small, o), 1u);
  const uint32_t k = internal::SourceDepthScale(sphere, large, o);
  EXPECT_GE(k, 2u);
  EXPECT_LE(k, 4u);
  for (uint32_t w : {96u, 3840u}) {
    o.width = w;
    o.height = w * 9 / 16;
    EXPECT_EQ(internal::SourceDepthScale(sphere, large, o), k) << w;
    EXPECT_EQ(internal::SourceDepthScale(sphere, small, o), 1u) << w;
  }
  EXPECT_EQ(internal::SourceDepthScale({}, large, {}), 1u);
}

}  // namespace
}  // namespace hvdb::render
