#include "blockcode/record_block.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>
#include <vector>

namespace hvdb::blockcode {
namespace {

// A field of the 64-byte record (docs/FORMAT.md "Point record") and how it is predicted.
enum class Kind : uint8_t {
  kInt,     // integer: delta from the record before
  kFloat,   // IEEE float bits mapped to an order-preserving integer, then delta
  kColour,  // r or b minus g of the same record (mod 256), then delta
};
struct Field {
  uint8_t offset, bytes;
  Kind kind;
};
// Coding order. g comes before r and b, which are coded as differences from it.
constexpr std::array<Field, 19> kFields = {{
    {0, 8, Kind::kInt},     // id
    {8, 4, Kind::kFloat},   // x
    {12, 4, Kind::kFloat},  // y
    {16, 4, Kind::kFloat},  // z
    {20, 4, Kind::kInt},    // frame
    {24, 4, Kind::kFloat},  // cov xx
    {28, 4, Kind::kFloat},  // cov xy
    {32, 4, Kind::kFloat},  // cov xz
    {36, 4, Kind::kFloat},  // cov yy
    {40, 4, Kind::kFloat},  // cov yz
    {44, 4, Kind::kFloat},  // cov zz
    {48, 2, Kind::kInt},    // normal (octahedral) u
    {50, 2, Kind::kInt},    // normal v
    {52, 4, Kind::kInt},    // label
    {57, 1, Kind::kInt},    // g
    {56, 1, Kind::kColour},  // r
    {58, 1, Kind::kColour},  // b
    {59, 1, Kind::kInt},    // flags
    {60, 2, Kind::kInt},    // camera
}};
// Bytes 62-63 (reserved) are not a field: written as 0 and ignored on read (point.h), so the
// decoder writes zeros. The encoder requires them to be zero to stay lossless.

constexpr int kProbBits = 11;
constexpr uint32_t kProbScale = 1u << kProbBits;
// The state lives in [L, 2^32) and is renormalised 16 bits at a time: after a decoding step it
// is at least 2^(16 - 11), so one word always restores it, and the decoder renormalises
// without a branch (a byte-wise rANS needs 0, 1 or 2 bytes, a branch mispredicted at random,
// which was a quarter of the decoding time).
constexpr uint32_t kRansL = 1u << 16;
constexpr int kMaxSymbols = 65;        // magnitude classes 0..64

enum Mode : uint8_t { kAllZero = 0, kOneClass = 1, kTable = 2 };

inline uint64_t Mask(int bits) { return bits == 64 ? ~0ull : (1ull << bits) - 1; }

inline uint64_t Load(const uint8_t* p, int bytes) {
  uint64_t v = 0;
  for (int i = bytes - 1; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}
inline void Store(uint8_t* p, int bytes, uint64_t v) {
  for (int i = 0; i < bytes; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}

// The predicted-from quantity of a field of one record (a `bits`-bit integer).
inline uint64_t Transform(const uint8_t* rec, const Field& f) {
  uint64_t v = Load(rec + f.offset, f.bytes);
  switch (f.kind) {
    case Kind::kInt: return v;
    case Kind::kFloat: return (v & 0x80000000u) ? (~v & 0xFFFFFFFFu) : (v | 0x80000000u);
    case Kind::kColour: return (v - rec[57]) & 0xFF;
  }
  return v;
}
inline uint64_t Untransform(uint64_t t, const uint8_t* rec, const Field& f) {
  switch (f.kind) {
    case Kind::kInt: return t;
    case Kind::kFloat: return (t & 0x80000000u) ? (t & 0x7FFFFFFFu) : (~t & 0xFFFFFFFFu);
    case Kind::kColour: return (t + rec[57]) & 0xFF;
  }
  return t;
}

void PutVarint(std::string* out, uint32_t v) {
  while (v >= 0x80) {
    out->push_back(static_cast<char>(v | 0x80));
    v >>= 7;
  }
  out->push_back(static_cast<char>(v));
}

// Scales counts to frequencies summing to kProbScale, every used class at least 1.
void Normalise(const uint32_t* count, uint32_t total, uint32_t* freq) {
  uint32_t sum = 0;
  int largest = 0;
  for (int s = 0; s < kMaxSymbols; ++s) {
    freq[s] = count[s] == 0 ? 0
                            : std::max<uint32_t>(
                                  1, static_cast<uint32_t>(uint64_t{count[s]} * kProbScale / total));
    sum += freq[s];
    if (freq[s] > freq[largest]) largest = s;
  }
  // Rounding left the sum off by a little: the largest class absorbs it, or, when that is not
  // enough, every class above 1 gives one in turn.
  while (sum != kProbScale) {
    if (sum < kProbScale) {
      freq[largest] += kProbScale - sum;
      sum = kProbScale;
    } else {
      for (int s = 0; s < kMaxSymbols && sum > kProbScale; ++s) {
        if (freq[s] > 1) {
          --freq[s];
          --sum;
        }
      }
    }
  }
}

class BitWriter {
 public:
  explicit BitWriter(std::string* out) : out_(out) {}
  void Put(uint64_t v, int bits) {  // bits <= 63
    if (bits > 32) {
      Put(v & 0xFFFFFFFFu, 32);
      Put(v >> 32, bits - 32);
      return;
    }
    acc_ |= v << fill_;
    fill_ += bits;
    while (fill_ >= 8) {
      out_->push_back(static_cast<char>(acc_ & 0xFF));
      acc_ >>= 8;
      fill_ -= 8;
    }
  }
  void Flush() {
    if (fill_ > 0) out_->push_back(static_cast<char>(acc_ & 0xFF));
    acc_ = 0;
    fill_ = 0;
  }

 private:
  std::string* out_;
  uint64_t acc_ = 0;
  int fill_ = 0;
};

class BitReader {
 public:
  BitReader(const uint8_t* p, const uint8_t* end) : p_(p), end_(end) {}
  // bits <= 63. Inlined into the decoding loops: it runs once per coded value.
  __attribute__((always_inline)) uint64_t Get(int bits) {
    if (bits > 56) return GetLong(bits);
    if (fill_ < bits) Refill(bits);
    const uint64_t v = acc_ & Mask(bits);
    acc_ >>= bits;
    fill_ -= bits;
    return v;
  }
  // Every bit read was there, and no whole byte is left over.
  bool ok() const { return !overrun_ && p_ == end_ && fill_ < 8; }

 private:
  uint64_t GetLong(int bits) {  // 57..63 bits: in two reads
    const uint64_t lo = Get(32);
    return lo | (Get(bits - 32) << 32);
  }
  void Refill(int bits) {
    if (end_ - p_ >= 8) {  // a word at once: whole bytes up to 56+ bits buffered
      uint64_t w;
      std::memcpy(&w, p_, 8);
      if constexpr (std::endian::native == std::endian::big) w = __builtin_bswap64(w);
      acc_ |= w << fill_;
      const int take = (63 - fill_) >> 3;
      p_ += take;
      fill_ += 8 * take;
      return;
    }
    while (fill_ <= 56 && p_ < end_) {
      acc_ |= uint64_t{*p_++} << fill_;
      fill_ += 8;
    }
    if (fill_ < bits) {  // past the end: damage, reported by ok(); zeros meanwhile
      overrun_ = true;
      fill_ = bits;
    }
  }

  const uint8_t* p_;
  const uint8_t* end_;
  uint64_t acc_ = 0;
  int fill_ = 0;
  bool overrun_ = false;
};

struct ColumnPlan {
  Mode mode = kAllZero;
  uint8_t one_class = 0;
  uint32_t freq[kMaxSymbols] = {};
  uint32_t cum[kMaxSymbols] = {};
};

inline int ClassOf(uint64_t z) { return 64 - std::countl_zero(z); }

// The rANS decoder's state while the fields are decoded one after another.
struct RansIn {
  uint32_t x;
  const uint8_t* p;
  const uint8_t* end;
  bool overrun;
};

// Decodes field f of records 1..m (record 0 is in place): one loop per coding mode, with the
// field's width and prediction known at compile time, since a cold query decodes every block
// it reads (this loop is where a cold frame's time goes).
template <typename T, Kind K>
void DecodeColumn(const ColumnPlan& pl, const Field& f, uint8_t* dst, uint32_t m, RansIn* in,
                  BitReader* br) {
  constexpr int kBits = 8 * sizeof(T);
  auto load = [&](const uint8_t* rec) {
    T v;
    std::memcpy(&v, rec + f.offset, sizeof(T));
    if constexpr (std::endian::native == std::endian::big) v = static_cast<T>(Load(reinterpret_cast<const uint8_t*>(&v), sizeof(T)));
    return v;
  };
  auto store = [&](uint8_t* rec, T v) {
    if constexpr (std::endian::native == std::endian::little) {
      std::memcpy(rec + f.offset, &v, sizeof(T));
    } else {
      Store(rec + f.offset, sizeof(T), v);
    }
  };
  auto forward = [&](uint8_t* rec, T v) -> T {  // predicted quantity -> stored value
    if constexpr (K == Kind::kFloat) {
      return (v & 0x80000000u) ? static_cast<T>(v & 0x7FFFFFFFu) : static_cast<T>(~v);
    } else if constexpr (K == Kind::kColour) {
      return static_cast<T>(v + rec[57]);
    } else {
      (void)rec;
      return v;
    }
  };
  T prev = static_cast<T>(Transform(dst, f));
  uint8_t* rec = dst + kRecordSize;
  auto emit = [&](uint64_t zz) {
    const T d = static_cast<T>((zz >> 1) ^ (0 - (zz & 1)));
    prev = static_cast<T>(prev + d);
    store(rec, forward(rec, prev));
    rec += kRecordSize;
  };
  (void)load;
  if (pl.mode == kAllZero) {
    const T v = load(dst);
    for (uint32_t i = 0; i < m; ++i, rec += kRecordSize) {
      if constexpr (K == Kind::kColour) {
        store(rec, forward(rec, prev));
      } else {
        store(rec, v);
      }
    }
    return;
  }
  if (pl.mode == kOneClass) {
    const int s = pl.one_class;
    for (uint32_t i = 0; i < m; ++i) {
      emit(s == 1 ? 1 : (uint64_t{1} << (s - 1)) | br->Get(s - 1));
    }
    return;
  }
  // Each slot of the scale: its class, frequency and cumulative frequency in one word.
  std::array<uint32_t, kProbScale> slots;
  for (int s = 0; s <= kBits; ++s) {
    const uint32_t e = static_cast<uint32_t>(s) | pl.freq[s] << 8 | pl.cum[s] << 20;
    for (uint32_t k = 0; k < pl.freq[s]; ++k) slots[pl.cum[s] + k] = e;
  }
  uint32_t x = in->x;
  for (uint32_t i = 0; i < m; ++i) {
    const uint32_t slot = x & (kProbScale - 1);
    const uint32_t e = slots[slot];
    const int s = static_cast<int>(e & 0xFF);
    x = ((e >> 8) & 0xFFF) * (x >> kProbBits) + slot - (e >> 20);
    const bool renorm = x < kRansL;
    const bool have = in->end - in->p >= 2;  // else zeros are read, and the block refused
    const uint32_t word = have ? (uint32_t{in->p[0]} << 8 | in->p[1]) : 0u;
    in->overrun |= renorm && !have;
    x = renorm ? (x << 16) | word : x;
    in->p += (renorm && have) ? 2 : 0;
    emit(s <= 1 ? static_cast<uint64_t>(s) : (uint64_t{1} << (s - 1)) | br->Get(s - 1));
  }
  in->x = x;
}

}  // namespace

void EncodeRecordBlock(const uint8_t* records, uint32_t n, std::string* out) {
  PutVarint(out, n);
  out->append(reinterpret_cast<const char*>(records), kRecordSize);
  const uint32_t m = n - 1;  // residuals per field
  // Residuals (zigzagged deltas) of every field, field-major.
  std::vector<uint64_t> z(size_t{m} * kFields.size());
  std::array<ColumnPlan, kFields.size()> plans;
  for (size_t c = 0; c < kFields.size(); ++c) {
    const Field& f = kFields[c];
    const int bits = 8 * f.bytes;
    uint64_t prev = Transform(records, f);
    uint32_t count[kMaxSymbols] = {};
    uint64_t* zc = z.data() + c * m;
    for (uint32_t i = 0; i < m; ++i) {
      const uint64_t t = Transform(records + size_t{i + 1} * kRecordSize, f);
      const uint64_t d = (t - prev) & Mask(bits);
      prev = t;
      // Zigzag in `bits` bits: small magnitudes of either sign become small numbers.
      const uint64_t sign = (d >> (bits - 1)) & 1;
      zc[i] = ((d << 1) ^ (sign ? Mask(bits) : 0)) & Mask(bits);
      ++count[ClassOf(zc[i])];
    }
    ColumnPlan& p = plans[c];
    int used = 0, last = 0;
    for (int s = 0; s < kMaxSymbols; ++s) {
      if (count[s]) {
        ++used;
        last = s;
      }
    }
    if (m == 0 || (used == 1 && last == 0)) {
      p.mode = kAllZero;
      out->push_back(static_cast<char>(kAllZero));
    } else if (used == 1) {
      p.mode = kOneClass;
      p.one_class = static_cast<uint8_t>(last);
      out->push_back(static_cast<char>(kOneClass));
      out->push_back(static_cast<char>(last));
    } else {
      p.mode = kTable;
      Normalise(count, m, p.freq);
      out->push_back(static_cast<char>(kTable));
      out->push_back(static_cast<char>(used));
      uint32_t cum = 0;
      for (int s = 0; s < kMaxSymbols; ++s) {
        p.cum[s] = cum;
        cum += p.freq[s];
        if (!p.freq[s]) continue;
        out->push_back(static_cast<char>(s));
        PutVarint(out, p.freq[s] - 1);
      }
    }
  }
  // rANS over the classes of the table-coded fields, encoded backwards so that the decoder
  // reads field 0's residuals first.
  std::vector<uint8_t> rans;
  bool any_table = false;
  for (const ColumnPlan& p : plans) any_table = any_table || p.mode == kTable;
  if (any_table) {
    uint32_t x = kRansL;
    for (size_t c = kFields.size(); c-- > 0;) {
      const ColumnPlan& p = plans[c];
      if (p.mode != kTable) continue;
      const uint64_t* zc = z.data() + c * m;
      for (uint32_t i = m; i-- > 0;) {
        const int s = ClassOf(zc[i]);
        const uint32_t f = p.freq[s];
        const uint32_t x_max = ((kRansL >> kProbBits) << 16) * f;
        if (x >= x_max) {
          rans.push_back(static_cast<uint8_t>(x & 0xFF));
          rans.push_back(static_cast<uint8_t>((x >> 8) & 0xFF));
          x >>= 16;
        }
        x = ((x / f) << kProbBits) + (x % f) + p.cum[s];
      }
    }
    for (int i = 0; i < 4; ++i) {
      rans.push_back(static_cast<uint8_t>(x & 0xFF));
      x >>= 8;
    }
    std::reverse(rans.begin(), rans.end());
    const auto size = static_cast<uint32_t>(rans.size());
    for (int i = 0; i < 4; ++i) out->push_back(static_cast<char>(size >> (8 * i)));
    out->append(reinterpret_cast<const char*>(rans.data()), rans.size());
  }
  // The bits below each residual's leading one, field-major, least significant bit first.
  BitWriter bw(out);
  for (size_t c = 0; c < kFields.size(); ++c) {
    const uint64_t* zc = z.data() + c * m;
    for (uint32_t i = 0; i < m; ++i) {
      const int s = ClassOf(zc[i]);
      if (s >= 2) bw.Put(zc[i] & Mask(s - 1), s - 1);
    }
  }
  bw.Flush();
}

bool DecodeRecordBlock(const uint8_t* src, size_t len, uint8_t* dst, uint32_t capacity,
                       uint32_t* n_out, std::string* error) {
  const uint8_t* p = src;
  const uint8_t* end = src + len;
  auto fail = [error](const char* what) {
    *error = what;
    return false;
  };
  uint32_t n = 0;
  for (int shift = 0;; shift += 7) {
    if (p >= end || shift > 28) return fail("truncated record count");
    n |= uint32_t{static_cast<uint8_t>(*p & 0x7F)} << shift;
    if (!(*p++ & 0x80)) break;
  }
  if (n == 0 || n > capacity || n > kMaxBlockRecords) return fail("record count out of range");
  if (static_cast<size_t>(end - p) < kRecordSize) return fail("truncated first record");
  std::memcpy(dst, p, kRecordSize);
  dst[62] = dst[63] = 0;
  p += kRecordSize;
  const uint32_t m = n - 1;
  std::array<ColumnPlan, kFields.size()> plans;
  bool any_table = false;
  for (size_t c = 0; c < kFields.size(); ++c) {
    ColumnPlan& pl = plans[c];
    if (p >= end) return fail("truncated field header");
    const uint8_t mode = *p++;
    const int max_class = 8 * kFields[c].bytes;
    if (mode == kAllZero) {
      pl.mode = kAllZero;
    } else if (mode == kOneClass) {
      if (p >= end) return fail("truncated field header");
      pl.mode = kOneClass;
      pl.one_class = *p++;
      if (pl.one_class > max_class || pl.one_class == 0) return fail("bad magnitude class");
    } else if (mode == kTable) {
      pl.mode = kTable;
      any_table = true;
      if (p >= end) return fail("truncated frequency table");
      const int used = *p++;
      if (used < 2 || used > max_class + 1) return fail("bad frequency table size");
      int prev = -1;
      uint32_t sum = 0;
      for (int k = 0; k < used; ++k) {
        if (p >= end) return fail("truncated frequency table");
        const int s = *p++;
        if (s <= prev || s > max_class) return fail("bad frequency table class");
        prev = s;
        uint32_t f = 0;
        for (int shift = 0;; shift += 7) {
          if (p >= end || shift > 14) return fail("truncated frequency table");
          f |= uint32_t{static_cast<uint8_t>(*p & 0x7F)} << shift;
          if (!(*p++ & 0x80)) break;
        }
        pl.freq[s] = f + 1;
        sum += f + 1;
        if (sum > kProbScale) return fail("frequencies exceed the scale");
      }
      if (sum != kProbScale) return fail("frequencies do not sum to the scale");
      uint32_t cum = 0;
      for (int s = 0; s < kMaxSymbols; ++s) {
        pl.cum[s] = cum;
        cum += pl.freq[s];
      }
    } else {
      return fail("unknown field mode");
    }
  }
  const uint8_t* rans = p;
  const uint8_t* rans_end = p;
  if (any_table) {
    if (end - p < 4) return fail("truncated rANS size");
    const uint32_t size = static_cast<uint32_t>(Load(p, 4));
    p += 4;
    if (size < 4 || size > static_cast<size_t>(end - p)) return fail("bad rANS size");
    rans = p;
    rans_end = p + size;
    p = rans_end;
  }
  uint32_t x = 0;
  if (any_table) {
    x = static_cast<uint32_t>(rans[0]) << 24 | static_cast<uint32_t>(rans[1]) << 16 |
        static_cast<uint32_t>(rans[2]) << 8 | rans[3];
    rans += 4;
    if (x < kRansL) return fail("bad rANS state");
  }
  BitReader br(p, end);
  RansIn in{x, rans, rans_end, false};
  for (size_t c = 0; c < kFields.size(); ++c) {
    const Field& f = kFields[c];
    switch (f.bytes) {
      case 8: DecodeColumn<uint64_t, Kind::kInt>(plans[c], f, dst, m, &in, &br); break;
      case 4:
        if (f.kind == Kind::kFloat) {
          DecodeColumn<uint32_t, Kind::kFloat>(plans[c], f, dst, m, &in, &br);
        } else {
          DecodeColumn<uint32_t, Kind::kInt>(plans[c], f, dst, m, &in, &br);
        }
        break;
      case 2: DecodeColumn<uint16_t, Kind::kInt>(plans[c], f, dst, m, &in, &br); break;
      default:
        if (f.kind == Kind::kColour) {
          DecodeColumn<uint8_t, Kind::kColour>(plans[c], f, dst, m, &in, &br);
        } else {
          DecodeColumn<uint8_t, Kind::kInt>(plans[c], f, dst, m, &in, &br);
        }
    }
  }
  x = in.x;
  rans = in.p;
  const bool rans_overrun = in.overrun;
  if (rans_overrun || (any_table && (rans != rans_end || x != kRansL))) {
    return fail("rANS stream damaged");
  }
  if (!br.ok()) {
    return fail("extra bits damaged (wrong length)");
  }
  for (uint32_t i = 1; i < n; ++i) {
    dst[size_t{i} * kRecordSize + 62] = 0;
    dst[size_t{i} * kRecordSize + 63] = 0;
  }
  *n_out = n;
  return true;
}

}  // namespace hvdb::blockcode
