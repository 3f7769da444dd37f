// The 3DGS forward rasteriser on the CPU (gaussian_raster.h).
//
// Why it is ours: no Debian package provides a CPU rasteriser of 3D Gaussian splats. The
// reference (graphdeco-inria/diff-gaussian-rasterization) and gsplat are CUDA extensions of
// PyTorch, and the viewers that draw 3DGS scenes do it in WebGL/Vulkan shaders with a global
// approximate sort and none of the reference's per-pixel early termination, so their images
// differ from the reference's. This file follows forward.cu's equations in float, organised
// for a few CPU cores instead of a GPU:
//
//  1. Preprocess, in parallel over chunks of splats: the view-space centre, the 2D covariance
//     and its conic, the opacity, the SH colour, the reference's tile rectangle, and the
//     ellipse where the splat's alpha can reach 1/255 (outside it every pixel skips the splat,
//     so leaving those pixels out changes nothing): its pixel box, and per row its span. The
//     visible splats of a chunk are packed into one 64-byte record each, in index order.
//  2. Bin: the records' depths radix-sorted (stable: ties keep index order, as the
//     reference's radix sort of tile|depth keys), then a counting sort by tile of the record
//     indices in that order, chunk after chunk, so that every tile's list comes out sorted
//     front to back. A splat goes to the tiles of the reference's rectangle that its box
//     reaches (in the others it would be skipped at every pixel).
//  3. Each tile, in parallel: its records gathered a batch at a time, and each blended over
//     the span of each of its rows, 8 pixels a vector (simd.h: AVX-512, AVX2 or SSE2 clone).
//     Pixels stop at the reference's transmittance threshold; a tile stops when all have.
#include "render/gaussian_raster.h"

#include <sys/mman.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>

#include "render/splat.h"
// simd.h's helpers pass vectors by value and are always inlined (see cpu_renderer.cc).
#pragma GCC diagnostic ignored "-Wpsabi"
#include "render/simd.h"

namespace hvdb::render {

namespace {

using internal::Broadcast;
using internal::F8;
using internal::ParallelFor;

constexpr int kTile = 16;  // the reference's BLOCK_X = BLOCK_Y
constexpr float kNearZ = 0.2f;
constexpr float kDilation = 0.3f;  // pixels^2 added to the 2D covariance's diagonal
constexpr float kMinAlpha = 1.0f / 255.0f;
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 0.0001f;
constexpr size_t kMinChunk = 16384;  // splats per task of steps 1 and 2
constexpr size_t kMaxChunks = 64;    // bounds the per-chunk tile counters
constexpr size_t kBatch = 64;        // records a tile gathers at a time
constexpr size_t kMaxListBytes = size_t{4} << 30;
constexpr size_t kKeepBytes = size_t{512} << 20;

// The reference's spherical-harmonic constants (auxiliary.h).
constexpr float kC0 = 0.28209479177387814f;
constexpr float kC1 = 0.4886025119029199f;
constexpr float kC2[5] = {1.0925484305920792f, -1.0925484305920792f, 0.31539156525252005f,
                          -1.0925484305920792f, 0.5462742152960396f};
constexpr float kC3[7] = {-0.5900435899266435f, 2.890611442640554f, -0.4570457994644658f,
                          0.3731763325901154f,  -0.4570457994644658f, 1.445305721320277f,
                          -0.5900435899266435f};

// A visible splat, as blending needs it: one cache line.
struct alignas(64) Record {
  float u, v;     // pixel position of the centre
  float a, b, c;  // conic: the inverse of the dilated 2D covariance (a b; b c)
  float opacity;  // after the sigmoid (and the antialiasing compensation)
  float rgb[3];
  // The ellipse where alpha can reach 1/255, in pixel offsets (ox, oy) from the centre: in
  // row oy it spans ox = slope oy -+ sqrt(half2 - half2_dy oy^2).
  float slope, half2, half2_dy;
  int16_t x0, x1, y0, y1;       // its pixel box, inclusive (within the image and the tiles)
  uint16_t tx0, tx1, ty0, ty1;  // its tiles, [tx0, tx1) x [ty0, ty1)
};
static_assert(sizeof(Record) == 64);

// The camera in float, as the reference holds it.
struct ViewF {
  float rot[9];    // camera-from-world rotation, row-major
  float trans[3];  // camera-from-world translation
  float centre[3]; // camera centre in the world
  float fx, fy, cx, cy;
  float lim_x, lim_y;  // 1.3 tan(half fov): the EWA Jacobian's clamp of x/z and y/z
  int width, height, tiles_x, tiles_y;
};

ViewF MakeView(const Camera& cam) {
  const auto& m = cam.world_from_camera;  // [R | t]: camera-from-world is [R^T | -R^T t]
  ViewF v{};
  for (int i = 0; i < 3; ++i) {
    double t = 0;
    for (int j = 0; j < 3; ++j) {
      v.rot[3 * i + j] = static_cast<float>(m[4 * j + i]);
      t -= m[4 * j + i] * m[4 * j + 3];
    }
    v.trans[i] = static_cast<float>(t);
    v.centre[i] = static_cast<float>(m[4 * i + 3]);
  }
  v.fx = static_cast<float>(cam.fx);
  v.fy = static_cast<float>(cam.fy);
  v.cx = static_cast<float>(cam.cx);
  v.cy = static_cast<float>(cam.cy);
  const float tan_fovx = static_cast<float>(cam.width / (2.0 * cam.fx));
  const float tan_fovy = static_cast<float>(cam.height / (2.0 * cam.fy));
  v.lim_x = 1.3f * tan_fovx;
  v.lim_y = 1.3f * tan_fovy;
  v.width = static_cast<int>(cam.width);
  v.height = static_cast<int>(cam.height);
  v.tiles_x = (v.width + kTile - 1) / kTile;
  v.tiles_y = (v.height + kTile - 1) / kTile;
  return v;
}

// getRect's tile index: (int) of a float clamped to [0, grid] (truncation and clamping commute
// there, and the float is finite: no undefined conversion).
inline int TileIndex(float t, int grid) {
  return static_cast<int>(std::min(std::max(t, 0.0f), static_cast<float>(grid)));
}

// Step 1 for splat i: false when it is culled or can reach no pixel.
HVDB_RENDER_CLONES
bool PrepareSplat(const formats::GaussianCloud& g, size_t i, const ViewF& v, Record* out,
                  float* depth) {
  const float* p = &g.position[3 * i];
  const float* R = v.rot;
  const float tx = R[0] * p[0] + R[1] * p[1] + R[2] * p[2] + v.trans[0];
  const float ty = R[3] * p[0] + R[4] * p[1] + R[5] * p[2] + v.trans[1];
  const float tz = R[6] * p[0] + R[7] * p[1] + R[8] * p[2] + v.trans[2];
  if (!(tz > kNearZ)) return false;

  // 3D covariance R S S^T R^T.
  const float* q = &g.rotation[4 * i];
  float qw = q[0], qx = q[1], qy = q[2], qz = q[3];
  const float qn = std::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  if (qn > 0) {
    qw /= qn, qx /= qn, qy /= qn, qz /= qn;
  } else {
    qw = 1, qx = qy = qz = 0;
  }
  const float* ls = &g.scale[3 * i];
  const float s0 = std::exp(ls[0]), s1 = std::exp(ls[1]), s2 = std::exp(ls[2]);
  const float M[9] = {
      (1.f - 2.f * (qy * qy + qz * qz)) * s0, 2.f * (qx * qy - qw * qz) * s1,
      2.f * (qx * qz + qw * qy) * s2,         2.f * (qx * qy + qw * qz) * s0,
      (1.f - 2.f * (qx * qx + qz * qz)) * s1, 2.f * (qy * qz - qw * qx) * s2,
      2.f * (qx * qz - qw * qy) * s0,         2.f * (qy * qz + qw * qx) * s1,
      (1.f - 2.f * (qx * qx + qy * qy)) * s2};  // R S
  auto row_dot = [&](int r, int s) {
    return M[3 * r] * M[3 * s] + M[3 * r + 1] * M[3 * s + 1] + M[3 * r + 2] * M[3 * s + 2];
  };
  const float S00 = row_dot(0, 0), S01 = row_dot(0, 1), S02 = row_dot(0, 2);
  const float S11 = row_dot(1, 1), S12 = row_dot(1, 2), S22 = row_dot(2, 2);

  // EWA: J W Sigma W^T J^T, the Jacobian at the centre clamped to 1.3 times the field of view.
  const float xc = std::min(v.lim_x, std::max(-v.lim_x, tx / tz)) * tz;
  const float yc = std::min(v.lim_y, std::max(-v.lim_y, ty / tz)) * tz;
  const float j00 = v.fx / tz, j02 = -(v.fx * xc) / (tz * tz);
  const float j11 = v.fy / tz, j12 = -(v.fy * yc) / (tz * tz);
  const float t0[3] = {j00 * R[0] + j02 * R[6], j00 * R[1] + j02 * R[7], j00 * R[2] + j02 * R[8]};
  const float t1[3] = {j11 * R[3] + j12 * R[6], j11 * R[4] + j12 * R[7], j11 * R[5] + j12 * R[8]};
  const float st0[3] = {S00 * t0[0] + S01 * t0[1] + S02 * t0[2],
                        S01 * t0[0] + S11 * t0[1] + S12 * t0[2],
                        S02 * t0[0] + S12 * t0[1] + S22 * t0[2]};
  const float st1[3] = {S00 * t1[0] + S01 * t1[1] + S02 * t1[2],
                        S01 * t1[0] + S11 * t1[1] + S12 * t1[2],
                        S02 * t1[0] + S12 * t1[1] + S22 * t1[2]};
  float cxx = t0[0] * st0[0] + t0[1] * st0[1] + t0[2] * st0[2];
  const float cxy = t1[0] * st0[0] + t1[1] * st0[1] + t1[2] * st0[2];
  float cyy = t1[0] * st1[0] + t1[1] * st1[1] + t1[2] * st1[2];
  const float det0 = cxx * cyy - cxy * cxy;
  cxx += kDilation;
  cyy += kDilation;
  const float det = cxx * cyy - cxy * cxy;
  if (det == 0.0f) return false;

  float opacity = 1.0f / (1.0f + std::exp(-g.opacity[i]));
  if (g.antialiased) opacity *= std::sqrt(std::max(0.0f, det0 / det));
  const float det_inv = 1.0f / det;
  const float ca = cyy * det_inv, cb = -cxy * det_inv, cc = cxx * det_inv;
  const float mid = 0.5f * (cxx + cyy);
  const float lambda1 = mid + std::sqrt(std::max(0.1f, mid * mid - det));
  const float radius = std::ceil(3.0f * std::sqrt(lambda1));
  const float u = v.fx * tx / tz + v.cx, w = v.fy * ty / tz + v.cy;
  if (!std::isfinite(u) || !std::isfinite(w) || !std::isfinite(radius) ||
      !std::isfinite(ca + cb + cc) || !std::isfinite(cxx + cyy) || !std::isfinite(opacity)) {
    return false;
  }
  // getRect: tiles [rx0, rx1) x [ry0, ry1).
  const int rx0 = TileIndex((u - radius) / kTile, v.tiles_x);
  const int ry0 = TileIndex((w - radius) / kTile, v.tiles_y);
  const int rx1 = TileIndex((u + radius + kTile - 1) / kTile, v.tiles_x);
  const int ry1 = TileIndex((w + radius + kTile - 1) / kTile, v.tiles_y);
  if ((rx1 - rx0) * (ry1 - ry0) == 0) return false;
  // alpha = min(0.99, opacity e^power) with power <= 0 never reaches 1/255: no pixel uses it.
  if (!(opacity >= kMinAlpha)) return false;

  // The box of the ellipse d^T conic d <= 2 ln(255 opacity) (alpha >= 1/255 within), widened
  // against rounding, in pixel centres; cut to the reference's rectangle and the image.
  const float k = 2.0f * std::log(255.0f * opacity) * 1.001f + 0.01f;
  const float ex = std::sqrt(k * cxx) * 1.001f + 0.01f;
  const float ey = std::sqrt(k * cyy) * 1.001f + 0.01f;
  auto pixel = [](float f, int size) {  // f clamped to [-1, size]: no undefined conversion
    return static_cast<int>(std::min(std::max(f, -1.0f), static_cast<float>(size)));
  };
  const int x0 = std::max(pixel(std::ceil(u - ex), v.width), rx0 * kTile);
  const int x1 = std::min({pixel(std::floor(u + ex), v.width), rx1 * kTile - 1, v.width - 1});
  const int y0 = std::max(pixel(std::ceil(w - ey), v.height), ry0 * kTile);
  const int y1 = std::min({pixel(std::floor(w + ey), v.height), ry1 * kTile - 1, v.height - 1});
  if (x0 > x1 || y0 > y1) return false;

  // Colour: SH of the direction from the camera centre, + 0.5, clamped below at 0.
  float dx = p[0] - v.centre[0], dy = p[1] - v.centre[1], dz = p[2] - v.centre[2];
  const float len = std::sqrt(dx * dx + dy * dy + dz * dz);
  dx /= len, dy /= len, dz /= len;
  float basis[15];
  const int deg = g.sh_degree;
  if (deg > 0) {
    basis[0] = -kC1 * dy;
    basis[1] = kC1 * dz;
    basis[2] = -kC1 * dx;
  }
  if (deg > 1) {
    const float xx = dx * dx, yy = dy * dy, zz = dz * dz;
    basis[3] = kC2[0] * dx * dy;
    basis[4] = kC2[1] * dy * dz;
    basis[5] = kC2[2] * (2.0f * zz - xx - yy);
    basis[6] = kC2[3] * dx * dz;
    basis[7] = kC2[4] * (xx - yy);
    if (deg > 2) {
      basis[8] = kC3[0] * dy * (3.0f * xx - yy);
      basis[9] = kC3[1] * dx * dy * dz;
      basis[10] = kC3[2] * dy * (4.0f * zz - xx - yy);
      basis[11] = kC3[3] * dz * (2.0f * zz - 3.0f * xx - 3.0f * yy);
      basis[12] = kC3[4] * dx * (4.0f * zz - xx - yy);
      basis[13] = kC3[5] * dz * (xx - yy);
      basis[14] = kC3[6] * dx * (xx - 3.0f * yy);
    }
  }
  const int per_channel = formats::ShRestPerChannel(deg);
  const float* rest = g.sh_rest.data() + i * 3 * static_cast<size_t>(per_channel);
  for (int ch = 0; ch < 3; ++ch) {
    float s = kC0 * g.sh_dc[3 * i + ch];
    for (int j = 0; j < per_channel; ++j) s += basis[j] * rest[ch * per_channel + j];
    s += 0.5f;
    if (!std::isfinite(s)) return false;
    out->rgb[ch] = std::max(s, 0.0f);
  }
  out->u = u;
  out->v = w;
  out->a = ca;
  out->b = cb;
  out->c = cc;
  out->opacity = opacity;
  out->slope = -cb / ca;
  out->half2 = k / ca;
  out->half2_dy = det_inv / ca;
  *depth = tz;
  out->x0 = static_cast<int16_t>(x0);
  out->x1 = static_cast<int16_t>(x1);
  out->y0 = static_cast<int16_t>(y0);
  out->y1 = static_cast<int16_t>(y1);
  out->tx0 = static_cast<uint16_t>(x0 / kTile);
  out->tx1 = static_cast<uint16_t>(x1 / kTile + 1);
  out->ty0 = static_cast<uint16_t>(y0 / kTile);
  out->ty1 = static_cast<uint16_t>(y1 / kTile + 1);
  return true;
}

// A tile's pixels, row-major: two vectors of 8 a row.
struct alignas(64) TileState {
  float T[kTile][kTile], r[kTile][kTile], g[kTile][kTile], b[kTile][kTile];
  float live[kTile][kTile];  // 1: the pixel still blends; 0: it stopped, or is not one
  uint32_t live_rows;        // bit y: row y has a live pixel
};

// Horizontal minimum or maximum.
typedef float F4 __attribute__((vector_size(16)));
HVDB_SIMD_INLINE float Fold(F8 v, bool max) {
  const F4 a = __builtin_shufflevector(v, v, 0, 1, 2, 3);
  const F4 b = __builtin_shufflevector(v, v, 4, 5, 6, 7);
  const F4 m4 = max ? internal::Max(a, b) : internal::Min(a, b);
  const F4 c = __builtin_shufflevector(m4, m4, 2, 3, 0, 1);
  const F4 m2 = max ? internal::Max(m4, c) : internal::Min(m4, c);
  const F4 d = __builtin_shufflevector(m2, m2, 1, 0, 3, 2);
  return (max ? internal::Max(m2, d) : internal::Min(m2, d))[0];
}

// e^x for x in [-20, 0], two vectors at once, their operations interleaved (one exp is a chain
// of ~15 dependent operations; two side by side keep the core busy where one leaves it
// waiting). Cephes' expf, as simd.h's Exp (the same polynomial, within an ulp of std::exp),
// with x log2(e) rounded to nearest by adding 1.5 2^23 instead of a floor.
HVDB_SIMD_INLINE void Exp2(F8* p, F8* q) {
  using internal::I8;
  constexpr float kRound = 12582912.0f;  // 1.5 2^23: adding it rounds to an integer
  const F8 x = *p, y = *q;
  const F8 fx = x * 1.44269504088896341f + kRound, fy = y * 1.44269504088896341f + kRound;
  const F8 gx = fx - kRound, gy = fy - kRound;  // round(x log2 e)
  I8 nx, ny, kr;
  std::memcpy(&nx, &fx, sizeof nx);
  std::memcpy(&ny, &fy, sizeof ny);
  const F8 round_v = Broadcast<F8>(kRound);
  std::memcpy(&kr, &round_v, sizeof kr);
  nx = (nx - kr) << 23;  // 2^n, as the exponent field
  ny = (ny - kr) << 23;
  F8 rx = x - gx * 0.693359375f, ry = y - gy * 0.693359375f;
  rx = rx - gx * -2.12194440e-4f;
  ry = ry - gy * -2.12194440e-4f;
  const F8 zx = rx * rx, zy = ry * ry;
  F8 px = Broadcast<F8>(1.9875691500e-4f), py = px;
  px = px * rx + 1.3981999507e-3f;
  py = py * ry + 1.3981999507e-3f;
  px = px * rx + 8.3334519073e-3f;
  py = py * ry + 8.3334519073e-3f;
  px = px * rx + 4.1665795894e-2f;
  py = py * ry + 4.1665795894e-2f;
  px = px * rx + 1.6666665459e-1f;
  py = py * ry + 1.6666665459e-1f;
  px = px * rx + 5.0000001201e-1f;
  py = py * ry + 5.0000001201e-1f;
  px = px * zx + rx + 1.0f;
  py = py * zy + ry + 1.0f;
  I8 bx, by;
  std::memcpy(&bx, &px, sizeof bx);
  std::memcpy(&by, &py, sizeof by);
  bx += nx;
  by += ny;
  std::memcpy(p, &bx, sizeof bx);
  std::memcpy(q, &by, sizeof by);
}

// One piece of work of a row: 8 pixels of a splat from tile column `at` on.
struct Piece {
  uint8_t splat, job, at;
};

// alpha of each piece's splat at its pixels, before the pixels' own state: 0 where the
// reference skips the splat (power > 0, or alpha below 1/255), else min(0.99, opacity
// e^power). Two pieces at once (see Exp2). Pixels of the tile that no piece covers lie outside
// the splat's ellipse, where alpha < 1/255: the reference skips them too.
HVDB_SIMD_INLINE void Alpha2(const Record* batch, const Piece& i0, const Piece& i1, int tx0,
                             float py, F8* out0, F8* out1) {
  const F8 lane = internal::VecTraits<F8>::kIota;
  const F8 zero{};
  const Record& s = batch[i0.splat];
  const Record& t = batch[i1.splat];
  // Offsets d = centre - pixel, tile-relative (exact: small integers and the centre's float).
  const F8 dx0 = (s.u - static_cast<float>(tx0 + i0.at)) - lane;
  const F8 dx1 = (t.u - static_cast<float>(tx0 + i1.at)) - lane;
  const float dy0 = s.v - py, dy1 = t.v - py;
  // The reference's -0.5 (a dx^2 + c dy^2) - b dx dy, as (-0.5 a dx - b dy) dx - 0.5 c dy^2.
  const F8 power0 = (-0.5f * s.a * dx0 - s.b * dy0) * dx0 - 0.5f * (s.c * dy0 * dy0);
  const F8 power1 = (-0.5f * t.a * dx1 - t.b * dy1) * dx1 - 0.5f * (t.c * dy1 * dy1);
  // Below -20, alpha < 1e-8 is skipped anyway: the clamp keeps lanes far outside the ellipse
  // from e^-87 and its subnormal products (a microcode assist each).
  F8 e0 = internal::Max(power0, Broadcast<F8>(-20.0f)), e1 = internal::Max(power1, Broadcast<F8>(-20.0f));
  Exp2(&e0, &e1);
  F8 a0 = internal::Min(Broadcast<F8>(kMaxAlpha), s.opacity * e0);
  F8 a1 = internal::Min(Broadcast<F8>(kMaxAlpha), t.opacity * e1);
  a0 = power0 > 0.0f ? zero : a0;
  a1 = power1 > 0.0f ? zero : a1;
  *out0 = a0 >= kMinAlpha ? a0 : zero;
  *out1 = a1 >= kMinAlpha ? a1 : zero;
}

// Eight pixels of a row: what blending carries from splat to splat.
struct Run {
  F8 T, r, g, b, live;
};

// The reference's per-pixel step for 8 pixels given the splat's alpha there; returns the
// smallest T (1 - alpha). Pixels that have stopped get alpha 0.
//
// Only selects (?:) of comparisons, no comparison results as integer vectors (GCC 12 makes
// those a scalar compare per lane in the AVX-512 clone). So a lane that must not change gets
// alpha 0: then T (1 - alpha) = T, never below the threshold (T only ever takes values at or
// above it), and the update adds 0 and keeps T.
HVDB_SIMD_INLINE F8 Step(const Record& s, F8 alpha, Run* run) {
  const F8 zero{};
  alpha = alpha * run->live;
  const F8 test_t = run->T * (1.0f - alpha);
  const F8 wt = test_t < kMinTransmittance ? zero : alpha * run->T;
  run->r += s.rgb[0] * wt;
  run->g += s.rgb[1] * wt;
  run->b += s.rgb[2] * wt;
  run->T = test_t < kMinTransmittance ? run->T : test_t;
  return test_t;
}

// Blends `n` <= kBatch records (front to back) into the tile at pixel (tx0, ty0); true once
// every pixel of the tile has stopped. First each row's jobs (the splats whose ellipse
// reaches it, with the row's span) and items (the halves of the row a job covers); then row by
// row the items' alphas, and the blending in order with the row's pixels in registers.
HVDB_RENDER_CLONES
bool BlendBatch(const Record* batch, size_t n, int tx0, int ty0, TileState* st) {
  using internal::Load;
  using internal::Store;
  Piece items[kTile][2 * kBatch + 2];
  uint8_t splat_of[kTile][kBatch + 1];  // each row's jobs' splats
  int jobs[kTile] = {}, count[kTile] = {};
  for (size_t j = 0; j < n; ++j) {
    const Record& s = batch[j];
    const int ya = std::max<int>(s.y0, ty0) - ty0, yb = std::min<int>(s.y1, ty0 + kTile - 1) - ty0;
    const int xa = std::max<int>(s.x0, tx0) - tx0, xb = std::min<int>(s.x1, tx0 + kTile - 1) - tx0;
    if (xa > xb || ya > yb) continue;
    uint32_t rows = st->live_rows & ((2u << yb) - 1) & ~((1u << ya) - 1);
    const float fxa = static_cast<float>(xa), fxb = static_cast<float>(xb);
    // Without branches on the data: a job and two pieces are written for every row, and the
    // counts advance only by what the row needs (mispredicted branches cost more than that).
    while (rows != 0) {
      const int y = __builtin_ctz(rows);
      rows &= rows - 1;
      // The row's span of the ellipse, widened by a hundredth of a pixel against rounding.
      const float oy = static_cast<float>(ty0 + y) - s.v;
      const float h2 = s.half2 - s.half2_dy * oy * oy;
      const float h = std::sqrt(h2 > 0 ? h2 : 0.0f) + 0.01f;
      const float centre = s.u + s.slope * oy - static_cast<float>(tx0);
      // Clamped (as selects: a branch here mispredicts) to the tile's columns in float, so the
      // conversions are defined whatever the splat's size.
      const float left = std::ceil(centre - h), right = std::floor(centre + h);
      const int lo = static_cast<int>(left > fxa ? left : fxa);
      const int hi = static_cast<int>(right < fxb ? right : fxb);
      const int reached = (h2 >= 0) & (lo <= hi);
      const int job = jobs[y];
      splat_of[y][job] = static_cast<uint8_t>(j);
      Piece* out = items[y] + count[y];
      out[0] = {static_cast<uint8_t>(j), static_cast<uint8_t>(job), static_cast<uint8_t>(lo)};
      out[1] = {static_cast<uint8_t>(j), static_cast<uint8_t>(job), static_cast<uint8_t>(lo + 8)};
      jobs[y] = job + reached;
      count[y] += reached * (1 + (hi - lo >= 8));  // spans are 16 pixels at most
    }
  }
  // Each job's alpha over the tile row, and 8 more columns where a piece may spill over.
  alignas(32) float alpha[kBatch][kTile + 8];
  for (int y = 0; y < kTile; ++y) {
    const int m = count[y];
    if (m == 0) continue;
    const float py = static_cast<float>(ty0 + y);
    for (int k = 0; k < jobs[y]; ++k) {
      for (int at = 0; at < kTile + 8; at += 8) Store(&alpha[k][at], F8{});
    }
    for (int k = 0; k < m; k += 2) {
      const Piece& i0 = items[y][k];
      const Piece& i1 = items[y][std::min(k + 1, m - 1)];
      F8 a0, a1;
      Alpha2(batch, i0, i1, tx0, py, &a0, &a1);
      Store(&alpha[i0.job][i0.at], a0);
      Store(&alpha[i1.job][i1.at], a1);
    }
    Run left{Load<F8>(&st->T[y][0]), Load<F8>(&st->r[y][0]), Load<F8>(&st->g[y][0]),
             Load<F8>(&st->b[y][0]), Load<F8>(&st->live[y][0])};
    Run right{Load<F8>(&st->T[y][8]), Load<F8>(&st->r[y][8]), Load<F8>(&st->g[y][8]),
              Load<F8>(&st->b[y][8]), Load<F8>(&st->live[y][8])};
    for (int k = 0; k < jobs[y]; ++k) {
      const Record& s = batch[splat_of[y][k]];
      const F8 t0 = Step(s, Load<F8>(&alpha[k][0]), &left);
      const F8 t1 = Step(s, Load<F8>(&alpha[k][8]), &right);
      if (Fold(internal::Min(t0, t1), false) < kMinTransmittance) {  // some pixel stops here
        const F8 zero{};
        left.live = t0 < kMinTransmittance ? zero : left.live;
        right.live = t1 < kMinTransmittance ? zero : right.live;
        if (Fold(internal::Max(left.live, right.live), true) == 0.0f) {
          st->live_rows &= ~(1u << y);  // every pixel of the row has stopped
          break;
        }
      }
    }
    const Run* halves[2] = {&left, &right};
    for (int h = 0; h < 2; ++h) {
      Store(&st->T[y][8 * h], halves[h]->T);
      Store(&st->r[y][8 * h], halves[h]->r);
      Store(&st->g[y][8 * h], halves[h]->g);
      Store(&st->b[y][8 * h], halves[h]->b);
      Store(&st->live[y][8 * h], halves[h]->live);
    }
  }
  return st->live_rows == 0;
}

// What step 2 sorts and bins: a visible splat's depth, record and tiles.
struct Item {
  uint32_t depth;  // the float's bits: positive floats order as their bits
  uint32_t index;  // of its record
  uint8_t tx0, ty0, tiles_w, tiles_h;  // tiles [tx0, tx0 + tiles_w] x [ty0, ty0 + tiles_h]
};
static_assert(sizeof(Item) == 12);

// Sorts `n` items by depth, stably: LSD radix sort, 11 bits a pass, on up to `threads` threads
// (each pass: histograms of slices, then each slice scattered). `tmp` holds n items of
// scratch. Passes where every item has the same digit are skipped.
void SortByDepth(Item* items, Item* tmp, size_t n, unsigned threads) {
  constexpr int kBits = 11, kBuckets = 1 << kBits;
  const size_t parts = std::max<size_t>(1, std::min<size_t>(threads, n / 65536));
  std::vector<size_t> at(parts * kBuckets);
  Item *src = items, *dst = tmp;
  auto slice = [&](size_t p) {
    return std::pair<size_t, size_t>(p * n / parts, (p + 1) * n / parts);
  };
  for (int shift = 0; shift < 32; shift += kBits) {
    ParallelFor(parts, static_cast<unsigned>(parts), [&](size_t p) {
      size_t* h = at.data() + p * kBuckets;
      std::fill_n(h, kBuckets, 0);
      const auto [b, e] = slice(p);
      for (size_t i = b; i < e; ++i) ++h[(src[i].depth >> shift) & (kBuckets - 1)];
    });
    bool one_digit = false;
    size_t sum = 0;
    for (int d = 0; d < kBuckets; ++d) {
      size_t digit_total = 0;
      for (size_t p = 0; p < parts; ++p) {
        const size_t k = at[p * kBuckets + d];
        at[p * kBuckets + d] = sum;
        sum += k;
        digit_total += k;
      }
      one_digit = one_digit || digit_total == n;
    }
    if (one_digit) continue;
    ParallelFor(parts, static_cast<unsigned>(parts), [&](size_t p) {
      size_t* next = at.data() + p * kBuckets;
      const auto [b, e] = slice(p);
      for (size_t i = b; i < e; ++i) dst[next[(src[i].depth >> shift) & (kBuckets - 1)]++] = src[i];
    });
    std::swap(src, dst);
  }
  if (src != items) std::memcpy(items, src, n * sizeof(Item));
}

// Anonymous memory of its own on 2 MiB pages where the kernel has them (transparent huge pages
// are "madvise" on Debian): the arrays are large and written once a render.
class Mapped {
 public:
  Mapped() = default;
  Mapped(const Mapped&) = delete;
  Mapped& operator=(const Mapped&) = delete;
  ~Mapped() { Release(); }
  // At least `bytes`, contents unspecified; false when it cannot be mapped.
  bool Reserve(size_t bytes) {
    if (bytes <= bytes_) return true;
    Release();
    const size_t want = bytes + bytes / 4;
    void* p = mmap(nullptr, want, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return false;
    madvise(p, want, MADV_HUGEPAGE);  // advice only
    data_ = p;
    bytes_ = want;
    return true;
  }
  void Release() {
    if (data_ != nullptr) munmap(data_, bytes_);
    data_ = nullptr;
    bytes_ = 0;
  }
  size_t bytes() const { return bytes_; }
  template <typename T>
  T* as() const {
    return static_cast<T*>(data_);
  }

 private:
  void* data_ = nullptr;
  size_t bytes_ = 0;
};

Status CheckArguments(const formats::GaussianCloud& g, const Camera& camera,
                      const GaussianRenderOptions& options) {
  for (double d : camera.distortion) {
    if (d != 0) {
      return Status::InvalidArgument(
          "gaussian mode renders pinhole cameras; this camera has lens distortion (k1 k2 p1 p2 "
          "k3 not all 0): render with the distortion set to 0, or undistort the images first");
    }
  }
  HVDB_RETURN_IF_ERROR(camera.Validate());
  if (options.threads < 0) {
    return Status::InvalidArgument("gaussian render: threads is " +
                                   std::to_string(options.threads) + " (0: every core)");
  }
  if (g.sh_degree < 0 || g.sh_degree > formats::kMaxShDegree) {
    return Status::InvalidArgument("gaussian render: sh_degree " + std::to_string(g.sh_degree) +
                                   " is outside 0..3");
  }
  const size_t n = g.size();
  auto wrong = [&](const char* name, size_t have, size_t want) {
    return Status::InvalidArgument("gaussian render: the cloud's " + std::string(name) +
                                   " holds " + std::to_string(have) + " values, " +
                                   std::to_string(n) + " splats need " + std::to_string(want));
  };
  if (g.position.size() != 3 * n) return wrong("position", g.position.size(), 3 * n);
  if (g.scale.size() != 3 * n) return wrong("scale", g.scale.size(), 3 * n);
  if (g.rotation.size() != 4 * n) return wrong("rotation", g.rotation.size(), 4 * n);
  if (g.sh_dc.size() != 3 * n) return wrong("sh_dc", g.sh_dc.size(), 3 * n);
  if (g.sh_rest.size() != n * g.sh_rest_per_splat()) {
    return wrong("sh_rest", g.sh_rest.size(), n * g.sh_rest_per_splat());
  }
  if (n >= (uint64_t{1} << 32)) {
    return Status::LimitExceeded("gaussian render: " + std::to_string(n) +
                                 " splats; at most 2^32 - 1 render at once");
  }
  return Status::OK();
}

}  // namespace

std::vector<uint8_t> GaussianImage::ToRgba8() const {
  const size_t pixels = static_cast<size_t>(width) * height;
  std::vector<uint8_t> out(pixels * 4);
  auto to8 = [](float v) {
    return static_cast<uint8_t>(std::round(std::min(std::max(v, 0.0f), 1.0f) * 255.0f));
  };
  for (size_t i = 0; i < pixels && 3 * i + 2 < rgb.size() && i < alpha.size(); ++i) {
    for (int c = 0; c < 3; ++c) out[4 * i + c] = to8(rgb[3 * i + c]);
    out[4 * i + 3] = to8(alpha[i]);
  }
  return out;
}

struct GaussianRasterizer::Buffers {
  Mapped records;  // a Record per visible splat, packed per chunk
  Mapped items;    // an Item per visible splat, packed per chunk, then sorted
  Mapped scratch;  // the sort's
  Mapped lists;    // uint32 record indices, tile after tile
  std::vector<uint32_t> counts;
  std::vector<uint64_t> tile_start;
};

GaussianRasterizer::GaussianRasterizer() : buffers_(std::make_unique<Buffers>()) {}
GaussianRasterizer::~GaussianRasterizer() = default;

Status GaussianRasterizer::Render(const formats::GaussianCloud& cloud, const Camera& camera,
                                  const GaussianRenderOptions& options, GaussianImage* out,
                                  GaussianRenderStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  HVDB_RETURN_IF_ERROR(CheckArguments(cloud, camera, options));
  const ViewF view = MakeView(camera);
  const unsigned threads = options.threads > 0 ? static_cast<unsigned>(options.threads)
                                               : std::max(1u, std::thread::hardware_concurrency());
  const size_t n = cloud.size();
  const size_t tiles = static_cast<size_t>(view.tiles_x) * view.tiles_y;
  const size_t chunk = std::max(kMinChunk, (n + kMaxChunks - 1) / kMaxChunks);
  const size_t chunks = (n + chunk - 1) / chunk;
  Buffers& buf = *buffers_;
  auto out_of_memory = [](size_t bytes) {
    return Status::LimitExceeded("gaussian render: cannot map " + std::to_string(bytes >> 20) +
                                 " MiB of working memory");
  };
  auto reserve = [&](Mapped& m, size_t bytes) {
    return m.Reserve(bytes) ? Status::OK() : out_of_memory(bytes);
  };
  HVDB_RETURN_IF_ERROR(reserve(buf.records, n * sizeof(Record)));
  HVDB_RETURN_IF_ERROR(reserve(buf.items, n * sizeof(Item)));
  HVDB_RETURN_IF_ERROR(reserve(buf.scratch, n * sizeof(Item)));
  Record* records = buf.records.as<Record>();
  Item* items = buf.items.as<Item>();

  // 1. Preprocess: chunk c's visible splats at records[c * chunk ...], their items likewise.
  std::vector<size_t> visible(chunks + 1, 0);
  ParallelFor(chunks, threads, [&](size_t c) {
    uint32_t k = 0;
    for (size_t i = c * chunk, end = std::min(n, i + chunk); i < end; ++i) {
      const size_t at = c * chunk + k;
      float depth;
      Record& r = records[at];
      if (!PrepareSplat(cloud, i, view, &r, &depth)) continue;
      Item& item = items[at];
      std::memcpy(&item.depth, &depth, 4);
      item.index = static_cast<uint32_t>(at);
      item.tx0 = static_cast<uint8_t>(r.tx0);
      item.ty0 = static_cast<uint8_t>(r.ty0);
      item.tiles_w = static_cast<uint8_t>(r.tx1 - r.tx0 - 1);
      item.tiles_h = static_cast<uint8_t>(r.ty1 - r.ty0 - 1);
      ++k;
    }
    visible[c] = k;
  });
  const auto preprocessed = std::chrono::steady_clock::now();

  // 2. Bin. The items packed, sorted front to back; then counted and scattered by tile in
  // that order, in chunks of the sorted items: counts[c * tiles + t] is chunk c's entries in
  // tile t, then where chunk c writes next in tile t's list.
  size_t m = 0;
  for (size_t c = 0; c < chunks; ++c) {
    std::memmove(items + m, items + c * chunk, visible[c] * sizeof(Item));
    m += visible[c];
  }
  SortByDepth(items, buf.scratch.as<Item>(), m, threads);
  const size_t sorted_chunk = std::max(kMinChunk, (m + kMaxChunks - 1) / kMaxChunks);
  const size_t sorted_chunks = (m + sorted_chunk - 1) / sorted_chunk;
  buf.counts.assign(sorted_chunks * tiles, 0);
  auto for_tiles = [&](size_t c, auto&& fn) {
    for (size_t i = c * sorted_chunk, end = std::min(m, i + sorted_chunk); i < end; ++i) {
      const Item& item = items[i];
      for (int ty = item.ty0; ty <= item.ty0 + item.tiles_h; ++ty) {
        for (int tx = item.tx0; tx <= item.tx0 + item.tiles_w; ++tx) {
          fn(static_cast<size_t>(ty) * view.tiles_x + tx, item.index);
        }
      }
    }
  };
  ParallelFor(sorted_chunks, threads, [&](size_t c) {
    uint32_t* count = buf.counts.data() + c * tiles;
    for_tiles(c, [&](size_t t, uint32_t) { ++count[t]; });
  });
  buf.tile_start.assign(tiles + 1, 0);
  for (size_t t = 0; t < tiles; ++t) {
    uint64_t at = 0;
    for (size_t c = 0; c < sorted_chunks; ++c) {
      const uint32_t k = buf.counts[c * tiles + t];
      buf.counts[c * tiles + t] = static_cast<uint32_t>(at);
      at += k;
    }
    buf.tile_start[t + 1] = buf.tile_start[t] + at;
  }
  const uint64_t entries = buf.tile_start[tiles];
  if (entries > kMaxListBytes / sizeof(uint32_t)) {
    return Status::LimitExceeded(
        "gaussian render: the splats cover " + std::to_string(entries) +
        " screen tiles in all, more than the rasteriser holds (" +
        std::to_string(kMaxListBytes >> 20) + " MiB of tile lists); move the camera back");
  }
  HVDB_RETURN_IF_ERROR(reserve(buf.lists, entries * sizeof(uint32_t)));
  uint32_t* lists = buf.lists.as<uint32_t>();
  ParallelFor(sorted_chunks, threads, [&](size_t c) {
    uint32_t* next = buf.counts.data() + c * tiles;
    for_tiles(c, [&](size_t t, uint32_t index) { lists[buf.tile_start[t] + next[t]++] = index; });
  });
  const auto binned = std::chrono::steady_clock::now();

  // 3. Blend the tiles.
  out->width = camera.width;
  out->height = camera.height;
  const size_t pixels = static_cast<size_t>(camera.width) * camera.height;
  out->rgb.resize(3 * pixels);
  out->alpha.resize(pixels);
  const auto bg = options.background;
  ParallelFor(tiles, threads, [&](size_t t) {
    const int tx0 = static_cast<int>(t % view.tiles_x) * kTile;
    const int ty0 = static_cast<int>(t / view.tiles_x) * kTile;
    const int cols = std::min(kTile, view.width - tx0), rows = std::min(kTile, view.height - ty0);
    TileState st;
    st.live_rows = (1u << rows) - 1;
    for (int y = 0; y < kTile; ++y) {
      for (int x = 0; x < kTile; ++x) {
        st.T[y][x] = 1;
        st.r[y][x] = st.g[y][x] = st.b[y][x] = 0;
        st.live[y][x] = y < rows && x < cols ? 1.0f : 0.0f;
      }
    }
    const uint32_t* list = lists + buf.tile_start[t];
    const size_t k_all = buf.tile_start[t + 1] - buf.tile_start[t];
    alignas(64) Record batch[kBatch];
    for (size_t at = 0; at < k_all; at += kBatch) {
      const size_t k = std::min(kBatch, k_all - at);
      for (size_t j = 0; j < k; ++j) batch[j] = records[list[at + j]];
      if (BlendBatch(batch, k, tx0, ty0, &st)) break;
    }
    for (int y = 0; y < rows; ++y) {
      const float *T = st.T[y], *r = st.r[y], *g = st.g[y], *b = st.b[y];
      const size_t row = static_cast<size_t>(ty0 + y) * camera.width + tx0;
      for (int x = 0; x < cols; ++x) {
        float* px = &out->rgb[3 * (row + x)];
        px[0] = r[x] + T[x] * bg[0];
        px[1] = g[x] + T[x] * bg[1];
        px[2] = b[x] + T[x] * bg[2];
        out->alpha[row + x] = 1.0f - T[x];
      }
    }
  });

  for (Mapped* mapped : {&buf.records, &buf.items, &buf.scratch, &buf.lists}) {
    if (mapped->bytes() > kKeepBytes) mapped->Release();
  }
  if (stats != nullptr) {
    const auto end = std::chrono::steady_clock::now();
    auto ms = [](auto from, auto to) {
      return std::chrono::duration<double, std::milli>(to - from).count();
    };
    stats->splats_in = n;
    stats->splats_visible = m;
    stats->tile_entries = entries;
    stats->milliseconds = ms(start, end);
    stats->preprocess_ms = ms(start, preprocessed);
    stats->bin_ms = ms(preprocessed, binned);
    stats->blend_ms = ms(binned, end);
  }
  return Status::OK();
}

Status RenderGaussians(const formats::GaussianCloud& cloud, const Camera& camera,
                       const GaussianRenderOptions& options, GaussianImage* out,
                       GaussianRenderStats* stats) {
  GaussianRasterizer rasterizer;
  return rasterizer.Render(cloud, camera, options, out, stats);
}

}  // namespace hvdb::render
