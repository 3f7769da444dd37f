// libFuzzer target for the log's record decoder (storage/wal.h, docs/FORMAT.md "Log"): any
// payload must decode to a record or a Corruption, never a crash or an allocation beyond the
// input. The first byte picks the record type (1 transaction, 2 bulk-load marker, 3 transaction
// with relabels); the rest is the payload, framed here with a valid header and checksums so that
// the fuzzer gets past them to the fields. scripts/test.sh runs it on
// tests/storage/wal_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/wal.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  if (size == 0) return 0;
  const uint8_t type = static_cast<uint8_t>(1 + data[0] % 3);
  const size_t len = size - 1;
  std::string rec(kWalRecordHeaderSize, '\0');
  rec.append(reinterpret_cast<const char*>(data + 1), len);
  auto* h = reinterpret_cast<uint8_t*>(rec.data());
  EncodeLE<uint32_t>(h + 4, static_cast<uint32_t>(len));
  EncodeLE<uint64_t>(h + 8, 1);
  h[16] = type;
  EncodeLE<uint32_t>(h + 17, crc32c::Mask(crc32c::Value(h + kWalRecordHeaderSize, len)));
  EncodeLE<uint32_t>(h, crc32c::Mask(crc32c::Value(h + 4, 17)));
  std::vector<TxnRecord> out;
  const size_t used = ReadWalTail(h, rec.size(), &out);
  if (used != 0 && used != rec.size()) __builtin_trap();
  for (const TxnRecord& t : out) {
    for (const FrameEffect& f : t.frames) {
      for (const Relabel& g : f.relabels) {
        // What decodes is what the format allows.
        if (g.flip == 0 || (g.after & ~g.flip) != 0 || g.ids.empty()) __builtin_trap();
        for (size_t i = 1; i < g.ids.size(); ++i) {
          if (g.ids[i] <= g.ids[i - 1]) __builtin_trap();
        }
      }
    }
  }
  return 0;
}
