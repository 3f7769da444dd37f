// Synthetic structured-light stereo recordings with ground truth (thesis 3.4, 4.1-4.3).
//
// A ray-cast analytic scene seen by a rig of 3D video bricks: per brick two grey cameras, one
// colour camera and a projector throwing a random binary vertical stripe pattern. The recording
// is written in the layout of docs/RECORDING.md (recording.yml, calibration.yml,
// frames/NNNNNN/<camera>.png) plus ground truth (groundtruth/NNNNNN/<camera>.depth.exr and
// <camera>.object.png), so every ingest stage can be tested against exact geometry.
//
// Conventions
//   World: metres, right-handed, +y UP. The floor is the rectangle y = kFloorY, x in [-2, 2],
//   z in [kWallZ, 1.5]; the back wall the rectangle z = kWallZ (facing +z), x in [-2, 2],
//   y in [kFloorY, 1]. On the floor, within about 2 m around the origin: three textured spheres
//   and a floating 0.28 m box (kObjectMoving) that moves along +x at 0.4 m/s, bouncing between
//   x = -0.75 and 0.75 (linear over any run of frames shorter than the 3.75 s half period).
//   Bricks stand on an arc of radius 2.7 m on the +z side (spread 30 degrees apart, at most 140
//   in all), 0.4 m above the origin, all looking at (0, -0.2, 0). Per brick: left and right grey
//   cameras `baseline` apart along the brick's x axis, each turned by up to 0.4 degrees about
//   every axis (rectification is needed); the colour camera 7 cm above the middle; the projector
//   9 cm below it. Every camera has a 50 degree horizontal field of view, slightly different
//   intrinsics and, with `distortion`, k1 ~ -0.06, k2 ~ 0.02, |p1|, |p2| < 8e-4 (several pixels
//   at the corners); without it, five zero coefficients.
//   Cameras: OpenCV's (x right, y down, z forward), X_cam = R X_world + T; pixel centres are at
//   integer pixel coordinates (pixel (u, v) covers [u-0.5, u+0.5] x [v-0.5, v+0.5]).
//   Projectors: pinholes whose pixels are about two camera pixels wide, throwing binary vertical
//   stripes of random widths 1-4 projector pixels, different for every brick and frame.
//   Images: grey = luminance(albedo) x (0.12 ambient + 0.45 n.l for each projector that lights
//   the point, with a shadow test) + Gaussian noise; colour = 0.9 x albedo (uniform light, no
//   stripes) + the same noise per channel; 8 bits, clamped. Rays that hit nothing see black.
//   Ground truth (depth, object id) is taken along the ray through the exact pixel centre.
//   Calibration: the exact parameters the images were made with; reprojection_error is set to
//   the nominal kGeneratorReprojectionError (0.1 px: antialiasing and 8-bit quantisation, there
//   is no calibration error).
//   recording.yml's generator.seed is a decimal string (FileStorage integers are 32-bit).
//   Object ids: 0 none, 1 floor, 2 back wall, 3..5 static spheres, 6 the moving box.
//   Randomness: everything derives from the seed through counter-based hashes, so a recording
//   is bit-identical for a seed whatever the thread count.
#ifndef HVDB_INGEST_GENERATOR_H_
#define HVDB_INGEST_GENERATOR_H_

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ingest/calibration.h"
#include "storage/status.h"

namespace hvdb::ingest {

inline constexpr double kGeneratorReprojectionError = 0.1;  // pixels, see above
inline constexpr double kFloorY = -0.9;                     // metres
inline constexpr double kWallZ = -1.0;                      // metres
inline constexpr int kObjectNone = 0, kObjectFloor = 1, kObjectWall = 2, kObjectFirstSphere = 3,
                     kObjectMoving = 6;

struct GeneratorOptions {
  int bricks = 3;                 // bricks on an arc around the scene, all looking at the centre
  int width = 320, height = 240;  // every camera's image size
  int frames = 4;
  double fps = 10;
  uint64_t seed = 1;
  bool distortion = true;  // small radial/tangential distortion on every camera (ingest must undistort)
  int supersample = 3;     // per-axis rays per pixel (antialiasing: realistic subpixel behaviour)
  double noise_sigma = 1.0;  // grey-level Gaussian sensor noise (8-bit units)
  double baseline = 0.12;    // metres between a brick's two grey cameras
  // > 0: live capture for rehearsing `hvdb-ingest run --follow`: recording.yml and
  // calibration.yml first, then frame f's images no earlier than start + f / realtime_fps (later
  // when rendering is slower), every file written to a temporary name and renamed into place.
  double realtime_fps = 0;
  // bricks 1..16, width/height 16..4096, frames 1..100000, fps in (0, 1000], supersample 1..8,
  // noise_sigma in [0, 64], baseline in [0.01, 1] metres, realtime_fps in [0, 1000].
  Status Validate() const;
};

struct GeneratedRecording {
  Calibration calibration;
  int frames = 0;
  double fps = 0;
};

// Writes a complete stereo recording to out_dir (created; must be empty or absent) plus ground
// truth. Deterministic for a seed. `progress` (optional) gets (frames done, total).
Result<GeneratedRecording> GenerateRecording(const GeneratorOptions& options,
                                             const std::string& out_dir,
                                             const std::function<void(int, int)>& progress = {});

// The rig GenerateRecording uses (cameras "b<k>_left", "b<k>_right", "b<k>_colour", bricks
// listed), without rendering anything.
Calibration GeneratorCalibration(const GeneratorOptions& options);

// Ground-truth scene queries for tests: the analytic scene at a frame.
struct Ray {
  cv::Vec3d origin, dir;  // dir need not be unit; SceneHit::t is in units of |dir|
};
struct SceneHit {
  double t;
  cv::Vec3d position, normal;  // normal: unit, facing the ray's origin
  cv::Vec3b colour_bgr;        // albedo, 8-bit
  int object;                  // kObject*
};

class SyntheticScene {
 public:
  SyntheticScene(uint64_t seed, int frame, double fps);
  std::optional<SceneHit> Intersect(const Ray& ray) const;  // nearest hit with t > 1e-9
  // bounding box of the scene (metres) at this frame
  void Bounds(cv::Vec3d* lo, cv::Vec3d* hi) const;

  // Whether anything lies on the ray strictly between t_min and t_max (shadow rays).
  bool Occluded(const Ray& ray, double t_min, double t_max) const;
  // Albedo (BGR, 0..1) of `object` at a surface point.
  cv::Vec3d Albedo(int object, const cv::Vec3d& position) const;
  // Centre of the moving box at this frame.
  cv::Vec3d MovingCentre() const { return box_centre_; }

 private:
  struct Sphere {
    cv::Vec3d centre;
    double radius;
    cv::Vec3d colour_a, colour_b;  // the texture blends these
  };
  std::optional<SceneHit> Nearest(const Ray& ray, double t_min, double t_max, bool any) const;

  uint64_t texture_key_;
  std::vector<Sphere> spheres_;
  cv::Vec3d box_centre_, box_half_;
  cv::Vec3d box_colour_;
};

// The viewing ray through pixel (u, v) of a (distorted) camera: origin at the centre of
// projection, dir the unit ray in world coordinates. Inverts CameraModel::Project's
// distortion (k1 k2 p1 p2 k3) by Newton iteration to ~1e-12.
Ray CameraRay(const CameraModel& camera, cv::Point2d pixel);

// One-channel float32 EXR depth maps (channel "Z"; +inf allowed). ReadDepthExr returns CV_32F.
Result<cv::Mat> ReadDepthExr(const std::string& path);
Status WriteDepthExr(const std::string& path, const cv::Mat& depth_f32);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_GENERATOR_H_
