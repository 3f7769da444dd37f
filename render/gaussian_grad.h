// The differentiable 3DGS rasteriser: the forward pass of the Gaussian render mode
// (gaussian_raster.h, the same equations and the same image within float rounding) that keeps
// what its backward pass needs, and that backward pass: the gradient of a loss with respect to
// every stored parameter of every splat (position, log scale, quaternion, logit opacity, SH
// coefficients), given the loss's gradient with respect to the image. Ingest fits Gaussians to
// calibrated photos with it (ingest/gaussian_fit.h).
//
// It follows the reference's backward pass (graphdeco-inria/diff-gaussian-rasterization,
// cuda_rasterizer/backward.cu) with two differences, both making the gradient that of the
// forward function exactly (tests/render/gaussian_grad_test.cc checks every parameter against
// central finite differences):
//   - where alpha is clamped at 0.99 its gradient is 0 (the reference passes it through);
//   - the EWA Jacobian's clamp of x/z and y/z contributes its own derivative with respect to
//     depth (the reference drops it).
// Antialiased (Mip-Splatting) clouds are refused: fitting produces plain 3DGS clouds.
//
// Work: splats are preprocessed in parallel; each 16x16 tile is blended (forward) and unblended
// back to front (backward) by one task, writing its splats' screen-space gradients to the tile
// list's own slots; those are summed per splat in list order, so results do not depend on the
// thread count or scheduling.
#ifndef HVDB_RENDER_GAUSSIAN_GRAD_H_
#define HVDB_RENDER_GAUSSIAN_GRAD_H_

#include <array>
#include <cstdint>
#include <vector>

#include "formats/gaussians.h"
#include "render/renderer.h"
#include "storage/status.h"

namespace hvdb::render {

// The gradient of a loss with respect to a cloud's stored values: the same arrays, same sizes.
using GaussianGradient = formats::GaussianCloud;

class GaussianGradRasterizer {
 public:
  // Renders `cloud` from `camera` into `rgb` (3 floats a pixel, row-major: C + T background, as
  // GaussianImage::rgb) and remembers what Backward needs. The same checks as RenderGaussians
  // (CheckGaussianRender), InvalidArgument for an antialiased cloud, and LimitExceeded when
  // the splats would cover over 10^8 (splat, tile) pairs (4 GiB of lists and gradient slots).
  // `cloud` must stay unchanged until Backward.
  Status Forward(const formats::GaussianCloud& cloud, const Camera& camera,
                 const std::array<float, 3>& background, int threads, std::vector<float>* rgb);

  // Given dL/drgb (3 floats a pixel, as Forward's rgb), sets *grad to dL/d(every value of the
  // cloud) (resized to the cloud's shape) and, when `screen_grad` is not null, resizes it to
  // the cloud's size and sets each splat's |dL/d(centre)| in normalised device coordinates
  // (pixel gradient times half the image size, as the reference's densification statistic;
  // -1 for splats the view culls). REQUIRES: a successful Forward, dL_drgb of its image's size.
  void Backward(const std::vector<float>& dL_drgb, GaussianGradient* grad,
                std::vector<float>* screen_grad = nullptr);

  // Splats the last Forward drew (passed culling) and its (splat, tile) pairs.
  uint64_t visible() const { return visible_; }
  uint64_t tile_entries() const { return list_.size(); }

 private:
  struct Splat {      // a visible splat's screen-space values, as forward.cu's preprocess keeps
    float u, v;       // pixel centre
    float A, B, C;    // conic
    float opacity;    // after the sigmoid
    float rgb[3];     // after + 0.5 and the clamp at 0
    uint8_t clamped;  // bit c: channel c was clamped
    int16_t x0, x1, y0, y1;  // the pixel box where alpha can reach 1/255 (inclusive)
  };
  const formats::GaussianCloud* cloud_ = nullptr;
  Camera camera_;
  std::array<float, 3> background_{};
  int threads_ = 1;
  uint64_t visible_ = 0;
  std::vector<Splat> splats_;         // per cloud splat; valid where visible
  std::vector<uint8_t> is_visible_;   // per cloud splat
  std::vector<uint32_t> list_;        // splat indices, tile after tile, front to back
  std::vector<uint32_t> tile_start_;  // tiles + 1 offsets into list_
  std::vector<float> final_T_;        // per pixel
  std::vector<uint32_t> last_;        // per pixel: entries of its tile's list it used
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_GAUSSIAN_GRAD_H_
