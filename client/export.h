// `hvdb export`: a dataset's frames written as point files (formats/point_files.h), one file a
// frame, read through a Backend (embedded or remote).
#ifndef HVDB_CLIENT_EXPORT_H_
#define HVDB_CLIENT_EXPORT_H_

#include <cstddef>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "codec/codec.h"
#include "formats/gaussians.h"
#include "formats/point_files.h"
#include "storage/status.h"

namespace hvdb::client {

class Backend;

struct ExportOptions {
  formats::FileCodec codec = formats::FileCodec::kHvdb7;
  codec::EncodeOptions encode;  // hvdb7 (and Draco's qp)
  bool temporal = false;        // hvdb7: each frame coded against the decoded previous one
  uint32_t first = 0;
  uint32_t count = 0;  // 0: to the last frame
  // Gaussian-splat files instead (k3dgsPly, kSpz, kSplat, kGlb): each frame's splats in load
  // order, with their Gaussian records (derived for points that have none).
  formats::GaussianFormat splats = formats::GaussianFormat::kUnknown;
  int spz_version = 3;  // kSpz: 2, 3 or 4 (formats::SpzWriteOptions)
};

// Points of a Gaussian-splat dataset `name` as one splat file of `format` (k3dgsPly, kSpz with
// `spz_version`, kSplat, kGlb), with their Gaussian records (read by id; derived for points that
// have none), in id order (*pts is sorted), written whole or not at all (temporary name, then
// rename). For `hvdb export` (a frame a file) and `hvdb window --codec 3dgs|...` (a crop).
Status WriteSplatFile(Backend& db, const std::string& name, const std::string& path,
                      formats::GaussianFormat format, int spz_version, std::vector<Point>* pts);

// Writes frames first.. of a dataset as DIR/NAME_FFFFFF.{hv7,drc,ply} (splats:
// .{ply,spz,splat,glb}), one file per frame, each whole or absent;
// progress(done, total) after each. Returns the files written.
Result<std::vector<std::string>> ExportFrames(Backend& db, const std::string& name,
                                              const std::string& dir, const ExportOptions& o,
                                              const std::function<void(size_t, size_t)>& progress);

}  // namespace hvdb::client

#endif  // HVDB_CLIENT_EXPORT_H_
