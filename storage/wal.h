// The write-ahead log of a dataset: one record per committed transaction, holding its full
// effect (points removed, with their before-images, and points added, per frame), so that
// recovery can redo it and Revert can derive its inverse. Format: docs/FORMAT.md, "Log".
#ifndef HVDB_STORAGE_WAL_H_
#define HVDB_STORAGE_WAL_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "storage/env.h"
#include "storage/point.h"

namespace hvdb {

// Labels changed in place (a selection, a graph cut): which points and which bits, not whole
// points. The bits `flip` of each point of `ids` flipped to the values `after` (after & ~flip
// is 0); ids ascending.
struct Relabel {
  uint32_t flip = 0;
  uint32_t after = 0;
  std::vector<uint64_t> ids;
};

struct FrameEffect {
  uint32_t frame = 0;
  std::vector<Point> removed;  // exact records as they were
  std::vector<Point> added;
  // When not empty, the step is these relabels: the log stores only them (a few bytes a point),
  // and removed/added are their resolution (each point before and after, pairwise), filled by
  // the writer or, for a step read from the log, by ResolveRelabels against the frame.
  std::vector<Relabel> relabels;
  // Not logged: where each removed point was found in the frame version the step is applied
  // to (-1: T0, else its tree slot), when the writer read it there; ApplyStep then marks it
  // dead without searching the frame again. Empty: ApplyStep searches.
  std::vector<int32_t> found_in;
};

// The inverse step (what Revert applies): removed and added swapped, relabels flipped back.
FrameEffect InverseEffect(const FrameEffect& f);
// Points the step adds and removes (a relabel removes and adds each of its points).
uint64_t EffectAdded(const FrameEffect& f);
uint64_t EffectRemoved(const FrameEffect& f);

struct TxnRecord {
  uint64_t lsn = 0;
  uint64_t reverts = 0;  // non-zero: this transaction undid transaction `reverts`
  std::vector<FrameEffect> frames;
  // A bulk load's marker (record type 2): frames[0].frame's state file was replaced, with
  // bulk_points points loaded (the record holds no points). Its lsn is the bulk load's own (the
  // state's applied LSN); markers of older logs repeat the last transaction's. Recovery skips
  // it; followers re-read that state; watchers see it as a "bulk" event.
  bool bulk = false;
  uint64_t bulk_points = 0;
  // A tier marker (record type 4): frames[0].frame's state file was rewritten into the other
  // tier (the cold tier's compaction: the same points, other trees). Its lsn repeats the last
  // one. Recovery and watchers skip it; followers re-read that state.
  bool tier = false;
};

// `forms`: record type 3's layout (a form byte per frame effect; docs/FORMAT.md).
Result<TxnRecord> DecodeTxnPayload(const std::string& payload, uint64_t lsn, bool forms = false);

struct WalContents {
  uint64_t start_lsn = 1;  // first sequence number this file may hold
  std::vector<TxnRecord> records;
  uint64_t valid_bytes = 0;  // length of the valid prefix
  bool torn_tail = false;    // bytes after valid_bytes were an incomplete last record
};

// Reads a log file. A torn last record (a crash mid-append) ends the log; a bad record with
// valid data after it is Corruption.
Result<WalContents> ReadWal(Env* env, const std::string& path);

// For a follower tailing a log another process appends to: decodes the records in
// data[0..size), which starts at a record boundary, up to the first record that is not
// complete (or not yet intact) and returns the bytes consumed. Never an error: what is not
// whole yet is read again on the next call.
size_t ReadWalTail(const uint8_t* data, size_t size, std::vector<TxnRecord>* out);
// The first LSN a log file may hold, from its 28-byte header; Corruption if it is not one.
Result<uint64_t> DecodeWalHeader(const uint8_t* data, size_t size, const std::string& what);

class WalWriter {
 public:
  // Opens `path` for appending after `valid_bytes` (truncating a torn tail), or creates it
  // with the given start_lsn when it does not exist.
  static Result<std::unique_ptr<WalWriter>> Open(Env* env, const std::string& path,
                                                 uint64_t start_lsn,
                                                 uint64_t valid_bytes, bool exists);
  // Appends the records in one write; on failure none of them stays in the file.
  Status Append(const std::vector<TxnRecord>& records);
  Status Sync() { return file_->Sync(); }
  uint64_t size() const { return file_->size(); }

 private:
  explicit WalWriter(std::unique_ptr<WritableFile> f) : file_(std::move(f)) {}
  std::unique_ptr<WritableFile> file_;
};

inline constexpr size_t kWalHeaderSize = 28;
// header crc, length, lsn, type, payload crc
inline constexpr size_t kWalRecordHeaderSize = 21;

}  // namespace hvdb

#endif  // HVDB_STORAGE_WAL_H_
