// Reading PNG, JPEG and binary PNM images with libpng and libjpeg directly, for the commands
// that must start fast (`hvdb-ingest stereo`): OpenCV's imgcodecs brings about 120 more shared
// libraries (GDAL and the formats it reads) into a process, and the dynamic loader's work on
// them is most of such a command's start (bench/README.md, "Bulk ingest at capture rate").
#ifndef HVDB_FORMATS_IMAGE_DECODE_H_
#define HVDB_FORMATS_IMAGE_DECODE_H_

#include <opencv2/core/mat.hpp>
#include <string>

#include "storage/status.h"

namespace hvdb::formats {

// The image at `path` as 8-bit BGR (colour) or grey: PNG (any colour type; 16-bit samples are
// scaled to 8 bits), baseline or progressive JPEG, binary PGM/PPM (P5/P6, maxval <= 255).
// NotFound for a missing file; InvalidArgument naming the file for anything else.
Result<cv::Mat> ReadImageFile(const std::string& path, bool colour);
// The same for the file's bytes; `what` names them in errors.
Result<cv::Mat> DecodeImage(const std::string& bytes, const std::string& what, bool colour);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_IMAGE_DECODE_H_
