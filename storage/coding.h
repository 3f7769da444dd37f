// Little-endian fixed-width encoding, and Morton codes. Every on-disk and on-wire integer and float in hvdb goes
// through these, so the formats in docs/FORMAT.md hold on any host byte order.
#ifndef HVDB_STORAGE_CODING_H_
#define HVDB_STORAGE_CODING_H_

#include <bit>
#include <cstdint>
#include <cstring>
#include <string>

namespace hvdb {

// The Morton (Z-order) code of three 21-bit coordinates (higher bits are dropped): x's bits at
// positions 0, 3, 6, ..., y's at 1, 4, ..., z's at 2, 5, .... Sorting by it keeps points that
// are near in space mostly near in the order (codec's hierarchy, edit's neighbour grid).
inline uint64_t Morton3(uint64_t x, uint64_t y, uint64_t z) {
  auto spread = [](uint64_t v) {  // 21 bits -> every third bit of 63
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
  };
  return spread(x) | spread(y) << 1 | spread(z) << 2;
}

template <typename T>
inline void EncodeLE(uint8_t* dst, T v) {
  static_assert(std::is_trivially_copyable_v<T>);
  if constexpr (sizeof(T) == 1) {
    std::memcpy(dst, &v, 1);
  } else if constexpr (std::is_floating_point_v<T>) {
    using U = std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>;
    EncodeLE<U>(dst, std::bit_cast<U>(v));
  } else {
    using U = std::make_unsigned_t<T>;
    U u = static_cast<U>(v);
    for (size_t i = 0; i < sizeof(T); ++i) dst[i] = static_cast<uint8_t>(u >> (8 * i));
  }
}

template <typename T>
inline T DecodeLE(const uint8_t* src) {
  static_assert(std::is_trivially_copyable_v<T>);
  if constexpr (sizeof(T) == 1) {
    T v;
    std::memcpy(&v, src, 1);
    return v;
  } else if constexpr (std::is_floating_point_v<T>) {
    using U = std::conditional_t<sizeof(T) == 4, uint32_t, uint64_t>;
    return std::bit_cast<T>(DecodeLE<U>(src));
  } else {
    using U = std::make_unsigned_t<T>;
    U u = 0;
    for (size_t i = 0; i < sizeof(T); ++i) u |= static_cast<U>(static_cast<U>(src[i]) << (8 * i));
    return static_cast<T>(u);
  }
}

// Append-style writer and bounds-checked reader over byte strings, for manifests and log records.
class Writer {
 public:
  // Appends to `buf` (moved in; take it back with data()).
  explicit Writer(std::string buf = {}) : buf_(std::move(buf)) {}
  template <typename T>
  void Put(T v) {
    uint8_t b[sizeof(T)];
    EncodeLE(b, v);
    buf_.append(reinterpret_cast<const char*>(b), sizeof(T));
  }
  void PutBytes(const void* p, size_t n) { buf_.append(static_cast<const char*>(p), n); }
  void PutString(const std::string& s) {
    Put<uint32_t>(static_cast<uint32_t>(s.size()));
    buf_ += s;
  }
  std::string& data() { return buf_; }

 private:
  std::string buf_;
};

class Reader {
 public:
  Reader(const uint8_t* p, size_t n) : p_(p), end_(p + n) {}
  // Returns false (and reads nothing) when fewer than sizeof(T) bytes remain.
  template <typename T>
  bool Get(T* out) {
    if (static_cast<size_t>(end_ - p_) < sizeof(T)) return false;
    *out = DecodeLE<T>(p_);
    p_ += sizeof(T);
    return true;
  }
  bool GetBytes(void* out, size_t n) {
    if (static_cast<size_t>(end_ - p_) < n) return false;
    std::memcpy(out, p_, n);
    p_ += n;
    return true;
  }
  bool GetString(std::string* s, size_t max_len = 1 << 20) {
    uint32_t n;
    if (!Get(&n) || n > max_len || static_cast<size_t>(end_ - p_) < n) return false;
    s->assign(reinterpret_cast<const char*>(p_), n);
    p_ += n;
    return true;
  }
  const uint8_t* pos() const { return p_; }
  size_t remaining() const { return static_cast<size_t>(end_ - p_); }
  bool Skip(size_t n) {
    if (remaining() < n) return false;
    p_ += n;
    return true;
  }

 private:
  const uint8_t* p_;
  const uint8_t* end_;
};

// LEB128, as protobuf's varints: ids ascending are stored as their gaps, a byte or two each
// (the log's relabels, the protocol's label flips).
inline void PutVarint(std::string* out, uint64_t v) {
  while (v >= 0x80) {
    out->push_back(static_cast<char>(v | 0x80));
    v >>= 7;
  }
  out->push_back(static_cast<char>(v));
}

// False when the bytes end first or the value does not fit 64 bits.
inline bool GetVarint(Reader* r, uint64_t* v) {
  *v = 0;
  for (int shift = 0; shift < 64; shift += 7) {
    uint8_t b;
    if (!r->Get(&b)) return false;
    *v |= uint64_t{b & 0x7fu} << shift;
    if (!(b & 0x80)) return shift < 63 || b <= 1;
  }
  return false;
}

}  // namespace hvdb

#endif  // HVDB_STORAGE_CODING_H_
