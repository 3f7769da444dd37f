// CRC-32C (Castagnoli), the checksum of every block and log record.
//
// Written here rather than taken from a library because Debian 12 packages no C++ CRC-32C with
// the SSE4.2 instruction path; Boost.CRC (table-driven, ~10x slower) is the portable fallback
// and the reference the tests compare against.
#ifndef HVDB_STORAGE_CRC32C_H_
#define HVDB_STORAGE_CRC32C_H_

#include <cstddef>
#include <cstdint>

namespace hvdb::crc32c {

// Extends `init` (the CRC of some prefix) with data[0, n).
uint32_t Extend(uint32_t init, const void* data, size_t n);
inline uint32_t Value(const void* data, size_t n) { return Extend(0, data, n); }
// The portable implementation, exposed for tests.
uint32_t ExtendPortable(uint32_t init, const void* data, size_t n);

// Stored checksums are masked (as in LevelDB) so that a CRC over data that itself holds CRCs
// does not degenerate.
inline uint32_t Mask(uint32_t crc) { return ((crc >> 15) | (crc << 17)) + 0xa282ead8u; }
inline uint32_t Unmask(uint32_t m) {
  uint32_t rot = m - 0xa282ead8u;
  return (rot >> 17) | (rot << 15);
}

}  // namespace hvdb::crc32c

#endif  // HVDB_STORAGE_CRC32C_H_
