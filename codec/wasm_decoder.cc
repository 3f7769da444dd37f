// The hvdb7 decoder of the web page (web/src/hvdb7_worker.js), compiled to WebAssembly by
// codec/wasm.cmake. A tiny C ABI: the page copies a stream into hvdb7_buffer(n), calls
// hvdb7_decode(buffer, n) and reads the packed columns it returns (until the next call).
//
// Result layout (little endian, every offset a multiple of 4, from the result's start):
//   u32 count, u32 attributes (codec::Attribute bits the stream carries), u32 offsets of the
//   position (f32 x 3n), colour (u8 x 3n), covariance (f32 x 6n), label (u32 x n) and flags
//   (u8 x n) columns (0: the stream has no such attribute), u32 total bytes.
// These are the columns the renderer draws (web/src/renderer.js createChunk), as the COLUMNS
// encoding carries them (docs/PROTOCOL.md, "Point columns").
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "codec/codec.h"

namespace {

std::vector<uint8_t> g_input;
std::vector<uint32_t> g_result;  // u32 words: keeps the columns 4-byte aligned
std::string g_error;

constexpr uint64_t kMaxPoints = 1u << 22;

uint32_t Words(uint64_t bytes) { return static_cast<uint32_t>((bytes + 3) / 4); }

}  // namespace

extern "C" {

// A buffer of at least `size` bytes for the stream (owned here, reused by later calls).
uint8_t* hvdb7_buffer(uint32_t size) {
  if (g_input.size() < size) g_input.resize(size);
  return g_input.data();
}

// Decodes `len` bytes at `data`; null on error (then hvdb7_error() says why).
const uint32_t* hvdb7_decode(const uint8_t* data, uint32_t len) {
  using namespace hvdb;
  codec::StreamInfo info;
  std::string_view stream(reinterpret_cast<const char*>(data), len);
  Status st = codec::ReadInfo(stream, &info);
  std::vector<Point> pts;
  if (st.ok()) {
    codec::DecodeOptions o;
    o.threads = 1;  // no std::thread without SharedArrayBuffer
    // A server batch holds at most 16 384 points; a header claiming far more is refused with a
    // message rather than aborting on a 2 GiB memory.
    o.max_points = kMaxPoints;
    st = codec::Decode(stream, &pts, o);
  }
  if (!st.ok()) {
    g_error = st.ToString();
    return nullptr;
  }
  const size_t n = pts.size();
  const uint32_t a = info.attributes;
  constexpr uint32_t kHeaderWords = 8;
  uint32_t at = kHeaderWords;
  auto place = [&](bool has, uint64_t bytes) -> uint32_t {
    if (!has) return 0;
    uint32_t off = at * 4;
    at += Words(bytes);
    return off;
  };
  const uint32_t pos = place(true, 12 * n);
  const uint32_t color = place(a & codec::kColor, 3 * n);
  const uint32_t cov = place(a & codec::kCovariance, 24 * n);
  const uint32_t label = place(a & codec::kLabel, 4 * n);
  const uint32_t flags = place(a & codec::kFlags, n);
  g_result.assign(at, 0);
  uint32_t* w = g_result.data();
  auto* bytes = reinterpret_cast<uint8_t*>(w);
  w[0] = static_cast<uint32_t>(n);
  w[1] = a;
  w[2] = pos, w[3] = color, w[4] = cov, w[5] = label, w[6] = flags;
  w[7] = at * 4;
  for (size_t i = 0; i < n; ++i) {
    const Point& p = pts[i];
    const float xyz[3] = {p.x, p.y, p.z};
    std::memcpy(bytes + pos + 12 * i, xyz, 12);
    if (color) {
      bytes[color + 3 * i] = p.r, bytes[color + 3 * i + 1] = p.g, bytes[color + 3 * i + 2] = p.b;
    }
    if (cov) std::memcpy(bytes + cov + 24 * i, p.cov.data(), 24);
    if (label) std::memcpy(bytes + label + 4 * i, &p.label, 4);
    if (flags) bytes[flags + i] = p.flags;
  }
  return w;
}

const char* hvdb7_error() { return g_error.c_str(); }

}  // extern "C"
