// The differentiable 3DGS rasteriser (gaussian_grad.h).
//
// Why it is ours: the reference (graphdeco-inria/diff-gaussian-rasterization) and gsplat are
// CUDA extensions of PyTorch; no Debian package differentiates a Gaussian splatting render on
// the CPU. Scalar float code, organised as the reference: a preprocess per splat, per-tile
// lists sorted front to back, a forward blend per pixel that records each pixel's final
// transmittance and last contributor, and a backward pass that walks each pixel's splats back
// to front recovering T by division (backward.cu's renderCUDA), then per splat the chain rule
// through the conic, the EWA projection, the covariance, the quaternion and the SH
// (backward.cu's computeCov2DCUDA, computeCov3D, computeColorFromSH). Equation numbers below
// refer to the 3DGS paper (Kerbl et al. 2023) and the EWA splatting paper (Zwicker et al. 2002).
#include "render/gaussian_grad.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <thread>

#include "render/gaussian_raster.h"
#include "render/gaussian_view.h"
#include "render/splat.h"

namespace hvdb::render {

namespace {

using gaussian::kTile;
using gaussian::ViewF;

constexpr float kNearZ = 0.2f;
constexpr float kDilation = 0.3f;
constexpr float kMinAlpha = 1.0f / 255.0f;
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 0.0001f;
constexpr size_t kChunk = 4096;  // splats per preprocessing task
// (splat, tile) pairs a view may have: the list's 4 bytes and the backward pass's 36 a pair
// stay within 4 GiB, and the list's offsets within 32 bits.
constexpr uint64_t kMaxPairs = 100'000'000;

constexpr float kC0 = static_cast<float>(formats::kShC0);
constexpr float kC1 = static_cast<float>(formats::kShC1);

// Everything about one splat's projection that both passes need, recomputed by the backward
// pass rather than stored (it is cheap next to the blending).
struct Geometry {
  float t[3];            // view-space centre (eq. 29 of EWA: W p + trans)
  float q[4];            // the normalised quaternion w x y z
  float qn;              // the stored quaternion's norm (0: the identity was used)
  float s[3];            // e^(log scale)
  float R[9];            // rotation of q, row-major
  float M[9];            // R S
  float Sigma[6];        // R S S^T R^T: xx xy xz yy yz zz (3DGS eq. 6)
  float t0[3], t1[3];    // the rows of J W (EWA eq. 31, 3DGS eq. 5)
  float j02, j12;        // J's entries that depend on x and y
  int clamp_x, clamp_y;  // 0, or the sign of the limit x/z (y/z) was clamped to
  float cov[3];          // the dilated 2D covariance a b c
  float det;             // a c - b^2
  float dir[3];          // unit direction from the camera centre
  float dist;            // and the distance
  float basis[15];       // the SH basis for dir, signs folded in (forward.cu's computeColorFromSH)
};

// Sets g from splat i; false when the reference culls it (behind the near plane, a singular
// 2D covariance, or non-finite values).
bool Project(const formats::GaussianCloud& cloud, size_t i, const ViewF& v, Geometry* g) {
  const float* p = &cloud.position[3 * i];
  const float* W = v.rot;
  for (int r = 0; r < 3; ++r)
    g->t[r] = W[3 * r] * p[0] + W[3 * r + 1] * p[1] + W[3 * r + 2] * p[2] + v.trans[r];
  const float tz = g->t[2];
  if (!(tz > kNearZ)) return false;
  const float* q = &cloud.rotation[4 * i];
  g->qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (g->qn > 0) {
    for (int k = 0; k < 4; ++k) g->q[k] = q[k] / g->qn;
  } else {
    g->q[0] = 1, g->q[1] = g->q[2] = g->q[3] = 0;
  }
  const float w = g->q[0], x = g->q[1], y = g->q[2], z = g->q[3];
  const float R[9] = {
      1.f - 2.f * (y * y + z * z), 2.f * (x * y - w * z),       2.f * (x * z + w * y),
      2.f * (x * y + w * z),       1.f - 2.f * (x * x + z * z), 2.f * (y * z - w * x),
      2.f * (x * z - w * y),       2.f * (y * z + w * x),       1.f - 2.f * (x * x + y * y)};
  std::memcpy(g->R, R, sizeof R);
  for (int k = 0; k < 3; ++k) g->s[k] = std::exp(std::min(cloud.scale[3 * i + k], 80.0f));
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) g->M[3 * r + c] = R[3 * r + c] * g->s[c];
  }
  const float* M = g->M;
  auto row_dot = [&](int r, int c) {
    return M[3 * r] * M[3 * c] + M[3 * r + 1] * M[3 * c + 1] + M[3 * r + 2] * M[3 * c + 2];
  };
  g->Sigma[0] = row_dot(0, 0), g->Sigma[1] = row_dot(0, 1), g->Sigma[2] = row_dot(0, 2);
  g->Sigma[3] = row_dot(1, 1), g->Sigma[4] = row_dot(1, 2), g->Sigma[5] = row_dot(2, 2);

  // The Jacobian of the projection at the centre, x/z and y/z clamped to 1.3 tan(half fov).
  const float inv_z = 1.0f / tz;
  const float rx = g->t[0] * inv_z, ry = g->t[1] * inv_z;
  g->clamp_x = rx < -v.lim_x ? -1 : (rx > v.lim_x ? 1 : 0);
  g->clamp_y = ry < -v.lim_y ? -1 : (ry > v.lim_y ? 1 : 0);
  const float xc = std::min(v.lim_x, std::max(-v.lim_x, rx)) * tz;
  const float yc = std::min(v.lim_y, std::max(-v.lim_y, ry)) * tz;
  const float j00 = v.fx * inv_z, j11 = v.fy * inv_z;
  g->j02 = -(v.fx * xc) * (inv_z * inv_z);
  g->j12 = -(v.fy * yc) * (inv_z * inv_z);
  for (int k = 0; k < 3; ++k) {
    g->t0[k] = j00 * W[k] + g->j02 * W[6 + k];
    g->t1[k] = j11 * W[3 + k] + g->j12 * W[6 + k];
  }
  const float* S = g->Sigma;
  auto quad = [&](const float* a, const float* b) {  // a^T Sigma b
    const float sb[3] = {S[0] * b[0] + S[1] * b[1] + S[2] * b[2],
                         S[1] * b[0] + S[3] * b[1] + S[4] * b[2],
                         S[2] * b[0] + S[4] * b[1] + S[5] * b[2]};
    return a[0] * sb[0] + a[1] * sb[1] + a[2] * sb[2];
  };
  g->cov[0] = quad(g->t0, g->t0) + kDilation;
  g->cov[1] = quad(g->t0, g->t1);
  g->cov[2] = quad(g->t1, g->t1) + kDilation;
  g->det = g->cov[0] * g->cov[2] - g->cov[1] * g->cov[1];
  if (!(g->det != 0.0f) || !std::isfinite(g->det)) return false;

  float d[3] = {p[0] - v.centre[0], p[1] - v.centre[1], p[2] - v.centre[2]};
  g->dist = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  const float inv = g->dist > 0 ? 1.0f / g->dist : 0.0f;
  for (int k = 0; k < 3; ++k) g->dir[k] = d[k] * inv;
  const float dx = g->dir[0], dy = g->dir[1], dz = g->dir[2];
  const float xx = dx * dx, yy = dy * dy, zz = dz * dz;
  const float b[15] = {-kC1 * dy,
                       kC1 * dz,
                       -kC1 * dx,
                       float(formats::kShC2[0]) * dx * dy,
                       float(formats::kShC2[1]) * dy * dz,
                       float(formats::kShC2[2]) * (2.0f * zz - xx - yy),
                       float(formats::kShC2[3]) * dx * dz,
                       float(formats::kShC2[4]) * (xx - yy),
                       float(formats::kShC3[0]) * dy * (3.0f * xx - yy),
                       float(formats::kShC3[1]) * dx * dy * dz,
                       float(formats::kShC3[2]) * dy * (4.0f * zz - xx - yy),
                       float(formats::kShC3[3]) * dz * (2.0f * zz - 3.0f * xx - 3.0f * yy),
                       float(formats::kShC3[4]) * dx * (4.0f * zz - xx - yy),
                       float(formats::kShC3[5]) * dz * (xx - yy),
                       float(formats::kShC3[6]) * dx * (xx - 3.0f * yy)};
  std::memcpy(g->basis, b, sizeof b);
  return true;
}

// d basis_j / d dir for j in [0, 15): the gradient of each basis function above.
void BasisGradient(const float* dir, float out[15][3]) {
  const float x = dir[0], y = dir[1], z = dir[2];
  const float xx = x * x, yy = y * y, zz = z * z;
  const float c1 = kC1;
  const double* c2 = formats::kShC2;
  const double* c3 = formats::kShC3;
  const float g[15][3] = {
      {0, -c1, 0},
      {0, 0, c1},
      {-c1, 0, 0},
      {float(c2[0]) * y, float(c2[0]) * x, 0},
      {0, float(c2[1]) * z, float(c2[1]) * y},
      {float(c2[2]) * -2 * x, float(c2[2]) * -2 * y, float(c2[2]) * 4 * z},
      {float(c2[3]) * z, 0, float(c2[3]) * x},
      {float(c2[4]) * 2 * x, float(c2[4]) * -2 * y, 0},
      {float(c3[0]) * 6 * x * y, float(c3[0]) * (3 * xx - 3 * yy), 0},
      {float(c3[1]) * y * z, float(c3[1]) * x * z, float(c3[1]) * x * y},
      {float(c3[2]) * -2 * x * y, float(c3[2]) * (4 * zz - xx - 3 * yy), float(c3[2]) * 8 * y * z},
      {float(c3[3]) * -6 * x * z, float(c3[3]) * -6 * y * z,
       float(c3[3]) * (6 * zz - 3 * xx - 3 * yy)},
      {float(c3[4]) * (4 * zz - 3 * xx - yy), float(c3[4]) * -2 * x * y, float(c3[4]) * 8 * x * z},
      {float(c3[5]) * 2 * x * z, float(c3[5]) * -2 * y * z, float(c3[5]) * (xx - yy)},
      {float(c3[6]) * (3 * xx - 3 * yy), float(c3[6]) * -6 * x * y, 0},
  };
  std::memcpy(out, g, sizeof g);
}

unsigned Threads(int threads) {
  if (threads > 0) return static_cast<unsigned>(threads);
  return std::max(1u, std::thread::hardware_concurrency());
}

// The screen-space gradient slots of a tile-list entry: du dv dA dB dC dopacity dr dg db.
constexpr int kSlot = 9;

}  // namespace

Status GaussianGradRasterizer::Forward(const formats::GaussianCloud& cloud, const Camera& camera,
                                       const std::array<float, 3>& background, int threads,
                                       std::vector<float>* rgb) {
  GaussianRenderOptions check;
  check.threads = threads;
  HVDB_RETURN_IF_ERROR(CheckGaussianRender(cloud, camera, check));
  if (cloud.antialiased) {
    return Status::InvalidArgument(
        "the differentiable rasteriser draws plain 3DGS clouds, not antialiased (Mip-Splatting) "
        "ones");
  }
  cloud_ = &cloud;
  camera_ = camera;
  background_ = background;
  threads_ = static_cast<int>(Threads(threads));
  const ViewF v = gaussian::MakeView(camera);
  const size_t n = cloud.size();
  splats_.resize(n);
  is_visible_.assign(n, 0);
  std::vector<float> depth(n, 0.0f);
  // Per splat: its tiles [tx0, tx1) x [ty0, ty1), packed.
  std::vector<std::array<uint16_t, 4>> rect(n);
  const int per_channel = formats::ShRestPerChannel(cloud.sh_degree);
  internal::ParallelFor((n + kChunk - 1) / kChunk, threads_, [&](size_t c) {
    Geometry g;
    for (size_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) {
      if (!Project(cloud, i, v, &g)) continue;
      Splat& s = splats_[i];
      const float inv_det = 1.0f / g.det;
      s.A = g.cov[2] * inv_det;
      s.B = -g.cov[1] * inv_det;
      s.C = g.cov[0] * inv_det;
      s.opacity = formats::Sigmoid(cloud.opacity[i]);
      s.u = v.fx * g.t[0] / g.t[2] + v.cx;
      s.v = v.fy * g.t[1] / g.t[2] + v.cy;
      s.clamped = 0;
      bool finite = std::isfinite(s.u) && std::isfinite(s.v) && std::isfinite(s.A + s.B + s.C);
      const float* rest = cloud.sh_rest.data() + i * 3 * static_cast<size_t>(per_channel);
      for (int ch = 0; ch < 3; ++ch) {
        float col = kC0 * cloud.sh_dc[3 * i + ch];
        for (int j = 0; j < per_channel; ++j) col += g.basis[j] * rest[ch * per_channel + j];
        col += 0.5f;
        finite = finite && std::isfinite(col);
        if (col < 0.0f) s.clamped |= 1u << ch;
        s.rgb[ch] = std::max(col, 0.0f);
      }
      if (!finite || s.opacity < kMinAlpha) continue;
      // The reference's rectangle (getRect) of radius ceil(3 sqrt(largest eigenvalue)), cut to
      // the box of the ellipse where alpha can reach 1/255 (outside it every pixel skips the
      // splat): the same box as the forward rasteriser's (gaussian_raster_kernels.h).
      const float mid = 0.5f * (g.cov[0] + g.cov[2]);
      const float radius =
          std::ceil(3.0f * std::sqrt(mid + std::sqrt(std::max(0.1f, mid * mid - g.det))));
      if (!std::isfinite(radius)) continue;
      auto tile = [](float t, int grid) {
        return static_cast<int>(std::min(std::max(t, 0.0f), static_cast<float>(grid)));
      };
      const int rx0 = tile((s.u - radius) / kTile, v.tiles_x);
      const int ry0 = tile((s.v - radius) / kTile, v.tiles_y);
      const int rx1 = tile((s.u + radius + kTile - 1) / kTile, v.tiles_x);
      const int ry1 = tile((s.v + radius + kTile - 1) / kTile, v.tiles_y);
      const float kq = 2.0f * std::log(std::max(255.0f * s.opacity, 1.0f)) * 1.001f + 0.01f;
      const float ex = std::sqrt(kq * std::max(g.cov[0], 0.0f)) * 1.001f + 0.01f;
      const float ey = std::sqrt(kq * std::max(g.cov[2], 0.0f)) * 1.001f + 0.01f;
      // Clamped to [-1, size] before the conversions, so they are defined wherever the splat is.
      auto clamp = [](float x, int size) { return std::min(std::max(x, -1.0f), float(size)); };
      const int x0 = std::max(static_cast<int>(std::ceil(clamp(s.u - ex, v.width))), 0);
      const int x1 = std::min(static_cast<int>(std::floor(clamp(s.u + ex, v.width))), v.width - 1);
      const int y0 = std::max(static_cast<int>(std::ceil(clamp(s.v - ey, v.height))), 0);
      const int y1 =
          std::min(static_cast<int>(std::floor(clamp(s.v + ey, v.height))), v.height - 1);
      const int tx0 = std::max(rx0, x0 / kTile), tx1 = std::min(rx1, x1 / kTile + 1);
      const int ty0 = std::max(ry0, y0 / kTile), ty1 = std::min(ry1, y1 / kTile + 1);
      if (x0 > x1 || y0 > y1 || tx0 >= tx1 || ty0 >= ty1) continue;
      s.x0 = static_cast<int16_t>(x0), s.x1 = static_cast<int16_t>(x1);
      s.y0 = static_cast<int16_t>(y0), s.y1 = static_cast<int16_t>(y1);
      rect[i] = {static_cast<uint16_t>(tx0), static_cast<uint16_t>(tx1), static_cast<uint16_t>(ty0),
                 static_cast<uint16_t>(ty1)};
      depth[i] = g.t[2];
      is_visible_[i] = 1;
    }
  });

  // Front to back, ties by index (the reference's stable radix sort of tile|depth keys), then
  // a counting sort by tile keeps that order within every tile.
  std::vector<uint32_t> visible;
  std::vector<float> keys;
  for (size_t i = 0; i < n; ++i) {
    if (!is_visible_[i]) continue;
    visible.push_back(static_cast<uint32_t>(i));
    keys.push_back(depth[i]);
  }
  visible_ = visible.size();
  const std::vector<uint32_t> order = internal::StableOrder(keys);
  const size_t tiles = static_cast<size_t>(v.tiles_x) * v.tiles_y;
  uint64_t pairs = 0;
  for (uint32_t i : visible) {
    const auto& r = rect[i];
    pairs += static_cast<uint64_t>(r[1] - r[0]) * static_cast<uint64_t>(r[3] - r[2]);
  }
  if (pairs > kMaxPairs) {
    return Status::LimitExceeded(
        "the differentiable rasteriser's splats cover " + std::to_string(pairs) +
        " (splat, tile) pairs in this view, more than " + std::to_string(kMaxPairs) +
        " (40 bytes each): fit at a smaller size or from fewer or smaller splats");
  }
  tile_start_.assign(tiles + 1, 0);
  for (uint32_t i : visible) {
    const auto& r = rect[i];
    for (int ty = r[2]; ty < r[3]; ++ty) {
      for (int tx = r[0]; tx < r[1]; ++tx)
        ++tile_start_[static_cast<size_t>(ty) * v.tiles_x + tx + 1];
    }
  }
  for (size_t t = 0; t < tiles; ++t) tile_start_[t + 1] += tile_start_[t];
  list_.resize(tile_start_[tiles]);
  std::vector<uint32_t> next(tile_start_.begin(), tile_start_.end() - 1);
  for (uint32_t o : order) {
    const uint32_t i = visible[o];
    const auto& r = rect[i];
    for (int ty = r[2]; ty < r[3]; ++ty) {
      for (int tx = r[0]; tx < r[1]; ++tx)
        list_[next[static_cast<size_t>(ty) * v.tiles_x + tx]++] = i;
    }
  }

  // Blend, per pixel front to back (3DGS eq. 3; forward.cu's renderCUDA). Splat-major within a
  // tile: each splat in depth order visits only the pixels of its box, each pixel keeping its
  // own state, which gives every pixel the reference's sequence without testing every splat of
  // the tile at every pixel.
  const size_t pixels = static_cast<size_t>(v.width) * v.height;
  rgb->assign(3 * pixels, 0.0f);
  final_T_.assign(pixels, 1.0f);
  last_.assign(pixels, 0);
  internal::ParallelFor(tiles, threads_, [&](size_t t) {
    const int x0 = static_cast<int>(t % v.tiles_x) * kTile,
              y0 = static_cast<int>(t / v.tiles_x) * kTile;
    const int x1 = std::min(v.width, x0 + kTile) - 1, y1 = std::min(v.height, y0 + kTile) - 1;
    float T[kTile * kTile], C[kTile * kTile][3] = {};
    uint32_t last[kTile * kTile] = {};
    bool done[kTile * kTile] = {};
    std::fill_n(T, kTile * kTile, 1.0f);
    int live = (x1 - x0 + 1) * (y1 - y0 + 1);
    const uint32_t begin = tile_start_[t], end = tile_start_[t + 1];
    for (uint32_t k = begin; k < end && live > 0; ++k) {
      const Splat& s = splats_[list_[k]];
      const int xa = std::max<int>(s.x0, x0), xb = std::min<int>(s.x1, x1);
      const int ya = std::max<int>(s.y0, y0), yb = std::min<int>(s.y1, y1);
      for (int y = ya; y <= yb; ++y) {
        const float dy = s.v - static_cast<float>(y);
        for (int x = xa; x <= xb; ++x) {
          const int p = (y - y0) * kTile + (x - x0);
          if (done[p]) continue;
          const float dx = s.u - static_cast<float>(x);
          const float power = -0.5f * (s.A * dx * dx + s.C * dy * dy) - s.B * dx * dy;
          if (power > 0.0f) continue;
          const float alpha = std::min(kMaxAlpha, s.opacity * std::exp(power));
          if (alpha < kMinAlpha) continue;
          const float test_T = T[p] * (1.0f - alpha);
          if (test_T < kMinTransmittance) {
            done[p] = true;
            --live;
            continue;
          }
          for (int ch = 0; ch < 3; ++ch) C[p][ch] += s.rgb[ch] * alpha * T[p];
          T[p] = test_T;
          last[p] = k - begin + 1;
        }
      }
    }
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const int p = (y - y0) * kTile + (x - x0);
        const size_t q = static_cast<size_t>(y) * v.width + x;
        final_T_[q] = T[p];
        last_[q] = last[p];
        for (int ch = 0; ch < 3; ++ch) (*rgb)[3 * q + ch] = C[p][ch] + T[p] * background_[ch];
      }
    }
  });
  return Status::OK();
}

void GaussianGradRasterizer::Backward(const std::vector<float>& dL_drgb, GaussianGradient* grad,
                                      std::vector<float>* screen_grad) {
  const formats::GaussianCloud& cloud = *cloud_;
  const ViewF v = gaussian::MakeView(camera_);
  const size_t n = cloud.size();
  const size_t tiles = tile_start_.size() - 1;

  // 1. Per pixel, back to front: each entry's screen-space gradient (backward.cu's renderCUDA),
  // splat-major within the tile as the forward pass, each pixel from its last contributor.
  std::vector<float> slots(list_.size() * kSlot, 0.0f);
  internal::ParallelFor(tiles, threads_, [&](size_t t) {
    constexpr int kPixels = kTile * kTile;
    const int x0 = static_cast<int>(t % v.tiles_x) * kTile,
              y0 = static_cast<int>(t / v.tiles_x) * kTile;
    const int x1 = std::min(v.width, x0 + kTile) - 1, y1 = std::min(v.height, y0 + kTile) - 1;
    const uint32_t begin = tile_start_[t];
    float T[kPixels], final_T[kPixels], bg_dot[kPixels], last_alpha[kPixels] = {};
    float dpix[kPixels][3] = {}, accum[kPixels][3] = {}, last_colour[kPixels][3] = {};
    uint32_t last[kPixels] = {}, most = 0;
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        const int p = (y - y0) * kTile + (x - x0);
        const size_t q = static_cast<size_t>(y) * v.width + x;
        T[p] = final_T[p] = final_T_[q];
        last[p] = last_[q];
        most = std::max(most, last[p]);
        for (int ch = 0; ch < 3; ++ch) dpix[p][ch] = dL_drgb[3 * q + ch];
        bg_dot[p] =
            background_[0] * dpix[p][0] + background_[1] * dpix[p][1] + background_[2] * dpix[p][2];
      }
    }
    for (uint32_t k = begin + most; k-- > begin;) {
      const Splat& s = splats_[list_[k]];
      const int xa = std::max<int>(s.x0, x0), xb = std::min<int>(s.x1, x1);
      const int ya = std::max<int>(s.y0, y0), yb = std::min<int>(s.y1, y1);
      float g[kSlot] = {};
      const uint32_t rank = k - begin;
      for (int y = ya; y <= yb; ++y) {
        const float dy = s.v - static_cast<float>(y);
        for (int x = xa; x <= xb; ++x) {
          const int p = (y - y0) * kTile + (x - x0);
          if (rank >= last[p]) continue;  // behind the pixel's last contributor
          const float dx = s.u - static_cast<float>(x);
          const float power = -0.5f * (s.A * dx * dx + s.C * dy * dy) - s.B * dx * dy;
          if (power > 0.0f) continue;
          const float G = std::exp(power);
          const float raw = s.opacity * G;
          const float alpha = std::min(kMaxAlpha, raw);
          if (alpha < kMinAlpha) continue;
          T[p] = T[p] / (1.0f - alpha);
          // dC/dalpha = T (c - what lies behind, relative to T after this splat).
          float dL_dalpha = 0.0f;
          for (int ch = 0; ch < 3; ++ch) {
            accum[p][ch] =
                last_alpha[p] * last_colour[p][ch] + (1.0f - last_alpha[p]) * accum[p][ch];
            last_colour[p][ch] = s.rgb[ch];
            dL_dalpha += (s.rgb[ch] - accum[p][ch]) * dpix[p][ch];
            g[6 + ch] += alpha * T[p] * dpix[p][ch];
          }
          dL_dalpha *= T[p];
          last_alpha[p] = alpha;
          dL_dalpha += (-final_T[p] / (1.0f - alpha)) * bg_dot[p];  // the background behind
          if (raw >= kMaxAlpha) continue;  // clamped: alpha does not move with G or opacity
          g[5] += G * dL_dalpha;
          const float dL_dpower = raw * dL_dalpha;
          g[0] += dL_dpower * (-s.A * dx - s.B * dy);
          g[1] += dL_dpower * (-s.C * dy - s.B * dx);
          g[2] += dL_dpower * (-0.5f * dx * dx);
          g[3] += dL_dpower * (-dx * dy);
          g[4] += dL_dpower * (-0.5f * dy * dy);
        }
      }
      std::copy_n(g, kSlot, &slots[static_cast<size_t>(k) * kSlot]);
    }
  });

  // 2. Summed per splat in list order (the same sums whatever the threads did).
  std::vector<float> screen(n * kSlot, 0.0f);
  for (size_t k = 0; k < list_.size(); ++k) {
    float* to = &screen[static_cast<size_t>(list_[k]) * kSlot];
    const float* from = &slots[k * kSlot];
    for (int j = 0; j < kSlot; ++j) to[j] += from[j];
  }
  slots = {};

  // 3. Per splat, the chain rule back to the stored values.
  grad->sh_degree = cloud.sh_degree;
  grad->antialiased = false;
  grad->Resize(n);
  std::fill(grad->position.begin(), grad->position.end(), 0.0f);
  std::fill(grad->scale.begin(), grad->scale.end(), 0.0f);
  std::fill(grad->rotation.begin(), grad->rotation.end(), 0.0f);
  std::fill(grad->opacity.begin(), grad->opacity.end(), 0.0f);
  std::fill(grad->sh_dc.begin(), grad->sh_dc.end(), 0.0f);
  std::fill(grad->sh_rest.begin(), grad->sh_rest.end(), 0.0f);
  if (screen_grad != nullptr) screen_grad->assign(n, -1.0f);  // -1: culled
  const int per_channel = formats::ShRestPerChannel(cloud.sh_degree);
  internal::ParallelFor((n + kChunk - 1) / kChunk, threads_, [&](size_t c) {
    Geometry g;
    float basis_grad[15][3];
    for (size_t i = c * kChunk; i < std::min(n, (c + 1) * kChunk); ++i) {
      if (!is_visible_[i]) continue;
      const float* sg = &screen[i * kSlot];
      const Splat& s = splats_[i];
      Project(cloud, i, v, &g);
      if (screen_grad != nullptr) {
        const float gx = sg[0] * 0.5f * v.width, gy = sg[1] * 0.5f * v.height;
        (*screen_grad)[i] = std::sqrt(gx * gx + gy * gy);
      }
      // Colour (3DGS's SH evaluation): c = max(0, C0 dc + sum basis_j rest_j + 0.5).
      float dL_ddir[3] = {0, 0, 0};
      const float* rest = cloud.sh_rest.data() + i * 3 * static_cast<size_t>(per_channel);
      float* grest = grad->sh_rest.data() + i * 3 * static_cast<size_t>(per_channel);
      if (per_channel > 0) BasisGradient(g.dir, basis_grad);
      for (int ch = 0; ch < 3; ++ch) {
        if (s.clamped & (1u << ch)) continue;
        const float gc = sg[6 + ch];
        grad->sh_dc[3 * i + ch] = kC0 * gc;
        for (int j = 0; j < per_channel; ++j) {
          grest[ch * per_channel + j] = g.basis[j] * gc;
          for (int k = 0; k < 3; ++k)
            dL_ddir[k] += gc * rest[ch * per_channel + j] * basis_grad[j][k];
        }
      }
      // Opacity through the sigmoid.
      grad->opacity[i] = sg[5] * s.opacity * (1.0f - s.opacity);

      // Conic Q = Sigma2^-1: dL/dSigma2 = -Q (dL/dQ) Q, with the off-diagonal B counted once
      // in each of its two places.
      const float A = s.A, B = s.B, Cc = s.C;
      const float gA = sg[2], gB = 0.5f * sg[3], gC = sg[4];
      // P = Q GQ Q for symmetric Q = [A B; B Cc] and GQ = [gA gB; gB gC].
      const float qg00 = A * gA + B * gB, qg01 = A * gB + B * gC;
      const float qg10 = B * gA + Cc * gB, qg11 = B * gB + Cc * gC;
      const float P00 = qg00 * A + qg01 * B, P01 = qg00 * B + qg01 * Cc;
      const float P11 = qg10 * B + qg11 * Cc;
      const float ga = -P00, gb = -2.0f * P01, gc = -P11;

      // Sigma2 = T Sigma T^T with T's rows t0, t1 (EWA eq. 31); the dilation is a constant.
      const float* S = g.Sigma;
      auto mul = [&](const float* a, float* out) {
        out[0] = S[0] * a[0] + S[1] * a[1] + S[2] * a[2];
        out[1] = S[1] * a[0] + S[3] * a[1] + S[4] * a[2];
        out[2] = S[2] * a[0] + S[4] * a[1] + S[5] * a[2];
      };
      float st0[3], st1[3];
      mul(g.t0, st0);
      mul(g.t1, st1);
      float dt0[3], dt1[3];
      for (int k = 0; k < 3; ++k) {
        dt0[k] = 2.0f * ga * st0[k] + gb * st1[k];
        dt1[k] = gb * st0[k] + 2.0f * gc * st1[k];
      }
      // dL/dSigma, symmetrised (Sigma = M M^T, so dL/dM = (G + G^T) M).
      float Gs[9];
      for (int r = 0; r < 3; ++r) {
        for (int k = 0; k < 3; ++k) {
          Gs[3 * r + k] = 2.0f * ga * g.t0[r] * g.t0[k] +
                          gb * (g.t0[r] * g.t1[k] + g.t1[r] * g.t0[k]) +
                          2.0f * gc * g.t1[r] * g.t1[k];
        }
      }
      float dM[9];
      for (int r = 0; r < 3; ++r) {
        for (int k = 0; k < 3; ++k) {
          dM[3 * r + k] =
              Gs[3 * r] * g.M[k] + Gs[3 * r + 1] * g.M[3 + k] + Gs[3 * r + 2] * g.M[6 + k];
        }
      }
      // M = R S: scales (log) and the rotation.
      float dR[9];
      for (int k = 0; k < 3; ++k) {
        float ds = 0.0f;
        for (int r = 0; r < 3; ++r) {
          ds += dM[3 * r + k] * g.R[3 * r + k];
          dR[3 * r + k] = dM[3 * r + k] * g.s[k];
        }
        grad->scale[3 * i + k] = cloud.scale[3 * i + k] < 80.0f ? ds * g.s[k] : 0.0f;
      }
      const float w = g.q[0], x = g.q[1], y = g.q[2], z = g.q[3];
      float dq[4] = {
          2.0f * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]),
          2.0f * (y * dR[1] + z * dR[2] + y * dR[3] - 2 * x * dR[4] - w * dR[5] + z * dR[6] +
                  w * dR[7] - 2 * x * dR[8]),
          2.0f * (-2 * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] +
                  z * dR[7] - 2 * y * dR[8]),
          2.0f * (-2 * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - 2 * z * dR[4] + y * dR[5] +
                  x * dR[6] + y * dR[7])};
      if (g.qn > 0) {  // through the normalisation q / |q|
        const float dot = w * dq[0] + x * dq[1] + y * dq[2] + z * dq[3];
        for (int k = 0; k < 4; ++k) grad->rotation[4 * i + k] = (dq[k] - g.q[k] * dot) / g.qn;
      }

      // The Jacobian's entries: t0 = j00 W0 + j02 W2, t1 = j11 W1 + j12 W2.
      const float* W = v.rot;
      const float dj00 = dt0[0] * W[0] + dt0[1] * W[1] + dt0[2] * W[2];
      const float dj02 = dt0[0] * W[6] + dt0[1] * W[7] + dt0[2] * W[8];
      const float dj11 = dt1[0] * W[3] + dt1[1] * W[4] + dt1[2] * W[5];
      const float dj12 = dt1[0] * W[6] + dt1[1] * W[7] + dt1[2] * W[8];
      const float tz = g.t[2], iz = 1.0f / tz, iz2 = iz * iz;
      float gt[3] = {0, 0, 0};
      gt[2] += dj00 * (-v.fx * iz2) + dj11 * (-v.fy * iz2);
      if (g.clamp_x == 0) {  // j02 = -fx x / z^2
        gt[0] += dj02 * (-v.fx * iz2);
        gt[2] += dj02 * (2.0f * v.fx * g.t[0] * iz2 * iz);
      } else {  // j02 = -fx (+-lim) / z
        gt[2] += dj02 * (v.fx * g.clamp_x * v.lim_x * iz2);
      }
      if (g.clamp_y == 0) {
        gt[1] += dj12 * (-v.fy * iz2);
        gt[2] += dj12 * (2.0f * v.fy * g.t[1] * iz2 * iz);
      } else {
        gt[2] += dj12 * (v.fy * g.clamp_y * v.lim_y * iz2);
      }
      // The centre's projection u = fx x/z + cx, v = fy y/z + cy.
      gt[0] += sg[0] * v.fx * iz;
      gt[1] += sg[1] * v.fy * iz;
      gt[2] += -sg[0] * v.fx * g.t[0] * iz2 - sg[1] * v.fy * g.t[1] * iz2;
      // View space to world (t = W p + trans), and the SH direction (p - centre) / |p - centre|.
      const float ddot = g.dir[0] * dL_ddir[0] + g.dir[1] * dL_ddir[1] + g.dir[2] * dL_ddir[2];
      const float inv_dist = g.dist > 0 ? 1.0f / g.dist : 0.0f;
      for (int k = 0; k < 3; ++k) {
        grad->position[3 * i + k] = W[k] * gt[0] + W[3 + k] * gt[1] + W[6 + k] * gt[2] +
                                    (dL_ddir[k] - g.dir[k] * ddot) * inv_dist;
      }
    }
  });
}

}  // namespace hvdb::render
