// Record blocks: lossless coding of a run of 64-byte point records (docs/CODEC.md, "Record
// blocks"), the coding of the storage engine's compressed cold tier (docs/FORMAT.md).
//
// hvdb7's principles (predict, then entropy-code the residual's magnitude class with an
// adaptive model and send the bits below its leading one as they are), cut down to what a block
// of a tree file needs: every field of the record exact, bit for bit, and decoding at a few
// nanoseconds per field, because a cold query decodes every block it reads. The pair
// hierarchy of codec/codec.h is left out on purpose: it decodes lossless streams at ~0.8 M
// points/s, so a cold window would be bound by it; here the kd-tree's buckets already group
// neighbours, and each field is predicted from the record before it.
//
// The coder is static rANS (Duda 2013; the form of ryg_rans) over each field's magnitude
// classes, one frequency table per field and block: blocks decode on their own, in parallel.
// Written here because Debian ships no rANS/tANS library with a symbol-level API (zstd's FSE
// is internal), and it is ~100 lines specified to the bit in docs/CODEC.md.
//
// blockcode/ sits below storage/ (the storage engine links it; codec/ builds on the storage
// engine) and depends on nothing else in hvdb, so it reports errors as text, not as Status.
#ifndef HVDB_BLOCKCODE_RECORD_BLOCK_H_
#define HVDB_BLOCKCODE_RECORD_BLOCK_H_

#include <cstddef>
#include <cstdint>
#include <string>

namespace hvdb::blockcode {

inline constexpr size_t kRecordSize = 64;
// Records per block the format allows (a 1 MiB block of 64-byte records).
inline constexpr uint32_t kMaxBlockRecords = 1u << 14;

// Appends the coding of records[0 .. n) (n * 64 bytes, 1 <= n <= kMaxBlockRecords) to *out.
void EncodeRecordBlock(const uint8_t* records, uint32_t n, std::string* out);

// Decodes one block coded by EncodeRecordBlock from src[0 .. len) into dst, which holds
// `capacity` records. Sets *n to the number decoded. Any damage (truncation, a bad table,
// trailing bytes, more records than `capacity`) returns false with *error saying what; the
// caller still checks the decoded bytes' checksum.
bool DecodeRecordBlock(const uint8_t* src, size_t len, uint8_t* dst, uint32_t capacity,
                       uint32_t* n, std::string* error);

}  // namespace hvdb::blockcode

#endif  // HVDB_BLOCKCODE_RECORD_BLOCK_H_
