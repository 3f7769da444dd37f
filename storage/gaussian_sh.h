// The spherical harmonics and rotations of 3D Gaussian splats, shared by the splat files'
// transforms (formats/gaussian_transform.h), edits of Gaussian-splat datasets (a transform
// transaction turns each splat's covariance and SH) and the renderers (the basis constants).
//
// The basis is the one the 3DGS reference evaluates (auxiliary.h's SH_C0..SH_C3, signs
// included, coefficients m = -l..l as the Inria PLY stores them), so a rotation computed here
// agrees with every renderer by construction.
#ifndef HVDB_STORAGE_GAUSSIAN_SH_H_
#define HVDB_STORAGE_GAUSSIAN_SH_H_

#include <array>
#include <vector>

namespace hvdb {

// The degree-0 basis constant, 1 / (2 sqrt(pi)): a splat's base colour is 0.5 + kShC0 * f_dc
// per channel (before clamping to 0..1).
inline constexpr double kShC0 = 0.28209479177387814;
// The basis constants of degrees 1-3 (SH_C1, SH_C2, SH_C3 of the reference), signs included.
inline constexpr double kShC1 = 0.4886025119029199;
inline constexpr double kShC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                                    -1.0925484305920792, 0.5462742152960396};
inline constexpr double kShC3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                                    0.3731763325901154,  -0.4570457994644658, 1.445305721320277,
                                    -0.5900435899266435};

using Mat3d = std::array<double, 9>;  // row-major

// The 2l + 1 basis functions of degree l (1..3) at the direction (x, y, z).
void ShBasis(int l, double x, double y, double z, double* out);

// The matrix taking a degree-l coefficient vector (2l+1 values of one channel) to that of the
// function turned by the orthogonal matrix `r`: c' = M c with f'(d) = f(r^T d). l is 1..3;
// row-major. A mirror (det -1) works as well as a rotation: each degree's functions are
// polynomials of that degree, closed under every orthogonal map. Exact to double rounding.
std::vector<double> ShRotationMatrix(int l, const Mat3d& r);

// The colour term of one channel's SH degrees 1..degree at a unit direction d: the sum of its
// coefficients (`rest`, (degree + 1)^2 - 1 of them) times the basis.
double EvalShRest(int degree, const float* rest, const std::array<double, 3>& d);

// The unit quaternion (w x y z) of a proper rotation matrix, in 3DGS's convention
// (build_rotation: the matrix of a normalised q).
std::array<double, 4> QuaternionOf(const Mat3d& r);

// The rotation matrix of quaternion q (w x y z), normalised first (the identity if q is zero).
Mat3d RotationOf(const std::array<double, 4>& q);

// The Hamilton product a * b (w x y z).
std::array<double, 4> QuaternionProduct(const std::array<double, 4>& a,
                                        const std::array<double, 4>& b);

Mat3d Mul3(const Mat3d& a, const Mat3d& b);
double Det3(const Mat3d& a);

// Eigen-decomposition of a symmetric 3x3 matrix by Jacobi rotations: eigenvalues in `values`,
// eigenvectors the columns of `vectors` (orthonormal, det +1).
void SymmetricEigen3(const Mat3d& a, std::array<double, 3>* values, Mat3d* vectors);

}  // namespace hvdb

#endif  // HVDB_STORAGE_GAUSSIAN_SH_H_
