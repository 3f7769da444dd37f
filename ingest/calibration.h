// Camera calibration of a recording rig (thesis 3.2, 4.3): pinhole intrinsics K, Brown-Conrady
// distortion, world-to-camera pose (R, T: X_cam = R X_world + T, so the centre of projection is
// O = -R^T T), image size, and the calibration's reprojection error sigma_C (pixels), which
// feeds the point uncertainties of eq. 5.8.
//
// Stored as an OpenCV FileStorage YAML (docs/RECORDING.md has the keys). A rig is a list of
// cameras plus, for stereo recordings, the bricks that group them: two grey cameras and one
// colour camera each.
#ifndef HVDB_INGEST_CALIBRATION_H_
#define HVDB_INGEST_CALIBRATION_H_

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "render/renderer.h"
#include "storage/status.h"

namespace hvdb::ingest {

struct CameraModel {
  std::string name;                     // unique in the rig; names the image files
  cv::Matx33d K = cv::Matx33d::eye();   // fx 0 cx; 0 fy cy; 0 0 1 (pixels)
  std::vector<double> dist;             // k1 k2 p1 p2 [k3]; empty = no distortion
  cv::Matx33d R = cv::Matx33d::eye();   // world -> camera rotation
  cv::Vec3d T{0, 0, 0};                 // world -> camera translation (metres)
  cv::Size size{0, 0};                  // image width, height
  double reprojection_error = 0;        // RMS pixels, from calibration (0 if exact)

  cv::Vec3d Centre() const { return -(R.t() * T); }
  // Projects a world point to pixel coordinates (with distortion); z_cam receives the depth.
  cv::Point2d Project(const cv::Vec3d& world, double* z_cam = nullptr) const;
  // The same camera in the renderer's terms (world_from_camera, distortion).
  render::Camera ToRenderCamera() const;
  Status Validate() const;
};

struct Brick {
  int id = 0;
  int left = -1, right = -1, colour = -1;  // indices into Calibration::cameras
};

struct Calibration {
  std::vector<CameraModel> cameras;
  std::vector<Brick> bricks;  // empty for depth recordings

  // sigma_C of eq. 5.8: the mean reprojection error over the cameras.
  double SigmaC() const;
  int Find(const std::string& name) const;  // index or -1
  Status Validate() const;
};

Result<Calibration> LoadCalibration(const std::string& path);

// Checkerboard calibration (4.3) of one camera, or of a stereo pair when `right` is given:
// OpenCV calibrateCamera per camera, then stereoCalibrate with the intrinsics fixed. The left
// camera defines the world (R = I, T = 0). Images where the board is not found in both views
// are left out and listed in `skipped`; fewer than 3 usable views is an error.
struct CheckerboardOptions {
  cv::Size pattern{9, 6};  // inner corners per row, per column
  double square = 0.025;   // metres
  std::string left_name = "left", right_name = "right";
};
struct CheckerboardResult {
  Calibration calibration;  // one or two cameras
  double left_rms = 0, right_rms = 0, stereo_rms = 0;  // pixels
  std::vector<std::string> used, skipped;
};
Result<CheckerboardResult> CalibrateCheckerboard(const std::vector<std::string>& left,
                                                 const std::vector<std::string>& right,
                                                 const CheckerboardOptions& options);
Status SaveCalibration(const Calibration& calibration, const std::string& path);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_CALIBRATION_H_
