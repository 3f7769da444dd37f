// Hyperslice geometry (thesis 8.2): selection by eq. 8.1, projection of positions by eq. 8.2
// and of covariances by eq. 8.3.
//
// Coordinates are X = (x, y, z, s t) with s the dataset's space/time scale. The hyperplane
// frame R_H = (V1, V2, V3, V4)^T has V1 = N; V2..V4 come from Gram-Schmidt over
// e_x, e_y, e_z, e_t (skipping the one most parallel to N), so a slice orthogonal to t
// projects (x, y, z, s t) to (x, y, z) and a slice with N = e_x projects to (y, z, s t).
#ifndef HVDB_STORAGE_HYPERSLICE_H_
#define HVDB_STORAGE_HYPERSLICE_H_

#include <array>

#include "storage/database.h"
#include "storage/kdtree_format.h"

namespace hvdb {

class SliceGeometry {
 public:
  // Validates the slice (finite values, non-zero normal, thickness >= 0, clip lo <= hi).
  static Result<SliceGeometry> Make(const Slice& slice, double space_time_scale);

  // Signed distance N . X - b of a point of frame time t.
  double Distance(float x, float y, float z, double t) const {
    return n_[0] * x + n_[1] * y + n_[2] * z + n_[3] * s_ * t - b_;
  }
  bool Selects(float x, float y, float z, double t) const {
    double d = Distance(x, y, z, t);
    return d <= db_ && d >= -db_;
  }
  // How the slab of frame time t relates to a 3D box.
  Relation Classify(const Box3& box, double t) const;
  // Range [t0, t1] of times at which the slab meets the box (t0 > t1: never);
  // unbounded (+-inf) when N is orthogonal to t and the box is met.
  std::pair<double, double> TimeRange(const Box3& box) const;
  // Projects the point in place: position by eq. 8.2, covariance by eq. 8.3 with
  // T4 = (0, 0, 0, dt). dt is the temporal extent of a sample in seconds.
  void Project(Point* p, double t, double dt) const;

  const std::array<double, 4>& normal() const { return n_; }
  const std::array<std::array<double, 4>, 3>& basis() const { return v_; }

 private:
  std::array<double, 4> n_{};
  double b_ = 0, db_ = 0, s_ = 1;
  std::array<std::array<double, 4>, 3> v_{};  // V2, V3, V4
};

// Relation of a box to a window's spatial part.
Relation ClassifyWindow(const Window& w, const Box3& box);
bool WindowContains(const Window& w, float x, float y, float z);
Status ValidateWindow(const Window& w);

}  // namespace hvdb

#endif  // HVDB_STORAGE_HYPERSLICE_H_
