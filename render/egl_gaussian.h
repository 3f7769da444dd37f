// The 3DGS forward rasteriser of gaussian_raster.h on the GPU, through headless EGL (OpenGL 4.3
// core: the GPU's driver, or Mesa's llvmpipe where there is none).
//
// The same rules, splat by splat: culling at z <= 0.2, the EWA covariance with the clamped
// Jacobian and 0.3 px dilation, the opacity through the sigmoid (Mip-Splatting's factor for an
// antialiased cloud), the SH colour for the view direction + 0.5 clamped at 0, alpha =
// min(0.99, o e^power) skipped below 1/255 and where power > 0, and the pixels a splat may touch
// those of the reference's tiles within its alpha >= 1/255 ellipse. Per pixel the splats are
// composited front to back in depth order (the CPU sorts the depths; "under" blending into a
// float target), without the reference's stop before the splat that would bring T below 1e-4:
// blending cannot read the pixel, so that splat and those behind it are added, at most
// ~1% of the colour (T <= 1e-4 / (1 - 0.99)) where a pixel is that opaque. The cloud's arrays
// go to storage buffers as they are (no repacking); the vertex shader does each splat's set-up,
// one instanced quad a splat.
#ifndef HVDB_RENDER_EGL_GAUSSIAN_H_
#define HVDB_RENDER_EGL_GAUSSIAN_H_

#include <memory>
#include <string>

#include "render/gaussian_raster.h"

namespace hvdb::render {

class EglGaussianRasterizer {
 public:
  // Unsupported, with the reason, where no OpenGL 4.3 core context can be made (or
  // HVDB_RENDER_NO_EGL is set).
  static Result<std::unique_ptr<EglGaussianRasterizer>> Create();
  // One of the process's idle rasterisers (a context and program made once, not per render
  // job), else Create(); Recycle gives it back (at most 4 are kept idle).
  static Result<std::unique_ptr<EglGaussianRasterizer>> Take();
  static void Recycle(std::unique_ptr<EglGaussianRasterizer> r);
  ~EglGaussianRasterizer();
  EglGaussianRasterizer(const EglGaussianRasterizer&) = delete;
  EglGaussianRasterizer& operator=(const EglGaussianRasterizer&) = delete;

  // "egl: <GL_RENDERER>, OpenGL <version> (<display>)"; whether that is a hardware GPU.
  const std::string& name() const;
  bool hardware() const;

  // As RenderGaussians (the same checks and output). One call at a time per object.
  // LimitExceeded where the GPU cannot hold the cloud (a storage-buffer bound, out of memory):
  // the CPU rasteriser can then draw it.
  Status Render(const formats::GaussianCloud& cloud, const Camera& camera,
                const GaussianRenderOptions& options, GaussianImage* out,
                GaussianRenderStats* stats = nullptr);

 private:
  EglGaussianRasterizer();
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_EGL_GAUSSIAN_H_
