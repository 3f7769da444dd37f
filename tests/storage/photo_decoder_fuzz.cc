// libFuzzer target for the photo file decoder (storage/photos.h, docs/FORMAT.md "Photo"): any
// bytes must give a photo or a Corruption, never a crash or an allocation beyond the input.
// When the first byte's low bit is set, the checksum of the rest is fixed up first, so that the
// fuzzer gets past it to the lengths and fields. scripts/test.sh runs it on
// tests/storage/photo_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/photos.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  if (size == 0) return 0;
  std::string file(reinterpret_cast<const char*>(data + 1), size - 1);
  if ((data[0] & 1) && file.size() >= 4) {
    uint8_t crc[4];
    EncodeLE<uint32_t>(crc, crc32c::Mask(crc32c::Value(file.data(), file.size() - 4)));
    file.replace(file.size() - 4, 4, reinterpret_cast<const char*>(crc), 4);
  }
  auto photo = DecodePhoto(file, "fuzz");
  if (photo.ok()) {
    // What decodes must encode back to the same bytes.
    if (EncodePhoto(*photo) != file) __builtin_trap();
  }
  return 0;
}
