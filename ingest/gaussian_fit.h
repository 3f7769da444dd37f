// Gaussians fitted to a frame's calibrated photos: 3D Gaussian splatting's optimisation
// (Kerbl et al. 2023, section 5 and 7.1; graphdeco-inria/gaussian-splatting's train.py),
// through the differentiable rasteriser render/gaussian_grad.h, on the CPU.
//
// Each iteration draws one training view (a seeded shuffle of all of them, epoch after epoch),
// renders it, takes the loss (1 - lambda) L1 + lambda (1 - SSIM) against the photo
// (gaussian_loss.h) and steps Adam on every parameter with 3DGS's per-parameter learning rates
// (the position's decaying exponentially). The SH degree grows by one every
// sh_degree_interval iterations up to sh_degree. Densification as 3DGS: every densify_interval
// iterations between densify_from and densify_until, splats whose mean screen-space gradient
// passes densify_gradient are cloned (small ones) or split in two (large ones, their scale
// divided by 1.6), and splats whose opacity fell below prune_opacity are removed.
//
// Results are deterministic for a seed whatever the thread count.
#ifndef HVDB_INGEST_GAUSSIAN_FIT_H_
#define HVDB_INGEST_GAUSSIAN_FIT_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "formats/gaussians.h"
#include "render/renderer.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::ingest {

// A training view: a pinhole camera and its photo, 3 floats a pixel in [0, 1] (row-major RGB,
// the photo's own display values: 3DGS fits in them).
struct FitView {
  render::Camera camera;
  std::vector<float> rgb;
  // Empty: the whole cloud is fitted. Set in every view (one byte a pixel; a warm start passes
  // ChangedPixels): only the splats whose centre some view sees on a set pixel are fitted (and
  // densified, and pruned), the others keep their values bit for bit; views with no pixel set
  // are not drawn.
  std::vector<uint8_t> mask;
  // Empty: every pixel is fitted. Else one byte a pixel: only pixels with a non-zero byte count
  // in the loss (the frame's geometry covers them: gaussian_frames.h). Outside them the target
  // is the render itself and the gradient is cut; SSIM windows across the border still see
  // both, so the border's few pixels are fitted approximately.
  std::vector<uint8_t> valid;
};

// The pixels of `now` that differ from `before` (the same camera's photo of the previous frame):
// any channel by more than `threshold`, grown by `grow` pixels (a square), so that the loss's
// 11x11 SSIM window around a moving edge is inside. Both 3 floats a pixel.
std::vector<uint8_t> ChangedPixels(const std::vector<float>& before, const std::vector<float>& now,
                                   int width, int height, float threshold = 0.06f, int grow = 6);

struct FitOptions {
  // The defaults fit an 8-camera 1080p frame at 1/4 size in a few minutes on 2 cores
  // (bench/README.md); Scheduled() scales the schedule below to other iteration counts.
  int iterations = 600;
  int sh_degree = 3;
  int sh_degree_interval = 150;  // 3DGS: 1000 of 30000
  float lambda_dssim = 0.2f;
  // Learning rates (train.py's defaults). The position's is relative to the scene's extent
  // (the radius of the cameras' centres around their mean, times 1.1, as 3DGS's
  // spatial_lr_scale), decaying from lr_position to lr_position_final over the iterations.
  float lr_position = 1.6e-4f, lr_position_final = 1.6e-6f;
  float lr_sh_dc = 2.5e-3f, lr_sh_rest = 2.5e-3f / 20.0f;
  float lr_opacity = 0.025f, lr_scale = 5e-3f, lr_rotation = 1e-3f;
  // Densification and pruning.
  bool densify = true;
  int densify_from = 40, densify_until = 400, densify_interval = 40;
  float densify_gradient = 2e-4f;
  float percent_dense = 0.01f;  // clone below, split above this fraction of the extent
  float prune_opacity = 0.005f;
  size_t max_splats = 300'000;  // densification stops growing the cloud past this
  std::array<float, 3> background{0, 0, 0};
  uint64_t seed = 1;
  int threads = 0;  // 0: every core
  // Called every iteration with (done, total): a progress bar.
  std::function<void(int, int)> progress;
  // Asked before every iteration; true: the fit stops with Cancelled (the cloud as it was then).
  std::function<bool()> cancelled;
};

// `o` with `iterations` steps and its schedule scaled to them as the defaults are to 600:
// densification from 1/15 to 2/3 of the steps every 1/15, the SH degree raised every 1/4.
FitOptions Scheduled(FitOptions o, int iterations);

struct FitReport {
  int iterations = 0;
  double loss = 0;  // the mean loss of the last (possibly partial) epoch's views
  // Over every training view's valid pixels at the end (dB); NaN when no view has one.
  double psnr = 0;
  double seconds = 0;
  size_t splats_in = 0, splats_out = 0;
};

// The initial cloud of `points` (3DGS initialises from SfM points; these are the frame's
// probabilistic points, whose covariances are Gaussians already): each point's covariance
// eigen-decomposed into log scales and a rotation, its colour as the SH DC term, opacity 0.1,
// SH of degree `sh_degree` with zero higher coefficients. More points than `max_splats`: every
// k-th is taken (k = ceil(points / max_splats)). A covariance whose widest standard deviation
// is shorter than the root mean square distance to the point's 3 nearest (kept) neighbours is
// scaled up to it, shape and orientation kept (3DGS sizes its splats by that distance), so
// that sparse samples still cover their surface; a point without a covariance (all 0) becomes
// a round splat of that size, and no axis is left under 1/100 of the widest.
formats::GaussianCloud CloudFromPoints(std::span<const Point> points, int sh_degree,
                                       size_t max_splats = SIZE_MAX);

// Fits `cloud` (in: the start, from CloudFromPoints or a previous frame's fit; out: the result)
// to `views`. When every view's mask is set and empty (a warm start where nothing moved) the
// cloud is returned unchanged, with 0 iterations reported. InvalidArgument for no views, a view
// whose image does not match its camera, a camera the rasteriser refuses, an empty or invalid
// cloud, or options out of range; the rasteriser's LimitExceeded for splats that cover too
// much of a view (gaussian_grad.h).
Status FitGaussians(const std::vector<FitView>& views, const FitOptions& options,
                    formats::GaussianCloud* cloud, FitReport* report = nullptr);

// The index (y * width + x) of the pixel whose centre is nearest to where `camera` (pinhole:
// its distortion is not applied) sees world point (x, y, z); -1 behind it or outside the image.
long PixelOf(const render::Camera& camera, double x, double y, double z);

// PSNR (dB) of `render` against `target`, both 3 floats a pixel, values clamped to [0, 1]; over
// the pixels `valid` sets (one byte a pixel) when it is not empty (NaN when it sets none).
double Psnr(std::span<const float> render, std::span<const float> target,
            std::span<const uint8_t> valid = {});

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_GAUSSIAN_FIT_H_
