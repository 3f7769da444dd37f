// Compressed point files for the command line: hvdb7 streams (codec/, docs/CODEC.md) and Draco
// files, next to the PLY/CSV of client/ply.h.
#ifndef HVDB_CLIENT_POINT_FILES_H_
#define HVDB_CLIENT_POINT_FILES_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "client/ply.h"
#include "codec/codec.h"

namespace hvdb::client {

enum class FileCodec { kRaw, kHvdb7, kDraco };
// "raw", "hvdb7", "draco" -> FileCodec (InvalidArgument naming the choices otherwise).
Status ParseFileCodec(const std::string& name, FileCodec* out);

// A writer that collects a query's points and codes them into one file at Finish (a stream
// needs the whole point set: the hierarchy pairs points across batches). The file appears
// whole or not at all (temporary name, then rename).
Result<std::unique_ptr<ply::PointWriter>> OpenCompressedWriter(
    const std::string& path, FileCodec codec, const codec::EncodeOptions& options,
    const codec::Reference* reference = nullptr);

// True when the file starts like an hvdb7 stream.
bool IsHvdb7File(const std::string& path);

// True when the file starts like a Draco file ("DRACO").
bool IsDracoFile(const std::string& path);
// Reads a Draco file written by OpenCompressedWriter (hvdb export --codec draco).
Result<std::vector<Point>> ReadDracoFile(const std::string& path);

// Reads an hvdb7 stream into points (decoded against `reference` if it is temporal).
Result<std::vector<Point>> ReadHvdb7File(const std::string& path,
                                         const codec::Reference* reference = nullptr);

class Backend;

struct ExportOptions {
  FileCodec codec = FileCodec::kHvdb7;
  codec::EncodeOptions encode;  // hvdb7 (and Draco's qp)
  bool temporal = false;        // hvdb7: each frame coded against the decoded previous one
  uint32_t first = 0;
  uint32_t count = 0;           // 0: to the last frame
};

// Writes frames first.. of a dataset as DIR/NAME_FFFFFF.{hv7,drc,ply}, one file per frame;
// progress(done, total) after each. Returns the files written.
Result<std::vector<std::string>> ExportFrames(Backend& db, const std::string& name,
                                              const std::string& dir, const ExportOptions& o,
                                              const std::function<void(size_t, size_t)>& progress);

}  // namespace hvdb::client

#endif  // HVDB_CLIENT_POINT_FILES_H_
