// PNG, JPEG and binary PNM pictures read, and PNG written, with libpng and libjpeg(-turbo)
// directly: the one picture codec of every path a user's command or the server takes (hvdb,
// hvdb-server, the Python module, `hvdb-ingest stereo`). OpenCV's imgcodecs would bring about
// 120 more shared libraries (GDAL and the formats it reads) into each such process, and the
// dynamic loader's work on them was most of a command's start (bench/README.md, "Lean
// binaries"). Pictures are OpenCV Mats in OpenCV's channel order (BGR), since the renderers and
// ingest process them with OpenCV's core and imgproc.
#ifndef HVDB_FORMATS_IMAGE_CODEC_H_
#define HVDB_FORMATS_IMAGE_CODEC_H_

#include <opencv2/core/mat.hpp>
#include <string>
#include <string_view>

#include "storage/status.h"

namespace hvdb::formats {

// What a decoded picture holds, as imread's flags: kColour 8-bit BGR (alpha dropped, grey
// replicated, 16-bit samples their high byte), kGrey 8-bit grey (BGR's cvtColor: within a
// level of imread's where a PNG has no gAMA or sRGB chunk), kAsStored the file's own depth (8
// or 16 bits) and channels (grey, BGR or BGRA; palettes expanded, grey with alpha and colour
// with transparency chunks as BGRA). JPEGs are turned upright by their EXIF orientation, and
// CMYK ones converted, except as stored (as imread).
enum class ImageMode { kColour, kGrey, kAsStored };

// Decodes PNG (any colour type), baseline or progressive JPEG (grey, YCbCr, RGB, CMYK) and binary
// PGM/PPM (P5/P6, maxval <= 255), told apart by content. At most 16384 pixels a side.
// InvalidArgument naming `what` for anything else, truncated files included.
Result<cv::Mat> DecodeImage(std::string_view bytes, const std::string& what, ImageMode mode);
// The same for a file; NotFound for a missing one.
Result<cv::Mat> ReadImageFile(const std::string& path, ImageMode mode);

// A PNG of `m`: 8- or 16-bit samples, 1 (grey), 3 (BGR) or 4 (BGRA) channels, or RGB(A) with
// `rgb_order`. zlib level 1 with run-length matching by default, as OpenCV's imencode, which is
// fast for rendered and decoded frames.
Result<std::string> EncodePngImage(const cv::Mat& m, bool rgb_order = false, int zlib_level = 1);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_IMAGE_CODEC_H_
