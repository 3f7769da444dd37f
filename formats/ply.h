// PLY (and CSV) input/output of hvdb points.
//
// Reads the three PLY encodings (ascii, binary_little_endian, binary_big_endian) with the usual
// vertex properties (x y z, nx ny nz, red green blue [alpha]) plus hvdb's own (id_lo id_hi
// frame cov_xx..cov_zz label camera flags); other elements such as an empty `face` element are
// parsed and skipped. Writes binary little-endian (or ascii) PLY with every hvdb property, so a
// write followed by a read gives back each Point bit for bit.
//
// Like the storage API, nothing here throws: errors come back as Status / Result<T>, with a
// message that names the file and the problem. Reading is ply_read.cc, writing ply_write.cc.
#ifndef HVDB_FORMATS_PLY_H_
#define HVDB_FORMATS_PLY_H_

#include <array>
#include <cstdint>
#include <cstdio>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "storage/gaussian_column.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::formats {

// How ReadPly reads a file.
struct ReadOptions {
  // Multiplies positions (0.01: the file is in centimetres); covariances scale by scale^2.
  double scale = 1.0;
  // Frame given to points when the file has no `frame` property (or always, if force_frame).
  uint32_t frame = 0;
  bool force_frame = false;
  // Points without cov_* properties get the isotropic covariance sigma^2 I (sigma in metres,
  // after scaling). Estimating it from the nearest-neighbour spacing would cost a k-d tree
  // per file, so a fixed value is used; 0.005 m is about the spacing of a Kinect fusion cloud.
  double default_sigma = 0.005;
  // A vertex with a NaN or infinite x, y or z (a hole of an organised cloud, a broken exporter;
  // also a value beyond float range once scaled) makes the read fail, so that points never go
  // missing unnoticed. true: such vertices are left out, counted in ReadStats.
  bool skip_invalid = false;
};

// What a read found besides the points it returns.
struct ReadStats {
  uint64_t vertices = 0;            // in the file's vertex element
  uint64_t skipped_non_finite = 0;  // left out by ReadOptions::skip_invalid
};

// Reads the `vertex` element of a PLY file. Properties recognised (any PLY scalar type):
//   x y z                      position (required), times ReadOptions::scale
//   nx ny nz                   normal: sets Point::normal_oct and kFlagHasNormal (if non-zero)
//   red green blue (r g b)     colour: 8-bit integers as they are, floats as 0..1
//   id_lo id_hi (or id)        the point id (0: the engine assigns one on insert)
//   frame label camera flags   hvdb fields; `flags`, when present, is taken as written
//   cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz   covariance in m^2 (sets kFlagHasCovariance)
// Anything else (alpha, quality, list properties, other elements) is read and ignored.
// A vertex with a non-finite coordinate is InvalidArgument naming the file, the first such
// vertex and how many there are, unless opts.skip_invalid. stats (optional) is filled on success.
Result<std::vector<Point>> ReadPly(const std::string& path, const ReadOptions& opts = {},
                                   ReadStats* stats = nullptr);

// A sink for points, written batch by batch so a query result never has to fit in memory.
class PointWriter {
 public:
  virtual ~PointWriter() = default;
  virtual Status Append(std::span<const Point> pts) = 0;
  // A writer opened for Gaussian splats (CsvWriter with gaussians) takes each point's record
  // too, at SH degree 3 (records.size() == pts.size()); others write the points alone.
  virtual bool wants_gaussians() const { return false; }
  virtual Status AppendGaussians(std::span<const Point> pts, const GaussianColumns& records) {
    (void)records;
    return Append(pts);
  }
  // Completes the file; the writer accepts nothing afterwards.
  virtual Status Finish() = 0;
  uint64_t count() const { return count_; }

 protected:
  uint64_t count_ = 0;
};

// Streaming PLY writer. Properties, in order: x y z nx ny nz (float), red green blue (uchar),
// id_lo id_hi frame (uint), cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz (float), label (uint),
// camera (ushort), flags (uchar). The header is written with a placeholder vertex count that
// Finish() patches in place. A writer destroyed without Finish() leaves a file that claims
// zero vertices, so a partial export is never mistaken for a complete one.
class PlyWriter : public PointWriter {
 public:
  PlyWriter();
  ~PlyWriter() override;
  PlyWriter(const PlyWriter&) = delete;
  PlyWriter& operator=(const PlyWriter&) = delete;

  // ascii = false: binary_little_endian.
  Status Open(const std::string& path, bool ascii = false);
  Status Append(std::span<const Point> pts) override;
  Status Finish() override;

 private:
  Status Fail(const char* what);

  std::string path_;
  std::FILE* file_ = nullptr;
  bool ascii_ = false;
  int64_t count_offset_ = 0;  // where the patchable "element vertex" line starts
  std::vector<char> buf_;
};

// Streaming CSV writer: one header line, then one line per point with the columns
// id,frame,x,y,z,nx,ny,nz,red,green,blue,label,camera,flags,cov_xx,cov_xy,cov_xz,cov_yy,cov_yz,
// cov_zz (nx ny nz empty for points without a normal). Floats round-trip exactly. Opened with
// `gaussians` (the points of a Gaussian-splat dataset), each line goes on with the splat's
// record as the 3DGS PLY names and stores it: opacity (logit), scale_0..2 (logs), rot_0..3
// (w x y z as stored), f_dc_0..2, f_rest_0..44 (channel-major; degree 3, zeros above the
// splat's own degree).
class CsvWriter : public PointWriter {
 public:
  CsvWriter();
  ~CsvWriter() override;
  CsvWriter(const CsvWriter&) = delete;
  CsvWriter& operator=(const CsvWriter&) = delete;

  Status Open(const std::string& path, bool gaussians = false);
  Status Append(std::span<const Point> pts) override;
  bool wants_gaussians() const override { return gaussians_; }
  Status AppendGaussians(std::span<const Point> pts, const GaussianColumns& records) override;
  Status Finish() override;

 private:
  Status Write(std::span<const Point> pts, const GaussianColumns* records);

  std::string path_;
  std::FILE* file_ = nullptr;
  std::string buf_;
  bool gaussians_ = false;
};

// Picks the writer by extension: ".csv" (any case) gives CSV, ".ply" binary PLY (ascii PLY if
// ascii_ply); any other extension is InvalidArgument.
// gaussians: a CSV carries the points' Gaussian records (CsvWriter); a PLY ignores it (a
// splat file is `--codec 3dgs`).
Result<std::unique_ptr<PointWriter>> OpenPointWriter(const std::string& path,
                                                     bool ascii_ply = false,
                                                     bool gaussians = false);

// Whole-array conveniences over the writers above.
Status WritePly(const std::string& path, std::span<const Point> pts, bool ascii = false);
Status WriteCsv(const std::string& path, std::span<const Point> pts);

// Float values for a normal such that EncodeNormal() of them gives back `oct` exactly (on the
// octahedron's fold a zero component gets a tiny sign-carrying value). Used by the writers.
std::array<float, 3> NormalForOct(std::array<int16_t, 2> oct);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_PLY_H_
