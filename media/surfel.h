// Helpers shared by the plane and mesh samplers (not part of the module's interface).
#ifndef HVDB_MEDIA_SURFEL_H_
#define HVDB_MEDIA_SURFEL_H_

#include <array>

#include "storage/point.h"

namespace hvdb::media {

using Vec3 = std::array<double, 3>;

// The surfel's covariance: sigma along the tangents t1, t2 (unit, orthogonal to n), 2% of it
// across (a thin disc, not a degenerate one), with the normal and both flags set.
void SetSurfel(Point& p, const Vec3& n, const Vec3& t1, const Vec3& t2, double sigma);

// Two unit tangents orthogonal to the unit vector n.
void Tangents(const Vec3& n, Vec3* t1, Vec3* t2);

// The footprint's standard deviation in sample spacings: 0.6 overlaps neighbours enough that a
// regular grid (and an area-uniform sample) renders closed.
inline constexpr double kSigmaPerSpacing = 0.6;

}  // namespace hvdb::media

#endif  // HVDB_MEDIA_SURFEL_H_
