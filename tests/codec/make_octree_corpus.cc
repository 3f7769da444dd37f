// Writes the seed corpus of octree_fuzz (run by hand after a change of the octree coding):
// g++ -std=c++20 -O2 -I. tests/codec/make_octree_corpus.cc codec/octree.cc
// build/storage/libhvdb_storage.a -o /tmp/mk && /tmp/mk tests/codec/octree_fuzz_corpus
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "codec/octree.h"

int main(int, char** argv) {
  using namespace hvdb::codec;
  std::mt19937 rng(11);
  std::vector<uint64_t> reference;
  for (uint32_t i = 0; i < 64; ++i) reference.push_back(MortonCode(i % 4, i / 4 % 4, i / 16));
  std::sort(reference.begin(), reference.end());
  int k = 0;
  for (int depth : {1, 3, 6, 10, 14}) {
    for (int n : {1, 9, 200, 3000}) {
      for (bool temporal : {false, true}) {
        if (temporal && depth < 3) continue;
        std::vector<uint64_t> codes;
        const uint32_t side = 1u << depth;
        for (int i = 0; i < n; ++i) {
          // A sheet with some repeats: what captured frames look like.
          const uint32_t x = rng() % side, y = rng() % side;
          const uint32_t z = static_cast<uint32_t>((side - 1) * (0.5 + 0.4 * std::sin(6.0 * x / side)));
          codes.push_back(MortonCode(x, y, z));
          if (i % 9 == 0) codes.push_back(codes.back());
        }
        if (temporal) codes.insert(codes.end(), reference.begin(), reference.begin() + 20);
        std::sort(codes.begin(), codes.end());
        if (codes.size() > 65535) codes.resize(65535);
        std::string payload;
        EncodeOctree(codes, depth, temporal ? &reference : nullptr, 1, &payload);
        std::string seed;
        seed.push_back(static_cast<char>((depth - 1) | (temporal ? 0x80 : 0)));
        seed.push_back(static_cast<char>(codes.size() & 0xFF));
        seed.push_back(static_cast<char>(codes.size() >> 8));
        seed += payload;
        const std::string path = std::string(argv[1]) + "/seed" + std::to_string(k++);
        FILE* f = std::fopen(path.c_str(), "wb");
        if (!f) return 1;
        std::fwrite(seed.data(), 1, seed.size(), f);
        std::fclose(f);
      }
    }
  }
  return 0;
}
