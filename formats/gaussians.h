// Gaussian-splat files: the ecosystem's four formats for 3D Gaussian splatting (3DGS) scenes,
// read from and written to bytes in memory.
//
//   3DGS PLY   the Inria reference code's PLY (binary_little_endian; ascii and big-endian read
//              too): every stored value as a float, bit for bit (gaussian_ply.cc)
//   .splat     antimatter15/splat's 32 bytes a splat: degree 0, colour and rotation in 8 bits
//              (gaussian_splat.cc)
//   SPZ        Niantic's quantised layout: versions 2 and 3 (gzip), 4 (zstd streams)
//              (gaussian_spz.cc)
//   GLB        binary glTF 2.0 with the KHR_gaussian_splatting extension (gaussian_glb.cc)
//
// A GaussianCloud keeps the values as 3DGS trainers store them, before activation: log scales,
// logit opacity, an unnormalised quaternion, SH coefficients. Its coordinate system is that of
// the PLY (x right, y down, z forward: what trainers write); the SPZ reader and writer convert to
// and from SPZ's own (x right, y up, z back), the GLB's to and from glTF's (x left, y up, z
// forward). docs/FORMAT.md ("Gaussian-splat files") gives each
// format byte by byte.
//
// Nothing here throws. A reader returns a whole cloud or an error (Status, from storage/status.h)
// whose message names the file and what is wrong: a truncated file, counts that disagree, a NaN
// or infinite value (with the splat and property), an unknown property. Declared counts are
// checked against the bytes before anything is allocated for them.
#ifndef HVDB_FORMATS_GAUSSIANS_H_
#define HVDB_FORMATS_GAUSSIANS_H_

#include <array>
#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

#include "storage/gaussian_sh.h"
#include "storage/status.h"

namespace hvdb::formats {

// The SH basis constants of the 3DGS reference (storage/gaussian_sh.h): a splat's base colour
// is 0.5 + kShC0 * f_dc per channel (before clamping to 0..1).
using ::hvdb::kShC0;
using ::hvdb::kShC1;
using ::hvdb::kShC2;
using ::hvdb::kShC3;

// Spherical-harmonic degrees a cloud may have.
inline constexpr int kMaxShDegree = 3;

// SH coefficients per colour channel beyond the DC term: (d + 1)^2 - 1, i.e. 0, 3, 8 or 15.
constexpr int ShRestPerChannel(int degree) { return (degree + 1) * (degree + 1) - 1; }

// A Gaussian-splat scene: n splats, attributes in separate arrays (structure of arrays).
struct GaussianCloud {
  int sh_degree = 0;         // 0..3
  bool antialiased = false;  // trained with Mip-Splatting's 3D filter (SPZ's flag 0x1; the
                             // PLY and .splat have no place for it)
  std::vector<float> position;  // 3n: x y z
  std::vector<float> scale;     // 3n: log scales, as 3DGS stores them (activation: exp)
  std::vector<float> rotation;  // 4n: quaternion w x y z as stored, not normalised
  std::vector<float> opacity;   // n: logit (activation: Sigmoid)
  std::vector<float> sh_dc;     // 3n: f_dc_0..2, one per channel R G B
  // n * 3 * ShRestPerChannel(sh_degree): per splat channel-major, as the Inria PLY stores
  // f_rest_*: the R coefficients in order of degree and then order, then G, then B.
  std::vector<float> sh_rest;
  // Read only: properties of the file a reader passed over (a 3DGS PLY's extra vertex
  // properties, e.g. Mip-Splatting's filter_3D), which writing does not bring back.
  std::vector<std::string> ignored;

  size_t size() const { return opacity.size(); }
  size_t sh_rest_per_splat() const { return 3 * static_cast<size_t>(ShRestPerChannel(sh_degree)); }
  // Sets every array to the length n splats need (new values 0).
  void Resize(size_t n);
  // The covariance of splat i, R S S^T R^T with S = diag(exp(scale)) and R the rotation of the
  // normalised quaternion (the identity for a zero quaternion), as the upper triangle
  // xx xy xz yy yz zz. Computed in double. REQUIRES: i < size().
  std::array<float, 6> Covariance(size_t i) const;
};

// 1 / (1 + e^-x): opacity from its stored logit.
float Sigmoid(float x);
// log(p / (1 - p)), the inverse of Sigmoid; p is clamped to [1e-7, 1 - 1e-7] first.
float Logit(float p);

// OK when the arrays have the lengths size() and sh_degree ask for, sh_degree is 0..3 and every
// value is finite; else InvalidArgument naming `name` and the first offence (for a value: the
// splat and the PLY property name, e.g. "splat 12: opacity is nan").
Status ValidateGaussianCloud(const GaussianCloud& cloud, const std::string& name);

enum class GaussianFormat { k3dgsPly, kSpz, kSplat, kGlb, kUnknown };
// "3DGS PLY", "SPZ", ".splat", "GLB", "unknown"
const char* GaussianFormatName(GaussianFormat format);

// The format of a file by its content:
//   k3dgsPly  "ply" then a header (within its first 64 KiB) with the vertex properties f_dc_0,
//             opacity and rot_0 (a PLY of plain points is kUnknown)
//   kSpz      a gzip stream whose first four bytes inflate to "NGSP"; or "NGSP" itself (SPZ
//             version 4)
//   kGlb      the GLB magic "glTF" (whether it holds splats is ReadGlb's to say)
//   kSplat    none of those, a non-zero multiple of 32 bytes, and the first 1024 splats hold
//             finite positions and finite, non-negative scales (.splat has no magic)
GaussianFormat DetectGaussianFormat(std::string_view bytes);

// 3DGS PLY. Reading takes the vertex element's properties in any order, each a float:
// x y z, f_dc_0..2, f_rest_0..f_rest_{K-1} with K = 3 * ShRestPerChannel(d) (0, 9, 24 or 45),
// opacity, scale_0..2, rot_0..3, and optionally nx ny nz (ignored). Other scalar properties are
// read over and named in `ignored` (their values are not kept); list properties, other
// non-empty elements, or bytes after the vertex data are errors. Writing gives the Inria layout
// exactly: x y z nx ny nz f_dc_* f_rest_* opacity scale_* rot_*, normals 0, binary little-endian,
// so a file in that layout reads and writes back byte for byte.
Result<GaussianCloud> ReadGaussianPly(std::string_view bytes, const std::string& name);
Result<std::string> WriteGaussianPly(const GaussianCloud& cloud, const std::string& name);

// antimatter15 .splat: 32 bytes a splat (position and linear scale as float32, RGBA and the
// quaternion w x y z as uint8). Reading gives degree 0; writing drops sh_rest and keeps the
// cloud's splat order (the viewer sorts by size on its own).
Result<GaussianCloud> ReadSplat(std::string_view bytes, const std::string& name);
Result<std::string> WriteSplat(const GaussianCloud& cloud, const std::string& name);

// Niantic SPZ: versions 2 and 3 (one gzip stream) and 4 (a 32-byte header, a table of contents
// and one zstd stream per attribute). SPZ extensions (flag 0x2, which may change the coordinate
// system) and SH degree 4 are refused as unsupported.
struct SpzWriteOptions {
  // 2: rotation as x y z in 8 bits each; 3: "smallest three" in 32 bits; 4: as 3, zstd streams.
  // 3 is the default: every SPZ reader reads it (version 4 needs the 2025 reference or later).
  int version = 3;
  // Fixed-point fraction bits of positions (0..23; 12: 1/4096 units, +-2048 reach). Lowered, for
  // the whole file, as far as the farthest position needs to fit the 24 bits.
  int fractional_bits = 12;
};
Result<GaussianCloud> ReadSpz(std::string_view bytes, const std::string& name);
Result<std::string> WriteSpz(const GaussianCloud& cloud, const std::string& name,
                             const SpzWriteOptions& options = {});

// GLB (binary glTF 2.0) with KHR_gaussian_splatting. Reading takes every triangle-free POINTS
// primitive carrying the extension, in mesh order, and needs POSITION, the extension's ROTATION,
// SCALE, OPACITY and SH_DEGREE_0_COEF_0 (float, or the normalised/integer component types the
// extension allows) and whole SH degrees; a file without such a primitive, a node transform, an
// external or data: URI buffer or sparse accessors are errors. Values are converted to the
// cloud's conventions (log scale, logit opacity, w x y z, channel-major SH, x right y down z
// forward). Writing gives one primitive, float accessors, COLOR_0 as the extension's fallback.
Result<GaussianCloud> ReadGlb(std::string_view bytes, const std::string& name);
Result<std::string> WriteGlb(const GaussianCloud& cloud, const std::string& name);

// DetectGaussianFormat, then that format's reader; InvalidArgument for kUnknown.
Result<GaussianCloud> ReadGaussians(std::string_view bytes, const std::string& name);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_GAUSSIANS_H_
