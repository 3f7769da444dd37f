// Adaptive binary range coder and the integer binarisation the point coder puts on it.
//
// The coder is the one LZMA uses (a carry-propagating range encoder over 11-bit adaptive bit
// probabilities, shift-5 adaptation), the standard answer for "arithmetic coding of modelled
// binary decisions" since Moffat et al. 1998 (thesis 7.4 cites them). It is written here rather
// than taken from a library because Debian ships no standalone adaptive arithmetic coder with
// a bit-model API (liblzma hides its coder), and it is 100 lines. docs/CODEC.md specifies it
// to the bit, so an independent decoder can be written from the document alone.
//
// Integers are binarised Exp-Golomb style with adaptive contexts: a zero flag, a sign, the
// length of the magnitude in unary (one adaptive bit per length); below the leading one, for
// magnitudes of up to 6 bits every bit in a binary tree of contexts per length, for longer ones
// the next two bits adaptive and the rest as equiprobable bits.
#ifndef HVDB_CODEC_RANGE_CODER_H_
#define HVDB_CODEC_RANGE_CODER_H_

#include <bit>
#include <cstddef>
#include <cstdint>
#include <string>

namespace hvdb::codec {

inline constexpr int kProbBits = 11;
inline constexpr uint16_t kProbInit = 1u << (kProbBits - 1);
inline constexpr int kMoveBits = 5;
inline constexpr uint32_t kTop = 1u << 24;

// Probability that the next bit is 0, in units of 2^-11.
struct BitModel {
  uint16_t p = kProbInit;
};

class RangeEncoder {
 public:
  explicit RangeEncoder(std::string* out) : out_(out) {}

  void Bit(BitModel& m, unsigned bit) {
    BitP(m.p, kProbBits, bit);
    if (bit == 0) {
      m.p = static_cast<uint16_t>(m.p + (((1u << kProbBits) - m.p) >> kMoveBits));
    } else {
      m.p = static_cast<uint16_t>(m.p - (m.p >> kMoveBits));
    }
  }
  // A bit whose probability of being 0 is p / 2^bits (0 < p < 2^bits, bits <= 16), no model:
  // the octree's contexts keep their own (codec/octree.cc).
  void BitP(uint32_t p, int bits, unsigned bit) {
    const uint32_t bound = (range_ >> bits) * p;
    if (bit == 0) {
      range_ = bound;
    } else {
      low_ += bound;
      range_ -= bound;
    }
    while (range_ < kTop) {
      range_ <<= 8;
      ShiftLow();
    }
  }
  // `count` equiprobable bits of v, most significant first.
  void Direct(uint64_t v, int count) {
    for (int i = count - 1; i >= 0; --i) {
      range_ >>= 1;
      if ((v >> i) & 1) low_ += range_;
      while (range_ < kTop) {
        range_ <<= 8;
        ShiftLow();
      }
    }
  }
  // Writes the last bytes; the encoder is done afterwards.
  void Finish() {
    for (int i = 0; i < 5; ++i) ShiftLow();
  }

 private:
  void ShiftLow() {
    if (static_cast<uint32_t>(low_) < 0xFF000000u || (low_ >> 32) != 0) {
      uint8_t carry = static_cast<uint8_t>(low_ >> 32);
      uint8_t temp = cache_;
      do {
        out_->push_back(static_cast<char>(static_cast<uint8_t>(temp + carry)));
        temp = 0xFF;
      } while (--cache_size_ != 0);
      cache_ = static_cast<uint8_t>(low_ >> 24);
    }
    ++cache_size_;
    low_ = (low_ & 0x00FFFFFFu) << 8;
  }

  std::string* out_;
  uint64_t low_ = 0;
  uint32_t range_ = 0xFFFFFFFFu;
  uint8_t cache_ = 0;
  uint64_t cache_size_ = 1;
};

// Reads past the end as zero bytes and counts them: a well-formed sub-stream is never read
// past its end, so overrun() != 0 after decoding means the data was corrupt or truncated.
class RangeDecoder {
 public:
  RangeDecoder(const uint8_t* p, size_t n) : p_(p), end_(p + n) {
    for (int i = 0; i < 5; ++i) code_ = (code_ << 8) | Next();
  }

  unsigned Bit(BitModel& m) {
    const unsigned bit = BitP(m.p, kProbBits);
    if (bit == 0) {
      m.p = static_cast<uint16_t>(m.p + (((1u << kProbBits) - m.p) >> kMoveBits));
    } else {
      m.p = static_cast<uint16_t>(m.p - (m.p >> kMoveBits));
    }
    return bit;
  }
  unsigned BitP(uint32_t p, int bits) {
    const uint32_t bound = (range_ >> bits) * p;
    unsigned bit;
    if (code_ < bound) {
      range_ = bound;
      bit = 0;
    } else {
      code_ -= bound;
      range_ -= bound;
      bit = 1;
    }
    while (range_ < kTop) {
      range_ <<= 8;
      code_ = (code_ << 8) | Next();
    }
    return bit;
  }
  uint64_t Direct(int count) {
    uint64_t v = 0;
    for (int i = 0; i < count; ++i) {
      range_ >>= 1;
      unsigned bit = code_ >= range_ ? 1 : 0;
      if (bit) code_ -= range_;
      v = (v << 1) | bit;
      while (range_ < kTop) {
        range_ <<= 8;
        code_ = (code_ << 8) | Next();
      }
    }
    return v;
  }
  size_t overrun() const { return overrun_; }

 private:
  uint32_t Next() {
    if (p_ < end_) return *p_++;
    ++overrun_;
    return 0;
  }

  const uint8_t* p_;
  const uint8_t* end_;
  uint32_t code_ = 0;
  uint32_t range_ = 0xFFFFFFFFu;
  size_t overrun_ = 0;
};

// Adaptive model of one integer-valued symbol (one context).
struct IntModel {
  static constexpr int kMaxLen = 64;
  BitModel zero, sign;
  BitModel len[kMaxLen];    // unary length of the magnitude: bit i = "longer than i+1 bits"
  BitModel second[kMaxLen]; // the bit below the leading one, per length
  BitModel third[kMaxLen][2];  // the next bit, per length and second bit
  // Short magnitudes (bit length <= kTreeLen + 1): every bit below the leading one, in a
  // binary tree per length (the whole distribution inside each length class).
  static constexpr int kTreeLen = 5;
  BitModel tree[kTreeLen + 1][1 << kTreeLen];
};

// Magnitude m >= 1: its bit length in unary, then the bits below the leading one (above).
inline void EncodeMagnitude(RangeEncoder& rc, IntModel& m, uint64_t mag) {
  int k = std::bit_width(mag) - 1;  // 0..63
  for (int i = 0; i < k; ++i) rc.Bit(m.len[i], 1);
  if (k < IntModel::kMaxLen - 1) rc.Bit(m.len[k], 0);
  if (k >= 1 && k <= IntModel::kTreeLen) {
    unsigned node = 1;
    for (int i = k - 1; i >= 0; --i) {
      const unsigned bit = static_cast<unsigned>((mag >> i) & 1);
      rc.Bit(m.tree[k][node], bit);
      node = (node << 1) | bit;
    }
  } else if (k >= 1) {
    const unsigned b2 = static_cast<unsigned>((mag >> (k - 1)) & 1);
    rc.Bit(m.second[k], b2);
    if (k >= 2) {
      rc.Bit(m.third[k][b2], static_cast<unsigned>((mag >> (k - 2)) & 1));
      if (k >= 3) rc.Direct(mag, k - 2);
    }
  }
}

inline uint64_t DecodeMagnitude(RangeDecoder& rc, IntModel& m) {
  int k = 0;
  while (k < IntModel::kMaxLen - 1 && rc.Bit(m.len[k])) ++k;
  uint64_t mag = 1;
  if (k >= 1 && k <= IntModel::kTreeLen) {
    unsigned node = 1;
    for (int i = 0; i < k; ++i) node = (node << 1) | rc.Bit(m.tree[k][node]);
    mag = node;
  } else if (k >= 1) {
    const unsigned b2 = rc.Bit(m.second[k]);
    mag = (mag << 1) | b2;
    if (k >= 2) {
      mag = (mag << 1) | rc.Bit(m.third[k][b2]);
      if (k >= 3) mag = (mag << (k - 2)) | rc.Direct(k - 2);
    }
  }
  return mag;
}

inline void EncodeUnsigned(RangeEncoder& rc, IntModel& m, uint64_t v) {
  rc.Bit(m.zero, v == 0 ? 0 : 1);
  if (v != 0) EncodeMagnitude(rc, m, v);
}
inline uint64_t DecodeUnsigned(RangeDecoder& rc, IntModel& m) {
  if (!rc.Bit(m.zero)) return 0;
  return DecodeMagnitude(rc, m);
}

// Signed values travel as a zero flag, a sign and |v| (two's complement wrap for INT64_MIN).
inline void EncodeSigned(RangeEncoder& rc, IntModel& m, int64_t v) {
  rc.Bit(m.zero, v == 0 ? 0 : 1);
  if (v == 0) return;
  rc.Bit(m.sign, v < 0 ? 1 : 0);
  uint64_t mag = v < 0 ? 0 - static_cast<uint64_t>(v) : static_cast<uint64_t>(v);
  EncodeMagnitude(rc, m, mag);
}
inline int64_t DecodeSigned(RangeDecoder& rc, IntModel& m) {
  if (!rc.Bit(m.zero)) return 0;
  bool neg = rc.Bit(m.sign) != 0;
  uint64_t mag = DecodeMagnitude(rc, m);
  return neg ? static_cast<int64_t>(0 - mag) : static_cast<int64_t>(mag);
}

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_RANGE_CODER_H_
