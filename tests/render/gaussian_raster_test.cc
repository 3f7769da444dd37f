// The 3DGS rasteriser (render/gaussian_raster.h) against a reference written plainly from the
// equations: Kerbl et al. 2023 (eqs. 2-3 and the reference code's forward pass: the 0.2 near
// plane, the 0.3 dilation, alpha clamped to 0.99, skipped below 1/255, the 1e-4 transmittance
// stop) and EWA splatting (Zwicker et al.: the Jacobian of the perspective projection, with the
// reference's clamp of x/z and y/z to 1.3 tan(half fov)). The reference works in double, per
// pixel, over every splat sorted by depth (stable by index), with no tiles except the one rule
// the output depends on: a splat reaches a pixel only if the pixel's 16x16 tile lies in the
// splat's rectangle as forward.cu's getRect computes it.
#include "render/gaussian_raster.h"
#include "render/egl_gaussian.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <numeric>
#include <random>
#include <vector>

#include "formats/gaussians.h"
#include "formats/ply.h"

namespace hvdb::render {
namespace {

using formats::GaussianCloud;
using M3 = std::array<std::array<double, 3>, 3>;

// ----- The reference -----

struct RefSplat {
  double u, v, a, b, c, opacity, depth;
  double rgb[3];
  int rect[4];  // tiles [rect[0], rect[2]) x [rect[1], rect[3])
};

M3 Mul(const M3& x, const M3& y) {
  M3 r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) r[i][j] += x[i][k] * y[k][j];
  return r;
}
M3 Transpose(const M3& x) {
  M3 r{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[i][j] = x[j][i];
  return r;
}

// The colour of SH degree `deg` for the unit direction d: the reference's formula term by term.
std::array<double, 3> ShColour(const GaussianCloud& g, size_t i, const double d[3]) {
  const double C0 = 0.28209479177387814, C1 = 0.4886025119029199;
  const double C2[] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                       -1.0925484305920792, 0.5462742152960396};
  const double C3[] = {-0.5900435899266435, 2.890611442640554,   -0.4570457994644658,
                       0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                       -0.5900435899266435};
  const int K = formats::ShRestPerChannel(g.sh_degree);
  std::array<double, 3> out{};
  for (int ch = 0; ch < 3; ++ch) {
    // sh[0] is f_dc; sh[j], j >= 1, is f_rest of channel ch, coefficient j - 1 (channel-major).
    auto sh = [&](int j) -> double {
      return j == 0 ? g.sh_dc[3 * i + ch] : g.sh_rest[i * 3 * K + ch * K + (j - 1)];
    };
    double x = d[0], y = d[1], z = d[2];
    double r = C0 * sh(0);
    if (g.sh_degree > 0) r = r - C1 * y * sh(1) + C1 * z * sh(2) - C1 * x * sh(3);
    if (g.sh_degree > 1) {
      double xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
      r += C2[0] * xy * sh(4) + C2[1] * yz * sh(5) + C2[2] * (2 * zz - xx - yy) * sh(6) +
           C2[3] * xz * sh(7) + C2[4] * (xx - yy) * sh(8);
      if (g.sh_degree > 2) {
        r += C3[0] * y * (3 * xx - yy) * sh(9) + C3[1] * xy * z * sh(10) +
             C3[2] * y * (4 * zz - xx - yy) * sh(11) +
             C3[3] * z * (2 * zz - 3 * xx - 3 * yy) * sh(12) +
             C3[4] * x * (4 * zz - xx - yy) * sh(13) + C3[5] * z * (xx - yy) * sh(14) +
             C3[6] * x * (xx - 3 * yy) * sh(15);
      }
    }
    out[ch] = std::max(r + 0.5, 0.0);
  }
  return out;
}

// forward.cu's getRect for one axis: (int) truncates towards zero, then clamps to [0, grid].
int RectIndex(double t, int grid) {
  t = std::clamp(t, -1e9, 1e9);
  return std::min(grid, std::max(0, static_cast<int>(t)));
}

// The splats that survive the reference's preprocessing, sorted by depth (stable by index).
std::vector<RefSplat> RefPreprocess(const GaussianCloud& g, const Camera& cam) {
  const auto& m = cam.world_from_camera;
  M3 Rwc{};  // world-from-camera rotation; W = its transpose, camera-from-world
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) Rwc[i][j] = m[4 * i + j];
  const M3 W = Transpose(Rwc);
  const double t[3] = {m[3], m[7], m[11]};
  const int grid_x = static_cast<int>((cam.width + 15) / 16);
  const int grid_y = static_cast<int>((cam.height + 15) / 16);
  std::vector<RefSplat> out;
  for (size_t i = 0; i < g.size(); ++i) {
    const double p[3] = {g.position[3 * i], g.position[3 * i + 1], g.position[3 * i + 2]};
    double pc[3] = {0, 0, 0};
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k) pc[r] += W[r][k] * (p[k] - t[k]);
    if (pc[2] <= 0.2) continue;
    // Sigma = R S S^T R^T.
    double q[4] = {g.rotation[4 * i], g.rotation[4 * i + 1], g.rotation[4 * i + 2],
                   g.rotation[4 * i + 3]};
    double qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (qn == 0) {
      q[0] = 1, qn = 1;
    }
    const double w = q[0] / qn, x = q[1] / qn, y = q[2] / qn, z = q[3] / qn;
    const M3 R = {{{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                   {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                   {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}}};
    M3 S{};
    for (int k = 0; k < 3; ++k) S[k][k] = std::exp(static_cast<double>(g.scale[3 * i + k]));
    const M3 RS = Mul(R, S);
    const M3 Sigma = Mul(RS, Transpose(RS));
    // EWA: J W Sigma W^T J^T, J at the centre with x/z, y/z clamped.
    const double limx = 1.3 * cam.width / (2 * cam.fx), limy = 1.3 * cam.height / (2 * cam.fy);
    const double xc = std::clamp(pc[0] / pc[2], -limx, limx) * pc[2];
    const double yc = std::clamp(pc[1] / pc[2], -limy, limy) * pc[2];
    const double zz = pc[2] * pc[2];
    const M3 J = {{{cam.fx / pc[2], 0, -cam.fx * xc / zz},
                   {0, cam.fy / pc[2], -cam.fy * yc / zz},
                   {0, 0, 0}}};
    const M3 T = Mul(J, W);
    const M3 cov = Mul(Mul(T, Sigma), Transpose(T));
    const double det0 = cov[0][0] * cov[1][1] - cov[0][1] * cov[1][0];
    const double cxx = cov[0][0] + 0.3, cyy = cov[1][1] + 0.3, cxy = cov[0][1];
    const double det = cxx * cyy - cxy * cxy;
    if (det == 0) continue;
    RefSplat s;
    s.opacity = 1 / (1 + std::exp(-static_cast<double>(g.opacity[i])));
    if (g.antialiased) s.opacity *= std::sqrt(std::max(0.0, det0 / det));
    s.a = cyy / det, s.b = -cxy / det, s.c = cxx / det;
    const double mid = 0.5 * (cxx + cyy);
    const double lambda1 = mid + std::sqrt(std::max(0.1, mid * mid - det));
    const double radius = std::ceil(3 * std::sqrt(lambda1));
    s.u = cam.fx * pc[0] / pc[2] + cam.cx;
    s.v = cam.fy * pc[1] / pc[2] + cam.cy;
    s.rect[0] = RectIndex((s.u - radius) / 16, grid_x);
    s.rect[1] = RectIndex((s.v - radius) / 16, grid_y);
    s.rect[2] = RectIndex((s.u + radius + 15) / 16, grid_x);
    s.rect[3] = RectIndex((s.v + radius + 15) / 16, grid_y);
    if ((s.rect[2] - s.rect[0]) * (s.rect[3] - s.rect[1]) == 0) continue;
    double dir[3] = {p[0] - t[0], p[1] - t[1], p[2] - t[2]};
    const double len = std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    for (double& d : dir) d /= len;
    const auto rgb = ShColour(g, i, dir);
    std::copy(rgb.begin(), rgb.end(), s.rgb);
    s.depth = pc[2];
    out.push_back(s);
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const RefSplat& x, const RefSplat& y) { return x.depth < y.depth; });
  return out;
}

struct RefImage {
  std::vector<double> rgb, alpha;
};

RefImage RefRender(const GaussianCloud& g, const Camera& cam, std::array<float, 3> bg) {
  const std::vector<RefSplat> splats = RefPreprocess(g, cam);
  RefImage img;
  img.rgb.resize(3 * size_t{cam.width} * cam.height);
  img.alpha.resize(size_t{cam.width} * cam.height);
  for (uint32_t py = 0; py < cam.height; ++py) {
    for (uint32_t px = 0; px < cam.width; ++px) {
      const int tx = static_cast<int>(px / 16), ty = static_cast<int>(py / 16);
      double T = 1, C[3] = {0, 0, 0};
      for (const RefSplat& s : splats) {
        if (tx < s.rect[0] || tx >= s.rect[2] || ty < s.rect[1] || ty >= s.rect[3]) continue;
        const double dx = s.u - px, dy = s.v - py;
        const double power = -0.5 * (s.a * dx * dx + s.c * dy * dy) - s.b * dx * dy;
        if (power > 0) continue;
        const double alpha = std::min(0.99, s.opacity * std::exp(power));
        if (alpha < 1.0 / 255) continue;
        const double test_t = T * (1 - alpha);
        if (test_t < 0.0001) break;
        for (int ch = 0; ch < 3; ++ch) C[ch] += s.rgb[ch] * alpha * T;
        T = test_t;
      }
      const size_t at = size_t{py} * cam.width + px;
      for (int ch = 0; ch < 3; ++ch) img.rgb[3 * at + ch] = C[ch] + T * bg[ch];
      img.alpha[at] = 1 - T;
    }
  }
  return img;
}

// ----- Comparison -----

int To8(double v) { return static_cast<int>(std::round(std::clamp(v, 0.0, 1.0) * 255)); }

struct Agreement {
  double psnr = 0;    // over RGB clamped to [0, 1]
  int max_diff8 = 0;  // over RGBA in 8 bits
  double mean_alpha = 0;
};

Agreement Compare(const GaussianImage& got, const RefImage& want) {
  Agreement a;
  double se = 0;
  const std::vector<uint8_t> rgba = got.ToRgba8();
  const size_t pixels = want.alpha.size();
  for (size_t i = 0; i < pixels; ++i) {
    for (int ch = 0; ch < 3; ++ch) {
      const double d = std::clamp<double>(got.rgb[3 * i + ch], 0, 1) -
                       std::clamp(want.rgb[3 * i + ch], 0.0, 1.0);
      se += d * d;
      a.max_diff8 = std::max(a.max_diff8, std::abs(rgba[4 * i + ch] - To8(want.rgb[3 * i + ch])));
    }
    a.max_diff8 = std::max(a.max_diff8, std::abs(rgba[4 * i + 3] - To8(want.alpha[i])));
    a.mean_alpha += want.alpha[i] / static_cast<double>(pixels);
  }
  const double mse = se / (3.0 * static_cast<double>(pixels));
  a.psnr = mse == 0 ? 200 : 10 * std::log10(1 / mse);
  return a;
}

// Renders with the rasteriser and the reference and checks they agree.
void ExpectMatchesReference(const GaussianCloud& g, const Camera& cam,
                            std::array<float, 3> bg = {0, 0, 0}, double min_coverage = 0.05) {
  GaussianImage img;
  GaussianRenderOptions options;
  options.background = bg;
  GaussianRenderStats stats;
  ASSERT_TRUE(RenderGaussians(g, cam, options, &img, &stats).ok());
  ASSERT_EQ(img.width, cam.width);
  ASSERT_EQ(img.rgb.size(), 3 * size_t{cam.width} * cam.height);
  const RefImage want = RefRender(g, cam, bg);
  const Agreement a = Compare(img, want);
  EXPECT_GE(a.psnr, 60) << "max 8-bit difference " << a.max_diff8;
  EXPECT_LE(a.max_diff8, 1) << "PSNR " << a.psnr;
  // The scene must actually be seen, or the comparison says little.
  EXPECT_GE(a.mean_alpha, min_coverage);
  EXPECT_GT(stats.splats_visible, 0u);
  std::printf(
      "  %u x %u: PSNR %.1f dB, max 8-bit diff %d, mean alpha %.2f, %llu of %llu splats "
      "visible, %llu tile entries\n",
      cam.width, cam.height, a.psnr, a.max_diff8, a.mean_alpha,
      static_cast<unsigned long long>(stats.splats_visible),
      static_cast<unsigned long long>(stats.splats_in),
      static_cast<unsigned long long>(stats.tile_entries));
}

// ----- Scenes -----

// n anisotropic splats in the cube [-1, 1]^3: scales over two decades with needles among them,
// random unnormalised quaternions, opacity from nearly clear to nearly opaque, SH of `degree`.
GaussianCloud RandomCloud(size_t n, int degree, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> uni(0, 1);
  auto range = [&](float lo, float hi) { return lo + (hi - lo) * uni(rng); };
  std::normal_distribution<float> normal(0, 1);
  GaussianCloud g;
  g.sh_degree = degree;
  g.Resize(n);
  const size_t K = g.sh_rest_per_splat();
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) g.position[3 * i + k] = range(-1, 1);
    const float base = std::log(range(0.008f, 0.08f));
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = base + std::log(range(0.15f, 2.5f));
    const float len = range(0.3f, 3.0f);
    for (int k = 0; k < 4; ++k) g.rotation[4 * i + k] = normal(rng) * len;
    g.opacity[i] = range(-5, 6);
    for (int k = 0; k < 3; ++k) g.sh_dc[3 * i + k] = range(-1.7f, 1.7f);
    for (size_t k = 0; k < K; ++k) g.sh_rest[i * K + k] = range(-0.35f, 0.35f);
  }
  return g;
}

// The same splats with SH truncated to `degree` (the first coefficients of each channel).
GaussianCloud WithDegree(const GaussianCloud& g, int degree) {
  GaussianCloud out = g;
  out.sh_degree = degree;
  const size_t from = static_cast<size_t>(formats::ShRestPerChannel(g.sh_degree));
  const size_t to = static_cast<size_t>(formats::ShRestPerChannel(degree));
  out.sh_rest.assign(g.size() * 3 * to, 0);
  for (size_t i = 0; i < g.size(); ++i)
    for (size_t ch = 0; ch < 3; ++ch)
      for (size_t k = 0; k < to; ++k)
        out.sh_rest[(i * 3 + ch) * to + k] = g.sh_rest[(i * 3 + ch) * from + k];
  return out;
}

// Cameras around and inside the cube.
std::vector<Camera> TestCameras() {
  std::vector<Camera> cams;
  // Outside, looking at the centre.
  cams.push_back(Camera::LookAt({0.3, -0.6, -3.2}, {0, 0, 0}, {0, -1, 0}, 50, 200, 150));
  // Oblique, an image size that is not a multiple of 16, off-centre principal point, fx != fy.
  Camera c = Camera::LookAt({2.4, 1.1, 1.7}, {0.1, 0, 0}, {0, -1, 0}, 45, 203, 147);
  c.fx *= 1.1;
  c.cx += 13.25;
  c.cy -= 7.5;
  cams.push_back(c);
  // Inside the cloud: splats behind the camera, at the near plane, and larger than the image.
  cams.push_back(Camera::LookAt({0.1, 0.2, -0.3}, {1, -0.2, 1}, {0, -1, 0}, 70, 200, 150));
  // Just outside a face: many splats a little either side of z = 0.2.
  cams.push_back(Camera::LookAt({0, 0, -1.1}, {0, 0, 0}, {0, -1, 0}, 60, 192, 144));
  return cams;
}

TEST(GaussianRaster, MatchesReferenceFromSeveralCameras) {
  const GaussianCloud g = RandomCloud(3000, 3, 7);
  for (const Camera& cam : TestCameras()) ExpectMatchesReference(g, cam);
}

TEST(GaussianRaster, MatchesReferenceForEveryShDegree) {
  const GaussianCloud g3 = RandomCloud(2500, 3, 11);
  const Camera cam = TestCameras()[1];
  for (int d = 0; d <= 3; ++d) {
    SCOPED_TRACE("sh_degree " + std::to_string(d));
    ExpectMatchesReference(WithDegree(g3, d), cam);
  }
}

TEST(GaussianRaster, MatchesReferenceAntialiased) {
  GaussianCloud g = RandomCloud(3000, 2, 13);
  g.antialiased = true;
  for (const Camera& cam : TestCameras()) ExpectMatchesReference(g, cam);
}

TEST(GaussianRaster, MatchesReferenceWithBackground) {
  const GaussianCloud g = RandomCloud(2000, 1, 17);
  const Camera cam = TestCameras()[0];
  ExpectMatchesReference(g, cam, {0.2f, 0.5f, 0.9f});
}

// A real surface: the Stanford bunny's scanned points (res2, 8171 vertices) as flat splats in
// random orientations, coloured by height with degree-2 SH.
TEST(GaussianRaster, MatchesReferenceOnTheScannedBunny) {
  const std::string path =
      std::string(HVDB_SHARED_DATA) + "/stanford-bunny/reconstruction/bun_zipper_res2.ply";
  ASSERT_TRUE(std::filesystem::exists(path)) << path << " is not there (../shared/data)";
  auto points = formats::ReadPly(path);
  ASSERT_TRUE(points.ok()) << points.status().ToString();
  const size_t n = points->size();
  GaussianCloud g = RandomCloud(n, 2, 19);
  for (size_t i = 0; i < n; ++i) {
    const Point& p = (*points)[i];
    g.position[3 * i] = p.x;
    g.position[3 * i + 1] = -p.y;  // the scan is y up; the cloud y down
    g.position[3 * i + 2] = p.z;
    g.scale[3 * i] = g.scale[3 * i + 1] = std::log(0.0025f);
    g.scale[3 * i + 2] = std::log(0.0004f);
    g.opacity[i] = 2.5f;
    g.sh_dc[3 * i] = (p.y - 0.1f) * 20;
  }
  const Camera cam =
      Camera::LookAt({-0.02, -0.1, -0.3}, {-0.02, -0.1, 0}, {0, -1, 0}, 40, 160, 160);
  ExpectMatchesReference(g, cam, {0.1f, 0.1f, 0.1f}, 0.2);
}

// ----- Exact values -----

// 101 x 81 pixels, focal length 100, the optical axis through the centre of pixel (50, 40).
Camera CentredCamera() {
  Camera cam;
  cam.width = 101, cam.height = 81;
  cam.fx = cam.fy = 100;
  cam.cx = 50, cam.cy = 40;
  return cam;
}

// One isotropic splat straight ahead: every quantity is known in closed form.
TEST(GaussianRaster, SingleSplatHasTheExpectedPixels) {
  const Camera cam = CentredCamera();
  GaussianCloud g;
  g.sh_degree = 1;
  g.Resize(1);
  g.position = {0, 0, 2};     // u = 50, v = 40: the centre of pixel (50, 40)
  const double sigma = 0.02;  // 1 pixel at z = 2: screen variance 1 + 0.3
  g.scale = {std::log(0.02f), std::log(0.02f), std::log(0.02f)};
  g.rotation = {1, 0, 0, 0};
  g.opacity = {0};  // sigmoid: 0.5
  g.sh_dc = {1.0f, -0.5f, 0.25f};
  // Degree 1, channel-major f_rest (R: 3, G: 3, B: 3). Towards +z only the second coefficient
  // (SH_C1 z) counts: give G one.
  g.sh_rest.assign(9, 0);
  g.sh_rest[3 + 1] = 0.4f;
  g.sh_rest[3 + 0] = 5.0f;  // y and x coefficients: the direction has neither
  g.sh_rest[3 + 2] = 5.0f;
  const double c0 = 0.28209479177387814, c1 = 0.4886025119029199;
  const double rgb[3] = {0.5 + c0 * 1.0, 0.5 + c0 * -0.5 + c1 * 0.4, 0.5 + c0 * 0.25};
  GaussianImage img;
  GaussianRenderOptions options;
  options.background = {0.1f, 0.2f, 0.3f};
  ASSERT_TRUE(RenderGaussians(g, cam, options, &img).ok());
  const double var = (100 * sigma / 2) * (100 * sigma / 2) + 0.3;
  auto expect_pixel = [&](int x, int y) {
    const double d2 = (x - 50.0) * (x - 50.0) + (y - 40.0) * (y - 40.0);
    const double alpha = 0.5 * std::exp(-0.5 * d2 / var);
    const size_t at = static_cast<size_t>(y) * cam.width + x;
    for (int ch = 0; ch < 3; ++ch) {
      EXPECT_NEAR(img.rgb[3 * at + ch], rgb[ch] * alpha + (1 - alpha) * options.background[ch],
                  1e-5)
          << x << "," << y << " channel " << ch;
    }
    EXPECT_NEAR(img.alpha[at], alpha, 1e-6) << x << "," << y;
  };
  expect_pixel(50, 40);  // alpha 0.5 exactly
  EXPECT_FLOAT_EQ(img.alpha[40 * 101 + 50], 0.5f);
  expect_pixel(51, 40);
  expect_pixel(49, 41);
  expect_pixel(52, 38);
  // Radius ceil(3 sqrt(1.3)) = 4 pixels, but alpha falls below 1/255 at d^2 > 2 ln(127.5) 1.3
  // (~3.56 pixels): the pixel 4 away is background.
  const size_t far = 40 * 101 + 54;
  EXPECT_EQ(img.alpha[far], 0.0f);
  EXPECT_FLOAT_EQ(img.rgb[3 * far + 2], 0.3f);
  const std::vector<uint8_t> rgba = img.ToRgba8();
  EXPECT_EQ(rgba[4 * (40 * 101 + 50) + 3], 128);  // round(0.5 * 255) = round(127.5)
  EXPECT_EQ(rgba[4 * far + 0], 26);               // round(0.1 * 255) = round(25.5)
}

TEST(GaussianRaster, OpaqueSplatsStopThePixel) {
  // Three splats on the axis, front one 0.99 opaque after the clamp: the second brings T to
  // 1e-4 exactly in the equations; T (1 - alpha) < 1e-4 ends the pixel before the third.
  Camera cam;
  cam.width = cam.height = 32;
  cam.fx = cam.fy = 50;
  cam.cx = cam.cy = 16;
  GaussianCloud g;
  g.Resize(3);
  g.position = {0, 0, 1, 0, 0, 2, 0, 0, 3};
  for (size_t i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = std::log(0.2f);
    g.rotation[4 * i] = 1;
    g.opacity[i] = 8;  // sigmoid 0.99966: alpha clamped to 0.99
  }
  g.sh_dc = {1, 1, 1, -1, -1, -1, 3, 0, 0};
  GaussianImage img;
  ASSERT_TRUE(RenderGaussians(g, cam, {}, &img).ok());
  const size_t c = 16 * 32 + 16;
  const double first = 0.5 + 0.28209479177387814;
  const double second = 0.5 - 0.28209479177387814;
  // Second: T = 0.01, alpha 0.99 -> test T = 1e-4 in real numbers; in float 0.01 * 0.01 lands
  // within a rounding of the threshold either way, so accept both endings, never the third.
  const double one = first * 0.99;
  const double two = one + second * 0.99 * 0.01;
  EXPECT_TRUE(std::abs(img.rgb[3 * c] - one) < 1e-5 || std::abs(img.rgb[3 * c] - two) < 1e-5)
      << img.rgb[3 * c];
  EXPECT_LT(img.rgb[3 * c + 0], two + 1e-5);  // the red third splat never added
}

// ----- Properties -----

TEST(GaussianRaster, SameImageWhateverTheThreadCount) {
  const GaussianCloud g = RandomCloud(4000, 3, 23);
  const Camera cam = TestCameras()[2];
  GaussianImage one, three;
  GaussianRenderOptions options;
  options.threads = 1;
  ASSERT_TRUE(RenderGaussians(g, cam, options, &one).ok());
  options.threads = 3;
  GaussianRasterizer rasterizer;
  // A rasterizer reused across clouds and sizes gives what a fresh one gives.
  GaussianImage other;
  ASSERT_TRUE(rasterizer.Render(RandomCloud(500, 0, 1), TestCameras()[1], options, &other).ok());
  ASSERT_TRUE(rasterizer.Render(g, cam, options, &three).ok());
  EXPECT_EQ(one.rgb, three.rgb);
  EXPECT_EQ(one.alpha, three.alpha);
}

// Enough splats that every step splits its work (the depth sort into slices, the tile lists
// into chunks): 1 and 3 threads must still give the same image bit for bit.
TEST(GaussianRaster, LargeCloudSameImageWhateverTheThreadCount) {
  GaussianCloud g = RandomCloud(300000, 1, 31);
  for (size_t i = 0; i < g.size(); ++i) {
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] -= 1.5f;  // smaller: ~1-3 pixels
  }
  const Camera cam = Camera::LookAt({0.2, -0.3, -2.6}, {0, 0, 0}, {0, -1, 0}, 60, 320, 240);
  GaussianImage one, three;
  GaussianRenderStats s1, s3;
  GaussianRenderOptions options;
  options.threads = 1;
  ASSERT_TRUE(RenderGaussians(g, cam, options, &one, &s1).ok());
  options.threads = 3;
  ASSERT_TRUE(RenderGaussians(g, cam, options, &three, &s3).ok());
  EXPECT_GT(s1.splats_visible, 200000u);
  EXPECT_EQ(s1.splats_visible, s3.splats_visible);
  EXPECT_EQ(s1.tile_entries, s3.tile_entries);
  EXPECT_EQ(one.rgb, three.rgb);
  EXPECT_EQ(one.alpha, three.alpha);
}

// Splats at exactly the same depth blend in index order, as the reference's stable sort puts
// them, also when the depth sort splits its work (over 65536 visible splats: slices and
// buckets) and whatever the thread count.
TEST(GaussianRaster, TiedDepthsBlendInIndexOrder) {
  const Camera cam = CentredCamera();
  GaussianCloud g;
  g.sh_degree = 0;
  const size_t n = 100000;
  g.Resize(n);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> x(0.8f, 1.5f), y(-1, 1), z(5, 10);
  for (size_t i = 0; i < n; ++i) {  // tiny splats off to the side, behind: not at the centre
    g.position[3 * i] = x(rng), g.position[3 * i + 1] = y(rng), g.position[3 * i + 2] = z(rng);
    for (int k = 0; k < 3; ++k) g.scale[3 * i + k] = std::log(0.004f);
    g.rotation[4 * i] = 1;
    g.opacity[i] = 2;
  }
  // Red, green and blue, the same splat otherwise, at indices far apart.
  const size_t at[3] = {10, 50000, 99990};
  const double c0 = 0.28209479177387814;
  for (int k = 0; k < 3; ++k) {
    const size_t i = at[k];
    g.position[3 * i] = 0, g.position[3 * i + 1] = 0, g.position[3 * i + 2] = 2;
    for (int c = 0; c < 3; ++c) {
      g.scale[3 * i + c] = std::log(0.05f);
      g.sh_dc[3 * i + c] = static_cast<float>((c == k ? 0.5 : -0.5) / c0);  // colour 1 or 0
    }
    g.opacity[i] = 0;  // 0.5
  }
  for (int threads : {1, 3}) {
    GaussianImage img;
    GaussianRenderOptions options;
    options.threads = threads;
    GaussianRenderStats stats;
    ASSERT_TRUE(RenderGaussians(g, cam, options, &img, &stats).ok());
    EXPECT_GT(stats.splats_visible, 65536u);
    const size_t centre = 40 * 101 + 50;  // alpha 0.5 each: 0.5 red, 0.25 green, 0.125 blue
    EXPECT_NEAR(img.rgb[3 * centre + 0], 0.5, 1e-5) << threads << " threads";
    EXPECT_NEAR(img.rgb[3 * centre + 1], 0.25, 1e-5) << threads << " threads";
    EXPECT_NEAR(img.rgb[3 * centre + 2], 0.125, 1e-5) << threads << " threads";
    EXPECT_NEAR(img.alpha[centre], 0.875, 1e-6) << threads << " threads";
  }
}

TEST(GaussianRaster, EmptyCloudGivesTheBackground) {
  GaussianCloud g;
  const Camera cam = TestCameras()[0];
  GaussianImage img;
  GaussianRenderOptions options;
  options.background = {0.25f, 0.5f, 1.0f};
  GaussianRenderStats stats;
  ASSERT_TRUE(RenderGaussians(g, cam, options, &img, &stats).ok());
  ASSERT_EQ(img.alpha.size(), size_t{200} * 150);
  for (size_t i = 0; i < img.alpha.size(); ++i) {
    ASSERT_EQ(img.alpha[i], 0.0f);
    ASSERT_EQ(img.rgb[3 * i], 0.25f);
    ASSERT_EQ(img.rgb[3 * i + 1], 0.5f);
    ASSERT_EQ(img.rgb[3 * i + 2], 1.0f);
  }
  EXPECT_EQ(stats.splats_in, 0u);
  EXPECT_EQ(stats.tile_entries, 0u);
  // Everything behind the camera: the background too.
  GaussianCloud behind = RandomCloud(100, 0, 3);
  for (size_t i = 0; i < behind.size(); ++i) behind.position[3 * i + 2] -= 10;
  Camera ahead;  // at the origin looking along +z
  ASSERT_TRUE(RenderGaussians(behind, ahead, options, &img, &stats).ok());
  EXPECT_EQ(stats.splats_visible, 0u);
  EXPECT_EQ(*std::max_element(img.alpha.begin(), img.alpha.end()), 0.0f);
}

TEST(GaussianRaster, RefusesWhatItCannotRender) {
  const GaussianCloud g = RandomCloud(10, 1, 5);
  GaussianImage img;
  Camera cam = TestCameras()[0];
  cam.distortion[0] = 0.1;
  Status s = RenderGaussians(g, cam, {}, &img);
  EXPECT_TRUE(s.IsInvalidArgument());
  EXPECT_EQ(s.message().rfind("gaussian mode renders pinhole cameras", 0), 0u) << s.message();
  for (auto [w, h] : {std::pair<uint32_t, uint32_t>{0, 100}, {100, 0}, {4097, 100}}) {
    cam = TestCameras()[0];
    cam.width = w;
    cam.height = h;
    EXPECT_TRUE(RenderGaussians(g, cam, {}, &img).IsInvalidArgument()) << w << "x" << h;
  }
  cam = TestCameras()[0];
  GaussianCloud bad = g;
  bad.sh_rest.pop_back();
  EXPECT_TRUE(RenderGaussians(bad, cam, {}, &img).IsInvalidArgument());
  bad = g;
  bad.sh_degree = 4;
  EXPECT_TRUE(RenderGaussians(bad, cam, {}, &img).IsInvalidArgument());
  GaussianRenderOptions options;
  options.threads = -1;
  EXPECT_TRUE(RenderGaussians(g, cam, options, &img).IsInvalidArgument());
}

TEST(GaussianRaster, NonFiniteSplatsAreCulled) {
  GaussianCloud g = RandomCloud(200, 1, 29);
  const Camera cam = TestCameras()[0];
  GaussianImage want;
  ASSERT_TRUE(RenderGaussians(g, cam, {}, &want).ok());
  // Splats nobody can see, with NaN and infinite values, change nothing.
  GaussianCloud more = g;
  more.Resize(g.size() + 3);
  const size_t n = g.size();
  more.position[3 * n] = std::nanf("");
  more.position[3 * (n + 1) + 2] = 1;
  more.scale[3 * (n + 1)] = INFINITY;
  more.position[3 * (n + 2) + 2] = 1;
  more.sh_dc[3 * (n + 2)] = INFINITY;
  more.opacity[n + 2] = 10;
  GaussianImage got;
  ASSERT_TRUE(RenderGaussians(more, cam, {}, &got).ok());
  EXPECT_EQ(want.rgb, got.rgb);
}

TEST(GaussianRaster, ToRgba8RoundsAndClamps) {
  GaussianImage img;
  img.width = 2, img.height = 1;
  img.rgb = {-0.5f, 0.5f, 2.0f, 1.0f / 255, 0.998f, 0.0019f};
  img.alpha = {0.25f, 1.0f};
  const std::vector<uint8_t> want = {0, 128, 255, 64, 1, 254, 0, 255};
  EXPECT_EQ(img.ToRgba8(), want);
}

// ----- The same on the GPU through EGL (render/egl_gaussian.h; Mesa's llvmpipe here) -----

// Against the double-precision reference: the GPU composites without the reference's 1e-4
// transmittance stop and in the driver's float (its exp and log), so a splat whose alpha lies
// within rounding of 1/255 at a pixel may be kept on one side and skipped on the other: the
// bounds are 50 dB (the 40 with room; llvmpipe gives 73-86) and 4 steps in 8 bits at
// any pixel, where the CPU rasteriser holds 60 dB and one step.
void ExpectEglMatchesReference(EglGaussianRasterizer& egl, const GaussianCloud& g,
                               const Camera& cam, std::array<float, 3> bg = {0, 0, 0}) {
  GaussianImage img;
  GaussianRenderOptions options;
  options.background = bg;
  GaussianRenderStats stats;
  Status st = egl.Render(g, cam, options, &img, &stats);
  ASSERT_TRUE(st.ok()) << st.ToString();
  ASSERT_EQ(img.rgb.size(), 3 * size_t{cam.width} * cam.height);
  const Agreement a = Compare(img, RefRender(g, cam, bg));
  EXPECT_GE(a.psnr, 50) << "max 8-bit difference " << a.max_diff8;
  EXPECT_LE(a.max_diff8, 4) << "PSNR " << a.psnr;
  EXPECT_GE(a.mean_alpha, 0.05);
  std::printf("  egl %u x %u: PSNR %.1f dB, max 8-bit diff %d (%s)\n", cam.width, cam.height,
              a.psnr, a.max_diff8, egl.name().c_str());
}

TEST(EglGaussian, MatchesReferenceFromEveryCameraDegreeAndBackground) {
  auto egl = EglGaussianRasterizer::Create();
  ASSERT_TRUE(egl.ok()) << egl.status().ToString();
  const GaussianCloud g = RandomCloud(3000, 3, 7);
  for (const Camera& cam : TestCameras()) ExpectEglMatchesReference(**egl, g, cam);
  for (int d = 0; d <= 2; ++d) {
    SCOPED_TRACE("sh_degree " + std::to_string(d));
    ExpectEglMatchesReference(**egl, WithDegree(g, d), TestCameras()[1]);
  }
  GaussianCloud aa = RandomCloud(2000, 1, 13);
  aa.antialiased = true;
  ExpectEglMatchesReference(**egl, aa, TestCameras()[0], {0.2f, 0.5f, 0.9f});
}

TEST(EglGaussian, EmptyNonFiniteAndRefused) {
  auto egl = EglGaussianRasterizer::Create();
  ASSERT_TRUE(egl.ok()) << egl.status().ToString();
  GaussianImage img;
  GaussianRenderOptions options;
  options.background = {0.25f, 0.5f, 1.0f};
  ASSERT_TRUE((*egl)->Render(GaussianCloud{}, TestCameras()[0], options, &img).ok());
  for (size_t i = 0; i < img.alpha.size(); ++i) {
    ASSERT_EQ(img.alpha[i], 0.0f);
    ASSERT_EQ(img.rgb[3 * i + 2], 1.0f);
  }
  // Non-finite splats change nothing, as on the CPU.
  GaussianCloud g = RandomCloud(200, 1, 29);
  GaussianImage want, got;
  ASSERT_TRUE((*egl)->Render(g, TestCameras()[0], {}, &want).ok());
  const size_t n = g.size();
  g.Resize(n + 2);
  g.position[3 * n] = std::nanf("");
  g.position[3 * (n + 1) + 2] = 1;
  g.sh_dc[3 * (n + 1)] = INFINITY;
  g.opacity[n + 1] = 10;
  ASSERT_TRUE((*egl)->Render(g, TestCameras()[0], {}, &got).ok());
  EXPECT_EQ(want.rgb, got.rgb);
  Camera distorted = TestCameras()[0];
  distorted.distortion[0] = 0.1;
  EXPECT_TRUE((*egl)->Render(g, distorted, {}, &img).IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb::render
