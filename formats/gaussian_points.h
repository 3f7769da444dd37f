// A Gaussian-splat cloud (formats/gaussians.h) as hvdb points with their Gaussian records
// (storage/gaussian_column.h), and back: what `hvdb import` and `hvdb export --codec
// 3dgs|spz|splat` convert at the edge.
//
// A splat becomes a point at its position (the file's coordinates, unchanged) with the
// covariance its scales and rotation imply (R S S^T R^T, in double) and the colour of its
// degree-0 term (0.5 + C0 f_dc, clamped, rounded to 8 bits: what plain-point renderers and the
// page's points draw); its record keeps every stored value bit for bit. Back, the position is
// the point's (edits move it) and the rest the record's, so an unedited round trip gives the
// cloud it came from.
#ifndef HVDB_FORMATS_GAUSSIAN_POINTS_H_
#define HVDB_FORMATS_GAUSSIAN_POINTS_H_

#include <span>
#include <vector>

#include "formats/gaussians.h"
#include "storage/gaussian_column.h"
#include "storage/point.h"

namespace hvdb::formats {

// The points (ids 0, frame `frame`) and records of `cloud`. REQUIRES: a valid cloud.
void CloudToPoints(const GaussianCloud& cloud, uint32_t frame, std::vector<Point>* points,
                   GaussianColumns* records);
// The cloud of `points` and their records (same order). REQUIRES: records.size() == points.size().
GaussianCloud PointsToCloud(std::span<const Point> points, const GaussianColumns& records);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_GAUSSIAN_POINTS_H_
