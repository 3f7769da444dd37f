// Image files: 8-bit sRGB PNG (and JPEG input) through image_codec.h (libpng, libjpeg), and
// OpenEXR with float colour, alpha and depth. The image types are what render/ draws into and its metrics
// compare (render/renderer.h and render/metrics.h use them under their own names); they live
// here, below render/, so that reading and writing images needs no renderer.
//
// Like the storage API, nothing here throws: errors come back as Status / Result<T>.
#ifndef HVDB_FORMATS_IMAGE_IO_H_
#define HVDB_FORMATS_IMAGE_IO_H_

#include <cstdint>
#include <string>
#include <vector>

#include "storage/status.h"

namespace hvdb::formats {

// Per side: the largest image render/ draws and DecodeExr reads.
inline constexpr uint32_t kMaxImageSize = 4096;

// A rendered image, row-major from the top-left pixel.
struct Image {
  uint32_t width = 0, height = 0;
  // Linear RGBA, premultiplied: the splats over the background.
  std::vector<float> rgba;
  // Coverage of the splats alone, 0..1 (before the background).
  std::vector<float> coverage;
  // Camera-space z (m) of the nearest splat touching the pixel; +infinity where none does.
  std::vector<float> depth;

  size_t pixels() const { return size_t{width} * height; }
};

// Interleaved 8-bit sRGB pixels, row-major from the top-left: channels 1 (grey), 3 (RGB) or
// 4 (RGBA, straight alpha).
struct Srgb8Image {
  uint32_t width = 0, height = 0, channels = 3;
  std::vector<uint8_t> data;
};

// The sRGB transfer function and its inverse (IEC 61966-2-1).
float SrgbToLinear(float v);
float LinearToSrgb(float v);

// 8-bit sRGB PNG: RGB when every pixel is opaque, else RGBA with straight alpha.
Result<std::string> EncodePng(const Image& image);
Status WritePng(const Image& image, const std::string& path);
// OpenEXR with float channels R G B A (linear, premultiplied) and Z (depth, +inf where empty).
Result<std::string> EncodeExr(const Image& image);
Status WriteExr(const Image& image, const std::string& path);
// Reads what EncodeExr writes (R G B A, and Z where present); coverage is A. InvalidArgument
// for bytes that are not such an EXR.
Result<Image> DecodeExr(const std::string& bytes);
// By extension: ".png" or ".exr".
Status WriteImage(const Image& image, const std::string& path);

// The rendered image as it is written to PNG: RGB if every pixel is opaque, else RGBA.
Srgb8Image ToSrgb8(const Image& image);
// Reads PNG or JPEG (any 8-bit image OpenCV reads), colour channels in RGB order.
Result<Srgb8Image> ReadSrgb8(const std::string& path);
Status WriteSrgb8Png(const Srgb8Image& image, const std::string& path);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_IMAGE_IO_H_
