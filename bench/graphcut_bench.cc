// graphcut-bench: the 4D graph cut of edit/graph_cut.h (thesis 9.3.2) against the size of the
// region of interest — neighbour search, GMMs, graph construction and max-flow — on the moving-
// sphere scene of tests/edit/scene.h over 10 frames, and on real data (tests/edit/
// panoptic_scene.h: the Panoptic person against touching floor and wall textured by real
// photographs, strokes in the first frame): time and precision/recall per frame. Writes JSON
// (bench/README.md schema).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sys/resource.h>
#include <array>
#include <vector>

#include "edit/graph_cut.h"
#include "tests/edit/panoptic_scene.h"
#include "tests/edit/scene.h"

using hvdb::edit::GraphCutParams;
using hvdb::edit::Seed;

namespace {

nlohmann::json Figure(const std::string& name, const std::string& unit, std::vector<double> v,
                      nlohmann::json params) {
  std::sort(v.begin(), v.end());
  return {{"name", name}, {"unit", unit}, {"median", v[v.size() / 2]}, {"min", v.front()},
          {"max", v.back()}, {"repetitions", v.size()}, {"params", std::move(params)}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"graphcut-bench: 4D graph-cut selection time against region size"};
  std::string out = "graphcut.json";
  bool quick = false;
  int reps = 3, frames = 10;
  app.add_option("--out", out, "JSON output file")->capture_default_str();
  app.add_flag("--quick", quick, "small sizes only (CI smoke run)");
  app.add_option("--repetitions", reps, "runs per size")->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_option("--frames", frames, "frames in the region of interest")->capture_default_str()
      ->check(CLI::Range(1, 100));
  std::vector<double> only;
  app.add_option("--spacing", only, "sample spacings (m) to run instead of the default series; "
                                    "0.0033 gives ~1.2 M points over 10 frames")
      ->check(CLI::Range(0.001, 0.1));
  std::string shared = "../shared/data";
  int real_frames = 5;
  double plane_spacing = 0.006;
  app.add_option("--shared-data", shared, "the shared data folder (for the real scene)")
      ->capture_default_str();
  app.add_option("--real-frames", real_frames, "frames of the real scene (0: skip it)")
      ->capture_default_str()->check(CLI::Range(0, 16));
  app.add_option("--plane-spacing", plane_spacing, "floor and wall sample spacing (m)")
      ->capture_default_str()->check(CLI::Range(0.002, 0.1));
  GraphCutParams tuned;
  app.add_option("--max-color-diff", tuned.max_color_diff, "arc exclusion: colour")->capture_default_str();
  app.add_option("--max-normal-diff", tuned.max_normal_diff, "arc exclusion: normal")->capture_default_str();
  app.add_option("--lambda-i", tuned.lambda_i, "weight of intra-frame links")->capture_default_str();
  app.add_option("--lambda-t", tuned.lambda_t, "weight of inter-frame links")->capture_default_str();
  app.add_option("--beta-c", tuned.beta_c, "eq. 9.6 colour beta (0: adaptive)")->capture_default_str();
  app.add_option("--beta-n", tuned.beta_n, "eq. 9.6 normal beta (0: adaptive)")->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  // Sample spacing -> points per frame (plane 1 m^2 + sphere of radius 15 cm).
  std::vector<double> spacings = quick ? std::vector<double>{0.02, 0.012}
                                       : std::vector<double>{0.012, 0.007, 0.005, 0.004, 0.0033};
  if (!only.empty()) spacings = only;
  if (quick) reps = 1;
  nlohmann::json figures = nlohmann::json::array();
  for (double spacing : spacings) {
    auto scene = hvdb::testing::MovingSphereScene(frames, spacing);
    std::vector<hvdb::Point> pts;
    std::vector<Seed> seeds(scene.size(), Seed::kUnknown);
    float top = -1;
    for (const auto& s : scene) {
      if (s.sphere && s.p.frame == 0) top = std::max(top, s.p.z);
    }
    for (size_t i = 0; i < scene.size(); ++i) {
      const hvdb::Point& p = scene[i].p;
      pts.push_back(p);
      if (p.frame != 0) continue;
      if (scene[i].sphere && p.z > top - 0.015) seeds[i] = Seed::kForeground;
      if (std::hypot(p.x - 0.8, p.y - 0.2) < 0.03 && p.z == 0) seeds[i] = Seed::kBackground;
    }
    std::vector<double> total, neigh, gmm, graph, flow, precision, recall;
    uint64_t edges = 0;
    for (int r = 0; r < reps; ++r) {
      auto t0 = std::chrono::steady_clock::now();
      auto res = hvdb::edit::RunGraphCut(pts, seeds, GraphCutParams{});
      double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      if (!res.ok()) {
        std::fprintf(stderr, "graphcut-bench: %s\n", res.status().ToString().c_str());
        return 1;
      }
      total.push_back(ms);
      neigh.push_back(res->neighbours_ms);
      gmm.push_back(res->gmm_ms);
      graph.push_back(res->graph_ms);
      flow.push_back(res->maxflow_ms);
      edges = res->intra_edges + res->inter_edges;
      double tp = 0, fp = 0, fn = 0;
      for (size_t i = 0; i < scene.size(); ++i) {
        bool sel = res->selected[i];
        tp += sel && scene[i].sphere;
        fp += sel && !scene[i].sphere;
        fn += !sel && scene[i].sphere;
      }
      precision.push_back(tp / std::max(1.0, tp + fp));
      recall.push_back(tp / std::max(1.0, tp + fn));
    }
    nlohmann::json params = {{"points", pts.size()}, {"frames", frames}, {"spacing_m", spacing},
                             {"arcs", edges}};
    figures.push_back(Figure("graphcut_total", "ms", total, params));
    figures.push_back(Figure("graphcut_neighbours", "ms", neigh, params));
    figures.push_back(Figure("graphcut_gmm", "ms", gmm, params));
    figures.push_back(Figure("graphcut_graph_construction", "ms", graph, params));
    figures.push_back(Figure("graphcut_maxflow", "ms", flow, params));
    figures.push_back(Figure("graphcut_precision", "ratio", precision, params));
    figures.push_back(Figure("graphcut_recall", "ratio", recall, params));
    std::printf("%8zu points, %9llu arcs: total %8.0f ms (neighbours %6.0f, GMM %6.0f, graph %6.0f, "
                "max-flow %6.0f) precision %.3f recall %.3f\n",
                pts.size(), static_cast<unsigned long long>(edges), total[total.size() / 2],
                neigh[neigh.size() / 2], gmm[gmm.size() / 2], graph[graph.size() / 2],
                flow[flow.size() / 2], precision[0], recall[0]);
    std::fflush(stdout);
  }
  if (real_frames > 0) {
    auto scene = hvdb::testing::PanopticScene(shared, static_cast<uint32_t>(real_frames),
                                              quick ? 0.015 : plane_spacing);
    if (!scene.ok()) {
      std::fprintf(stderr, "graphcut-bench: %s\n", scene.status().ToString().c_str());
      return 1;
    }
    std::vector<double> total, neigh, gmm, graph, flow;
    std::vector<std::array<double, 2>> quality;
    hvdb::edit::GraphCutResult last;
    uint64_t edges = 0;
    for (int r = 0; r < reps; ++r) {
      auto t0 = std::chrono::steady_clock::now();
      auto res = hvdb::edit::RunGraphCut(scene->points, scene->seeds, tuned);
      total.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (!res.ok()) {
        std::fprintf(stderr, "graphcut-bench: %s\n", res.status().ToString().c_str());
        return 1;
      }
      edges = res->intra_edges + res->inter_edges;
      neigh.push_back(res->neighbours_ms);
      gmm.push_back(res->gmm_ms);
      graph.push_back(res->graph_ms);
      flow.push_back(res->maxflow_ms);
      quality = hvdb::testing::PerFrameQuality(*scene, res->selected);
      last = *res;
    }
    nlohmann::json params = {{"scene", "panoptic person, floor and wall"},
                             {"points", scene->points.size()}, {"frames", real_frames},
                             {"plane_spacing_m", quick ? 0.015 : plane_spacing}, {"arcs", edges}};
    figures.push_back(Figure("graphcut_real_total", "ms", total, params));
    figures.push_back(Figure("graphcut_real_neighbours", "ms", neigh, params));
    figures.push_back(Figure("graphcut_real_gmm", "ms", gmm, params));
    figures.push_back(Figure("graphcut_real_graph_construction", "ms", graph, params));
    figures.push_back(Figure("graphcut_real_maxflow", "ms", flow, params));
    auto median = [](std::vector<double> v) {
      std::sort(v.begin(), v.end());
      return v[v.size() / 2];
    };
    std::printf("real scene: %zu points over %d frames, %llu arcs: %.0f ms (neighbours %.0f, GMM "
                "%.0f, graph %.0f, max-flow %.0f; medians of %d; %llu augmentations)\n",
                scene->points.size(), real_frames, static_cast<unsigned long long>(edges),
                median(total), median(neigh), median(gmm), median(graph), median(flow), reps,
                static_cast<unsigned long long>(last.augmentations));
    for (size_t f = 0; f < quality.size(); ++f) {
      nlohmann::json pf = params;
      pf["frame"] = f;
      figures.push_back(Figure("graphcut_real_precision", "ratio", {quality[f][0]}, pf));
      figures.push_back(Figure("graphcut_real_recall", "ratio", {quality[f][1]}, pf));
      std::printf("  frame %zu: precision %.3f recall %.3f\n", f, quality[f][0], quality[f][1]);
    }
    // One more stroke, in the last frame (a 5 cm brush on the person's middle): the re-cut
    // on the kept graph and flow, next to a cold cut with all strokes (same energy).
    std::vector<Seed> more = scene->seeds;
    {
      const uint32_t lastf = static_cast<uint32_t>(real_frames - 1);
      double cx = 0, cy = 0, cz = 0;
      size_t m = 0;
      for (size_t i = 0; i < scene->points.size(); ++i) {
        const auto& p = scene->points[i];
        if (p.frame == lastf && scene->person[i]) cx += p.x, cy += p.y, cz += p.z, ++m;
      }
      cx /= m, cy /= m, cz /= m;
      size_t best = 0;
      double bd = 1e30;
      for (size_t i = 0; i < scene->points.size(); ++i) {
        const auto& p = scene->points[i];
        if (p.frame != lastf || !scene->person[i]) continue;
        double d = (p.x - cx) * (p.x - cx) + (p.y - cy) * (p.y - cy) + (p.z - cz) * (p.z - cz);
        if (d < bd) bd = d, best = i;
      }
      const auto& c = scene->points[best];
      for (size_t i = 0; i < scene->points.size(); ++i) {
        const auto& p = scene->points[i];
        if (p.frame == lastf && std::hypot(p.x - c.x, p.y - c.y, p.z - c.z) <= 0.05) {
          more[i] = Seed::kForeground;
        }
      }
    }
    std::vector<double> recut_ms, recut_flow_ms, cold_ms;
    double agreement = 0, energy_gap = 0;
    for (int r = 0; r < reps; ++r) {
      auto g = hvdb::edit::GraphCut::Build(scene->points, tuned);
      if (!g.ok() || !(*g)->Cut(scene->seeds).ok()) {
        std::fprintf(stderr, "graphcut-bench: the first cut failed\n");
        return 1;
      }
      auto t0 = std::chrono::steady_clock::now();
      auto warm = (*g)->Cut(more);
      recut_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      g->reset();
      t0 = std::chrono::steady_clock::now();
      auto cold = hvdb::edit::RunGraphCut(scene->points, more, tuned);
      cold_ms.push_back(
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      if (!warm.ok() || !cold.ok()) {
        std::fprintf(stderr, "graphcut-bench: the re-cut failed\n");
        return 1;
      }
      recut_flow_ms.push_back(warm->maxflow_ms);
      std::printf("  re-cut: %llu augmentations, energy %.3f (cold %.3f, %llu augmentations)\n",
                  static_cast<unsigned long long>(warm->augmentations), warm->energy, cold->energy,
                  static_cast<unsigned long long>(cold->augmentations));
      size_t same = 0;
      for (size_t i = 0; i < more.size(); ++i) same += warm->selected[i] == cold->selected[i];
      agreement = static_cast<double>(same) / more.size();
      energy_gap = std::abs(warm->energy - cold->energy) / std::max(cold->energy, 1e-9);
    }
    nlohmann::json rp = params;
    rp["added_stroke"] = "5 cm brush on the person in the last frame";
    rp["agreement_with_cold_cut"] = agreement;
    rp["energy_relative_difference"] = energy_gap;
    figures.push_back(Figure("graphcut_real_recut", "ms", recut_ms, rp));
    figures.push_back(Figure("graphcut_real_recut_maxflow", "ms", recut_flow_ms, rp));
    figures.push_back(Figure("graphcut_real_cold_with_the_stroke", "ms", cold_ms, rp));
    std::sort(recut_ms.begin(), recut_ms.end());
    std::sort(cold_ms.begin(), cold_ms.end());
    std::printf("re-cut after one more stroke: %.0f ms (max-flow %.0f) vs %.0f ms cold; labels "
                "agree on %.5f of the points, energies differ by %.2g\n",
                recut_ms[recut_ms.size() / 2], recut_flow_ms[recut_flow_ms.size() / 2],
                cold_ms[cold_ms.size() / 2], agreement, energy_gap);
  }
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  nlohmann::json doc = {{"benchmark", "graphcut"},
                        {"peak_rss_mib", ru.ru_maxrss / 1024.0},
                        {"figures", figures}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
