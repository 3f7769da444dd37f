#include "bench/real_recordings.h"

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>

namespace hvdb::bench {

const std::vector<double> kEye{1, 0, 0, 0, 1, 0, 0, 0, 1}, kZero{0, 0, 0};

void WriteYaml(const std::string& path, const std::string& text) {
  std::ofstream(path) << "%YAML:1.0\n---\n" << text;
}

namespace {
std::string Matrix(int rows, int cols, const std::vector<double>& v) {
  std::ostringstream o;
  o.precision(17);
  o << "!!opencv-matrix\n      rows: " << rows << "\n      cols: " << cols << "\n      dt: d\n      data: [ ";
  for (size_t i = 0; i < v.size(); ++i) o << (i ? ", " : "") << v[i];
  o << " ]\n";
  return o.str();
}
}  // namespace

std::string CameraYaml(const std::string& name, int w, int h, double fx, double fy, double cx,
                       double cy, const std::vector<double>& R, const std::vector<double>& T,
                       const std::vector<double>& dist) {
  std::ostringstream o;
  o << "   - name: " << name << "\n     width: " << w << "\n     height: " << h
    << "\n     K: " << Matrix(3, 3, {fx, 0, cx, 0, fy, cy, 0, 0, 1});
  if (!dist.empty()) o << "     dist: " << Matrix(1, static_cast<int>(dist.size()), dist);
  o << "     R: " << Matrix(3, 3, R) << "     T: " << Matrix(3, 1, T)
    << "     reprojection_error: 0.5\n";
  return o.str();
}

Status WritePanopticRecording(const std::string& data, const std::string& dir, int frames) {
  namespace fs = std::filesystem;
  const std::string src = data + "/cmu-panoptic-kinoptic-171026-pose3/";
  std::ifstream in(src + "calibration_171026_pose3.json");
  if (!in) return Status::NotFound("Panoptic data missing: " + src + "calibration_171026_pose3.json");
  const nlohmann::json doc = nlohmann::json::parse(in, nullptr, false);
  if (doc.is_discarded()) return Status::Corruption(src + "calibration_171026_pose3.json: not JSON");
  std::error_code ec;
  fs::create_directories(dir, ec);
  std::string cams = "cameras:\n", files = "cameras:\n";
  for (const auto& c : doc["cameras"]) {
    if (c.value("type", "") != "kinect-color") continue;
    const std::string name = c["name"].get<std::string>();
    std::vector<double> R(9), T(3), dist(5);
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R[3 * i + j] = c["R"][i][j].get<double>();
      T[i] = c["t"][i][0].get<double>() / 100.0;  // cm to m, as the clouds after ply_scale
    }
    for (int i = 0; i < 5; ++i) dist[i] = c["distCoef"][i].get<double>();
    cams += CameraYaml("\"" + name + "\"", c["resolution"][0].get<int>(), c["resolution"][1].get<int>(),
                       c["K"][0][0].get<double>(), c["K"][1][1].get<double>(),
                       c["K"][0][2].get<double>(), c["K"][1][2].get<double>(), R, T, dist);
    files += "   - { name: \"" + name + "\", colour: \"" + src + "kinectImgs/{camera}/{camera}_{frame:08d}.jpg\" }\n";
  }
  WriteYaml(dir + "/calibration.yml", cams);
  WriteYaml(dir + "/recording.yml",
            "format: \"hvdb-recording\"\nversion: 1\nkind: \"ply\"\nframes: " +
                std::to_string(frames) + "\nfps: 29.97\nfirst_frame: 380\nply: \"" + src +
                "kinoptic_ptclouds/ptcloud_hd{frame:08d}.ply\"\nply_scale: 0.01\n" + files);
  return Status::OK();
}

Status WriteSjtuRecording(const std::string& data, const std::string& dir) {
  namespace fs = std::filesystem;
  const std::string src = data + "/sjtu-fvv-multiview-rgbd/";
  std::ifstream in(src + "para_cameras.txt");
  if (!in) return Status::NotFound("SJTU data missing: " + src + "para_cameras.txt");
  std::error_code ec;
  fs::create_directories(dir, ec);
  double zmin = 0, zmax = 0;
  in >> zmin >> zmax;
  std::string cams = "cameras:\n", files = "cameras:\n", key;
  for (int c = 0; c < 10; ++c) {
    int id = 0, w = 0, h = 0;
    double fx, fy, cx, cy, C[3];
    std::vector<double> R(9);
    in >> key >> id >> key >> w >> h >> key >> fx >> fy >> cx >> cy >> key;
    for (double& r : R) in >> r;
    in >> key >> C[0] >> C[1] >> C[2];
    if (!in) return Status::Corruption(src + "para_cameras.txt: cannot read camera " + std::to_string(c));
    // Cameras held out of the shared copy (3 and 6) have no images.
    if (!fs::exists(src + "frame_0/images/" + std::to_string(id) + ".png")) continue;
    // X_cam = R (X - C): T = -R C.
    std::vector<double> T{-(R[0] * C[0] + R[1] * C[1] + R[2] * C[2]),
                          -(R[3] * C[0] + R[4] * C[1] + R[5] * C[2]),
                          -(R[6] * C[0] + R[7] * C[1] + R[8] * C[2])};
    const std::string name = "cam" + std::to_string(id);
    cams += CameraYaml(name, w, h, fx, fy, cx, cy, R, T);
    files += "   - { name: " + name + ", colour: \"" + src + "frame_0/images/" +
             std::to_string(id) + ".png\", depth: \"" + src + "frame_0/depths/" +
             std::to_string(id) + ".png\" }\n";
  }
  WriteYaml(dir + "/calibration.yml", cams);
  std::ostringstream o;
  o.precision(17);
  o << "format: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\nframes: 1\nfps: 30\n"
       "depth_encoding: \"inverse8\"\ndepth_invalid: [ 0 ]\nz_near: "
    << zmin << "\nz_far: " << zmax << "\nworld_scale: 0.37\n" << files;
  WriteYaml(dir + "/recording.yml", o.str());
  return Status::OK();
}

}  // namespace hvdb::bench
