// EWA splatting of hvdb points: images of the scene from any virtual camera (thesis 5.1.2, 5.4).
//
// Every point is a 3D Gaussian (its covariance, for slices the projected one of eq. 8.3). Its
// screen footprint is the Gaussian under the local affine approximation of the projection
// (EWA, Zwicker et al. 2001), convolved with a screen-space antialiasing filter and cut off at
// `cutoff_radius` standard deviations. Two modes:
//   kVisibility     fig. 5.2: fuzzy depth test (threshold dz), additive blending, normalisation;
//                   order independent (the two-pass depth-then-blend method of 5.1.2). Unlike
//                   fig. 5.2, which sets alpha to one, coverage is the sum of the kernels at a
//                   pixel clamped to one, so silhouettes stay antialiased.
//   kProbabilistic  5.4.1: splats front to back, accumulation stops when alpha saturates
// and, with either, view-dependent blending weights (eqs. 5.15-5.17).
//
// Two implementations of the same algorithm: EglRenderer (OpenGL 4.3+ through headless EGL:
// the vendor's driver on a GPU, Mesa llvmpipe elsewhere) and CpuRenderer (multi-threaded, the
// reference used by tests and ingest, and the fallback when no EGL context can be made).
//
// Colour: point colours are sRGB; blending happens in linear light; Image holds linear values
// and formats::WritePng encodes sRGB. Thread safety: one Render at a time per Renderer (calls
// from different threads are serialised); use one Renderer per concurrent render.
#ifndef HVDB_RENDER_RENDERER_H_
#define HVDB_RENDER_RENDERER_H_

#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "formats/image_io.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::render {

// The rendered image, its size limit and the sRGB transfer function are formats/image_io.h's,
// which also reads and writes images (PNG, EXR).
using formats::Image;
using formats::kMaxImageSize;
using formats::LinearToSrgb;
using formats::SrgbToLinear;

// A camera with OpenCV conventions: x right, y down, looking along +z; the centre of pixel
// (u, v) is at image coordinates (u, v). Same fields as storage's CameraInfo.
struct Camera {
  uint32_t width = 640, height = 480;
  double fx = 500, fy = 500, cx = 319.5, cy = 239.5;
  std::array<double, 5> distortion{};  // k1 k2 p1 p2 k3 (OpenCV order); all zero: pinhole
  // Row-major 4x4 world-from-camera transform (metres): its columns are the camera's axes
  // and centre in the world.
  std::array<double, 16> world_from_camera{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

  // A pinhole camera at `eye` looking at `target`; `up` is the world direction that appears
  // upwards in the image; fov_y_deg is the vertical field of view.
  static Camera LookAt(const std::array<double, 3>& eye, const std::array<double, 3>& target,
                       const std::array<double, 3>& up, double fov_y_deg, uint32_t width,
                       uint32_t height);
  // The same view at another image size (the intrinsics scale with the image).
  Camera Resized(uint32_t new_width, uint32_t new_height) const;
  // Checks sizes (1..kMaxImageSize), focal lengths and that the pose is a rigid transform.
  Status Validate() const;
};

// kGaussian is the render job's (render/job.h): 3D Gaussian splatting as its reference
// rasteriser draws (render/gaussian_raster.h); the point renderers draw the other two.
enum class Mode : uint8_t { kVisibility, kProbabilistic, kGaussian };

// A source (acquisition) camera of the recording, for view-dependent blending: points carry
// the id of the camera they came from (Point::camera).
struct SourceCamera {
  uint16_t id = 0;
  std::array<double, 16> world_from_camera{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
};

struct RenderOptions {
  Mode mode = Mode::kVisibility;
  // Weights each splat by the angle between the virtual camera and its source camera
  // (eqs. 5.15-5.17); needs `source_cameras`. Points whose camera is not listed get weight 1.
  bool view_dependent = false;
  std::vector<SourceCamera> source_cameras;
  // Weights are clamped to [min_view_weight, 1] relative to the best-aligned camera.
  float min_view_weight = 0.01f;
  float depth_threshold = 0.02f;  // dz of the fuzzy depth test (m), visibility mode
  float cutoff_radius = 2.5f;     // r_C, in standard deviations of the screen Gaussian
  float filter_variance = 1.0f;   // screen-space antialiasing filter (pixels^2)
  // Splats grow by this factor (their covariance by its square): 2^(i/2) at level of detail
  // i (thesis 8.4), what storage's Batch::splat_scale holds.
  float splat_scale = 1.0f;
  // Standard deviation (m) of points whose flags lack kFlagHasCovariance.
  float default_sigma = 0.005f;
  float near_plane = 0.01f;  // points closer to the camera plane than this (m) are culled
  // Linear RGBA painted where no splat covers a pixel (and blended at partial coverage).
  std::array<float, 4> background{0, 0, 0, 1};
  // 0: the camera's size; else the camera is Resized() to this size first.
  uint32_t width = 0, height = 0;
  // Only Image::depth: the nearest fragment's depth at each pixel (the depth either mode
  // reports), rgba and coverage left empty. What projective texturing needs of its source
  // cameras; it skips the blending pass and the colour resolve and readback.
  bool depth_only = false;
};

enum class RendererKind : uint8_t { kAuto, kEgl, kCpu };
const char* RendererKindName(RendererKind kind);  // "auto", "egl", "cpu"
// Parses "auto", "egl" or "cpu".
Result<RendererKind> ParseRendererKind(const std::string& name);

struct RenderStats {
  uint64_t points = 0;  // given to Render
  double milliseconds = 0;
};

class Renderer {
 public:
  virtual ~Renderer() = default;
  // kEgl or kCpu: which implementation this is.
  virtual RendererKind kind() const = 0;
  // For logs and replies, e.g. "cpu (2 threads)", "egl: llvmpipe (LLVM 15.0.6, 256 bits)".
  virtual std::string name() const = 0;
  // Renders `points` seen by `camera`. Errors: InvalidArgument for bad options or cameras,
  // Internal for driver failures.
  virtual Result<Image> Render(std::span<const Point> points, const Camera& camera,
                               const RenderOptions& options) = 0;
  // The same into `image`, reusing its buffers where they have the size already: a viewer or
  // a sequence that keeps its Image saves allocating, zeroing and faulting in 24 bytes a pixel
  // each frame (~4 ms at 1080p). On error `image` is left unspecified.
  virtual Status RenderInto(std::span<const Point> points, const Camera& camera,
                            const RenderOptions& options, Image* image);
  // What the last successful Render did.
  virtual RenderStats last_stats() const = 0;
  // True when it draws on a GPU (not on a software OpenGL driver such as Mesa's llvmpipe).
  virtual bool hardware() const { return false; }
};

// The checks Render does on its arguments, without rendering: InvalidArgument naming the bad
// field (camera size, intrinsics, pose; option ranges).
Status CheckRenderArguments(const Camera& camera, const RenderOptions& options);

// threads = 0: std::thread::hardware_concurrency().
std::unique_ptr<Renderer> MakeCpuRenderer(unsigned threads = 0);
// Headless OpenGL through EGL: the EGL device platform first (a GPU where the vendor's EGL
// is installed), then Mesa's surfaceless platform. Fails when no OpenGL 4.3 core context can
// be made; the message says why. The environment variable HVDB_RENDER_NO_EGL=1 disables it
// (Unsupported), which makes kAuto use the CPU renderer.
Result<std::unique_ptr<Renderer>> MakeEglRenderer();
// kCpu: the CPU renderer. kEgl: the EGL renderer or its error. kAuto: the faster of the two
// here: the EGL renderer on a GPU (hardware()); the CPU renderer where EGL runs on a software
// rasteriser (llvmpipe: the CPU renderer is many times faster on the same cores) or where no
// context can be made (after a warning through the log handler). `why`, when given, gets one
// line saying which and why (logged for kAuto; replies and `hvdb render --json` show it); ask
// the result's kind() which one you got.
Result<std::unique_ptr<Renderer>> MakeRenderer(RendererKind kind, std::string* why = nullptr);
// kAuto's choice given a working EGL renderer: it, or a CPU renderer; `why` as above.
std::unique_ptr<Renderer> ChooseAuto(std::unique_ptr<Renderer> egl, std::string* why);
// True for the GL_RENDERER strings of software OpenGL drivers (llvmpipe, softpipe, swrast).
bool IsSoftwareRasteriser(const std::string& gl_renderer);

// Where the render library reports warnings (such as the CPU fallback) and notes (such as
// kAuto's choice, prefixed "note: "). Default: stderr.
void SetLogHandler(std::function<void(const std::string&)> handler);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_RENDERER_H_
