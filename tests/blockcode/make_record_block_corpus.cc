// Writes the seed corpus of record_block_fuzz (run by hand after a change of the record-block
// coding): g++ -std=c++20 -I. tests/blockcode/make_record_block_corpus.cc blockcode/record_block.cc
// -o /tmp/mk && /tmp/mk tests/blockcode/record_block_fuzz_corpus
#include <cstdio>
#include <random>
#include <string>
#include <vector>
#include "blockcode/record_block.h"
int main(int, char** argv) {
  std::mt19937_64 rng(5);
  for (int k = 0; k < 6; ++k) {
    uint32_t n = k == 0 ? 1 : (k == 1 ? 2 : 40 * k);
    std::vector<uint8_t> recs(n * 64, 0);
    for (uint32_t i = 0; i < n; ++i) {
      uint8_t* r = recs.data() + i * 64;
      uint64_t id = 1000 + i * (k + 1);
      for (int b = 0; b < 8; ++b) r[b] = uint8_t(id >> (8 * b));
      for (int b = 8; b < 62; ++b) r[b] = (k % 2) ? uint8_t(rng()) : uint8_t((b * 7 + i * (b % 5)) & 0xFF);
      r[62] = r[63] = 0;
    }
    std::string out;
    hvdb::blockcode::EncodeRecordBlock(recs.data(), n, &out);
    std::string path = std::string(argv[1]) + "/seed" + std::to_string(k);
    FILE* f = std::fopen(path.c_str(), "wb");
    std::fwrite(out.data(), 1, out.size(), f);
    std::fclose(f);
  }
}
