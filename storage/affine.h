// Applying a 4D affine map (database.h, Affine4) to a point: position and time by X' = A X + c,
// the frame from the new time, the covariance by the spatial block S (S V S^T) and the normal by
// S^-T. Used by transform transactions and by the editing operators (paste, compositing).
#ifndef HVDB_STORAGE_AFFINE_H_
#define HVDB_STORAGE_AFFINE_H_

#include "storage/database.h"

namespace hvdb {

class AffineMap {
 public:
  // Checks the map (finite, spatial block not singular).
  static Result<AffineMap> Make(const Affine4& map, double fps);
  // The transformed point; InvalidArgument when it would leave the video (t < 0) or go
  // non-finite. The id is kept.
  Result<Point> Apply(const Point& p) const;

 private:
  Affine4 m_;
  double fps_ = 30;
  double s_[3][3] = {};
  double cof_[3][3] = {};  // cofactors: det(S) S^-T
  double det_ = 1;
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_AFFINE_H_
