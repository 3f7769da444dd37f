// render-bench-gpu: the render service's renderers in all three modes (visibility,
// probabilistic: render/renderer.h; Gaussian: render/gaussian_raster.h, egl_gaussian.h) on
// seeded synthetic scenes at 1920x1080, built to be carried to a GPU machine that has none of
// the Debian stack: it links render/ and its image formats only (no FFmpeg, no OpenCV
// imgcodecs, no storage engine I/O, no client), so its shared libraries beyond glibc,
// libstdc++ and libGL/libEGL stay under 40 MiB (the test command checks; bench/README.md,
// "Carrying render-bench-gpu").
//
// Per renderer (cpu, egl), mode and size: one warm-up render, then --reps timed renders into
// the same image, as a render job does (upload + draw + readback for EGL); medians of wall
// time, splats/s, and the fixed cost a render (the median time of an empty scene). Each EGL
// image is compared with the CPU renderer's (PSNR on 8-bit sRGB). It prints the OpenGL
// renderer and driver it got; --require-gpu fails when that is a software rasteriser. JSON to
// --out: where the renderer is not a GPU, its "gpu" field says "not measured".
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/gaussian_scene.h"
#include "render/egl_gaussian.h"
#include "render/gaussian_raster.h"
#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/render/test_scenes.h"

namespace render = hvdb::render;
using nlohmann::json;

namespace {

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

std::vector<std::string> Split(const std::string& s) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string item; std::getline(in, item, ',');) out.push_back(item);
  return out;
}

// One renderer of every mode: the point renderer (visibility, probabilistic) and the 3DGS
// rasteriser of the same kind.
struct Renderers {
  std::string name;
  std::unique_ptr<render::Renderer> points;
  std::unique_ptr<render::EglGaussianRasterizer> egl_gaussians;  // null for the CPU
  render::GaussianRasterizer cpu_gaussians;
};

// One render of a mode (into images the case keeps, as a render job reuses its buffers).
using Draw = std::function<hvdb::Status()>;

struct Timing {
  double median_ms = 0;
  std::vector<double> runs_ms;
  render::Srgb8Image image;
};

hvdb::Result<Timing> Time(const Draw& draw, int reps) {
  Timing t;
  HVDB_RETURN_IF_ERROR(draw());  // warm-up: buffers grown, programs compiled
  for (int r = 0; r < reps; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    HVDB_RETURN_IF_ERROR(draw());
    t.runs_ms.push_back(
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  t.median_ms = Median(t.runs_ms);
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("render-bench-gpu: the renderers (CPU and EGL) in every mode at 1080p, "
               "carried to GPU machines");
  std::string out = "render-gpu.json", millions = "0.1,1,2";
  std::string modes_arg = "visibility,probabilistic,gaussian";
  std::string renderers_arg = "cpu,egl";
  int reps = 5;
  uint32_t width = 1920, height = 1080;
  bool quick = false, require_gpu = false;
  app.add_option("--out", out, "JSON file")->capture_default_str();
  app.add_option("--millions", millions, "Scene sizes, millions of splats, comma-separated")
      ->capture_default_str();
  app.add_option("--modes", modes_arg, "visibility, probabilistic, gaussian")
      ->capture_default_str();
  app.add_option("--renderers", renderers_arg, "cpu, egl")->capture_default_str();
  app.add_option("--reps", reps, "Timed renders per case (median)")->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--width", width)->capture_default_str()->check(CLI::Range(1u, 4096u));
  app.add_option("--height", height)->capture_default_str()->check(CLI::Range(1u, 4096u));
  app.add_flag("--require-gpu", require_gpu, "Fail when EGL gives a software rasteriser");
  app.add_flag("--quick", quick, "Smoke run: 0.05 M splats, 2 renders");
  CLI11_PARSE(app, argc, argv);
  if (quick) millions = "0.05", reps = 2;
  std::vector<double> sizes;
  for (const std::string& m : Split(millions)) sizes.push_back(std::stod(m));
  const std::vector<std::string> modes = Split(modes_arg);
  for (const std::string& m : modes) {
    if (m != "visibility" && m != "probabilistic" && m != "gaussian") {
      std::fprintf(stderr, "render-bench-gpu: unknown mode '%s' (visibility, probabilistic, "
                           "gaussian)\n", m.c_str());
      return 2;
    }
  }

  std::vector<std::unique_ptr<Renderers>> rs;  // GaussianRasterizer does not move
  std::string gl_renderer = "none";
  bool hardware = false;
  for (const std::string& name : Split(renderers_arg)) {
    auto made = std::make_unique<Renderers>();
    Renderers& r = *made;
    r.name = name;
    if (name == "cpu") {
      r.points = render::MakeCpuRenderer();
    } else if (name == "egl") {
      auto p = render::MakeEglRenderer();
      auto g = render::EglGaussianRasterizer::Create();
      if (!p.ok() || !g.ok()) {
        std::fprintf(stderr, "render-bench-gpu: no EGL renderer: %s\n",
                     (!p.ok() ? p.status() : g.status()).ToString().c_str());
        return 1;
      }
      r.points = std::move(p).value();
      r.egl_gaussians = std::move(g).value();
      gl_renderer = r.points->name();
      hardware = r.points->hardware();
      std::printf("renderer: %s (%s)\n", gl_renderer.c_str(),
                  hardware ? "a GPU" : "a software rasteriser");
      if (require_gpu && !hardware) {
        std::fprintf(stderr, "render-bench-gpu: --require-gpu, and EGL gave a software "
                             "rasteriser: %s\n", gl_renderer.c_str());
        return 1;
      }
    } else {
      std::fprintf(stderr, "render-bench-gpu: unknown renderer '%s' (cpu, egl)\n", name.c_str());
      return 2;
    }
    rs.push_back(std::move(made));
  }
  if (require_gpu && !hardware) {
    std::fprintf(stderr, "render-bench-gpu: --require-gpu needs --renderers with egl\n");
    return 1;
  }

  const render::Camera sphere_camera = hvdb::testing::ViewFrom(0.3, 0.4, 1, 3.5, width, height);
  const render::Camera scene_camera = hvdb::bench::GaussianSceneCamera(width, height);
  json cases = json::array();
  // A case: every renderer draws `mode` of an n-splat scene; the EGL image against the CPU's.
  auto run_case = [&](const std::string& mode, size_t n, bool fixed_cost) -> bool {
    const bool gaussian = mode == "gaussian";
    const std::vector<hvdb::Point> points = gaussian ? std::vector<hvdb::Point>()
                                                     : hvdb::testing::SphereScene(n);
    const hvdb::formats::GaussianCloud cloud =
        gaussian ? hvdb::bench::GaussianScene(n, 42) : hvdb::formats::GaussianCloud();
    render::Srgb8Image cpu_image;
    for (auto& rp : rs) {
      Renderers& r = *rp;
      render::Image image;
      render::GaussianImage gimage;
      render::RenderOptions o;
      o.mode = mode == "probabilistic" ? render::Mode::kProbabilistic : render::Mode::kVisibility;
      Draw draw = [&]() -> hvdb::Status {
        if (gaussian) {
          return r.egl_gaussians ? r.egl_gaussians->Render(cloud, scene_camera, {}, &gimage)
                                 : r.cpu_gaussians.Render(cloud, scene_camera, {}, &gimage);
        }
        return r.points->RenderInto(points, sphere_camera, o, &image);
      };
      auto t = Time(draw, reps);
      // The last render as 8-bit sRGB, for the comparison (not timed).
      if (t.ok()) {
        t->image = gaussian ? hvdb::bench::ToSrgb8(gimage)
                            : hvdb::formats::ToSrgb8(image);
      }
      if (!t.ok()) {
        std::fprintf(stderr, "render-bench-gpu: %s %s: %s\n", r.name.c_str(), mode.c_str(),
                     t.status().ToString().c_str());
        return false;
      }
      const double rate = static_cast<double>(n) / (t->median_ms / 1e3);
      json c = {{"renderer", r.name}, {"mode", mode},         {"splats", n},
                {"median_ms", t->median_ms}, {"runs_ms", t->runs_ms}};
      if (fixed_cost) {
        c["fixed_cost"] = true;
        std::printf("%-4s %-13s fixed cost (no splats): %.2f ms median of %d\n", r.name.c_str(),
                    mode.c_str(), t->median_ms, reps);
      } else {
        c["splats_per_s"] = rate;
        std::printf("%-4s %-13s %9zu splats: %8.2f ms, %7.2f M splats/s", r.name.c_str(),
                    mode.c_str(), n, t->median_ms, rate / 1e6);
      }
      if (r.name == "cpu") {
        cpu_image = t->image;
      } else if (!cpu_image.data.empty() && !fixed_cost) {
        const double psnr = std::min(render::Psnr(cpu_image, t->image), 200.0);
        c["psnr_vs_cpu_db"] = psnr;
        std::printf(", %.1f dB against the CPU's image", psnr);
      }
      if (!fixed_cost) std::printf("\n");
      std::fflush(stdout);
      cases.push_back(c);
    }
    return true;
  };
  for (const std::string& mode : modes) {
    if (!run_case(mode, 0, true)) return 1;
    for (double m : sizes) {
      if (!run_case(mode, static_cast<size_t>(m * 1e6), false)) return 1;
    }
  }
  json doc = {
      {"benchmark", "render-bench-gpu"},
      {"size", std::to_string(width) + "x" + std::to_string(height)},
      {"scenes",
       "visibility, probabilistic: Fibonacci sphere of surfels (tests/render/test_scenes.h); "
       "gaussian: the 3DGS-like floor, wall and spheres (bench/gaussian_scene.h), seed 42"},
      {"egl_renderer", gl_renderer},
      {"gpu", hardware ? "measured: " + gl_renderer
                       : "not measured: no GPU here (EGL gave " + gl_renderer + ")"},
      {"hardware_threads", std::thread::hardware_concurrency()},
      {"reps", reps},
      {"cases", cases}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
