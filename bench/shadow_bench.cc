// shadow-bench: what shadows cost a render (render/shadow.h; issue 33 part 5: a shadowed 1080p
// render within 2x the unshadowed one). The CMU Panoptic cloud of frame 380 with its upper 30%
// (head and shoulders) labelled as casters, rendered by the CPU renderer from each of the 10
// Kinect colour cameras at their 1920x1080, without and with shadows (render + shadow pass),
// from a point light above the person and from a directional light. Medians of --reps runs
// per camera; JSON to --out (bench/results/shadows.json).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <vector>

#include "render/renderer.h"
#include "render/shadow.h"
#include "tests/render/panoptic_data.h"

namespace render = hvdb::render;
namespace pan = hvdb::testing::panoptic;
using Clock = std::chrono::steady_clock;
using nlohmann::json;

namespace {

double Ms(Clock::time_point since) {
  return std::chrono::duration<double, std::milli>(Clock::now() - since).count();
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app("shadow-bench: the cost of shadows in 1080p renders of the Panoptic data");
  std::string out = "bench/results/shadows.json";
  std::string data = std::string(HVDB_SHARED_DATA) + "/" + pan::kSubdir;
  int reps = 5;
  int cameras = 10;
  app.add_option("--out", out, "JSON file")->capture_default_str();
  app.add_option("--data", data, "The Panoptic folder")->capture_default_str();
  app.add_option("--reps", reps, "Runs per camera and setting (median)")->capture_default_str();
  app.add_option("--cameras", cameras, "Kinect cameras used (1..10)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  auto cams = pan::LoadCameras(data);
  auto cloud = pan::LoadCloud(data, 380);
  if (!cams.ok() || !cloud.ok()) {
    std::fprintf(stderr, "shadow-bench: cannot read %s: %s\n", data.c_str(),
                 (!cams.ok() ? cams.status() : cloud.status()).ToString().c_str());
    return 1;
  }
  constexpr uint32_t kBit = 2;
  float ymin = 1e9f, ymax = -1e9f, xs = 0, zs = 0;
  for (const hvdb::Point& p : *cloud) {
    ymin = std::min(ymin, p.y), ymax = std::max(ymax, p.y);
    xs += p.x, zs += p.z;
  }
  const double cx = xs / cloud->size(), cz = zs / cloud->size();
  size_t casters = 0;
  for (hvdb::Point& p : *cloud) {
    if (p.y < ymin + 0.3f * (ymax - ymin)) p.label |= 1u << kBit, ++casters;
  }
  auto cpu = render::MakeCpuRenderer();
  render::RenderOptions o;
  o.depth_threshold = 0.05f;
  struct Light {
    const char* name;
    render::ShadowOptions s;
  };
  std::vector<Light> lights(2);
  lights[0].name = "point light 1.5 m above the head";
  lights[0].s.light = {cx + 0.3, ymin - 1.5, cz};  // y points down
  lights[1].name = "directional light from above";
  lights[1].s.light = {0.2, -1, 0.1};
  lights[1].s.directional = true;
  for (Light& l : lights) l.s.caster_bit = kBit;

  json per_camera = json::array();
  std::vector<double> plain_all, ratio_point, ratio_dir;
  std::vector<double> shadow_pass_ms;
  render::Image img;
  for (int c = 0; c < std::min<int>(cameras, int(cams->size())); ++c) {
    const pan::KinectCamera& k = (*cams)[size_t(c)];
    std::vector<double> plain;
    for (int r = 0; r < reps; ++r) {
      const auto t0 = Clock::now();
      if (!cpu->RenderInto(*cloud, k.camera, o, &img).ok()) return 1;
      plain.push_back(Ms(t0));
    }
    json row = {{"camera", k.name}, {"unshadowed_ms", Median(plain)}};
    plain_all.push_back(Median(plain));
    for (size_t li = 0; li < lights.size(); ++li) {
      std::vector<double> shadowed, pass;
      uint64_t px = 0;
      for (int r = 0; r < reps; ++r) {
        const auto t0 = Clock::now();
        if (!cpu->RenderInto(*cloud, k.camera, o, &img).ok()) return 1;
        render::ShadowStats st;
        hvdb::Status s = render::ApplyShadows(*cloud, k.camera, o, lights[li].s, &img, &st);
        if (!s.ok()) {
          std::fprintf(stderr, "shadow-bench: %s\n", s.ToString().c_str());
          return 1;
        }
        shadowed.push_back(Ms(t0));
        pass.push_back(st.milliseconds);
        px = st.shadowed_pixels;
      }
      const double ratio = Median(shadowed) / Median(plain);
      (li == 0 ? ratio_point : ratio_dir).push_back(ratio);
      shadow_pass_ms.push_back(Median(pass));
      row[li == 0 ? "point" : "directional"] = {{"shadowed_ms", Median(shadowed)},
                                                {"shadow_pass_ms", Median(pass)},
                                                {"ratio", ratio},
                                                {"shadowed_pixels", px}};
    }
    std::printf("%s: %.1f ms plain, x%.2f point light, x%.2f directional\n", k.name.c_str(),
                Median(plain), ratio_point.back(), ratio_dir.back());
    per_camera.push_back(row);
  }
  const double worst = std::max(*std::max_element(ratio_point.begin(), ratio_point.end()),
                                *std::max_element(ratio_dir.begin(), ratio_dir.end()));
  json doc = {
      {"benchmark", "shadow-bench"},
      {"scene", "CMU Panoptic 171026_pose3 frame 380, upper 30% of the person casting"},
      {"points", cloud->size()},
      {"casters", casters},
      {"size", "1920x1080"},
      {"renderer", cpu->name()},
      {"reps", reps},
      {"lights", {lights[0].name, lights[1].name}},
      {"median_unshadowed_ms", Median(plain_all)},
      {"median_shadow_pass_ms", Median(shadow_pass_ms)},
      {"median_ratio_point", Median(ratio_point)},
      {"median_ratio_directional", Median(ratio_dir)},
      {"worst_camera_ratio", worst},
      {"targets", json::array({{{"name", "shadowed 1080p render <= 2x unshadowed (median over cameras)"},
                                {"value", std::max(Median(ratio_point), Median(ratio_dir))},
                                {"limit", 2.0},
                                {"met", std::max(Median(ratio_point), Median(ratio_dir)) <= 2.0}}})},
      {"cameras", per_camera}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("median x%.2f (point), x%.2f (directional); shadow pass %.1f ms; wrote %s\n",
              Median(ratio_point), Median(ratio_dir), Median(shadow_pass_ms), out.c_str());
  return 0;
}
