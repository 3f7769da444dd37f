// The kernels of the CPU 3DGS rasteriser: steps 1 and 3 of gaussian_raster.cc (its only
// includer; internal to render/): a group of 8 splats preprocessed into records, and a batch
// of records blended into a 16x16 tile. Float arithmetic, 8 lanes a vector (simd.h); the hot
// functions are built for AVX-512, AVX2 and the x86-64 baseline (HVDB_RENDER_CLONES). Sqrt
// below becomes one vector instruction only with -fno-math-errno (render/CMakeLists.txt).
#ifndef HVDB_RENDER_GAUSSIAN_RASTER_KERNELS_H_
#define HVDB_RENDER_GAUSSIAN_RASTER_KERNELS_H_

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "formats/gaussians.h"
#include "render/gaussian_view.h"
#include "render/renderer.h"
// simd.h's helpers pass vectors by value and are always inlined (see cpu_renderer.cc).
#pragma GCC diagnostic ignored "-Wpsabi"
#include "render/simd.h"

namespace hvdb::render::gaussian {

using internal::Broadcast;
using internal::F8;

constexpr float kNearZ = 0.2f;
constexpr float kDilation = 0.3f;  // pixels^2 added to the 2D covariance's diagonal
constexpr float kMinAlpha = 1.0f / 255.0f;
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 0.0001f;
constexpr float kLog2E = 1.44269504088896341f;
constexpr size_t kBatch = 64;  // records a tile blends at a time (BlendBatch)

// The reference's spherical-harmonic constants (formats/gaussians.h), in float.
constexpr float kC0 = static_cast<float>(formats::kShC0);
constexpr float kC1 = static_cast<float>(formats::kShC1);
constexpr float kC2[5] = {
    static_cast<float>(formats::kShC2[0]), static_cast<float>(formats::kShC2[1]),
    static_cast<float>(formats::kShC2[2]), static_cast<float>(formats::kShC2[3]),
    static_cast<float>(formats::kShC2[4]),
};
constexpr float kC3[7] = {
    static_cast<float>(formats::kShC3[0]), static_cast<float>(formats::kShC3[1]),
    static_cast<float>(formats::kShC3[2]), static_cast<float>(formats::kShC3[3]),
    static_cast<float>(formats::kShC3[4]), static_cast<float>(formats::kShC3[5]),
    static_cast<float>(formats::kShC3[6]),
};

// A visible splat, as blending needs it: one cache line.
struct alignas(64) Record {
  float u, v;  // pixel position of the centre
  // The reference's power -0.5 (a dx^2 + c dy^2) - b dx dy of the conic (a b; b c), the
  // inverse of the dilated 2D covariance, times log2(e): q = qa dx^2 + qb dx dy + qc dy^2.
  float qa, qb, qc;
  float opacity;  // after the sigmoid (and the antialiasing compensation)
  float rgb[3];
  // The ellipse where alpha can reach 1/255, in pixel offsets (ox, oy) from the centre: in
  // row oy it spans ox = slope oy -+ sqrt(half2 - half2_dy oy^2).
  float slope, half2, half2_dy;
  int16_t x0, x1, y0, y1;       // its pixel box, inclusive (within the image and the tiles)
  uint16_t tx0, tx1, ty0, ty1;  // its tiles, [tx0, tx1) x [ty0, ty1)
};
static_assert(sizeof(Record) == 64);

// What step 2 sorts and bins: a visible splat's depth, record and tiles.
struct Item {
  uint32_t depth;                      // the float's bits: positive floats order as their bits
  uint32_t index;                      // of its record
  uint8_t tx0, ty0, tiles_w, tiles_h;  // tiles [tx0, tx0 + tiles_w] x [ty0, ty0 + tiles_h]
};
static_assert(sizeof(Item) == 12);

typedef float F4 __attribute__((vector_size(16)));

// sqrt lane by lane: vsqrtps (this file is built with -fno-math-errno, so GCC vectorises it).
HVDB_SIMD_INLINE F8 Sqrt(F8 v) {
  F8 r;
  for (int i = 0; i < 8; ++i) r[i] = std::sqrt(v[i]);
  return r;
}

// Rounding of values within +-2^31 (callers clamp), by truncation to integers.
HVDB_SIMD_INLINE F8 Trunc(F8 x) {
  return __builtin_convertvector(__builtin_convertvector(x, internal::I8), F8);
}
HVDB_SIMD_INLINE F8 Ceil(F8 x) {
  const F8 t = Trunc(x);
  return t < x ? t + 1.0f : t;
}
HVDB_SIMD_INLINE F8 Floor(F8 x) {
  const F8 t = Trunc(x);
  return t > x ? t - 1.0f : t;
}

// ln x for finite x >= 1 (callers clamp): Cephes' logf (relative error ~1e-7).
HVDB_SIMD_INLINE F8 Log(F8 x) {
  using internal::I8;
  I8 bits;
  std::memcpy(&bits, &x, sizeof bits);
  F8 e = __builtin_convertvector((bits >> 23) - 126, F8);
  bits = (bits & 0x007fffff) | 0x3f000000;  // the mantissa in [0.5, 1)
  F8 m;
  std::memcpy(&m, &bits, sizeof m);
  const F8 small = m < 0.707106781186547524f ? Broadcast<F8>(1.0f) : F8{};
  e -= small;
  m = m + m * small - 1.0f;
  const F8 z = m * m;
  F8 y = Broadcast<F8>(7.0376836292e-2f);
  y = y * m - 1.1514610310e-1f;
  y = y * m + 1.1676998740e-1f;
  y = y * m - 1.2420140846e-1f;
  y = y * m + 1.4249322787e-1f;
  y = y * m - 1.6668057665e-1f;
  y = y * m + 2.0000714765e-1f;
  y = y * m - 2.4999993993e-1f;
  y = y * m + 3.3333331174e-1f;
  y = y * m * z;
  y += -2.12194440e-4f * e;
  y += -0.5f * z;
  return m + y + 0.693359375f * e;
}

// rows[r][c] -> out[c][r] for 8 vectors of 8 (AVX's unpack, shuffle and lane-swap sequence).
HVDB_SIMD_INLINE void Transpose8(const F8* rows, F8* out) {
  F8 t[8], u[8];
  for (int i = 0; i < 4; ++i) {
    t[2 * i] = __builtin_shufflevector(rows[2 * i], rows[2 * i + 1], 0, 8, 1, 9, 4, 12, 5, 13);
    t[2 * i + 1] =
        __builtin_shufflevector(rows[2 * i], rows[2 * i + 1], 2, 10, 3, 11, 6, 14, 7, 15);
  }
  for (int i = 0; i < 2; ++i) {
    for (int h = 0; h < 2; ++h) {
      const F8 a = t[4 * i + h], b = t[4 * i + 2 + h];
      u[4 * i + 2 * h] = __builtin_shufflevector(a, b, 0, 1, 8, 9, 4, 5, 12, 13);
      u[4 * i + 2 * h + 1] = __builtin_shufflevector(a, b, 2, 3, 10, 11, 6, 7, 14, 15);
    }
  }
  for (int i = 0; i < 4; ++i) {
    out[i] = __builtin_shufflevector(u[i], u[4 + i], 0, 1, 2, 3, 8, 9, 10, 11);
    out[4 + i] = __builtin_shufflevector(u[i], u[4 + i], 4, 5, 6, 7, 12, 13, 14, 15);
  }
}

// The SH part of a degree-3 splat's colour: its 45 coefficients (channel-major, 15 a channel)
// dotted with the basis b[0..15] (b[15] = 0), 8 products a vector, then the three sums. Reads
// rest[0..45]: one float past the splat's own, which the caller keeps inside the array. Why
// not the plain loop: 45 scalar multiply-adds a splat were most of step 1.
HVDB_SIMD_INLINE void ShRestDegree3(const float* rest, const float* b, float* sum) {
  using internal::Load;
  const F8 b0 = Load<F8>(b), b1 = Load<F8>(b + 8);
  const F8 r = Load<F8>(rest) * b0 + Load<F8>(rest + 8) * b1;
  const F8 g = Load<F8>(rest + 15) * b0 + Load<F8>(rest + 23) * b1;
  const F8 bl = Load<F8>(rest + 30) * b0 + Load<F8>(rest + 38) * b1;
  auto halves = [](F8 v) HVDB_SIMD_LAMBDA {  // lanes i and i + 4 summed
    return __builtin_shufflevector(v, v, 0, 1, 2, 3) + __builtin_shufflevector(v, v, 4, 5, 6, 7);
  };
  // Pairs of sums, twice: (r, g, b, 0) in the end.
  auto pairs = [](F4 x, F4 y) HVDB_SIMD_LAMBDA {
    return __builtin_shufflevector(x, y, 0, 4, 1, 5) + __builtin_shufflevector(x, y, 2, 6, 3, 7);
  };
  const F4 rg = pairs(halves(r), halves(g)), bz = pairs(halves(bl), F4{});
  const F4 all =
      __builtin_shufflevector(rg, bz, 0, 1, 4, 5) + __builtin_shufflevector(rg, bz, 2, 3, 6, 7);
  sum[0] = all[0];
  sum[1] = all[1];
  sum[2] = all[2];
}

// 8 triples (x y z x y z ...) from p into out[0..2] = the 8 x, y and z.
HVDB_SIMD_INLINE void Deinterleave3(const float* p, F8* out) {
  using internal::Load;
  const F8 a = Load<F8>(p), b = Load<F8>(p + 8), c = Load<F8>(p + 16);
  // a: x0 y0 z0 x1 y1 z1 x2 y2 | b: z2 x3 y3 z3 x4 y4 z4 x5 | c: y5 z5 x6 y6 z6 x7 y7 z7
  const F8 x = __builtin_shufflevector(a, b, 0, 3, 6, 9, 12, 15, 0, 0);
  const F8 y = __builtin_shufflevector(a, b, 1, 4, 7, 10, 13, 0, 0, 0);
  const F8 z = __builtin_shufflevector(a, b, 2, 5, 8, 11, 14, 0, 0, 0);
  out[0] = __builtin_shufflevector(x, c, 0, 1, 2, 3, 4, 5, 10, 13);
  out[1] = __builtin_shufflevector(y, c, 0, 1, 2, 3, 4, 8, 11, 14);
  out[2] = __builtin_shufflevector(z, c, 0, 1, 2, 3, 4, 9, 12, 15);
}

// 8 quadruples (w x y z ...) from p into out[0..3] = the 8 w, x, y and z.
HVDB_SIMD_INLINE void Deinterleave4(const float* p, F8* out) {
  using internal::Load;
  const F8 a = Load<F8>(p), b = Load<F8>(p + 8), c = Load<F8>(p + 16), d = Load<F8>(p + 24);
  const F8 ab0 = __builtin_shufflevector(a, b, 0, 4, 8, 12, 1, 5, 9, 13);  // w0-3 x0-3
  const F8 cd0 = __builtin_shufflevector(c, d, 0, 4, 8, 12, 1, 5, 9, 13);  // w4-7 x4-7
  const F8 ab1 = __builtin_shufflevector(a, b, 2, 6, 10, 14, 3, 7, 11, 15);  // y0-3 z0-3
  const F8 cd1 = __builtin_shufflevector(c, d, 2, 6, 10, 14, 3, 7, 11, 15);  // y4-7 z4-7
  out[0] = __builtin_shufflevector(ab0, cd0, 0, 1, 2, 3, 8, 9, 10, 11);
  out[1] = __builtin_shufflevector(ab0, cd0, 4, 5, 6, 7, 12, 13, 14, 15);
  out[2] = __builtin_shufflevector(ab1, cd1, 0, 1, 2, 3, 8, 9, 10, 11);
  out[3] = __builtin_shufflevector(ab1, cd1, 4, 5, 6, 7, 12, 13, 14, 15);
}

// Step 1 for the 8 splats from i0 (`count` of them real): the visible ones' records and items
// appended at records[*k], items[*k]. The arithmetic up to the 2D conic, the radius's square
// root and the SH basis runs on 8 splats at once (the cloud's arrays are structures of arrays);
// the decisions, the tiles and the colour splat by splat.
HVDB_RENDER_CLONES
static void PrepareGroup(const formats::GaussianCloud& g, size_t i0, int count, const ViewF& v,
                         Record* records, Item* items, uint32_t* k) {
  using internal::Load;
  using internal::Max;
  using internal::Min;
  using internal::Store;
  // The inputs, transposed: f[field] holds the field of the 8 splats. A full group by vector
  // loads and shuffles; the last, short one of a chunk lane by lane (its missing lanes repeat
  // the last splat).
  F8 f[11];
  if (count == 8) {
    Deinterleave3(&g.position[3 * i0], f);
    Deinterleave3(&g.scale[3 * i0], f + 3);
    Deinterleave4(&g.rotation[4 * i0], f + 6);
    f[10] = Load<F8>(&g.opacity[i0]);
  } else {
    alignas(32) float in[11][8];
    for (int l = 0; l < 8; ++l) {
      const size_t i = i0 + static_cast<size_t>(std::min(l, count - 1));
      for (int c = 0; c < 3; ++c) in[c][l] = g.position[3 * i + c];
      for (int c = 0; c < 3; ++c) in[3 + c][l] = g.scale[3 * i + c];
      for (int c = 0; c < 4; ++c) in[6 + c][l] = g.rotation[4 * i + c];
      in[10][l] = g.opacity[i];
    }
    for (int c = 0; c < 11; ++c) f[c] = Load<F8>(in[c]);
  }
  const F8 px = f[0], py = f[1], pz = f[2];
  const float* R = v.rot;
  const F8 tx = R[0] * px + R[1] * py + R[2] * pz + v.trans[0];
  const F8 ty = R[3] * px + R[4] * py + R[5] * pz + v.trans[1];
  const F8 tz = R[6] * px + R[7] * py + R[8] * pz + v.trans[2];

  // 3D covariance R S S^T R^T: R of the normalised quaternion (the identity for a zero one).
  F8 qw = f[6], qx = f[7], qy = f[8], qz = f[9];
  const F8 qn = Sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  const F8 zero{}, one = Broadcast<F8>(1.0f);
  const F8 inv_qn = qn > 0.0f ? one / qn : zero;
  qw = qn > 0.0f ? qw * inv_qn : one;
  qx *= inv_qn, qy *= inv_qn, qz *= inv_qn;
  // e^(log scale), clamped below overflow (an infinite covariance is culled below anyway).
  const F8 s0 = internal::Exp(Min(f[3], Broadcast<F8>(80.0f)));
  const F8 s1 = internal::Exp(Min(f[4], Broadcast<F8>(80.0f)));
  const F8 s2 = internal::Exp(Min(f[5], Broadcast<F8>(80.0f)));
  const F8 M[9] = {(1.f - 2.f * (qy * qy + qz * qz)) * s0, 2.f * (qx * qy - qw * qz) * s1,
                   2.f * (qx * qz + qw * qy) * s2,         2.f * (qx * qy + qw * qz) * s0,
                   (1.f - 2.f * (qx * qx + qz * qz)) * s1, 2.f * (qy * qz - qw * qx) * s2,
                   2.f * (qx * qz - qw * qy) * s0,         2.f * (qy * qz + qw * qx) * s1,
                   (1.f - 2.f * (qx * qx + qy * qy)) * s2};  // R S
  auto row_dot = [&](int r, int c) {
    return M[3 * r] * M[3 * c] + M[3 * r + 1] * M[3 * c + 1] + M[3 * r + 2] * M[3 * c + 2];
  };
  const F8 S00 = row_dot(0, 0), S01 = row_dot(0, 1), S02 = row_dot(0, 2);
  const F8 S11 = row_dot(1, 1), S12 = row_dot(1, 2), S22 = row_dot(2, 2);

  // EWA: J W Sigma W^T J^T, the Jacobian at the centre clamped to 1.3 times the field of view.
  const F8 inv_z = one / tz;
  const F8 xc = Min(Broadcast<F8>(v.lim_x), Max(Broadcast<F8>(-v.lim_x), tx * inv_z)) * tz;
  const F8 yc = Min(Broadcast<F8>(v.lim_y), Max(Broadcast<F8>(-v.lim_y), ty * inv_z)) * tz;
  const F8 j00 = v.fx * inv_z, j02 = -(v.fx * xc) * (inv_z * inv_z);
  const F8 j11 = v.fy * inv_z, j12 = -(v.fy * yc) * (inv_z * inv_z);
  const F8 t0[3] = {j00 * R[0] + j02 * R[6], j00 * R[1] + j02 * R[7], j00 * R[2] + j02 * R[8]};
  const F8 t1[3] = {j11 * R[3] + j12 * R[6], j11 * R[4] + j12 * R[7], j11 * R[5] + j12 * R[8]};
  const F8 st0[3] = {S00 * t0[0] + S01 * t0[1] + S02 * t0[2],
                     S01 * t0[0] + S11 * t0[1] + S12 * t0[2],
                     S02 * t0[0] + S12 * t0[1] + S22 * t0[2]};
  const F8 st1[3] = {S00 * t1[0] + S01 * t1[1] + S02 * t1[2],
                     S01 * t1[0] + S11 * t1[1] + S12 * t1[2],
                     S02 * t1[0] + S12 * t1[1] + S22 * t1[2]};
  F8 cxx = t0[0] * st0[0] + t0[1] * st0[1] + t0[2] * st0[2];
  const F8 cxy = t1[0] * st0[0] + t1[1] * st0[1] + t1[2] * st0[2];
  F8 cyy = t1[0] * st1[0] + t1[1] * st1[1] + t1[2] * st1[2];
  const F8 det0 = cxx * cyy - cxy * cxy;
  cxx += kDilation;
  cyy += kDilation;
  const F8 det = cxx * cyy - cxy * cxy;
  const F8 det_inv = one / det;
  const F8 logit = f[10];
  F8 opacity = one / (one + internal::Exp(Min(-logit, Broadcast<F8>(80.0f))));
  if (g.antialiased) opacity *= Sqrt(Max(zero, det0 / det));
  const F8 mid = 0.5f * (cxx + cyy);
  const F8 root3 = 3.0f * Sqrt(mid + Sqrt(Max(Broadcast<F8>(0.1f), mid * mid - det)));

  const F8 u = v.fx * tx * inv_z + v.cx, w = v.fy * ty * inv_z + v.cy;
  const F8 ca = cyy * det_inv, cb = -cxy * det_inv, cc = cxx * det_inv;

  // Which splats stay (as 1 or 0: lanes with infinities or NaNs, such as those behind the
  // camera, are cleared by these tests and never converted to integers unclamped).
  auto flag = [&](F8 keep, F8 test) { return test != 0.0f ? keep : zero; };
  auto is_finite = [&](F8 x) { return x - x == 0.0f ? one : zero; };
  F8 keep = tz > kNearZ ? one : zero;
  keep = flag(keep, det != 0.0f ? one : zero);
  keep = flag(keep, is_finite(u) * is_finite(w) * is_finite(root3) * is_finite(ca + cb + cc) *
                        is_finite(cxx + cyy) * is_finite(opacity));
  // getRect: tiles [rx0, rx1) x [ry0, ry1): (int) of the float clamped to [0, grid], by
  // truncation. The radius ceil(3 sqrt(lambda)) is capped where it covers any image anyway.
  const F8 radius = Ceil(Min(root3, Broadcast<F8>(1e9f)));
  auto tile = [&](F8 t, int grid) {
    return Trunc(Min(Max(t, zero), Broadcast<F8>(static_cast<float>(grid))));
  };
  const F8 rx0 = tile((u - radius) * (1.0f / kTile), v.tiles_x);
  const F8 ry0 = tile((w - radius) * (1.0f / kTile), v.tiles_y);
  const F8 rx1 = tile((u + radius + static_cast<float>(kTile - 1)) * (1.0f / kTile), v.tiles_x);
  const F8 ry1 = tile((w + radius + static_cast<float>(kTile - 1)) * (1.0f / kTile), v.tiles_y);
  keep = flag(keep, (rx1 - rx0) * (ry1 - ry0));
  // alpha = min(0.99, opacity e^power) with power <= 0 never reaches 1/255: no pixel uses it.
  keep = flag(keep, opacity >= kMinAlpha ? one : zero);
  // The box of the ellipse d^T conic d <= 2 ln(255 opacity) (alpha >= 1/255 within), widened
  // against rounding, in pixel centres; cut to the reference's rectangle and the image.
  const F8 kq = 2.0f * Log(Max(255.0f * opacity, one)) * 1.001f + 0.01f;
  const F8 ex = Sqrt(kq * Max(cxx, zero)) * 1.001f + 0.01f;
  const F8 ey = Sqrt(kq * Max(cyy, zero)) * 1.001f + 0.01f;
  const F8 width = Broadcast<F8>(static_cast<float>(v.width));
  const F8 height = Broadcast<F8>(static_cast<float>(v.height));
  auto clamp = [&](F8 x, F8 size) { return Min(Max(x, Broadcast<F8>(-1.0f)), size); };
  const F8 x0 = Max(Ceil(clamp(u - ex, width)), rx0 * static_cast<float>(kTile));
  const F8 x1 =
      Min(Min(Floor(clamp(u + ex, width)), rx1 * static_cast<float>(kTile) - 1.0f), width - 1.0f);
  const F8 y0 = Max(Ceil(clamp(w - ey, height)), ry0 * static_cast<float>(kTile));
  const F8 y1 =
      Min(Min(Floor(clamp(w + ey, height)), ry1 * static_cast<float>(kTile) - 1.0f), height - 1.0f);
  keep = flag(keep, x0 <= x1 ? one : zero);
  keep = flag(keep, y0 <= y1 ? one : zero);

  alignas(32) float out[16][8];
  Store(out[0], tz);
  Store(out[1], keep);
  Store(out[2], u);
  Store(out[3], w);
  Store(out[4], ca);
  Store(out[5], cb);
  Store(out[6], cc);
  Store(out[7], opacity);
  Store(out[8], -cb / ca);  // the spans: slope, half2, half2_dy
  Store(out[9], kq / ca);
  Store(out[10], det_inv / (ca * ca));  // det(conic) / a^2
  Store(out[11], x0);
  Store(out[12], x1);
  Store(out[13], y0);
  Store(out[14], y1);

  // The SH basis for the directions from the camera centre (signs folded in).
  const int deg = g.sh_degree;
  alignas(32) float basis[15][8];
  if (deg > 0) {
    F8 dx = px - v.centre[0], dy = py - v.centre[1], dz = pz - v.centre[2];
    const F8 inv_len = one / Sqrt(dx * dx + dy * dy + dz * dz);
    dx *= inv_len, dy *= inv_len, dz *= inv_len;
    Store(basis[0], -kC1 * dy);
    Store(basis[1], kC1 * dz);
    Store(basis[2], -kC1 * dx);
    if (deg > 1) {
      const F8 xx = dx * dx, yy = dy * dy, zz = dz * dz;
      Store(basis[3], kC2[0] * dx * dy);
      Store(basis[4], kC2[1] * dy * dz);
      Store(basis[5], kC2[2] * (2.0f * zz - xx - yy));
      Store(basis[6], kC2[3] * dx * dz);
      Store(basis[7], kC2[4] * (xx - yy));
      if (deg > 2) {
        Store(basis[8], kC3[0] * dy * (3.0f * xx - yy));
        Store(basis[9], kC3[1] * dx * dy * dz);
        Store(basis[10], kC3[2] * dy * (4.0f * zz - xx - yy));
        Store(basis[11], kC3[3] * dz * (2.0f * zz - 3.0f * xx - 3.0f * yy));
        Store(basis[12], kC3[4] * dx * (4.0f * zz - xx - yy));
        Store(basis[13], kC3[5] * dz * (xx - yy));
        Store(basis[14], kC3[6] * dx * (xx - 3.0f * yy));
      }
    }
  }
  const int per_channel = formats::ShRestPerChannel(deg);
  // Degree 3: the basis of each splat as a row of 16 (the 15 values and a 0), for ShRestDegree3.
  alignas(32) float basis_of[8][16];
  if (deg == 3) {
    F8 rows[16], cols[16];
    for (int j = 0; j < 15; ++j) rows[j] = Load<F8>(basis[j]);
    rows[15] = zero;
    Transpose8(rows, cols);
    Transpose8(rows + 8, cols + 8);
    for (int l = 0; l < 8; ++l) {
      Store(basis_of[l], cols[l]);
      Store(basis_of[l] + 8, cols[8 + l]);
    }
  }
  const size_t n_all = g.size();

  for (int l = 0; l < count; ++l) {
    if (out[1][l] == 0.0f) continue;
    const size_t i = i0 + static_cast<size_t>(l);
    const int x0l = static_cast<int>(out[11][l]), x1l = static_cast<int>(out[12][l]);
    const int y0l = static_cast<int>(out[13][l]), y1l = static_cast<int>(out[14][l]);
    // Colour: the SH, + 0.5, clamped below at 0.
    Record& r = records[*k];
    const float* rest = g.sh_rest.data() + i * 3 * static_cast<size_t>(per_channel);
    bool finite = true;
    if (deg == 3 && i + 1 < n_all) {
      float sum[3];
      ShRestDegree3(rest, basis_of[l], sum);
      for (int ch = 0; ch < 3; ++ch) {
        const float c = kC0 * g.sh_dc[3 * i + ch] + sum[ch] + 0.5f;
        finite = finite && std::isfinite(c);
        r.rgb[ch] = std::max(c, 0.0f);
      }
    } else {
      for (int ch = 0; ch < 3; ++ch) {
        // Three partial sums: one chain of 15 dependent multiply-adds a channel would wait on
        // each result (~60 cycles a splat); three run side by side.
        const float* rc = rest + ch * per_channel;
        float c0 = kC0 * g.sh_dc[3 * i + ch], c1 = 0, c2 = 0;
        int j = 0;
        for (; j + 3 <= per_channel; j += 3) {
          c0 += basis[j][l] * rc[j];
          c1 += basis[j + 1][l] * rc[j + 1];
          c2 += basis[j + 2][l] * rc[j + 2];
        }
        for (; j < per_channel; ++j) c0 += basis[j][l] * rc[j];
        float c = c0 + (c1 + c2);
        c += 0.5f;
        finite = finite && std::isfinite(c);
        r.rgb[ch] = std::max(c, 0.0f);
      }
    }
    if (!finite) continue;
    r.u = out[2][l];
    r.v = out[3][l];
    r.qa = out[4][l] * -0.5f * kLog2E;
    r.qb = out[5][l] * -kLog2E;
    r.qc = out[6][l] * -0.5f * kLog2E;
    r.opacity = out[7][l];
    r.slope = out[8][l];
    r.half2 = out[9][l];
    r.half2_dy = out[10][l];
    r.x0 = static_cast<int16_t>(x0l);
    r.x1 = static_cast<int16_t>(x1l);
    r.y0 = static_cast<int16_t>(y0l);
    r.y1 = static_cast<int16_t>(y1l);
    r.tx0 = static_cast<uint16_t>(x0l / kTile);
    r.tx1 = static_cast<uint16_t>(x1l / kTile + 1);
    r.ty0 = static_cast<uint16_t>(y0l / kTile);
    r.ty1 = static_cast<uint16_t>(y1l / kTile + 1);
    Item& item = items[*k];
    std::memcpy(&item.depth, &out[0][l], 4);
    item.tx0 = static_cast<uint8_t>(r.tx0);
    item.ty0 = static_cast<uint8_t>(r.ty0);
    item.tiles_w = static_cast<uint8_t>(r.tx1 - r.tx0 - 1);
    item.tiles_h = static_cast<uint8_t>(r.ty1 - r.ty0 - 1);
    ++*k;
  }
}

// A tile's pixels, row-major: two segments of 8 pixels a row (segment 2y + h: row y,
// columns 8h .. 8h + 7).
struct alignas(64) TileState {
  // The transmittance; negative once the pixel has stopped (at -T), and for the tile's
  // columns past the image, so that a stopped lane takes nothing more without a mask of its
  // own (T (1 - alpha) < 0 is below the threshold whatever alpha is).
  float T[kTile][kTile];
  float r[kTile][kTile], g[kTile][kTile], b[kTile][kTile];
  uint32_t live;  // bit 2y + h: that segment has a pixel still blending
};

// Horizontal minimum or maximum.
HVDB_SIMD_INLINE float Fold(F8 v, bool max) {
  const F4 a = __builtin_shufflevector(v, v, 0, 1, 2, 3);
  const F4 b = __builtin_shufflevector(v, v, 4, 5, 6, 7);
  const F4 m4 = max ? internal::Max(a, b) : internal::Min(a, b);
  const F4 c = __builtin_shufflevector(m4, m4, 2, 3, 0, 1);
  const F4 m2 = max ? internal::Max(m4, c) : internal::Min(m4, c);
  const F4 d = __builtin_shufflevector(m2, m2, 1, 0, 3, 2);
  return (max ? internal::Max(m2, d) : internal::Min(m2, d))[0];
}

// 2^q for q in [-20, 0]: q rounded to an integer n by adding 1.5 2^23, 2^(q - n) by a degree-5
// polynomial on [-0.5, 0.5] (fitted for relative error, 1.7e-7 at most; its constant term is
// 1, so 2^0 is exactly 1 and a splat's centre gets its opacity exactly), and n added to the
// exponent field. Why not simd.h's Exp: the reference's exp(power) costs ~17 operations a
// vector in Cephes' form; with the conic pre-scaled by log2(e) (Record::qa) this is 11, and
// the error stays ~1e-7 relative, far below an 8-bit step.
HVDB_SIMD_INLINE F8 Exp2(F8 q) {
  using internal::I8;
  constexpr float kRound = 12582912.0f;  // 1.5 2^23
  const F8 t = q + kRound;
  const F8 f = q - (t - kRound);
  F8 p = Broadcast<F8>(1.326472731307149e-3f);
  p = p * f + 9.671512991189957e-3f;
  p = p * f + 5.550733581185341e-2f;
  p = p * f + 2.4022242426872253e-1f;
  p = p * f + 6.931470036506653e-1f;
  p = p * f + 1.0f;
  I8 n, bits;
  std::memcpy(&n, &t, sizeof n);
  std::memcpy(&bits, &p, sizeof bits);
  const I8 round_bits = I8{} + 0x4b400000;  // the bits of 1.5 2^23
  bits += (n - round_bits) << 23;
  std::memcpy(&p, &bits, sizeof p);
  return p;
}

// What a batch's splats need per tile row besides their records: the row's part of
// q = power log2(e) = (qa ox + bo) ox + k, with ox = pixel column - centre, oy = row - centre,
// bo = qb oy and k = qc oy^2. Rows 0..15 of the tile; the spare 16 columns take the second
// vector of rows that RowSpans writes from a row past 0.
struct RowTerms {
  alignas(32) float bo[kBatch][2 * kTile];
  alignas(32) float k[kBatch][2 * kTile];
};

// For 8 rows from tile row ya (image row ty0 + ya), splat s's ellipse (widened by a hundredth
// of a pixel against rounding) cut to the tile columns [xa, xb] of the tile at column tx0:
// which of the rows' segments it reaches, as 16 bits (bit 2i: row ya + i's left segment, bit
// 2i + 1: its right one), and its RowTerms.
HVDB_SIMD_INLINE uint32_t RowSpans(const Record& s, int tx0, int ty0, int ya, int xa, int xb,
                                   float* bo, float* k) {
  const F8 lane = internal::VecTraits<F8>::kIota;
  const F8 zero{};
  const F8 oy = lane + (static_cast<float>(ty0 + ya) - s.v);  // pixel row - centre
  const F8 h2 = s.half2 - s.half2_dy * oy * oy;
  const F8 h = Sqrt(internal::Max(h2, zero)) + 0.01f;
  const F8 centre = (s.u - static_cast<float>(tx0)) + s.slope * oy;
  // Clamped to the tile's columns before rounding, so the conversions are defined whatever the
  // splat's size; ceil and floor by truncation (the values are then within [-1, 16]).
  const F8 left = internal::Max(centre - h, Broadcast<F8>(-1.0f));
  const F8 right = internal::Min(centre + h, Broadcast<F8>(16.0f));
  const F8 tl = Trunc(left), tr = Trunc(right);
  const F8 lo = internal::Max(tl < left ? tl + 1.0f : tl, Broadcast<F8>(static_cast<float>(xa)));
  const F8 hi = internal::Min(tr > right ? tr - 1.0f : tr, Broadcast<F8>(static_cast<float>(xb)));
  // Each lane's two bits as its weight 4^i (left) and 2 4^i (right), summed: exact in float.
  const F8 weight = {1, 4, 16, 64, 256, 1024, 4096, 16384};
  F8 bits = (lo < 8.0f ? weight : zero) + (hi >= 8.0f ? weight + weight : zero);
  bits = h2 >= 0.0f ? bits : zero;
  bits = lo <= hi ? bits : zero;
  const F4 b4 = __builtin_shufflevector(bits, bits, 0, 1, 2, 3) +
                __builtin_shufflevector(bits, bits, 4, 5, 6, 7);
  const F4 b2 = b4 + __builtin_shufflevector(b4, b4, 2, 3, 0, 1);
  internal::Store(bo + ya, s.qb * oy);
  internal::Store(k + ya, s.qc * (oy * oy));
  return static_cast<uint32_t>(b2[0] + b2[1]);
}

// |x| lane by lane (the sign bit cleared).
HVDB_SIMD_INLINE F8 Abs(F8 x) {
  internal::I8 bits;
  std::memcpy(&bits, &x, sizeof bits);
  bits &= 0x7fffffff;
  std::memcpy(&x, &bits, sizeof x);
  return x;
}

// Eight pixels of a segment: what blending carries from splat to splat.
struct Run {
  F8 T, r, g, b;
};

// The reference's per-pixel step for 8 pixels and splat s: alpha = min(0.99, opacity 2^q), 0
// where the reference skips the splat (power > 0, or alpha below 1/255). `dx` is the pixels'
// columns - the centre. A pixel stops (T negated) at the splat that would bring T (1 - alpha)
// below 1e-4, that splat not added.
//
// Only selects (?:) of comparisons, no comparison results as integer vectors (GCC 12 makes
// those a scalar compare per lane in the AVX-512 clone).
HVDB_SIMD_INLINE void Step(const Record& s, F8 dx, float bo, float k, Run* run) {
  const F8 zero{};
  const F8 q = (s.qa * dx + bo) * dx + k;
  const F8 ex = Exp2(internal::Max(q, Broadcast<F8>(-20.0f)));
  F8 alpha = internal::Min(Broadcast<F8>(kMaxAlpha), s.opacity * ex);
  alpha = q > 0.0f ? zero : alpha;
  alpha = alpha >= kMinAlpha ? alpha : zero;
  const F8 T = run->T;
  const F8 test_t = T * (1.0f - alpha);
  const F8 next = test_t < kMinTransmittance ? internal::Min(T, -T) : test_t;
  // alpha T where the pixel goes on (T - T (1 - alpha)), 0 where it stops here or had stopped
  // (|next| = |T|). From `next` rather than a second select of the same comparison: GCC then
  // keeps the comparison in a mask register instead of a vector that only the first 16
  // registers can take (VEX blends), which spilled the pixels' sums to the stack.
  const F8 wt = internal::Max(T - Abs(next), zero);
  run->r += s.rgb[0] * wt;
  run->g += s.rgb[1] * wt;
  run->b += s.rgb[2] * wt;
  run->T = next;
}

// A segment being blended: its pixels, jobs (bit j: batch record j, blended in bit order)
// and where it is.
struct Segment {
  Run run;
  F8 cols;        // its pixels' image columns
  uint64_t jobs;  // those not yet blended
  int y;          // tile row
};

HVDB_SIMD_INLINE bool Stopped(const Segment& g) { return Fold(g.run.T, true) < 0.0f; }
HVDB_SIMD_INLINE void StepSegment(const Record* batch, const RowTerms& rows, Segment* g) {
  const int j = __builtin_ctzll(g->jobs);
  g->jobs &= g->jobs - 1;
  const Record& s = batch[j];
  Step(s, g->cols - s.u, rows.bo[j][g->y], rows.k[j][g->y], &g->run);
}

// Blends `n` <= kBatch records (front to back) into the tile at pixel (tx0, ty0); true once
// every pixel of the tile has stopped. First which splats reach each segment (one bit a
// splat: the ellipse's row spans give a splat's segments as a mask, spread over the
// segments' masks), then the live segments two at a time, their pixels in registers: two
// independent chains of steps keep the core busy where one waits on its own results.
HVDB_RENDER_CLONES
static bool BlendBatch(const Record* batch, size_t n, int tx0, int ty0, TileState* st) {
  using internal::Load;
  using internal::Store;
  static_assert(kBatch <= 64, "a segment's jobs are the bits of a uint64_t");
  typedef uint64_t U8 __attribute__((vector_size(64)));
  U8 acc[2 * kTile / 8] = {};  // segment 8v + i's jobs in acc[v][i]
  alignas(32) RowTerms terms;
  const uint32_t live = st->live;
  for (size_t j = 0; j < n; ++j) {
    const Record& s = batch[j];
    const int ya = std::max<int>(s.y0, ty0) - ty0, yb = std::min<int>(s.y1, ty0 + kTile - 1) - ty0;
    const int xa = std::max<int>(s.x0, tx0) - tx0, xb = std::min<int>(s.x1, tx0 + kTile - 1) - tx0;
    if (xa > xb || ya > yb) continue;
    // The segments of rows ya .. yb that are still live.
    const uint64_t box = ((uint64_t{4} << (2 * yb)) - 1) & ~((uint64_t{1} << (2 * ya)) - 1);
    if ((box & live) == 0) continue;
    // Rows ya .. ya + 7 (and ya + 8 .. ya + 15 for taller boxes), 8 rows a vector.
    uint64_t segs = uint64_t{RowSpans(s, tx0, ty0, ya, xa, xb, terms.bo[j], terms.k[j])}
                    << (2 * ya);
    if (yb - ya >= 8) {
      segs |= uint64_t{RowSpans(s, tx0, ty0, ya + 8, xa, xb, terms.bo[j], terms.k[j])}
              << (2 * ya + 16);
    }
    // Bit j set in the masks of those segments, 8 segments a vector, without a branch.
    const U8 mask = U8{} + (segs & box & live);
    for (int v = 0; v < 2 * kTile / 8; ++v) {
      const U8 shift = U8{0, 1, 2, 3, 4, 5, 6, 7} + static_cast<uint64_t>(8 * v);
      acc[v] |= ((mask >> shift) & 1u) << j;
    }
  }
  alignas(32) uint64_t jobs[2 * kTile];
  std::memcpy(jobs, acc, sizeof jobs);
  // The live segments with jobs, left ones first then right ones, row after row: neighbours
  // in this order (the same columns, the next row) have much the same splats, so the two
  // chains blended together run about as long.
  int order[2 * kTile], m = 0;
  for (int h = 0; h < 2; ++h) {
    for (int y = 0; y < kTile; ++y) {
      const int seg = 2 * y + h;
      order[m] = seg;
      m += jobs[seg] != 0;
    }
  }
  auto open = [&](int seg) HVDB_SIMD_LAMBDA {
    const int y = seg >> 1, x = 8 * (seg & 1);
    Segment g;
    g.run = {Load<F8>(&st->T[y][x]), Load<F8>(&st->r[y][x]), Load<F8>(&st->g[y][x]),
             Load<F8>(&st->b[y][x])};
    g.cols = internal::VecTraits<F8>::kIota + static_cast<float>(tx0 + x);
    g.jobs = jobs[seg];
    g.y = y;
    return g;
  };
  auto close = [&](const Segment& g, int seg) HVDB_SIMD_LAMBDA {
    const int y = seg >> 1, x = 8 * (seg & 1);
    Store(&st->T[y][x], g.run.T);
    Store(&st->r[y][x], g.run.r);
    Store(&st->g[y][x], g.run.g);
    Store(&st->b[y][x], g.run.b);
    if (Stopped(g)) st->live &= ~(1u << seg);
  };
  // Every 8 steps a segment checks whether all its pixels have stopped, and ends if so.
  auto finish = [&](Segment* g, int done) HVDB_SIMD_LAMBDA {
    while (g->jobs != 0) {
      StepSegment(batch, terms, g);
      if ((++done & 7) == 0 && Stopped(*g)) break;
    }
  };
  for (int i = 0; i + 1 < m; i += 2) {
    Segment a = open(order[i]), b = open(order[i + 1]);
    int done = 0;
    while (a.jobs != 0 && b.jobs != 0) {
      StepSegment(batch, terms, &a);
      StepSegment(batch, terms, &b);
      if ((++done & 7) == 0) {
        if (Stopped(a)) a.jobs = 0;
        if (Stopped(b)) b.jobs = 0;
      }
    }
    finish(&a, done);
    finish(&b, done);
    close(a, order[i]);
    close(b, order[i + 1]);
  }
  if (m % 2 == 1) {
    Segment a = open(order[m - 1]);
    finish(&a, 0);
    close(a, order[m - 1]);
  }
  return st->live == 0;
}

// Row y of a band's tiles written out: `width` pixels, RGB (C + T background) and 1 - T, T
// being |T| (negative where the pixel stopped). 8 pixels a vector, their channels interleaved
// by shuffles; the last tile's columns past the image one by one.
HVDB_RENDER_CLONES
static void WriteRow(const TileState* tiles, int count, int y, int width, const float* bg,
                     float* rgb, float* alpha) {
  using internal::Load;
  using internal::Store;
  for (int t = 0; t < count; ++t) {
    const TileState& st = tiles[t];
    const int x0 = t * kTile;
    if (x0 + kTile <= width) {
      for (int h = 0; h < kTile; h += 8) {
        const F8 tr = Abs(Load<F8>(&st.T[y][h]));
        const F8 r = Load<F8>(&st.r[y][h]) + tr * bg[0];
        const F8 g = Load<F8>(&st.g[y][h]) + tr * bg[1];
        const F8 b = Load<F8>(&st.b[y][h]) + tr * bg[2];
        // r0 g0 b0 r1 g1 b1 r2 g2 | b2 r3 g3 b3 r4 g4 b4 r5 | g5 b5 r6 g6 b6 r7 g7 b7
        const F8 rg0 = __builtin_shufflevector(r, g, 0, 8, 0, 1, 9, 1, 2, 10);
        const F8 rg1 = __builtin_shufflevector(r, g, 2, 3, 11, 3, 4, 12, 4, 5);
        const F8 rg2 = __builtin_shufflevector(r, g, 13, 5, 6, 14, 6, 7, 15, 7);
        float* out = rgb + 3 * (x0 + h);
        Store(out, __builtin_shufflevector(rg0, b, 0, 1, 8, 3, 4, 9, 6, 7));
        Store(out + 8, __builtin_shufflevector(rg1, b, 10, 1, 2, 11, 4, 5, 12, 7));
        Store(out + 16, __builtin_shufflevector(rg2, b, 0, 13, 2, 3, 14, 5, 6, 15));
        Store(alpha + x0 + h, 1.0f - tr);
      }
    } else {
      for (int c = 0; x0 + c < width; ++c) {
        const float tr = std::fabs(st.T[y][c]);
        rgb[3 * (x0 + c) + 0] = st.r[y][c] + tr * bg[0];
        rgb[3 * (x0 + c) + 1] = st.g[y][c] + tr * bg[1];
        rgb[3 * (x0 + c) + 2] = st.b[y][c] + tr * bg[2];
        alpha[x0 + c] = 1.0f - tr;
      }
    }
  }
}

}  // namespace hvdb::render::gaussian

#endif  // HVDB_RENDER_GAUSSIAN_RASTER_KERNELS_H_
