// 8-bit images and the measures used to compare renderings with each other and with photos:
// PSNR and SSIM over an optional mask. Used by the tests, the benchmark and (later) ingest's
// photo-consistency step.
#ifndef HVDB_RENDER_METRICS_H_
#define HVDB_RENDER_METRICS_H_

#include <cstdint>
#include <string>
#include <vector>

#include "render/renderer.h"

namespace hvdb::render {

// Interleaved 8-bit sRGB pixels, row-major from the top-left: channels 1 (grey), 3 (RGB) or
// 4 (RGBA, straight alpha).
struct Srgb8Image {
  uint32_t width = 0, height = 0, channels = 3;
  std::vector<uint8_t> data;
};

// The rendered image as it is written to PNG: RGB if every pixel is opaque, else RGBA.
Srgb8Image ToSrgb8(const Image& image);
// Reads PNG or JPEG (any 8-bit image OpenCV reads), colour channels in RGB order.
Result<Srgb8Image> ReadSrgb8(const std::string& path);
Status WriteSrgb8Png(const Srgb8Image& image, const std::string& path);

// Peak signal-to-noise ratio (dB, peak 255) over the first three channels (the first for grey
// images) of the pixels where mask is non-zero (all pixels without a mask). Sizes must agree;
// +infinity for identical images, NaN when the mask is empty or the sizes differ.
double Psnr(const Srgb8Image& a, const Srgb8Image& b, const std::vector<uint8_t>* mask = nullptr);
// Mean structural similarity (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5,
// K1 = 0.01, K2 = 0.03) of the luma (BT.601) of both images, averaged over the mask's pixels.
double Ssim(const Srgb8Image& a, const Srgb8Image& b, const std::vector<uint8_t>* mask = nullptr);
// |a - b| per channel, amplified by `gain` and clamped: for looking at failures.
Srgb8Image AbsDiff(const Srgb8Image& a, const Srgb8Image& b, int gain = 4);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_METRICS_H_
