// libFuzzer target for the octree geometry decoder (codec/octree.h, docs/CODEC.md "Octree
// geometry") on its own, below the hvdb7 segment checksums that would stop most mutations:
// byte 0 = depth (mod 21, + 1) and, in its high bit, decode against a small fixed reference;
// bytes 1-2 = the point count (little-endian); the rest is the payload. It must return an
// error or exactly that many sorted cells, never crash, hang or allocate without bound.
// scripts/test.sh runs it on tests/codec/octree_fuzz_corpus.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string_view>
#include <vector>

#include "codec/octree.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb::codec;
  if (size < 3) return 0;
  static const std::vector<uint64_t> reference = [] {
    std::vector<uint64_t> r;
    for (uint32_t i = 0; i < 64; ++i) r.push_back(MortonCode(i % 4, i / 4 % 4, i / 16));
    std::sort(r.begin(), r.end());
    return r;
  }();
  const int depth = data[0] % 21 + 1;
  const bool temporal = data[0] & 0x80;
  const uint64_t points = data[1] | uint64_t{data[2]} << 8;
  std::string_view payload(reinterpret_cast<const char*>(data + 3), size - 3);
  std::vector<uint64_t> cells;
  for (int threads : {1, 2}) {
    if (DecodeOctree(payload, depth, points, temporal ? &reference : nullptr, threads, &cells).ok()) {
      if (cells.size() != points || !std::is_sorted(cells.begin(), cells.end())) std::abort();
      const uint64_t limit = depth == 21 ? ~uint64_t{0} >> 1 : uint64_t{1} << (3 * depth);
      for (uint64_t c : cells) {
        if (c >= limit) std::abort();
      }
    }
  }
  return 0;
}
