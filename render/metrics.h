// The measures used to compare renderings with each other and with photos, as 8-bit images
// (formats/image_io.h): PSNR and SSIM over an optional mask. Used by the tests, the benchmark
// and (later) ingest's photo-consistency step.
#ifndef HVDB_RENDER_METRICS_H_
#define HVDB_RENDER_METRICS_H_

#include <cstdint>
#include <string>
#include <vector>

#include "formats/image_io.h"
#include "render/renderer.h"

namespace hvdb::render {

// 8-bit sRGB pixels (formats/image_io.h: ToSrgb8 makes them of a rendered image, ReadSrgb8 of
// a PNG or JPEG file).
using formats::Srgb8Image;

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
