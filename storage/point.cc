#include "storage/point.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

#include "storage/coding.h"

namespace hvdb {

void EncodePoint(const Point& p, uint8_t* dst) {
  EncodeLE(dst + 0, p.id);
  EncodeLE(dst + 8, p.x);
  EncodeLE(dst + 12, p.y);
  EncodeLE(dst + 16, p.z);
  EncodeLE(dst + 20, p.frame);
  for (int i = 0; i < 6; ++i) EncodeLE(dst + 24 + 4 * i, p.cov[i]);
  EncodeLE(dst + 48, p.normal_oct[0]);
  EncodeLE(dst + 50, p.normal_oct[1]);
  EncodeLE(dst + 52, p.label);
  dst[56] = p.r;
  dst[57] = p.g;
  dst[58] = p.b;
  dst[59] = p.flags;
  EncodeLE(dst + 60, p.camera);
  EncodeLE<uint16_t>(dst + 62, 0);
}

Point DecodePointFieldwise(const uint8_t* src) {
  Point p;
  p.id = DecodeLE<uint64_t>(src + 0);
  p.x = DecodeLE<float>(src + 8);
  p.y = DecodeLE<float>(src + 12);
  p.z = DecodeLE<float>(src + 16);
  p.frame = DecodeLE<uint32_t>(src + 20);
  for (int i = 0; i < 6; ++i) p.cov[i] = DecodeLE<float>(src + 24 + 4 * i);
  p.normal_oct[0] = DecodeLE<int16_t>(src + 48);
  p.normal_oct[1] = DecodeLE<int16_t>(src + 50);
  p.label = DecodeLE<uint32_t>(src + 52);
  p.r = src[56];
  p.g = src[57];
  p.b = src[58];
  p.flags = src[59];
  p.camera = DecodeLE<uint16_t>(src + 60);
  p.reserved = 0;
  return p;
}

void EncodePoints(std::span<const Point> points, uint8_t* dst) {
  if (points.empty()) return;  // data() may be null: memcpy must not see it
  if constexpr (std::endian::native == std::endian::little) {
    // Same layout (static_asserts in point.h); only the reserved field must be cleared.
    std::memcpy(dst, points.data(), points.size() * kPointRecordSize);
    for (size_t i = 0; i < points.size(); ++i) EncodeLE<uint16_t>(dst + i * 64 + 62, 0);
  } else {
    for (size_t i = 0; i < points.size(); ++i) EncodePoint(points[i], dst + i * 64);
  }
}

void DecodePoints(const uint8_t* src, size_t n, Point* out) {
  if (n == 0) return;
  if constexpr (std::endian::native == std::endian::little) {
    std::memcpy(static_cast<void*>(out), src, n * kPointRecordSize);
  } else {
    for (size_t i = 0; i < n; ++i) out[i] = DecodePoint(src + i * 64);
  }
}

namespace {
float SignNotZero(float v) { return v >= 0.f ? 1.f : -1.f; }
int16_t ToSnorm16(float v) {
  return static_cast<int16_t>(std::lround(std::clamp(v, -1.f, 1.f) * 32767.f));
}
}  // namespace

std::array<int16_t, 2> EncodeNormal(float nx, float ny, float nz) {
  float l1 = std::fabs(nx) + std::fabs(ny) + std::fabs(nz);
  if (!(l1 > 0.f) || !std::isfinite(l1)) return {0, 0};  // +z
  float u = nx / l1, v = ny / l1;
  if (nz < 0.f) {
    float pu = (1.f - std::fabs(v)) * SignNotZero(u);
    float pv = (1.f - std::fabs(u)) * SignNotZero(v);
    u = pu;
    v = pv;
  }
  return {ToSnorm16(u), ToSnorm16(v)};
}

std::array<float, 3> DecodeNormal(std::array<int16_t, 2> oct) {
  float u = std::max(oct[0] / 32767.f, -1.f), v = std::max(oct[1] / 32767.f, -1.f);
  float z = 1.f - std::fabs(u) - std::fabs(v);
  if (z < 0.f) {
    float pu = (1.f - std::fabs(v)) * SignNotZero(u);
    float pv = (1.f - std::fabs(u)) * SignNotZero(v);
    u = pu;
    v = pv;
  }
  float len = std::sqrt(u * u + v * v + z * z);
  return {u / len, v / len, z / len};
}

std::array<float, 6> CovarianceFromSpanning(const float t1[3], const float t2[3],
                                            const float t3[3]) {
  std::array<float, 6> c{};
  const float* t[3] = {t1, t2, t3};
  for (const float* v : t) {
    c[0] += v[0] * v[0];
    c[1] += v[0] * v[1];
    c[2] += v[0] * v[2];
    c[3] += v[1] * v[1];
    c[4] += v[1] * v[2];
    c[5] += v[2] * v[2];
  }
  return c;
}

}  // namespace hvdb
