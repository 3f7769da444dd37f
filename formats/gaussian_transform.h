// Moving a Gaussian-splat cloud (formats/gaussians.h) rigidly, with a uniform scale: what
// `hvdb import --rotate/--units-scale` does to splat files, and the SH rotation an edit needs.
//
// A similarity p -> s R p + t maps each splat's mean the same way, its covariance to
// s^2 R Sigma R^T (the quaternion left-multiplied by R's, the log scales raised by ln s), and its
// view-dependent colour so that every direction keeps its colour: the colour seen along R d
// afterwards is the one seen along d before, f'(R d) = f(d). Per SH degree l the 2l + 1
// coefficients of each channel are multiplied by a (2l+1)x(2l+1) matrix, the rotation of the
// real spherical harmonics 3DGS evaluates (the reference's constants and signs).
#ifndef HVDB_FORMATS_GAUSSIAN_TRANSFORM_H_
#define HVDB_FORMATS_GAUSSIAN_TRANSFORM_H_

#include <array>
#include <string>
#include <vector>

#include "formats/gaussians.h"
#include "storage/gaussian_sh.h"
#include "storage/status.h"

namespace hvdb::formats {

// p -> scale * rotation * p + translation; rotation row-major, a proper rotation.
struct Similarity {
  std::array<double, 9> rotation = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  double scale = 1;
  std::array<double, 3> translation = {0, 0, 0};

  // Rotations about x, then y, then z, in degrees (splat-transform's -r x,y,z).
  static Similarity FromEulerDegrees(double x, double y, double z);
  bool IsIdentity() const;
};

// The SH rotation and evaluation (storage/gaussian_sh.h), for the callers of this header.
using ::hvdb::EvalShRest;
using ::hvdb::ShRotationMatrix;

// Applies `m` to every splat of `cloud`. InvalidArgument, naming `name`, when the rotation is not
// a proper rotation (orthonormal within 1e-6, determinant +1: a mirror would need the SH's
// reflection and a quaternion cannot hold it), the scale is not finite and positive, or a
// result is not finite (a splat named); the cloud is then unchanged. The identity leaves every
// bit as it was; a pure translation or scale leaves the rotations and SH bit for bit.
Status TransformCloud(GaussianCloud* cloud, const Similarity& m, const std::string& name);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_GAUSSIAN_TRANSFORM_H_
