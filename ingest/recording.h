// Recordings: what hvdb-ingest reads (docs/RECORDING.md has the format byte by byte).
//
// A recording is a directory with recording.yml (an OpenCV FileStorage YAML: the kind, the
// frames, and where each camera's files are, as path patterns) and, for the stereo and depth
// kinds, calibration.yml (ingest/calibration.h). Three kinds:
//   stereo  per brick two grey images under structured light and one colour image per frame
//   depth   per camera a colour image and a depth map (OpenEXR float metres, 16-bit PNG with a
//           scale, or 8-bit inverse depth between z_near and z_far), optionally a pose per frame
//   ply     one PLY point cloud per frame
// Path patterns are relative to the recording directory (or absolute) and may contain
// {frame} (the source frame number, optionally {frame:06d}-style zero padded) and {camera}.
//
// Loading a frame checks every file: missing or unreadable files, wrong image sizes, depth maps
// with NaN, point clouds with NaN or infinite coordinates, and images that do not match the
// calibration are errors naming the file.
#ifndef HVDB_INGEST_RECORDING_H_
#define HVDB_INGEST_RECORDING_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "ingest/calibration.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::ingest {

enum class RecordingKind { kStereo, kDepth, kPly };
enum class DepthEncoding { kExr, kPng16, kInverse8 };

struct CameraFiles {
  std::string camera;  // name in the calibration
  std::string colour, depth, pose;  // patterns; pose "" = the calibration's extrinsics
  std::string left, right;          // stereo: the brick's grey images (camera = the brick's colour camera)
};

struct Recording {
  std::string dir;
  RecordingKind kind = RecordingKind::kStereo;
  int frames = 0;            // frames in the recording (ingest frame i = source frame first + i*step)
  int first_frame = 0, frame_step = 1;
  double fps = 30;
  Calibration calibration;   // stereo, depth
  std::vector<CameraFiles> files;  // stereo: one per brick (same order as calibration.bricks)
  std::string ply;           // ply: pattern
  double ply_scale = 1.0;    // ply: positions multiplied by this (0.01: centimetres)
  DepthEncoding depth_encoding = DepthEncoding::kExr;
  double depth_scale = 0.001;          // png16: metres per unit
  std::vector<int> depth_invalid{0};   // png16/inverse8: raw values meaning "no depth"
  double z_near = 0, z_far = 0;        // inverse8: depth range
  double world_scale = 1.0;            // depth: positions multiplied by this (model units -> m)
  // stereo: the projector patterns change from frame to frame, so the spacetime matcher
  // (thesis 3.4) may match each frame together with `spacetime` frames on either side.
  int spacetime = 0;
  // stereo: the grey cameras see projected stripes (the rig of thesis 4.1; the default). The
  // subpixel stage then defaults to Levenberg-Marquardt, which pays on stripes (0.05 px);
  // without (natural texture) to the parabola, which scores as well there at 1/50 of the time.
  bool structured_light = true;

  int SourceFrame(int i) const { return first_frame + i * frame_step; }
  // The path of a pattern at ingest frame i for a camera.
  std::string Path(const std::string& pattern, int i, const std::string& camera = "") const;
};

Result<Recording> OpenRecording(const std::string& dir);
// Writes recording.yml (the calibration is saved separately with SaveCalibration).
Status SaveRecording(const Recording& recording);

// One frame's inputs, loaded and checked.
struct StereoView {
  int brick = 0;
  cv::Mat left, right;  // CV_8UC1
  cv::Mat colour;       // CV_8UC3 BGR
  std::string colour_path;  // the file it came from
};
struct DepthFrameView {
  int camera = 0;           // index into calibration.cameras
  CameraModel model;        // the calibration's camera, with this frame's pose when given
  cv::Mat colour;           // CV_8UC3 BGR
  std::string colour_path;  // the file it came from
  cv::Mat depth;            // CV_32F metres (0 = none)
};
struct FrameInput {
  int index = 0;
  std::vector<StereoView> stereo;
  std::vector<DepthFrameView> depth;
  std::vector<Point> points;  // ply
  uint64_t skipped_invalid = 0;  // ply: points left out for a NaN or infinite coordinate
  uint64_t bytes_read = 0;
};
// A ply frame with a NaN or infinite coordinate is an error naming the file, unless
// skip_invalid: then those points are left out and counted in FrameInput::skipped_invalid.
Result<FrameInput> LoadFrame(const Recording& recording, int index, bool skip_invalid = false);

// Reads a 4x4 row-major camera-to-world matrix (tolerant of tabs, CRLF and 3-digit exponents).
Result<cv::Matx44d> ReadPoseFile(const std::string& path);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_RECORDING_H_
