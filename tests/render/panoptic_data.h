// The CMU Panoptic "171026_pose3" copy in ../shared/data (README.md there): a fused, coloured
// point cloud per frame (PLY, centimetres, with normals) and the 10 Kinect colour cameras
// (50_01 .. 50_10, 1920x1080) with their calibration. Header-only: the render tests and the
// render benchmark (bench/render_bench.cc) both read it.
#ifndef HVDB_TESTS_RENDER_PANOPTIC_DATA_H_
#define HVDB_TESTS_RENDER_PANOPTIC_DATA_H_

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "formats/image_io.h"
#include "formats/ply.h"
#include "render/metrics.h"
#include "render/renderer.h"
#include "storage/point.h"

namespace hvdb::testing::panoptic {

inline constexpr const char* kSubdir = "cmu-panoptic-kinoptic-171026-pose3";

struct KinectCamera {
  std::string name;  // "50_01"
  render::Camera camera;
};

// The 10 Kinect colour cameras, in metres: x_cam = R X + t/100 (calibration t is in cm).
inline Result<std::vector<KinectCamera>> LoadCameras(const std::string& dir) {
  std::ifstream in(dir + "/calibration_171026_pose3.json");
  if (!in) return Status::NotFound(dir + "/calibration_171026_pose3.json: missing");
  nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
  if (doc.is_discarded()) return Status::Corruption("calibration: not JSON");
  std::vector<KinectCamera> out;
  for (const auto& c : doc["cameras"]) {
    if (c.value("type", "") != "kinect-color") continue;
    KinectCamera k;
    k.name = c["name"].get<std::string>();
    render::Camera& cam = k.camera;
    cam.width = c["resolution"][0].get<uint32_t>();
    cam.height = c["resolution"][1].get<uint32_t>();
    cam.fx = c["K"][0][0].get<double>();
    cam.fy = c["K"][1][1].get<double>();
    cam.cx = c["K"][0][2].get<double>();
    cam.cy = c["K"][1][2].get<double>();
    for (int i = 0; i < 5; ++i) cam.distortion[i] = c["distCoef"][i].get<double>();
    double R[3][3], t[3];
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R[i][j] = c["R"][i][j].get<double>();
      t[i] = c["t"][i][0].get<double>() / 100.0;
    }
    // world_from_camera = [R^T | -R^T t].
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) cam.world_from_camera[i * 4 + j] = R[j][i];
      cam.world_from_camera[i * 4 + 3] = -(R[0][i] * t[0] + R[1][i] * t[1] + R[2][i] * t[2]);
    }
    out.push_back(k);
  }
  std::sort(out.begin(), out.end(),
            [](const KinectCamera& a, const KinectCamera& b) { return a.name < b.name; });
  return out;
}

// Tangent-plane surfels from the cloud's normals: sigma_t across the surface (about the point
// spacing) and sigma_n along the normal, V = sigma_t^2 (I - n n^T) + sigma_n^2 n n^T.
inline void SurfelCovariances(std::vector<Point>* pts, float sigma_t, float sigma_n) {
  for (Point& p : *pts) {
    if (!(p.flags & kFlagHasNormal)) continue;
    auto n = DecodeNormal(p.normal_oct);
    float a = sigma_t * sigma_t, b = sigma_n * sigma_n - a;
    p.cov = {a + b * n[0] * n[0], b * n[0] * n[1], b * n[0] * n[2],
             a + b * n[1] * n[1], b * n[1] * n[2], a + b * n[2] * n[2]};
    p.flags |= kFlagHasCovariance;
  }
}

inline std::string CloudPath(const std::string& dir, int frame) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "/kinoptic_ptclouds/ptcloud_hd%08d.ply", frame);
  return dir + buf;
}

inline std::string ImagePath(const std::string& dir, const std::string& cam, int frame) {
  char buf[96];
  std::snprintf(buf, sizeof(buf), "/kinectImgs/%s/%s_%08d.jpg", cam.c_str(), cam.c_str(), frame);
  return dir + buf;
}

// The cloud of `frame` in metres, with surfel covariances (sigma_t 4 mm, sigma_n 1 mm).
inline Result<std::vector<Point>> LoadCloud(const std::string& dir, int frame) {
  formats::ReadOptions o;
  o.scale = 0.01;  // centimetres
  HVDB_ASSIGN_OR_RETURN(std::vector<Point> pts, formats::ReadPly(CloudPath(dir, frame), o));
  SurfelCovariances(&pts, 0.004f, 0.001f);
  return pts;
}

struct Comparison {
  double psnr = 0, ssim = 0;
  size_t pixels = 0;  // in the mask
};

// Compares a rendering with the photo over the pixels the splats cover fully (the person).
inline Comparison CompareWithPhoto(const render::Image& rendered, const render::Srgb8Image& photo,
                                   bool with_ssim) {
  Comparison c;
  render::Srgb8Image r = formats::ToSrgb8(rendered);
  std::vector<uint8_t> mask(rendered.pixels());
  for (size_t i = 0; i < mask.size(); ++i) {
    mask[i] = rendered.coverage[i] >= 0.99f;
    c.pixels += mask[i];
  }
  c.psnr = render::Psnr(r, photo, &mask);
  c.ssim = with_ssim ? render::Ssim(r, photo, &mask) : 0;
  return c;
}

}  // namespace hvdb::testing::panoptic

#endif  // HVDB_TESTS_RENDER_PANOPTIC_DATA_H_
