// render-bench: EWA splatting throughput (render/renderer.h) — splats per second and frames per
// second for 0.1, 1 and 2 million points at 1024x768, for each mode (visibility, probabilistic,
// each with and without view-dependent weights), CPU and EGL — and the image quality on real
// data: the CMU Panoptic cloud of frame 380 rendered from each of the 10 Kinect colour cameras
// against their photos (PSNR and SSIM over the person). Writes JSON in the figure format of the
// other benchmarks (bench/README.md).
//
// Scene: a closed sphere of radius 1 m seen from 3.5 m, sampled with n surfels whose size
// follows the sample spacing (sigma = 0.6 spacing), so the surface stays closed and the covered
// screen area stays the same at every n: the cost per splat falls as splats get smaller.
#include <sys/resource.h>
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/render/panoptic_data.h"
#include "tests/render/test_scenes.h"

namespace render = hvdb::render;
namespace pan = hvdb::testing::panoptic;

namespace {

nlohmann::json Figure(const std::string& name, const std::string& unit, std::vector<double> v,
                      nlohmann::json params) {
  std::sort(v.begin(), v.end());
  return {{"name", name},
          {"unit", unit},
          {"median", v[v.size() / 2]},
          {"min", v.front()},
          {"max", v.back()},
          {"repetitions", v.size()},
          {"params", std::move(params)}};
}

struct ModeCase {
  const char* name;
  render::Mode mode;
  bool view_dependent;
};

const ModeCase kModes[] = {
    {"visibility", render::Mode::kVisibility, false},
    {"probabilistic", render::Mode::kProbabilistic, false},
    {"visibility+view_dependent", render::Mode::kVisibility, true},
    {"probabilistic+view_dependent", render::Mode::kProbabilistic, true},
};

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"render-bench: splatting throughput (CPU and EGL) and quality on Panoptic data"};
  std::string out = "render.json";
  std::string renderers = "cpu,egl";
  std::string data = HVDB_SHARED_DATA;
  bool quick = false;
  int reps = 3;
  uint32_t width = 1024, height = 768;
  std::vector<double> millions = {0.1, 1, 2};
  app.add_option("--out", out, "JSON output file")->capture_default_str();
  app.add_flag("--quick", quick, "0.1 M points, one repetition, 3 Panoptic cameras (CI smoke)");
  app.add_option("--renderers", renderers, "comma-separated: cpu, egl")->capture_default_str();
  app.add_option("--points", millions, "scene sizes in millions of points")->capture_default_str();
  app.add_option("--repetitions", reps, "timed renders per case (after one warm-up)")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_option("--width", width)->capture_default_str()->check(CLI::Range(1u, 4096u));
  app.add_option("--height", height)->capture_default_str()->check(CLI::Range(1u, 4096u));
  app.add_option("--data", data, "the shared data directory (Panoptic set inside)")
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  if (quick) {
    millions = {0.1};
    reps = 1;
  }

  // Renderers, by name; EGL may be missing (then it is reported, not faked).
  std::vector<std::pair<std::string, std::unique_ptr<render::Renderer>>> rs;
  nlohmann::json machine = {{"hardware_threads", std::thread::hardware_concurrency()}};
  for (size_t at = 0; at <= renderers.size();) {
    size_t comma = std::min(renderers.find(',', at), renderers.size());
    std::string name = renderers.substr(at, comma - at);
    at = comma + 1;
    if (name == "cpu") {
      rs.emplace_back(name, render::MakeCpuRenderer());
    } else if (name == "egl") {
      auto r = render::MakeEglRenderer();
      if (r.ok()) {
        rs.emplace_back(name, std::move(r).value());
      } else {
        std::fprintf(stderr, "render-bench: no EGL renderer: %s\n", r.status().ToString().c_str());
        machine["egl_error"] = r.status().ToString();
      }
    } else if (!name.empty()) {
      std::fprintf(stderr, "render-bench: unknown renderer '%s'\n", name.c_str());
      return 2;
    }
  }
  for (const auto& [name, r] : rs) machine[name] = r->name();

  nlohmann::json figures = nlohmann::json::array();
  render::Camera camera = hvdb::testing::ViewFrom(0.3, 0.4, 1, 3.5, width, height);
  std::vector<render::SourceCamera> sources;
  for (int i = 1; i <= 4; ++i) {
    render::Camera c =
        hvdb::testing::ViewFrom(std::cos(i * 1.5708), 0.3, std::sin(i * 1.5708), 3, 10, 10);
    sources.push_back({static_cast<uint16_t>(i), c.world_from_camera});
  }
  for (double m : millions) {
    auto points = hvdb::testing::SphereScene(static_cast<size_t>(m * 1e6));
    for (const ModeCase& mc : kModes) {
      render::RenderOptions o;
      o.mode = mc.mode;
      o.view_dependent = mc.view_dependent;
      o.source_cameras = sources;
      std::vector<render::Srgb8Image> images;  // one per renderer, for their agreement
      for (const auto& [name, r] : rs) {
        std::vector<double> fps, splats;
        for (int rep = -1; rep < reps; ++rep) {  // rep -1: warm-up (shader compiles, buffers)
          auto t0 = std::chrono::steady_clock::now();
          auto img = r->Render(points, camera, o);
          double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
          if (!img.ok()) {
            std::fprintf(stderr, "render-bench: %s\n", img.status().ToString().c_str());
            return 1;
          }
          if (rep < 0) {
            images.push_back(render::ToSrgb8(*img));
            continue;
          }
          fps.push_back(1 / s);
          splats.push_back(static_cast<double>(points.size()) / s);
        }
        nlohmann::json params = {{"renderer", name},
                                 {"mode", mc.name},
                                 {"points", points.size()},
                                 {"width", width},
                                 {"height", height}};
        figures.push_back(Figure("render_fps", "frames/s", fps, params));
        figures.push_back(Figure("render_splats_per_s", "splats/s", splats, params));
        std::sort(fps.begin(), fps.end());
        std::sort(splats.begin(), splats.end());
        std::printf("%-4s %-29s %8zu points: %7.2f fps, %6.2f M splats/s\n", name.c_str(), mc.name,
                    points.size(), fps[fps.size() / 2], splats[splats.size() / 2] / 1e6);
        std::fflush(stdout);
      }
      if (images.size() == 2) {
        // The two renderers draw the same algorithm: their images should agree (>= 35 dB),
        // here also across the EGL renderer's upload chunks (1 Mi points each).
        double psnr = render::Psnr(images[0], images[1]);
        figures.push_back(Figure("render_agreement_psnr", "dB", {std::min(psnr, 999.0)},
                                 {{"renderers", rs[0].first + "," + rs[1].first},
                                  {"mode", mc.name},
                                  {"points", points.size()}}));
        std::printf("     agreement %s vs %s: PSNR %.1f dB\n", rs[0].first.c_str(),
                    rs[1].first.c_str(), psnr);
      }
    }
  }

  // Real data: Panoptic frame 380 from the 10 Kinect colour cameras, full 1920x1080.
  const std::string dir = data + "/" + pan::kSubdir;
  nlohmann::json panoptic;
  if (std::filesystem::exists(dir)) {
    auto cams = pan::LoadCameras(dir);
    auto cloud = pan::LoadCloud(dir, 380);
    if (!cams.ok() || !cloud.ok()) {
      std::fprintf(stderr, "render-bench: Panoptic data unreadable\n");
      return 1;
    }
    auto cpu = render::MakeCpuRenderer();
    size_t ncams = quick ? 3 : cams->size();
    for (const ModeCase& mc : kModes) {
      if (mc.view_dependent) continue;  // the cloud carries no source camera ids
      render::RenderOptions o;
      o.mode = mc.mode;
      o.depth_threshold = 0.05f;
      std::vector<double> psnrs, ssims;
      for (size_t i = 0; i < ncams; ++i) {
        const pan::KinectCamera& k = (*cams)[i];
        auto img = cpu->Render(*cloud, k.camera, o);
        auto photo = render::ReadSrgb8(pan::ImagePath(dir, k.name, 380));
        if (!img.ok() || !photo.ok()) {
          std::fprintf(stderr, "render-bench: Panoptic camera %s failed\n", k.name.c_str());
          return 1;
        }
        pan::Comparison c = pan::CompareWithPhoto(*img, *photo, true);
        psnrs.push_back(c.psnr);
        ssims.push_back(c.ssim);
        nlohmann::json params = {{"camera", k.name},
                                 {"mode", mc.name},
                                 {"frame", 380},
                                 {"mask_pixels", c.pixels},
                                 {"points", cloud->size()}};
        figures.push_back(Figure("panoptic_psnr", "dB", {c.psnr}, params));
        figures.push_back(Figure("panoptic_ssim", "ratio", {c.ssim}, params));
        std::printf("panoptic %-13s %s: PSNR %.2f dB, SSIM %.3f over %zu pixels\n", mc.name,
                    k.name.c_str(), c.psnr, c.ssim, c.pixels);
        std::fflush(stdout);
      }
      double mp = 0, ms = 0;
      for (size_t i = 0; i < psnrs.size(); ++i) {
        mp += psnrs[i] / psnrs.size();
        ms += ssims[i] / ssims.size();
      }
      panoptic[mc.name] = {{"mean_psnr_db", mp}, {"mean_ssim", ms}, {"cameras", psnrs.size()}};
    }
  } else {
    panoptic["skipped"] = dir + " is not there";
  }

  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  nlohmann::json doc = {{"benchmark", "render"},
                        {"machine", machine},
                        {"peak_rss_mib", ru.ru_maxrss / 1024.0},
                        {"panoptic", panoptic},
                        {"figures", figures}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
