// Recording files (docs/RECORDING.md) for the real data of ../shared/data, written by the
// benchmarks that ingest it (ingest-bench, view-bench).
#ifndef HVDB_BENCH_REAL_RECORDINGS_H_
#define HVDB_BENCH_REAL_RECORDINGS_H_

#include <string>
#include <vector>

#include "storage/status.h"

namespace hvdb::bench {

// Writes an OpenCV FileStorage YAML file (the header, then `text`).
void WriteYaml(const std::string& path, const std::string& text);
// One camera of a calibration.yml's `cameras:` list.
// dist: k1 k2 p1 p2 [k3] (empty: none).
std::string CameraYaml(const std::string& name, int w, int h, double fx, double fy, double cx,
                       double cy, const std::vector<double>& R, const std::vector<double>& T,
                       const std::vector<double>& dist = {});
extern const std::vector<double> kEye, kZero;

// The SJTU stage frame (`data`/sjtu-fvv-multiview-rgbd: 8 cameras of 10, 1920x1080, 8-bit
// inverse depth, model units of ~0.37 m) as a depth recording in `dir`; cameras are named
// cam<id>, in id order.
Status WriteSjtuRecording(const std::string& data, const std::string& dir);

// The CMU Panoptic sequence (`data`/cmu-panoptic-kinoptic-171026-pose3: fused point clouds in
// centimetres, frames 380-395) as a ply recording with its 10 Kinect colour cameras (1920x1080,
// with lens distortion), `frames` frames from 380.
Status WritePanopticRecording(const std::string& data, const std::string& dir, int frames);

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_REAL_RECORDINGS_H_
