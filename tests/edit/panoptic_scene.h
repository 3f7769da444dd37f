// Issue 15's scene, from the shared data: the real CMU Panoptic person (its own colours and
// normals, metres) standing on a floor and in front of a wall that touch it within the graph
// cut's 2 cm, the floor and the wall coloured by real photographs (a 7-Scenes kitchen frame, an
// APC shelf frame), with a few millimetres of noise; strokes placed as a user would paint them
// in the first frame only: foreground on the head, chest and legs, background on floor and wall.
// Ground truth from construction: which points are the person. Used by tests/edit/ and
// graphcut-bench.
#ifndef HVDB_TESTS_EDIT_PANOPTIC_SCENE_H_
#define HVDB_TESTS_EDIT_PANOPTIC_SCENE_H_

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "edit/graph_cut.h"
#include "formats/ply.h"
#include "storage/point.h"

namespace hvdb::testing {

struct RealScene {
  std::vector<Point> points;         // all frames
  std::vector<uint8_t> person;       // ground truth, per point
  std::vector<edit::Seed> seeds;     // strokes (frame 0 only)
  uint32_t frames = 0;
};

// `shared_data`: the ../shared/data folder; `frames` Panoptic frames (1..16); `spacing`: the
// sample spacing of floor and wall (m).
inline Result<RealScene> PanopticScene(const std::string& shared_data, uint32_t frames,
                                       double spacing, uint64_t seed = 15) {
  namespace fs = std::filesystem;
  const fs::path clouds =
      fs::path(shared_data) / "cmu-panoptic-kinoptic-171026-pose3" / "kinoptic_ptclouds";
  std::vector<fs::path> files;
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(clouds, ec)) {
    if (e.path().extension() == ".ply") files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  if (files.size() < frames || frames == 0) {
    return Status::NotFound("Panoptic frames missing from " + clouds.string());
  }
  cv::Mat floor_img = cv::imread(
      (fs::path(shared_data) / "sevenscenes-redkitchen-rgbd" / "rgbd-frames" / "frame-000150.color.png")
          .string(),
      cv::IMREAD_COLOR);
  cv::Mat wall_img = cv::imread(
      (fs::path(shared_data) / "apc-shelf-rgbd-sequence" / "sample" / "frame-000015.color.png")
          .string(),
      cv::IMREAD_COLOR);
  if (floor_img.empty() || wall_img.empty()) {
    return Status::NotFound("7-Scenes or APC shelf colour images missing from " + shared_data);
  }
  RealScene scene;
  scene.frames = frames;
  std::array<float, 3> lo{1e9f, 1e9f, 1e9f}, hi{-1e9f, -1e9f, -1e9f};
  std::vector<std::vector<Point>> people;
  for (uint32_t f = 0; f < frames; ++f) {
    formats::ReadOptions o;
    o.scale = 0.01;  // centimetres
    o.frame = f;
    o.force_frame = true;
    HVDB_ASSIGN_OR_RETURN(auto pts, formats::ReadPly(files[f].string(), o));
    for (const Point& p : pts) {
      const float c[3] = {p.x, p.y, p.z};
      for (int a = 0; a < 3; ++a) {
        lo[static_cast<size_t>(a)] = std::min(lo[static_cast<size_t>(a)], c[a]);
        hi[static_cast<size_t>(a)] = std::max(hi[static_cast<size_t>(a)], c[a]);
      }
    }
    people.push_back(std::move(pts));
  }
  // y points down: the feet are at the largest y, the camera looks along +z, so the wall is
  // behind the person at the largest z. Both planes 5 mm from the person's extreme points.
  const float floor_y = hi[1] + 0.005f, wall_z = hi[2] + 0.005f;
  const float x0 = lo[0] - 0.6f, x1 = hi[0] + 0.6f, z0 = lo[2] - 0.6f, y0 = lo[1] - 0.3f;
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> noise(0.f, 0.0015f);
  std::uniform_real_distribution<float> jitter(-0.25f, 0.25f);
  auto texel = [](const cv::Mat& img, double u, double v) {
    int x = std::clamp(static_cast<int>(u * (img.cols - 1)), 0, img.cols - 1);
    int y = std::clamp(static_cast<int>(v * (img.rows - 1)), 0, img.rows - 1);
    cv::Vec3b bgr = img.at<cv::Vec3b>(y, x);
    return std::array<uint8_t, 3>{bgr[2], bgr[1], bgr[0]};
  };
  const auto up = EncodeNormal(0, -1, 0), toward_camera = EncodeNormal(0, 0, -1);
  const auto ds = static_cast<float>(spacing);
  for (uint32_t f = 0; f < frames; ++f) {
    for (const Point& p : people[f]) {
      scene.points.push_back(p);
      scene.person.push_back(1);
    }
    auto plane_point = [&](float x, float y, float z, std::array<uint8_t, 3> rgb,
                           std::array<int16_t, 2> n) {
      Point p;
      p.x = x;
      p.y = y;
      p.z = z;
      p.frame = f;
      p.r = rgb[0];
      p.g = rgb[1];
      p.b = rgb[2];
      p.normal_oct = n;
      p.flags = kFlagHasNormal;
      scene.points.push_back(p);
      scene.person.push_back(0);
    };
    for (float x = x0; x <= x1; x += ds) {
      for (float z = z0; z <= wall_z; z += ds) {  // the floor, up to the wall
        float px = x + jitter(rng) * ds, pz = z + jitter(rng) * ds;
        plane_point(px, floor_y + noise(rng), pz,
                    texel(floor_img, (px - x0) / (x1 - x0), (pz - z0) / (wall_z - z0)), up);
      }
      for (float y = y0; y <= floor_y; y += ds) {  // the wall, down to the floor
        float px = x + jitter(rng) * ds, py = y + jitter(rng) * ds;
        plane_point(px, py, wall_z + noise(rng),
                    texel(wall_img, (px - x0) / (x1 - x0), (py - y0) / (floor_y - y0)),
                    toward_camera);
      }
    }
  }
  // Strokes in frame 0, 5 cm brushes: on the person's front (nearest person point to a spot
  // 30 cm in front of the body's centre at that height) and on floor and wall.
  scene.seeds.assign(scene.points.size(), edit::Seed::kUnknown);
  auto nearest = [&](bool person, std::array<float, 3> at) {
    size_t best = 0;
    float bd = 1e30f;
    for (size_t i = 0; i < scene.points.size(); ++i) {
      const Point& p = scene.points[i];
      if (p.frame != 0 || (scene.person[i] != 0) != person) continue;
      float d = (p.x - at[0]) * (p.x - at[0]) + (p.y - at[1]) * (p.y - at[1]) +
                (p.z - at[2]) * (p.z - at[2]);
      if (d < bd) bd = d, best = i;
    }
    return best;
  };
  auto paint = [&](size_t centre, float radius, edit::Seed s) {
    const Point& c = scene.points[centre];
    for (size_t i = 0; i < scene.points.size(); ++i) {
      const Point& p = scene.points[i];
      if (p.frame != 0) continue;
      float d = std::hypot(p.x - c.x, p.y - c.y, p.z - c.z);
      if (d <= radius) scene.seeds[i] = s;
    }
  };
  auto band_centre = [&](float ya, float yb) {
    double sx = 0, sz = 0;
    size_t n = 0;
    for (size_t i = 0; i < scene.points.size(); ++i) {
      const Point& p = scene.points[i];
      if (p.frame != 0 || !scene.person[i] || p.y < ya || p.y > yb) continue;
      sx += p.x, sz += p.z, ++n;
    }
    return std::array<float, 2>{static_cast<float>(sx / std::max<size_t>(n, 1)),
                                static_cast<float>(sz / std::max<size_t>(n, 1))};
  };
  const float top = lo[1], feet = hi[1];
  for (float ya : {top + 0.05f, top + 0.40f, feet - 0.45f}) {  // head, chest, legs
    auto c = band_centre(ya, ya + 0.1f);
    paint(nearest(true, {c[0], ya + 0.05f, c[1] - 0.3f}), 0.05f, edit::Seed::kForeground);
  }
  paint(nearest(false, {x0 + 0.25f, floor_y, z0 + 0.25f}), 0.10f, edit::Seed::kBackground);
  paint(nearest(false, {x1 - 0.25f, floor_y, z0 + 0.4f}), 0.10f, edit::Seed::kBackground);
  paint(nearest(false, {x0 + 0.25f, y0 + 0.3f, wall_z}), 0.10f, edit::Seed::kBackground);
  paint(nearest(false, {x1 - 0.25f, y0 + 0.8f, wall_z}), 0.10f, edit::Seed::kBackground);
  return scene;
}

// Precision and recall of `selected` against the person, per frame.
inline std::vector<std::array<double, 2>> PerFrameQuality(const RealScene& s,
                                                          const std::vector<uint8_t>& selected) {
  std::vector<std::array<double, 3>> c(s.frames, {0, 0, 0});  // tp, fp, fn
  for (size_t i = 0; i < s.points.size(); ++i) {
    auto& k = c[s.points[i].frame];
    k[0] += selected[i] && s.person[i];
    k[1] += selected[i] && !s.person[i];
    k[2] += !selected[i] && s.person[i];
  }
  std::vector<std::array<double, 2>> out;
  for (const auto& k : c) {
    out.push_back({k[0] / std::max(1.0, k[0] + k[1]), k[0] / std::max(1.0, k[0] + k[2])});
  }
  return out;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_EDIT_PANOPTIC_SCENE_H_
