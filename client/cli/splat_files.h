// `hvdb import` of Gaussian-splat files (formats/gaussians.h): telling them from point files,
// reading a frame of splats with its Gaussian records, and a directory as a sequence.
#ifndef HVDB_CLIENT_CLI_SPLAT_FILES_H_
#define HVDB_CLIENT_CLI_SPLAT_FILES_H_

#include <string>
#include <vector>

#include "formats/gaussian_transform.h"
#include "formats/gaussians.h"
#include "storage/gaussian_column.h"
#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::cli {

// The splat format a file's first 64 KiB show (a 3DGS PLY header, SPZ's magic, a GLB naming
// KHR_gaussian_splatting), else kUnknown (.splat files have no signature: a Gaussian dataset
// reads every file as splats).
formats::GaussianFormat SniffSplatFile(const std::string& path);

// The splats of a file in any of the four formats, moved by `move` (their SH rotated with them),
// as points of `frame` with their records; *ignored: the file's properties that were read over
// (GaussianCloud::ignored). Errors name the file.
Result<std::vector<Point>> ReadSplatFrame(const std::string& path, uint32_t frame,
                                          const formats::Similarity& move,
                                          GaussianColumns* records,
                                          std::vector<std::string>* ignored);

// The command line's files with each directory replaced by the regular files in it, sorted by
// name with digit runs compared as numbers (frame_2 before frame_10): a sequence.
Result<std::vector<std::string>> ExpandSequence(const std::vector<std::string>& args);

}  // namespace hvdb::cli

#endif  // HVDB_CLIENT_CLI_SPLAT_FILES_H_
