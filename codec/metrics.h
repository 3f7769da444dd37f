// Quality of a coded point set against the original, with the thesis's metrics (7.5): PSNR of
// positions (Euclidean error, peak = the bounding-box diagonal), of colours per Y, U and V
// channel (peak 255), and of normals (angle, peak 180 degrees). Coders reorder points (ours
// by the hierarchy, Draco by its k-d tree), so samples are matched to their nearest
// neighbour, in both directions, and the worse direction counts (MPEG's D1 convention).
#ifndef HVDB_CODEC_METRICS_H_
#define HVDB_CODEC_METRICS_H_

#include <span>

#include "storage/point.h"

namespace hvdb::codec {

struct Quality {
  double position_psnr = 0;  // dB; +inf when identical
  double position_rmse = 0;  // in the points' units
  double y_psnr = 0, u_psnr = 0, v_psnr = 0;
  double normal_psnr = 0;
  double normal_rmse_degrees = 0;
};

Quality Compare(std::span<const Point> original, std::span<const Point> decoded);

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_METRICS_H_
