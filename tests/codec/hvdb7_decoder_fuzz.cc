// libFuzzer target for the hvdb7 decoder (codec/, docs/CODEC.md): any bytes, decoded whole and
// as a progressive prefix, and (when the fuzzer sets the first byte's low bit) as a temporal
// stream against a small fixed reference. It must return an error or points, never crash, hang
// or allocate without bound (the point limit is checked before anything is allocated).
// scripts/test.sh runs it on tests/codec/fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <vector>

#include "codec/codec.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  if (size == 0) return 0;
  static const codec::Reference* ref = [] {
    auto* r = new codec::Reference;
    for (int i = 0; i < 64; ++i) {
      Point p;
      p.x = static_cast<float>(i % 4);
      p.y = static_cast<float>(i / 4 % 4);
      p.z = static_cast<float>(i / 16);
      p.r = static_cast<uint8_t>(i * 4);
      r->points.push_back(p);
    }
    return r;
  }();
  std::string_view s(reinterpret_cast<const char*>(data + 1), size - 1);
  codec::DecodeOptions o;
  o.max_points = 1 << 16;
  if (data[0] & 1) o.reference = ref;
  std::vector<Point> out;
  (void)codec::Decode(s, &out, o);
  o.max_bytes = data[0] * 16 + 1;
  (void)codec::Decode(s, &out, o);
  codec::StreamInfo info;
  (void)codec::ReadInfo(s, &info);
  return 0;
}
