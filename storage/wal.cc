#include "storage/wal.h"

#include <cstring>

#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb {

static constexpr char kWalMagic[8] = {'H', 'V', 'D', 'B', 'W', 'A', 'L', '\0'};
static constexpr uint32_t kWalVersion = 1;
static constexpr uint8_t kTypeTxn = 1;
static constexpr uint8_t kTypeBulk = 2;
// A transaction whose frame effects each say their form: points (as kTypeTxn) or relabels.
static constexpr uint8_t kTypeTxnForms = 3;
static constexpr uint8_t kTypeTier = 4;
static constexpr uint8_t kFormPoints = 0;
static constexpr uint8_t kFormRelabels = 1;
static constexpr uint32_t kMaxRecord = 1u << 30;

static void PutPoints(Writer* w, const std::vector<Point>& pts) {
  w->Put<uint32_t>(static_cast<uint32_t>(pts.size()));
  // Encoded in place at the end of the buffer: a commit's points are copied once here.
  std::string& buf = w->data();
  const size_t at = buf.size();
  buf.resize(at + pts.size() * kPointRecordSize);
  EncodePoints(pts, reinterpret_cast<uint8_t*>(buf.data() + at));
}

static bool GetPoints(Reader* r, std::vector<Point>* pts) {
  uint32_t n;
  if (!r->Get(&n) || r->remaining() < uint64_t{n} * kPointRecordSize) return false;
  pts->resize(n);
  DecodePoints(r->pos(), n, pts->data());
  r->Skip(size_t{n} * kPointRecordSize);
  return true;
}

FrameEffect InverseEffect(const FrameEffect& f) {
  FrameEffect inv{f.frame, f.added, f.removed, f.relabels, {}};
  for (Relabel& r : inv.relabels) r.after ^= r.flip;
  return inv;
}

uint64_t EffectAdded(const FrameEffect& f) {
  if (!f.added.empty() || f.relabels.empty()) return f.added.size();
  uint64_t n = 0;
  for (const Relabel& r : f.relabels) n += r.ids.size();
  return n;
}

uint64_t EffectRemoved(const FrameEffect& f) {
  return f.removed.empty() && !f.relabels.empty() ? EffectAdded(f) : f.removed.size();
}

static bool HasRelabels(const TxnRecord& t) {
  for (const FrameEffect& f : t.frames) {
    if (!f.relabels.empty()) return true;
  }
  return false;
}

static void PutRelabels(Writer* w, const std::vector<Relabel>& groups) {
  w->Put<uint32_t>(static_cast<uint32_t>(groups.size()));
  for (const Relabel& g : groups) {
    w->Put<uint32_t>(g.flip);
    w->Put<uint32_t>(g.after);
    w->Put<uint32_t>(static_cast<uint32_t>(g.ids.size()));
    uint64_t prev = 0;
    for (uint64_t id : g.ids) {
      PutVarint(&w->data(), id - prev);
      prev = id;
    }
  }
}

static bool GetRelabels(Reader* r, std::vector<Relabel>* groups) {
  uint32_t n;
  if (!r->Get(&n) || n > 32 * 32 + 1) return false;  // at most one group per (flip, after)
  groups->resize(n);
  for (Relabel& g : *groups) {
    uint32_t count;
    if (!r->Get(&g.flip) || !r->Get(&g.after) || !r->Get(&count)) return false;
    if (g.flip == 0 || (g.after & ~g.flip) != 0 || count == 0 || count > r->remaining()) {
      return false;
    }
    g.ids.resize(count);
    uint64_t prev = 0;
    for (uint32_t i = 0; i < count; ++i) {
      uint64_t gap;
      if (!GetVarint(r, &gap) || (i > 0 && gap == 0) || gap > UINT64_MAX - prev) return false;
      prev += gap;
      g.ids[i] = prev;
    }
  }
  return true;
}

// Appends the payload of `t` to *out (the log's writer encodes it in place after its header).
// `forms`: the kTypeTxnForms layout (a form byte per frame effect) instead of kTypeTxn's.
static void AppendTxnPayload(const TxnRecord& t, bool forms, std::string* out) {
  size_t bytes = 12;
  for (const FrameEffect& f : t.frames) {
    bytes += 13 + (f.relabels.empty() ? (f.removed.size() + f.added.size()) * kPointRecordSize
                                      : 12 * f.relabels.size() + 2 * EffectAdded(f));
  }
  out->reserve(out->size() + bytes);
  Writer w(std::move(*out));
  w.Put<uint64_t>(t.reverts);
  w.Put<uint32_t>(static_cast<uint32_t>(t.frames.size()));
  for (const FrameEffect& f : t.frames) {
    w.Put<uint32_t>(f.frame);
    if (forms) w.Put<uint8_t>(f.relabels.empty() ? kFormPoints : kFormRelabels);
    if (forms && !f.relabels.empty()) {
      PutRelabels(&w, f.relabels);
      continue;
    }
    PutPoints(&w, f.removed);
    PutPoints(&w, f.added);
  }
  *out = std::move(w.data());
}

Result<TxnRecord> DecodeTxnPayload(const std::string& payload, uint64_t lsn, bool forms) {
  Reader r(reinterpret_cast<const uint8_t*>(payload.data()), payload.size());
  TxnRecord t;
  t.lsn = lsn;
  uint32_t nframes;
  if (!r.Get(&t.reverts) || !r.Get(&nframes)) {
    return Status::Corruption("log record " + std::to_string(lsn) + ": bad header");
  }
  for (uint32_t i = 0; i < nframes; ++i) {
    FrameEffect f;
    uint8_t form = kFormPoints;
    bool ok = r.Get(&f.frame) && (!forms || r.Get(&form));
    if (ok && form == kFormRelabels) {
      ok = GetRelabels(&r, &f.relabels) && !f.relabels.empty();
    } else {
      ok = ok && form == kFormPoints && GetPoints(&r, &f.removed) && GetPoints(&r, &f.added);
    }
    if (!ok) return Status::Corruption("log record " + std::to_string(lsn) + ": bad frame effect");
    t.frames.push_back(std::move(f));
  }
  if (r.remaining() != 0) {
    return Status::Corruption("log record " + std::to_string(lsn) + ": trailing bytes");
  }
  return t;
}

static Result<TxnRecord> DecodePayload(uint8_t type, const std::string& payload, uint64_t lsn) {
  if (type == kTypeTxn || type == kTypeTxnForms) {
    return DecodeTxnPayload(payload, lsn, type == kTypeTxnForms);
  }
  if (type == kTypeTier) {  // u32 frame
    if (payload.size() != 4) {
      return Status::Corruption("log record " + std::to_string(lsn) + ": bad tier marker");
    }
    TxnRecord t;
    t.lsn = lsn;
    t.tier = true;
    t.frames.emplace_back();
    t.frames[0].frame = DecodeLE<uint32_t>(reinterpret_cast<const uint8_t*>(payload.data()));
    return t;
  }
  if (type != kTypeBulk) {
    return Status::Corruption("log record " + std::to_string(lsn) + ": unknown type " +
                              std::to_string(type));
  }
  // u32 frame, then (since bulk loads have LSNs of their own) u64 points loaded.
  if (payload.size() != 4 && payload.size() != 12) {
    return Status::Corruption("log record " + std::to_string(lsn) + ": bad bulk-load marker");
  }
  TxnRecord t;
  t.lsn = lsn;
  t.bulk = true;
  t.frames.emplace_back();
  const auto* p = reinterpret_cast<const uint8_t*>(payload.data());
  t.frames[0].frame = DecodeLE<uint32_t>(p);
  if (payload.size() == 12) t.bulk_points = DecodeLE<uint64_t>(p + 4);
  return t;
}

Result<uint64_t> DecodeWalHeader(const uint8_t* p, size_t size, const std::string& what) {
  if (size < kWalHeaderSize || std::memcmp(p, kWalMagic, 8) != 0) {
    return Status::Corruption(what + ": bad magic");
  }
  if (crc32c::Unmask(DecodeLE<uint32_t>(p + 24)) != crc32c::Value(p, 24)) {
    return Status::Corruption(what + ": header checksum mismatch");
  }
  uint32_t version = DecodeLE<uint32_t>(p + 8);
  if (version != kWalVersion) {
    return Status::Corruption(what + ": unsupported log version " + std::to_string(version));
  }
  return DecodeLE<uint64_t>(p + 16);
}

size_t ReadWalTail(const uint8_t* p, size_t size, std::vector<TxnRecord>* out) {
  size_t pos = 0;
  while (size - pos >= kWalRecordHeaderSize) {
    if (crc32c::Unmask(DecodeLE<uint32_t>(p + pos)) != crc32c::Value(p + pos + 4, 17)) break;
    uint32_t len = DecodeLE<uint32_t>(p + pos + 4);
    if (kWalRecordHeaderSize + size_t{len} > size - pos) break;
    const uint8_t* payload = p + pos + kWalRecordHeaderSize;
    if (crc32c::Unmask(DecodeLE<uint32_t>(p + pos + 17)) != crc32c::Value(payload, len)) break;
    auto rec = DecodePayload(p[pos + 16], std::string(reinterpret_cast<const char*>(payload), len),
                             DecodeLE<uint64_t>(p + pos + 8));
    if (!rec.ok()) break;
    out->push_back(std::move(rec).value());
    pos += kWalRecordHeaderSize + len;
  }
  return pos;
}

Result<WalContents> ReadWal(Env* env, const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(std::string data, ReadWholeFile(env, path));
  WalContents out;
  const auto* p = reinterpret_cast<const uint8_t*>(data.data());
  if (data.size() < kWalHeaderSize) {
    // A crash while creating the file: nothing was ever committed to it.
    out.torn_tail = !data.empty();
    return out;
  }
  HVDB_ASSIGN_OR_RETURN(out.start_lsn, DecodeWalHeader(p, data.size(), path));
  auto all_zero = [&](size_t from) {
    for (size_t i = from; i < data.size(); ++i) {
      if (p[i] != 0) return false;
    }
    return true;
  };
  auto corrupt = [&](size_t at, const std::string& why) {
    return Status::Corruption(path + ": record at offset " + std::to_string(at) + ": " + why);
  };
  size_t pos = kWalHeaderSize;
  uint64_t expect_lsn = out.start_lsn - 1;
  while (pos < data.size()) {
    size_t left = data.size() - pos;
    // A crash mid-append leaves a prefix of the last record (or, on some file systems, zeros).
    if (left < kWalRecordHeaderSize || all_zero(pos)) {
      out.torn_tail = true;
      break;
    }
    // The header (length, lsn, type, payload checksum) has its own checksum: a damaged length
    // is caught here instead of being mistaken for a torn tail.
    if (crc32c::Unmask(DecodeLE<uint32_t>(p + pos)) != crc32c::Value(p + pos + 4, 17)) {
      return corrupt(pos, "header checksum mismatch");
    }
    uint32_t len = DecodeLE<uint32_t>(p + pos + 4);
    uint64_t lsn = DecodeLE<uint64_t>(p + pos + 8);
    uint8_t type = p[pos + 16];
    uint32_t pcrc = DecodeLE<uint32_t>(p + pos + 17);
    if (kWalRecordHeaderSize + size_t{len} > left) {
      out.torn_tail = true;  // an intact header whose payload was cut short
      break;
    }
    size_t end = pos + kWalRecordHeaderSize + len;
    if (crc32c::Unmask(pcrc) != crc32c::Value(p + pos + kWalRecordHeaderSize, len)) {
      if (end == data.size()) {
        out.torn_tail = true;
        break;
      }
      return corrupt(pos, "checksum mismatch, with valid-looking data after it");
    }
    if (type != kTypeTxn && type != kTypeBulk && type != kTypeTxnForms && type != kTypeTier) {
      return corrupt(pos, "unknown type " + std::to_string(type));
    }
    // A record's LSN is above the one before; a marker (a bulk load's of an older log, a tier
    // change's) may repeat it.
    const bool marker = type == kTypeBulk || type == kTypeTier;
    if (marker ? lsn < expect_lsn : lsn <= expect_lsn) {
      return corrupt(pos, "sequence number " + std::to_string(lsn) + " is not above " +
                              std::to_string(expect_lsn));
    }
    expect_lsn = lsn;
    HVDB_ASSIGN_OR_RETURN(TxnRecord t,
                          DecodePayload(type, data.substr(pos + kWalRecordHeaderSize, len), lsn));
    out.records.push_back(std::move(t));
    pos = end;
  }
  out.valid_bytes = pos;
  return out;
}

Result<std::unique_ptr<WalWriter>> WalWriter::Open(Env* env, const std::string& path, uint64_t start_lsn,
                                                   uint64_t valid_bytes, bool exists) {
  if (!exists || valid_bytes < kWalHeaderSize) {
    Writer h;
    h.PutBytes(kWalMagic, 8);
    h.Put<uint32_t>(kWalVersion);
    h.Put<uint32_t>(0);
    h.Put<uint64_t>(start_lsn);
    h.Put<uint32_t>(crc32c::Mask(crc32c::Value(h.data().data(), h.data().size())));
    HVDB_RETURN_IF_ERROR(WriteFileAtomic(env, path, h.data()));
    HVDB_ASSIGN_OR_RETURN(auto f, env->OpenWrite(path, /*truncate=*/false));
    return std::unique_ptr<WalWriter>(new WalWriter(std::move(f)));
  }
  HVDB_ASSIGN_OR_RETURN(auto f, env->OpenWrite(path, /*truncate=*/false));
  if (f->size() != valid_bytes) {
    HVDB_RETURN_IF_ERROR(f->Truncate(valid_bytes));
    HVDB_RETURN_IF_ERROR(f->Sync());
  }
  return std::unique_ptr<WalWriter>(new WalWriter(std::move(f)));
}

Status WalWriter::Append(const std::vector<TxnRecord>& records) {
  // One write for a whole commit group: the records, back to back, each payload encoded in
  // place after a header that is filled in once its length and checksum are known.
  std::string out;
  for (const TxnRecord& t : records) {
    const size_t at = out.size();
    out.resize(at + kWalRecordHeaderSize);
    if (t.tier) {
      out.resize(out.size() + 4);
      EncodeLE(reinterpret_cast<uint8_t*>(out.data() + out.size() - 4), t.frames.at(0).frame);
    } else if (t.bulk) {
      out.resize(out.size() + 12);
      auto* m = reinterpret_cast<uint8_t*>(out.data() + out.size() - 12);
      EncodeLE(m, t.frames.at(0).frame);
      EncodeLE(m + 4, t.bulk_points);
    } else {
      AppendTxnPayload(t, HasRelabels(t), &out);
    }
    const size_t len = out.size() - at - kWalRecordHeaderSize;
    if (len > kMaxRecord) {
      return Status::LimitExceeded("transaction too large for one log record (" +
                                   std::to_string(len) + " bytes, limit 1 GiB)");
    }
    auto* h = reinterpret_cast<uint8_t*>(out.data() + at);
    EncodeLE(h + 4, static_cast<uint32_t>(len));
    EncodeLE(h + 8, t.lsn);
    h[16] = t.tier ? kTypeTier : t.bulk ? kTypeBulk : HasRelabels(t) ? kTypeTxnForms : kTypeTxn;
    EncodeLE(h + 17, crc32c::Mask(crc32c::Value(h + kWalRecordHeaderSize, len)));
    EncodeLE(h, crc32c::Mask(crc32c::Value(h + 4, 17)));
  }
  return file_->Append(out);
}

}  // namespace hvdb
