// The Gaussian column of a Gaussian-splat dataset (DatasetInfo::gaussians): what a 3D Gaussian
// splat holds beyond the 64-byte point record, kept as 3DGS trainers store it (log scales, a
// logit opacity, the quaternion as given, spherical-harmonic coefficients), so that a splat file
// that goes in comes out bit for bit.
//
// Out of core, in immutable segment files DIR/<dataset>/gaussians/<first id>.gsc
// (docs/FORMAT.md "Gaussian column segment"): the records of a run of consecutive point ids, in
// id order, with a CRC-32C per block of records. Keyed by point id, not by tree position, the
// column is untouched by everything that moves records (merges, the cold tier, transforms in
// time, deletes and their undo); a segment is made durable before the points it describes
// are (Dataset::BulkLoadGaussians), and recovery deletes a segment whose ids were never issued.
#ifndef HVDB_STORAGE_GAUSSIAN_COLUMN_H_
#define HVDB_STORAGE_GAUSSIAN_COLUMN_H_

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <cstddef>
#include <string>
#include <vector>

#include "storage/env.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb {

inline constexpr int kMaxGaussianShDegree = 3;

// Floats of one record at SH degree d: opacity, scale[3], rotation[4] (w x y z), dc[3], then
// 3 * ((d + 1)^2 - 1) rest coefficients channel-major (R's, then G's, then B's), as the 3DGS PLY.
constexpr size_t GaussianRecordFloats(int degree) {
  return 11 + 3 * static_cast<size_t>((degree + 1) * (degree + 1) - 1);
}
// Offsets into a record.
enum GaussianField : size_t {
  kGsOpacity = 0, kGsScale = 1, kGsRotation = 4, kGsDc = 8, kGsRest = 11
};

// Records of n splats, structure of records: values[i * stride() ...].
struct GaussianColumns {
  int sh_degree = 0;
  bool antialiased = false;  // SPZ's flag: trained with Mip-Splatting's 3D filter
  std::vector<float> values;

  size_t stride() const { return GaussianRecordFloats(sh_degree); }
  size_t size() const { return values.size() / stride(); }
  float* record(size_t i) { return values.data() + i * stride(); }
  const float* record(size_t i) const { return values.data() + i * stride(); }
};

// Copies a record of SH degree `from` into one of degree `to` >= from: the fields before the
// rest coefficients as they are, each channel's rest run to its place (they are channel-major),
// the higher-degree coefficients zero. The one rule for reading records at a higher degree.
void WidenRecord(const float* src, int from, float* dst, int to);

// A point's Gaussian when it has no stored record (inserted by an edit, or into a dataset made
// without them): scales and rotation from the eigenvectors of its covariance, opacity
// Logit(0.99), SH degree 0 from its colour. Writes GaussianRecordFloats(0) floats at rec.
void DeriveGaussian(const Point& p, float* rec);

// Fills the records of the points whose found[i] is false with DeriveGaussian's (the rest of a
// higher-degree record zero); returns how many.
uint64_t DeriveMissing(std::span<const Point> points, const std::vector<bool>& found,
                       GaussianColumns* cols);

// The covariance upper triangle (xx xy xz yy yz zz) that record rec implies: R S S^T R^T with
// S = diag(exp(scale)) and R of the normalised quaternion (identity if it is zero), in double.
std::array<float, 6> GaussianCovariance(const float* rec);

// What a linear map of space x -> A x (the spatial block of an edit's transform) does to a
// splat's record: its covariance becomes A Sigma A^T and its view-dependent colour turns with
// the map, so that the colour seen along A d afterwards is the one seen along d before.
//  - A = k Q with Q a rotation (a similarity): the quaternion is left-multiplied by Q's (its
//    stored length kept), the log scales raised by ln k, the SH turned by Q, exactly.
//  - A = k Q with Q a mirror: the same with the mirrored frame's first axis flipped back (a
//    quaternion holds no mirror; the covariance is the same), the SH mirrored, exactly.
//  - any other A (a shear, an unequal scale): scales and rotation from the eigen-decomposition
//    of A Sigma A^T, the SH turned by A's nearest orthogonal map (its polar factor): a shear
//    bends directions unequally, which no SH of degree <= 3 can follow exactly.
// Opacity and the DC colour never change.
class GaussianRecordMap {
 public:
  // `a` row-major, invertible (checked by the caller: storage/affine.h).
  explicit GaussianRecordMap(const std::array<double, 9>& a);
  // Rewrites the record (GaussianRecordFloats(degree) floats); false if a value would not be
  // finite (the record is then unchanged).
  bool Apply(int degree, float* rec) const;
  // True when A is the identity: records are kept as they are.
  bool identity() const { return identity_; }

 private:
  std::array<double, 9> a_;
  bool identity_ = false, similarity_ = false, mirror_ = false;
  double log_scale_ = 0;
  std::array<double, 4> q_{};            // the rotation's quaternion (similarity, no mirror)
  std::array<double, 9> orthogonal_{};   // Q, or A's polar factor
  std::vector<double> sh_[kMaxGaussianShDegree + 1];  // per degree 1..3, row-major
};

// InvalidArgument naming the splat and value if a record is not finite or the degree is not
// 0..3, or the values' length is not a multiple of the stride.
Status ValidateGaussianColumns(const GaussianColumns& cols);

class GaussianColumn {
 public:
  // Opens DIR/gaussians (created if absent, for a writer). A writer removes temporary files and
  // segments whose first id is >= next_id (written for points whose load never committed). A
  // damaged segment does not fail the open: its ids read as without a record, and Verify names
  // it.
  static Result<std::unique_ptr<GaussianColumn>> Open(Env* env, const std::string& dataset_dir,
                                                      bool writer, uint64_t next_id);
  // A follower's reload: picks up segments the writer added, forgets those it removed.
  Status Refresh();
  // Becoming the writer (a promotion): as Open does for a writer.
  Status Recover(uint64_t next_id);

  // Writes the segment of ids [first_id, first_id + cols.size()) durably (temporary file,
  // sync, rename, directory sync). The caller issued those ids and loads their points after.
  Status Write(uint64_t first_id, const GaussianColumns& cols);
  // Removes the segment starting at first_id (its points' load failed).
  Status Remove(uint64_t first_id);

  // The records of `ids` at the highest degree among them (lower ones padded with zeros),
  // in the order given; found[i] false where an id has no record (its values are zero).
  // Corruption names the segment and block on a checksum mismatch; LimitExceeded when the ids
  // would need more than max_blocks blocks read (each is read whole, checked, once).
  Status Read(std::span<const uint64_t> ids, GaussianColumns* out, std::vector<bool>* found,
              size_t max_blocks = SIZE_MAX);

  struct Totals {
    uint64_t segments = 0, records = 0, bytes = 0;
  };
  Totals totals() const;
  // Every block's checksum; one line per problem.
  std::vector<std::string> Verify() const;

 private:
  struct Segment;
  GaussianColumn(Env* env, std::string dir) : env_(env), dir_(std::move(dir)) {}
  Result<std::shared_ptr<const Segment>> OpenSegment(const std::string& name);

  Env* const env_;
  const std::string dir_;
  mutable std::mutex mu_;
  std::map<uint64_t, std::shared_ptr<const Segment>> segments_;  // by first id
  std::vector<std::string> problems_;  // segments not used (damaged, overlapping)
  std::atomic<bool> writer_{false};    // knows every segment: no refresh on an unknown id
};

}  // namespace hvdb

#endif  // HVDB_STORAGE_GAUSSIAN_COLUMN_H_
