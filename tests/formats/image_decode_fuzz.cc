// libFuzzer target for formats/image_decode.h (PNG and JPEG through libpng/libjpeg, PGM/PPM by
// our own parser): any bytes must give an image or an error, never a crash, a hang or an
// allocation beyond the size limit. The first byte picks colour or grey output. scripts/test.sh
// runs it on tests/formats/image_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>

#include "formats/image_decode.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  auto image = hvdb::formats::DecodeImage(bytes, "fuzz", (data[0] & 1) != 0);
  if (image.ok() && (image->empty() || image->depth() != CV_8U)) __builtin_trap();
  return 0;
}
