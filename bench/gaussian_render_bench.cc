// gaussian-render-bench: the CPU 3DGS rasteriser (render/gaussian_raster.h) at 1920x1080.
//
// The scene is synthetic and seeded, shaped like a trained 3DGS scene (gaussian_scene.h).
// Rendered --reps times per size after one warm-up render (which grows
// the rasteriser's buffers); medians of wall time, of the process's CPU time, and of the
// rasteriser's three stages. JSON to --out (bench/results/gaussian_render.json). With --egl the
// GPU's rasteriser through EGL (render/egl_gaussian.h) instead, its image compared with the
// CPU's (PSNR); --require-gpu fails when EGL gives a software rasteriser.
#include <time.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bench/gaussian_scene.h"
#include "formats/gaussians.h"
#include "formats/image_io.h"
#include "render/egl_gaussian.h"
#include "render/gaussian_raster.h"

namespace render = hvdb::render;
using hvdb::formats::GaussianCloud;
using nlohmann::json;

namespace {

double CpuSeconds() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + static_cast<double>(ts.tv_nsec) * 1e-9;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("gaussian-render-bench: the CPU 3DGS rasteriser on synthetic scenes at 1080p");
  std::string out = "bench/results/gaussian_render.json";
  std::string millions = "1,0.3";
  std::string png;
  int reps = 7;
  int threads = 0;
  uint32_t width = 1920, height = 1080;
  bool quick = false, egl = false, require_gpu = false;
  app.add_option("--out", out, "JSON file")->capture_default_str();
  app.add_flag("--egl", egl, "The GPU's rasteriser through EGL (its image checked against the CPU's)");
  app.add_flag("--require-gpu", require_gpu, "With --egl: fail on a software rasteriser");
  app.add_option("--millions", millions, "Scene sizes, millions of splats, comma-separated")
      ->capture_default_str();
  app.add_option("--reps", reps, "Timed renders per scene (median)")->capture_default_str();
  app.add_option("--threads", threads, "Rasteriser threads (0: every core)")->capture_default_str();
  app.add_option("--width", width, "Image width")->capture_default_str();
  app.add_option("--height", height, "Image height")->capture_default_str();
  app.add_option("--png", png, "Write the first scene's image here (8-bit RGB)");
  app.add_flag("--quick", quick, "Smoke run: 0.1 M splats, 2 renders");
  CLI11_PARSE(app, argc, argv);
  if (quick) millions = "0.1", reps = 2;

  std::vector<double> sizes;
  std::stringstream list(millions);
  for (std::string item; std::getline(list, item, ',');) sizes.push_back(std::stod(item));
  const unsigned used_threads = threads > 0 ? static_cast<unsigned>(threads)
                                            : std::max(1u, std::thread::hardware_concurrency());
  const render::Camera camera = hvdb::bench::GaussianSceneCamera(width, height);
  render::GaussianRasterizer rasterizer;
  render::GaussianRenderOptions options;
  options.threads = threads;
  std::unique_ptr<render::EglGaussianRasterizer> gpu;
  std::string renderer = "cpu: 3DGS rasteriser";
  if (egl) {
    auto made = render::EglGaussianRasterizer::Create();
    if (!made.ok()) {
      std::fprintf(stderr, "gaussian-render-bench: %s\n", made.status().ToString().c_str());
      return 1;
    }
    gpu = std::move(made).value();
    renderer = gpu->name();
    std::printf("renderer: %s (%s)\n", renderer.c_str(), gpu->hardware() ? "hardware" : "software");
    if (require_gpu && !gpu->hardware()) {
      std::fprintf(stderr, "gaussian-render-bench: --require-gpu, and EGL gave a software "
                           "rasteriser: %s\n", renderer.c_str());
      return 1;
    }
  }
  auto draw = [&](const GaussianCloud& c, render::GaussianImage* img,
                  render::GaussianRenderStats* st) {
    return gpu ? gpu->Render(c, camera, options, img, st)
               : rasterizer.Render(c, camera, options, img, st);
  };
  json scenes = json::array();
  for (size_t s = 0; s < sizes.size(); ++s) {
    const size_t n = static_cast<size_t>(sizes[s] * 1e6);
    const GaussianCloud cloud = hvdb::bench::GaussianScene(n, 42);
    render::GaussianImage image;
    render::GaussianRenderStats stats;
    hvdb::Status st = draw(cloud, &image, &stats);  // warm-up
    if (!st.ok()) {
      std::fprintf(stderr, "gaussian-render-bench: %s\n", st.ToString().c_str());
      return 1;
    }
    std::vector<double> wall, cpu, pre, bin, blend;
    for (int r = 0; r < reps; ++r) {
      const double c0 = CpuSeconds();
      const auto t0 = std::chrono::steady_clock::now();
      st = draw(cloud, &image, &stats);
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (!st.ok()) {
        std::fprintf(stderr, "gaussian-render-bench: %s\n", st.ToString().c_str());
        return 1;
      }
      wall.push_back(ms);
      cpu.push_back((CpuSeconds() - c0) * 1e3);
      pre.push_back(stats.preprocess_ms);
      bin.push_back(stats.bin_ms);
      blend.push_back(stats.blend_ms);
    }
    // The GPU's picture against the CPU's (8-bit RGB, PSNR).
    double psnr_vs_cpu = -1;
    if (gpu) {
      render::GaussianImage ref;
      if (rasterizer.Render(cloud, camera, options, &ref).ok()) {
        const std::vector<uint8_t> a = image.ToRgba8(), b = ref.ToRgba8();
        double se = 0;
        for (size_t i = 0; i < a.size(); ++i) {
          if (i % 4 == 3) continue;
          se += (a[i] - b[i]) * (a[i] - b[i]);
        }
        const double mse = se / (0.75 * static_cast<double>(a.size()));
        psnr_vs_cpu = mse == 0 ? 200 : 10 * std::log10(255.0 * 255.0 / mse);
      }
    }
    double mean_alpha = 0;
    for (float a : image.alpha) mean_alpha += a;
    mean_alpha /= static_cast<double>(image.alpha.size());
    const double ms = Median(wall), cpu_ms = Median(cpu);
    const double rate = static_cast<double>(n) / (ms / 1e3);
    // As if the process had every core to itself: splats per CPU-second times the threads.
    const double cpu_rate = static_cast<double>(n) * used_threads / (cpu_ms / 1e3);
    std::printf(
        "%zu splats %ux%u, %u threads: %.1f ms median of %d (%.2f M splats/s; CPU %.1f ms, "
        "%.2f M splats/s with the cores to itself); preprocess %.1f, bin %.1f, blend %.1f "
        "ms; %llu visible, %llu tile entries, mean alpha %.2f\n",
        n, width, height, used_threads, ms, reps, rate / 1e6, cpu_ms, cpu_rate / 1e6, Median(pre),
        Median(bin), Median(blend), static_cast<unsigned long long>(stats.splats_visible),
        static_cast<unsigned long long>(stats.tile_entries), mean_alpha);
    std::fflush(stdout);
    scenes.push_back(
        {{"splats", n},
         {"visible", stats.splats_visible},
         {"tile_entries", stats.tile_entries},
         {"mean_alpha", mean_alpha},
         {"median_ms", ms},
         {"runs_ms", wall},
         {"median_cpu_ms", cpu_ms},
         {"splats_per_s", rate},
         {"splats_per_cpu_s_times_threads", cpu_rate},
         {"median_preprocess_ms", Median(pre)},
         {"median_bin_ms", Median(bin)},
         {"median_blend_ms", Median(blend)},
         {"psnr_vs_cpu_db", psnr_vs_cpu},
         {"target",
          {{"name", "splats/s at 1080p, 2 cores"}, {"limit", 10e6}, {"met", rate >= 10e6}}}});
    if (s == 0 && !png.empty()) {
      const hvdb::formats::Srgb8Image img = hvdb::bench::ToSrgb8(image);
      if (!hvdb::formats::WriteSrgb8Png(img, png).ok())
        std::fprintf(stderr, "cannot write %s\n", png.c_str());
    }
  }
  json doc = {{"benchmark", "gaussian-render-bench"},
              {"scene",
               "synthetic 3DGS-like: flat splats on a floor, a wall and 12 spheres, SH "
               "degree 3, seed 42"},
              {"size", std::to_string(width) + "x" + std::to_string(height)},
              {"renderer", renderer},
              {"threads", used_threads},
              {"hardware_threads", std::thread::hardware_concurrency()},
              {"reps", reps},
              {"scenes", scenes}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
