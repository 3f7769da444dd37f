// libFuzzer target for formats/image_codec.h (PNG and JPEG through libpng/libjpeg, PGM/PPM by
// our own parser): any bytes must give a picture or an error, never a crash, a hang or an
// allocation beyond the size limit. The first byte picks colour, grey or as-stored output, and
// a decoded picture is encoded back to PNG. scripts/test.sh runs it on
// tests/formats/image_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>

#include "formats/image_codec.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  using hvdb::formats::ImageMode;
  const ImageMode modes[] = {ImageMode::kColour, ImageMode::kGrey, ImageMode::kAsStored};
  const ImageMode mode = modes[data[0] % 3];
  const std::string bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  auto image = hvdb::formats::DecodeImage(bytes, "fuzz", mode);
  if (!image.ok()) return 0;
  if (image->empty() || (mode != ImageMode::kAsStored && image->depth() != CV_8U)) __builtin_trap();
  if (!hvdb::formats::EncodePngImage(*image).ok()) __builtin_trap();
  return 0;
}
