// 3D Gaussian splatting (3DGS, Kerbl et al. 2023) on the CPU: the forward pass of the reference
// rasteriser (graphdeco-inria/diff-gaussian-rasterization, cuda_rasterizer/forward.cu), so that
// a cloud trained by any 3DGS trainer (formats/gaussians.h reads its files) renders here as it
// does there.
//
// Per splat (values before activation, as the cloud stores them):
//   - the view-space centre; culled at z <= 0.2;
//   - the 3D covariance R S S^T R^T (S = diag(exp(log scale)), R of the normalised quaternion;
//     the identity for a zero quaternion, as GaussianCloud::Covariance), projected by the EWA
//     Jacobian at the centre with x/z and y/z clamped to 1.3 tan(half fov); then +0.3 pixel^2
//     on the diagonal. An antialiased cloud (Mip-Splatting) has its opacity multiplied by
//     sqrt(max(0, det before / det after)), as gsplat's antialiased mode;
//   - det == 0: culled; the conic is the inverse; radius = ceil(3 sqrt(largest eigenvalue))
//     with the reference's floor of 0.1 under the square root's discriminant;
//   - pixel position u = fx x/z + cx, v = fy y/z + cy (the centre of pixel (u, v) is at integer
//     coordinates, Camera's convention);
//   - colour: the SH of degree sh_degree for the direction from the camera centre to the splat,
//     + 0.5, clamped below at 0 (not above);
//   - 16x16-pixel tiles; a splat belongs to the tiles of its square [u-r, u+r] x [v-r, v+r] as
//     the reference's getRect computes them, and each tile blends its splats by view depth
//     (ties by index).
// Per pixel, front to back: power = -0.5 (a dx^2 + c dy^2) - b dx dy with d = centre - pixel;
// skipped when power > 0; alpha = min(0.99, opacity exp(power)), skipped below 1/255; the
// pixel stops at the splat that would bring T (1 - alpha) below 1e-4 (that splat not added);
// C += colour alpha T, T *= 1 - alpha. The pixel is C + T background.
//
// Float arithmetic throughout, as the reference; tests/render/gaussian_raster_test.cc checks it
// against a plain double-precision reading of the same equations (PSNR > 95 dB, 8-bit values
// within 1). Speed (bench/gaussian_render_bench.cc): a 1 M-splat scene of splats a few pixels
// across renders at 1920x1080 in ~95-130 ms on two cores (8-10 M splats/s); gaussian_raster.cc
// says how the work is organised.
#ifndef HVDB_RENDER_GAUSSIAN_RASTER_H_
#define HVDB_RENDER_GAUSSIAN_RASTER_H_

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include "formats/gaussians.h"
#include "render/renderer.h"
#include "storage/status.h"

namespace hvdb::render {

struct GaussianRenderOptions {
  std::array<float, 3> background{0, 0, 0};  // added as T * background (display values)
  int threads = 0;                           // 0: std::thread::hardware_concurrency()
};

// What the rasteriser computes, before any rounding to 8 bits.
struct GaussianImage {
  uint32_t width = 0, height = 0;
  // 3 floats a pixel, row-major: C + T * background, in the cloud's own colour values
  // (display-referred as 3DGS trains them: not linearised, not clamped above).
  std::vector<float> rgb;
  std::vector<float> alpha;  // 1 - T, the final transmittance's complement
  // RGBA, 8 bits a channel: each value clamped to [0, 1], then round(v * 255).
  std::vector<uint8_t> ToRgba8() const;
};

struct GaussianRenderStats {
  uint64_t splats_in = 0;  // cloud.size()
  // Splats that pass the reference's culling and can reach alpha 1/255 at some pixel centre
  // of their tiles (the others would change no pixel).
  uint64_t splats_visible = 0;
  // (splat, tile) pairs blended: the reference's tiles of each visible splat that the ellipse
  // where its alpha can reach 1/255 touches (the pixel box of that ellipse).
  uint64_t tile_entries = 0;
  double milliseconds = 0;   // the whole call; and its three stages:
  double preprocess_ms = 0;  // projection, 2D covariance, colour, tiles
  double bin_ms = 0;         // the depth sort and the tile lists
  double blend_ms = 0;       // the tiles blended and written out
};

// RenderGaussians' checks of its arguments (the GPU rasteriser, egl_gaussian.h, makes the same).
Status CheckGaussianRender(const formats::GaussianCloud& cloud, const Camera& camera,
                           const GaussianRenderOptions& options);

// Renders `cloud` seen by `camera` into `out` (its buffers are reused when large enough).
// InvalidArgument for a camera with lens distortion (3DGS renders pinhole cameras), a bad
// camera (size 0 or over kMaxImageSize a side, intrinsics, pose: Camera::Validate), a cloud
// whose arrays disagree with its size or sh_degree, or threads < 0; LimitExceeded when the
// splats' tile lists would pass 4 GiB or memory cannot be mapped. An empty cloud gives the
// background (alpha 0). Splats with non-finite values are culled.
Status RenderGaussians(const formats::GaussianCloud& cloud, const Camera& camera,
                       const GaussianRenderOptions& options, GaussianImage* out,
                       GaussianRenderStats* stats = nullptr);

// The same, keeping its working memory (88 bytes a splat and 4 a tile entry) between renders:
// a viewer's or a benchmark's next frame of a similar cloud maps and faults in no new pages.
// Buffers above 512 MiB are given back after each render. One Render at a time per object.
// RenderGaussians is a GaussianRasterizer made for one call.
class GaussianRasterizer {
 public:
  GaussianRasterizer();
  ~GaussianRasterizer();
  GaussianRasterizer(const GaussianRasterizer&) = delete;
  GaussianRasterizer& operator=(const GaussianRasterizer&) = delete;
  Status Render(const formats::GaussianCloud& cloud, const Camera& camera,
                const GaussianRenderOptions& options, GaussianImage* out,
                GaussianRenderStats* stats = nullptr);

 private:
  struct Buffers;
  std::unique_ptr<Buffers> buffers_;
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_GAUSSIAN_RASTER_H_
