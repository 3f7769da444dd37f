// Niantic's SPZ (formats/gaussians.h): the gzip-compressed versions 2 and 3 and version 4's zstd
// streams, following the reference implementation nianticlabs/spz (src/cc/load-spz.cc,
// splat-types.h, splat-utils.h): its constants, attribute order, float arithmetic and coordinate
// conversion. SPZ stores x right, y up, z back (RUB); hvdb's clouds are the PLY's x right, y
// down, z forward (RDF), so both directions negate y and z of positions, y and z of quaternions,
// and the SH coefficients that are odd in y or z (the reference's flipSh table for RDF <-> RUB).
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "formats/gaussians.h"

namespace hvdb::formats {
namespace {

constexpr uint32_t kMagic = 0x5053474e;  // "NGSP", little-endian
constexpr size_t kHeaderBytes = 16;    // versions 1-3, inside the gzip stream
constexpr size_t kV4HeaderBytes = 32;  // version 4, plain, before the table of contents
constexpr uint8_t kFlagAntialiased = 0x1;
constexpr uint8_t kFlagHasExtensions = 0x2;
constexpr float kColorScale = 0.15f;
constexpr float kSqrt1_2 = 0.707106781186547524401f;
// Deflate cannot compress better than 1032:1 (a 258-byte match per ~2 bits): more declared
// bytes than that is a lie, refused before inflating anything.
constexpr uint64_t kMaxDeflateRatio = 1032;
// Version 4: the reference's bound on points for a file's size (1024:1 over the 9 bytes of a
// position); any file the reference reads passes it.
constexpr uint64_t kMaxZstdRatio = 1024;
// And what all streams may inflate to before anything is allocated for them: 256 times the
// file plus 64 MiB. Real files inflate 3-10 times; zstd could go to ~32 000:1 (RLE blocks), so
// a few hostile kilobytes would otherwise claim gigabytes.
constexpr uint64_t kMaxInflateRatio = 256;
constexpr uint64_t kInflateSlack = uint64_t{64} << 20;
// Its zstd level (compressZstd in load-spz.cc).
constexpr int kZstdLevel = 12;

// RDF <-> RUB: flip x 1, y -1, z -1; the reference's flipP, flipQ (x y z of the quaternion) and
// flipSh (coefficient k of each channel, degree 1 to 3).
constexpr float kFlipP[3] = {1, -1, -1};
constexpr float kFlipQ[3] = {1, -1, -1};  // {y*z, x*z, x*y}
constexpr float kFlipSh[15] = {
    -1, -1, 1,                // degree 1: y z x
    -1, 1, 1, -1, 1, -1,      // degree 2: xy yz 1 xz 1 y
    1, -1, -1, 1, -1, 1};     // degree 3: xyz y z x z x

size_t RotationBytes(uint32_t version) { return version >= 3 ? 4 : 3; }

size_t BytesPerPoint(uint32_t version, int degree) {
  return 9 + 1 + 3 + 3 + RotationBytes(version) + 3 * static_cast<size_t>(ShRestPerChannel(degree));
}

// Version 4's attribute streams, in file order (positions, alphas, colours, scales, rotations,
// SH: the order of the legacy payload, so both decode through Unpack), for n points; the
// reference leaves out an empty stream (SH at degree 0).
std::vector<uint64_t> StreamSizes(uint64_t n, uint32_t version, int degree) {
  std::vector<uint64_t> sizes = {9 * n, n, 3 * n, 3 * n, RotationBytes(version) * n,
                                 3 * static_cast<uint64_t>(ShRestPerChannel(degree)) * n};
  std::erase(sizes, 0);
  return sizes;
}

uint64_t Load64(const unsigned char* p) {
  uint64_t v = 0;
  for (int k = 7; k >= 0; --k) v = (v << 8) | p[k];
  return v;
}

void Store64(uint64_t v, unsigned char* p) {
  for (int k = 0; k < 8; ++k) p[k] = static_cast<unsigned char>(v >> (8 * k));
}

uint32_t Load32(const unsigned char* p) {
  return p[0] | (uint32_t{p[1]} << 8) | (uint32_t{p[2]} << 16) | (uint32_t{p[3]} << 24);
}

void Store32(uint32_t v, unsigned char* p) {
  for (int k = 0; k < 4; ++k) p[k] = static_cast<unsigned char>(v >> (8 * k));
}

// The reference's toUint8 and quantizeSH (x pre-clamped so that the int conversion is defined;
// beyond +-2 the result is 0 or 255 either way).
uint8_t ToUint8(float x) { return static_cast<uint8_t>(std::clamp(std::round(x), 0.0f, 255.0f)); }

uint8_t QuantizeSh(float x, int bucket) {
  x = std::clamp(x, -2.0f, 2.0f);
  int q = static_cast<int>(std::round(x * 128.0f) + 128.0f);
  q = (q + bucket / 2) / bucket * bucket;
  return static_cast<uint8_t>(std::clamp(q, 0, 255));
}

float SigmoidF(float x) { return 1 / (1 + std::exp(-x)); }

// The reference's invSigmoid(alpha / 255), with 0 and 255 a quarter step inside (the reference
// gives +-infinity there); sigmoid of the result * 255 rounds back to the same byte.
float AlphaLogit(uint8_t a) {
  const float p = std::clamp(a / 255.0f, 0.25f / 255.0f, 254.75f / 255.0f);
  return std::log(p / (1.0f - p));
}

// Decodes the attribute streams of `n` points (the payload after the header) into `c`, in
// hvdb's (RDF) coordinates.
void Unpack(const unsigned char* d, size_t n, uint32_t version, int fractional_bits,
            GaussianCloud* c) {
  const size_t dim = static_cast<size_t>(ShRestPerChannel(c->sh_degree));
  const unsigned char* positions = d;
  const unsigned char* alphas = positions + 9 * n;
  const unsigned char* colors = alphas + n;
  const unsigned char* scales = colors + 3 * n;
  const unsigned char* rotations = scales + 3 * n;
  const unsigned char* sh = rotations + RotationBytes(version) * n;
  const float step = std::ldexp(1.0f, -fractional_bits);
  for (size_t i = 0; i < 3 * n; ++i) {
    int32_t fixed = positions[3 * i] | (positions[3 * i + 1] << 8) | (positions[3 * i + 2] << 16);
    if (fixed & 0x800000) fixed -= 0x1000000;  // sign extension
    c->position[i] = kFlipP[i % 3] * (static_cast<float>(fixed) * step);
  }
  for (size_t i = 0; i < n; ++i) c->opacity[i] = AlphaLogit(alphas[i]);
  for (size_t i = 0; i < 3 * n; ++i) {
    c->sh_dc[i] = ((colors[i] / 255.0f) - 0.5f) / kColorScale;
    c->scale[i] = scales[i] / 16.0f - 10.0f;
  }
  for (size_t i = 0; i < n; ++i) {
    float q[4];  // x y z w, as the reference
    if (version >= 3) {
      uint32_t comp = Load32(rotations + 4 * i);
      constexpr uint32_t kMask = (1u << 9) - 1;
      const int largest = static_cast<int>(comp >> 30);
      float sum = 0;
      for (int k = 3; k >= 0; --k) {
        if (k == largest) continue;
        const uint32_t mag = comp & kMask;
        const uint32_t negative = (comp >> 9) & 1;
        comp >>= 10;
        q[k] = kSqrt1_2 * static_cast<float>(mag) / static_cast<float>(kMask);
        if (negative) q[k] = -q[k];
        sum += q[k] * q[k];
      }
      q[largest] = std::sqrt(std::max(0.0f, 1.0f - sum));
    } else {
      const unsigned char* r = rotations + 3 * i;
      float sum = 0;
      for (int k = 0; k < 3; ++k) {
        q[k] = static_cast<float>(r[k]) * (1.0f / 127.5f) + -1.0f;
        sum += q[k] * q[k];
      }
      q[3] = std::sqrt(std::max(0.0f, 1.0f - sum));
    }
    c->rotation[4 * i] = q[3];
    for (int k = 0; k < 3; ++k) c->rotation[4 * i + 1 + k] = kFlipQ[k] * q[k];
  }
  // SPZ: per point coefficient-major (k, then channel); hvdb: channel-major (channel, then k).
  for (size_t i = 0; i < n; ++i) {
    for (size_t k = 0; k < dim; ++k) {
      for (size_t ch = 0; ch < 3; ++ch) {
        const float v = (static_cast<float>(sh[(i * dim + k) * 3 + ch]) - 128.0f) / 128.0f;
        c->sh_rest[i * 3 * dim + ch * dim + k] = kFlipSh[k] * v;
      }
    }
  }
}

// Inflates the rest of the gzip stream `z` (after the header) into exactly `want` bytes; more,
// fewer, a bad stream or bytes after it are Corruption.
Status InflatePayload(z_stream* z, uint64_t want, std::string* out, const std::string& name) {
  out->reserve(static_cast<size_t>(std::min<uint64_t>(want, 64u << 20)));
  unsigned char buf[1 << 16];
  for (;;) {
    z->next_out = buf;
    z->avail_out = sizeof buf;
    const int rc = inflate(z, Z_NO_FLUSH);
    const size_t got = sizeof buf - z->avail_out;
    if (out->size() + got > want) {
      return Status::Corruption(name + ": the gzip stream inflates to more than the " +
                                std::to_string(kHeaderBytes + want) +
                                " bytes its SPZ header declares (refused)");
    }
    out->append(reinterpret_cast<const char*>(buf), got);
    if (rc == Z_STREAM_END) break;
    if (rc == Z_OK) continue;
    if (rc == Z_BUF_ERROR && z->avail_in == 0) {
      return Status::Corruption(name + ": truncated: the gzip stream ends after " +
                                std::to_string(kHeaderBytes + out->size()) + " of the " +
                                std::to_string(kHeaderBytes + want) +
                                " bytes its SPZ header declares");
    }
    return Status::Corruption(name + ": gzip data error" +
                              (z->msg != nullptr ? std::string(" (") + z->msg + ")" : "") +
                              " after " + std::to_string(kHeaderBytes + out->size()) + " bytes");
  }
  if (out->size() != want) {
    return Status::Corruption(name + ": truncated: the SPZ data holds " +
                              std::to_string(kHeaderBytes + out->size()) + " bytes, its header " +
                              "declares " + std::to_string(kHeaderBytes + want));
  }
  if (z->avail_in != 0) {
    return Status::Corruption(name + ": " + std::to_string(z->avail_in) +
                              " bytes follow the end of the gzip stream");
  }
  return Status::OK();
}

struct Inflater {
  z_stream z{};
  bool open = false;
  ~Inflater() {
    if (open) inflateEnd(&z);
  }
};

// Quaternion (x y z w, normalised, in SPZ's coordinates) to the version's bytes.
void PackRotation(const float q[4], uint32_t version, unsigned char* r) {
  if (version >= 3) {
    int largest = 0;
    for (int k = 1; k < 4; ++k) {
      if (std::abs(q[k]) > std::abs(q[largest])) largest = k;
    }
    const uint32_t negate = q[largest] < 0;
    uint32_t comp = static_cast<uint32_t>(largest);
    for (int k = 0; k < 4; ++k) {
      if (k == largest) continue;
      const uint32_t negative = (q[k] < 0) ^ negate;
      // The reference's rounding; at most 511 (|q[k]| can pass 1/sqrt(2) by a rounding error,
      // which the reference lets carry into the sign bit).
      const auto mag = std::min<uint32_t>(
          511, static_cast<uint32_t>(float((1u << 9) - 1) * (std::fabs(q[k]) / kSqrt1_2) + 0.5f));
      comp = (comp << 10) | (negative << 9) | mag;
    }
    Store32(comp, r);
  } else {
    const float s = q[3] < 0 ? -127.5f : 127.5f;
    for (int k = 0; k < 3; ++k) r[k] = ToUint8(q[k] * s + 127.5f);
  }
}

Status Deflate(std::string_view raw, std::string* out, const std::string& name) {
  z_stream z{};
  // The reference's settings: default level, gzip wrapper, memLevel 9.
  if (deflateInit2(&z, Z_DEFAULT_COMPRESSION, Z_DEFLATED, 16 + MAX_WBITS, 9,
                   Z_DEFAULT_STRATEGY) != Z_OK) {
    return Status::Internal(name + ": deflateInit2 failed");
  }
  out->clear();
  out->reserve(raw.size() / 4 + 64);
  size_t in_pos = 0;
  unsigned char buf[1 << 16];
  int rc = Z_OK;
  do {
    const size_t chunk = std::min<size_t>(raw.size() - in_pos, 1u << 30);
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(raw.data() + in_pos));
    z.avail_in = static_cast<uInt>(chunk);
    const bool last = in_pos + chunk == raw.size();
    do {
      z.next_out = buf;
      z.avail_out = sizeof buf;
      rc = deflate(&z, last ? Z_FINISH : Z_NO_FLUSH);
      if (rc == Z_STREAM_ERROR) break;
      out->append(reinterpret_cast<const char*>(buf), sizeof buf - z.avail_out);
    } while (z.avail_out == 0);
    in_pos += chunk;
  } while (in_pos < raw.size() && rc != Z_STREAM_ERROR);
  deflateEnd(&z);
  if (rc != Z_STREAM_END) return Status::Internal(name + ": deflate failed");
  return Status::OK();
}

}  // namespace

namespace {

// What the three header layouts share; version was checked by the caller.
Status CheckHeader(int degree, int fractional_bits, uint8_t flags,
                   const std::string& name) {
  if (degree > kMaxShDegree) {
    return Status::Unsupported(name + ": SH degree " + std::to_string(degree) +
                               " (degrees 0 to 3 are supported)");
  }
  if (fractional_bits > 24) {
    return Status::Corruption(name + ": " + std::to_string(fractional_bits) +
                              " fractional bits for 24-bit positions (at most 24)");
  }
  if (flags & kFlagHasExtensions) {
    return Status::Unsupported(name + ": SPZ extensions (flag 0x2), which may change the "
                                      "coordinate system, are not supported");
  }
  return Status::OK();
}

// Version 4: header, table of contents (compressed and uncompressed size of each stream, u64
// each), then the zstd frames back to back. Each stream inflates into its place in one payload
// laid out as the legacy format's.
Result<GaussianCloud> ReadSpzV4(std::string_view bytes, const std::string& name) {
  const auto* b = reinterpret_cast<const unsigned char*>(bytes.data());
  if (bytes.size() < kV4HeaderBytes) {
    return Status::Corruption(name + ": truncated: " + std::to_string(bytes.size()) +
                              " bytes, less than SPZ version 4's 32-byte header");
  }
  const uint32_t count = Load32(b + 8);
  const int degree = b[12];
  const int fractional_bits = b[13];
  const uint8_t flags = b[14];
  const size_t num_streams = b[15];
  const uint64_t toc = Load32(b + 16);
  HVDB_RETURN_IF_ERROR(CheckHeader(degree, fractional_bits, flags, name));
  const std::vector<uint64_t> want = StreamSizes(count, 4, degree);
  if (num_streams != want.size()) {
    return Status::Corruption(name + ": " + std::to_string(num_streams) + " streams; SH degree " +
                              std::to_string(degree) + " with " + std::to_string(count) +
                              " points has " + std::to_string(want.size()));
  }
  if (toc != kV4HeaderBytes) {  // only extension records lie between, and flag 0x2 is refused
    return Status::Corruption(name + ": the table of contents at byte " + std::to_string(toc) +
                              ", not right after the 32-byte header (no extensions are flagged)");
  }
  if (uint64_t{count} * 9 > uint64_t{bytes.size()} * kMaxZstdRatio) {
    return Status::Corruption(name + ": the SPZ header declares " + std::to_string(count) +
                              " points, more than " + std::to_string(bytes.size()) +
                              " bytes of zstd streams can hold: a damaged header");
  }
  const uint64_t data_start = toc + 16 * num_streams;
  if (data_start > bytes.size()) {
    return Status::Corruption(name + ": truncated within the table of contents");
  }
  uint64_t total = 0;
  uint64_t at = data_start;
  std::vector<uint64_t> compressed(num_streams);
  for (size_t i = 0; i < num_streams; ++i) {
    compressed[i] = Load64(b + toc + 16 * i);
    const uint64_t raw = Load64(b + toc + 16 * i + 8);
    if (raw != want[i]) {
      return Status::Corruption(name + ": stream " + std::to_string(i) + " declares " +
                                std::to_string(raw) + " bytes, its points need " +
                                std::to_string(want[i]));
    }
    if (compressed[i] > bytes.size() - at) {
      return Status::Corruption(name + ": truncated: stream " + std::to_string(i) +
                                " needs " + std::to_string(compressed[i]) + " bytes at byte " +
                                std::to_string(at) + ", the file has " +
                                std::to_string(bytes.size()));
    }
    at += compressed[i];
    total += raw;
  }
  if (at != bytes.size()) {
    return Status::Corruption(name + ": " + std::to_string(bytes.size() - at) +
                              " bytes follow the last zstd stream");
  }
  if (total > uint64_t{bytes.size()} * kMaxInflateRatio + kInflateSlack) {
    return Status::Corruption(name + ": " + std::to_string(bytes.size()) + " bytes of zstd "
                              "streams declare " + std::to_string(total) + " bytes of points, "
                              "more than 256 times their size: refused before inflating");
  }
  // Each frame's own header, where it gives its size, must agree with the table.
  at = data_start;
  for (size_t i = 0; i < num_streams; ++i) {
    const unsigned long long size = ZSTD_getFrameContentSize(b + at, compressed[i]);
    if (size == ZSTD_CONTENTSIZE_ERROR || (size != ZSTD_CONTENTSIZE_UNKNOWN && size != want[i])) {
      return Status::Corruption(name + ": zstd stream " + std::to_string(i) + " is damaged (" +
                                (size == ZSTD_CONTENTSIZE_ERROR
                                     ? std::string("not a zstd frame")
                                     : "its frame holds " + std::to_string(size) +
                                           " bytes, the table says " + std::to_string(want[i])) +
                                ")");
    }
    at += compressed[i];
  }
  std::string payload(total, '\0');
  at = data_start;
  uint64_t out = 0;
  for (size_t i = 0; i < num_streams; ++i) {
    const size_t got = ZSTD_decompress(payload.data() + out, want[i], b + at, compressed[i]);
    if (ZSTD_isError(got) || got != want[i]) {
      return Status::Corruption(name + ": zstd stream " + std::to_string(i) + " is damaged (" +
                                (ZSTD_isError(got) ? ZSTD_getErrorName(got)
                                                   : "it inflates to another size") +
                                ")");
    }
    at += compressed[i];
    out += want[i];
  }
  GaussianCloud c;
  c.sh_degree = degree;
  c.antialiased = (flags & kFlagAntialiased) != 0;
  c.Resize(count);
  Unpack(reinterpret_cast<const unsigned char*>(payload.data()), count, 4, fractional_bits, &c);
  return c;
}

// The legacy payload (16-byte header, then the streams back to back) as version 4's file.
Result<std::string> CompressV4(std::string_view raw, uint32_t count, int degree,
                               const std::string& name) {
  const std::vector<uint64_t> sizes = StreamSizes(count, 4, degree);
  std::string out(kV4HeaderBytes + 16 * sizes.size(), '\0');
  auto* h = reinterpret_cast<unsigned char*>(out.data());
  Store32(kMagic, h);
  Store32(4, h + 4);
  Store32(count, h + 8);
  std::memcpy(h + 12, raw.data() + 12, 3);  // degree, fractional bits, flags
  h[15] = static_cast<unsigned char>(sizes.size());
  Store32(kV4HeaderBytes, h + 16);
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  if (cctx == nullptr) return Status::Internal(name + ": ZSTD_createCCtx failed");
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, kZstdLevel);
  size_t from = kHeaderBytes;
  std::string frame;
  for (size_t i = 0; i < sizes.size(); ++i) {
    frame.resize(ZSTD_compressBound(sizes[i]));
    const size_t n = ZSTD_compress2(cctx, frame.data(), frame.size(), raw.data() + from, sizes[i]);
    if (ZSTD_isError(n)) {
      ZSTD_freeCCtx(cctx);
      return Status::Internal(name + ": zstd: " + ZSTD_getErrorName(n));
    }
    h = reinterpret_cast<unsigned char*>(out.data());  // appends below may move the string
    Store64(n, h + kV4HeaderBytes + 16 * i);
    Store64(sizes[i], h + kV4HeaderBytes + 16 * i + 8);
    out.append(frame.data(), n);
    from += sizes[i];
  }
  ZSTD_freeCCtx(cctx);
  return out;
}

}  // namespace

Result<GaussianCloud> ReadSpz(std::string_view bytes, const std::string& name) {
  const auto* b = reinterpret_cast<const unsigned char*>(bytes.data());
  if (bytes.size() >= 8 && Load32(b) == kMagic) {
    const uint32_t version = Load32(b + 4);
    if (version == 4) return ReadSpzV4(bytes, name);
    if (version > 4) {
      return Status::Unsupported(name + ": SPZ version " + std::to_string(version) +
                                 " (versions 2 to 4 are read)");
    }
    return Status::Corruption(name + ": an uncompressed SPZ stream of version " +
                              std::to_string(version) + "; versions 1 to 3 are gzip-compressed");
  }
  if (bytes.size() < 2 || b[0] != 0x1f || b[1] != 0x8b) {
    return Status::InvalidArgument(name + ": not an SPZ file (neither the magic NGSP of version "
                                          "4 nor gzip's 1f 8b)");
  }
  Inflater in;
  if (inflateInit2(&in.z, 16 + MAX_WBITS) != Z_OK) {
    return Status::Internal(name + ": inflateInit2 failed");
  }
  in.open = true;
  // avail_in is 32 bits: larger inputs are refused rather than fed in pieces.
  if (bytes.size() > std::numeric_limits<uInt>::max()) {
    return Status::LimitExceeded(name + ": SPZ files over 4 GiB are not supported");
  }
  in.z.next_in = const_cast<Bytef*>(b);
  in.z.avail_in = static_cast<uInt>(bytes.size());
  unsigned char h[kHeaderBytes];
  in.z.next_out = h;
  in.z.avail_out = kHeaderBytes;
  while (in.z.avail_out > 0) {
    const int rc = inflate(&in.z, Z_NO_FLUSH);
    if (in.z.avail_out == 0) break;  // the header is whole (the stream may have ended too)
    if (rc == Z_OK) continue;
    if (rc == Z_STREAM_END || (rc == Z_BUF_ERROR && in.z.avail_in == 0)) {
      return Status::Corruption(name + ": truncated: the gzip stream ends within the 16-byte "
                                       "SPZ header");
    }
    return Status::Corruption(name + ": gzip data error" +
                              (in.z.msg != nullptr ? std::string(" (") + in.z.msg + ")" : "") +
                              " in the SPZ header");
  }
  if (Load32(h) != kMagic) {
    return Status::InvalidArgument(name + ": not an SPZ file (the gzip data does not start with "
                                          "the magic NGSP)");
  }
  const uint32_t version = Load32(h + 4);
  const uint32_t count = Load32(h + 8);
  const int degree = h[12];
  const int fractional_bits = h[13];
  const uint8_t flags = h[14];
  if (version == 1) {
    return Status::Unsupported(name + ": SPZ version 1 (float16 positions) is not supported");
  }
  if (version == 0 || version > 3) {
    return Status::Unsupported(name + ": SPZ version " + std::to_string(version) +
                               " in a gzip stream (versions 2 and 3 are gzip-compressed)");
  }
  HVDB_RETURN_IF_ERROR(CheckHeader(degree, fractional_bits, flags, name));
  const uint64_t want = count * uint64_t{BytesPerPoint(version, degree)};
  if (want > uint64_t{bytes.size()} * kMaxDeflateRatio) {
    return Status::Corruption(name + ": the SPZ header declares " + std::to_string(count) +
                              " points (" + std::to_string(want) + " bytes), more than " +
                              std::to_string(bytes.size()) +
                              " bytes of gzip can inflate to: a damaged header");
  }
  std::string payload;
  HVDB_RETURN_IF_ERROR(InflatePayload(&in.z, want, &payload, name));
  GaussianCloud c;
  c.sh_degree = degree;
  c.antialiased = (flags & kFlagAntialiased) != 0;
  c.Resize(count);
  Unpack(reinterpret_cast<const unsigned char*>(payload.data()), count, version, fractional_bits,
         &c);
  return c;
}

Result<std::string> WriteSpz(const GaussianCloud& c, const std::string& name,
                             const SpzWriteOptions& options) {
  if (options.version < 2 || options.version > 4) {
    return Status::InvalidArgument(name + ": SPZ version " + std::to_string(options.version) +
                                   " cannot be written (2, 3 or 4)");
  }
  if (options.fractional_bits < 0 || options.fractional_bits > 23) {
    return Status::InvalidArgument(name + ": " + std::to_string(options.fractional_bits) +
                                   " fractional bits (0 to 23)");
  }
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));
  const size_t n = c.size();
  if (n == 0) {
    return Status::InvalidArgument(name + ": an SPZ file of no splats (the reference loader "
                                          "refuses a point count of 0)");
  }
  if (n > static_cast<size_t>(std::numeric_limits<int32_t>::max())) {
    return Status::InvalidArgument(name + ": " + std::to_string(n) +
                                   " splats, more than SPZ's 2^31 - 1");
  }
  // The most fraction bits (up to the option's) that keep every position within 24 bits.
  float max_abs = 0;
  size_t farthest = 0;
  for (size_t i = 0; i < c.position.size(); ++i) {
    if (std::fabs(c.position[i]) > max_abs) max_abs = std::fabs(c.position[i]), farthest = i / 3;
  }
  constexpr float kMaxFixed = (1 << 23) - 1;
  int bits = options.fractional_bits;
  while (bits > 0 && std::round(max_abs * std::ldexp(1.0f, bits)) > kMaxFixed) --bits;
  if (std::round(max_abs * std::ldexp(1.0f, bits)) > kMaxFixed) {
    return Status::InvalidArgument(name + ": splat " + std::to_string(farthest) +
                                   ": a coordinate of " + std::to_string(max_abs) +
                                   " is beyond SPZ's 24-bit positions (at most 8388607)");
  }
  const auto version = static_cast<uint32_t>(options.version);
  const int degree = c.sh_degree;
  const size_t dim = static_cast<size_t>(ShRestPerChannel(degree));
  std::string raw(kHeaderBytes + n * BytesPerPoint(version, degree), '\0');
  auto* h = reinterpret_cast<unsigned char*>(raw.data());
  Store32(kMagic, h);
  Store32(version, h + 4);
  Store32(static_cast<uint32_t>(n), h + 8);
  h[12] = static_cast<unsigned char>(degree);
  h[13] = static_cast<unsigned char>(bits);
  h[14] = c.antialiased ? kFlagAntialiased : 0;
  h[15] = 0;
  unsigned char* positions = h + kHeaderBytes;
  unsigned char* alphas = positions + 9 * n;
  unsigned char* colors = alphas + n;
  unsigned char* scales = colors + 3 * n;
  unsigned char* rotations = scales + 3 * n;
  unsigned char* sh = rotations + RotationBytes(version) * n;
  const float unit = std::ldexp(1.0f, bits);
  for (size_t i = 0; i < 3 * n; ++i) {
    const auto fixed = static_cast<int32_t>(std::round(c.position[i] * unit * kFlipP[i % 3]));
    for (int k = 0; k < 3; ++k) positions[3 * i + k] = static_cast<unsigned char>(fixed >> (8 * k));
  }
  for (size_t i = 0; i < n; ++i) alphas[i] = ToUint8(SigmoidF(c.opacity[i]) * 255.0f);
  for (size_t i = 0; i < 3 * n; ++i) {
    colors[i] = ToUint8(c.sh_dc[i] * (kColorScale * 255.0f) + (0.5f * 255.0f));
    scales[i] = ToUint8((c.scale[i] + 10.0f) * 16.0f);
  }
  for (size_t i = 0; i < n; ++i) {
    const float* r = &c.rotation[4 * i];
    float q[4] = {r[1], r[2], r[3], r[0]};  // x y z w
    float norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(norm > 0) || !std::isfinite(norm)) {
      q[0] = q[1] = q[2] = 0, q[3] = 1, norm = 1;  // a zero quaternion: the identity
    }
    for (float& v : q) v /= norm;
    for (int k = 0; k < 3; ++k) q[k] *= kFlipQ[k];
    PackRotation(q, version, rotations + RotationBytes(version) * i);
  }
  for (size_t i = 0; i < n; ++i) {
    for (size_t k = 0; k < dim; ++k) {
      const int bucket = k < 3 ? 1 << (8 - 5) : 1 << (8 - 4);  // 5 bits degree 1, 4 the rest
      for (size_t ch = 0; ch < 3; ++ch) {
        sh[(i * dim + k) * 3 + ch] =
            QuantizeSh(kFlipSh[k] * c.sh_rest[i * 3 * dim + ch * dim + k], bucket);
      }
    }
  }
  if (version == 4) return CompressV4(raw, static_cast<uint32_t>(n), degree, name);
  std::string out;
  HVDB_RETURN_IF_ERROR(Deflate(raw, &out, name));
  return out;
}

}  // namespace hvdb::formats
