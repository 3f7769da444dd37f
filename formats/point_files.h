// Compressed point files: hvdb7 streams (codec/, docs/CODEC.md) and Draco files, next to the
// PLY/CSV of formats/ply.h. Library hvdb_point_files: above codec/ and protocol/ (whose Draco
// coding it uses), unlike the rest of formats/.
#ifndef HVDB_FORMATS_POINT_FILES_H_
#define HVDB_FORMATS_POINT_FILES_H_

#include <memory>
#include <string>
#include <vector>

#include "codec/codec.h"
#include "formats/ply.h"

namespace hvdb::formats {

enum class FileCodec { kRaw, kHvdb7, kDraco };
// "raw", "hvdb7", "draco" -> FileCodec (InvalidArgument naming the choices otherwise).
Status ParseFileCodec(const std::string& name, FileCodec* out);

// A writer that collects a query's points and codes them into one file at Finish (a stream
// needs the whole point set: the hierarchy pairs points across batches). The file appears
// whole or not at all (temporary name, then rename).
Result<std::unique_ptr<PointWriter>> OpenCompressedWriter(
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

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_POINT_FILES_H_
