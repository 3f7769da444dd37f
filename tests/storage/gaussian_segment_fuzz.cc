// libFuzzer target for the Gaussian column's segment files (storage/gaussian_column.h,
// docs/FORMAT.md "Gaussian column segment"): any file must open to a segment or a Corruption,
// and reads of any ids must give records or an error, never a crash or an allocation beyond the
// file. Byte 0's low bits say which checksums to make right (the header's, the table's, each
// block's) so that the fuzzer gets past them to the fields; the rest is the file.
// scripts/test.sh runs it on tests/storage/gaussian_segment_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "storage/coding.h"
#include "storage/crc32c.h"
#include "storage/env.h"
#include "storage/gaussian_column.h"

namespace {

const std::string& Dir() {
  static const std::string dir = [] {
    std::string tmpl = "/tmp/hvdb-gsc-fuzz-XXXXXX";
    const char* d = ::mkdtemp(tmpl.data());
    std::string out = d ? d : "/tmp";
    hvdb::Env::Default()->CreateDirs(out + "/gaussians").ok();
    return out;
  }();
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace hvdb;
  if (size < 1) return 0;
  const uint8_t fix = data[0];
  std::string file(reinterpret_cast<const char*>(data + 1), size - 1);
  auto* b = reinterpret_cast<uint8_t*>(file.data());
  if ((fix & 1) && file.size() >= 64) EncodeLE<uint32_t>(b + 60, crc32c::Mask(crc32c::Value(b, 60)));
  if ((fix & 6) && file.size() >= 64) {
    const uint32_t degree = DecodeLE<uint32_t>(b + 12) % 4;
    const uint64_t count = DecodeLE<uint64_t>(b + 32);
    const size_t rb = 4 * GaussianRecordFloats(static_cast<int>(degree));
    if (count > 0 && count <= (file.size() - 64) / rb) {
      const uint64_t blocks = (count + 1023) / 1024;
      const size_t table = 64 + count * rb;
      if (table + 4 * blocks + 4 <= file.size()) {
        if (fix & 4) {
          for (uint64_t k = 0; k < blocks; ++k) {
            const size_t lo = 64 + k * 1024 * rb;
            const size_t n = std::min<uint64_t>(count - k * 1024, 1024) * rb;
            EncodeLE<uint32_t>(b + table + 4 * k, crc32c::Mask(crc32c::Value(b + lo, n)));
          }
        }
        EncodeLE<uint32_t>(b + table + 4 * blocks,
                           crc32c::Mask(crc32c::Value(b + table, 4 * blocks)));
      }
    }
  }
  const std::string path = Dir() + "/gaussians/0000000000000001.gsc";
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(file.data(), static_cast<std::streamsize>(file.size()));
  }
  auto col = GaussianColumn::Open(Env::Default(), Dir(), /*writer=*/false, UINT64_MAX);
  if (!col.ok()) return 0;
  const std::vector<uint64_t> ids = {1, 2, 1025, 5000, 1u << 20, 0};
  GaussianColumns out;
  std::vector<bool> found;
  (*col)->Read(ids, &out, &found).ok();
  (*col)->Verify();
  return 0;
}
