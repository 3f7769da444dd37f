// libFuzzer target for the record-block decoder (blockcode/record_block.h, the cold tier's block
// coding): any bytes must decode or be refused, never crash, hang or read out of bounds.
// scripts/test.sh runs it on tests/blockcode/record_block_fuzz_corpus (seeds written by
// tests/blockcode/make_record_block_corpus.cc).
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "blockcode/record_block.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static std::vector<uint8_t> out(size_t{hvdb::blockcode::kMaxBlockRecords} * 64);
  uint32_t n = 0;
  std::string err;
  // The room a 64 KiB block gives (1024 records), as the tree reader passes.
  (void)hvdb::blockcode::DecodeRecordBlock(data, size, out.data(), 1024, &n, &err);
  return 0;
}
