// antimatter15/splat's .splat (formats/gaussians.h): 32 bytes a splat, no header. The writer
// follows the viewer's own PLY conversion (processPlyBuffer in main.js): double arithmetic and
// Uint8ClampedArray's rounding (to nearest, ties to even, clamped to 0..255).
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "formats/gaussians.h"

namespace hvdb::formats {
namespace {

constexpr size_t kSplatBytes = 32;

float LoadFloatLE(const char* p) {
  uint32_t u;
  std::memcpy(&u, p, 4);
  if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
  return std::bit_cast<float>(u);
}

void StoreFloatLE(float v, char* p) {
  uint32_t u = std::bit_cast<uint32_t>(v);
  if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
  std::memcpy(p, &u, 4);
}

// JavaScript's ToUint8Clamp, what storing into a Uint8ClampedArray does.
uint8_t ToUint8Clamp(double x) {
  if (!(x > 0)) return 0;  // NaN too
  if (x >= 255) return 255;
  const double f = std::floor(x);
  if (f + 0.5 < x) return static_cast<uint8_t>(f + 1);
  if (x < f + 0.5) return static_cast<uint8_t>(f);
  const auto fi = static_cast<uint8_t>(f);
  return fi % 2 == 0 ? fi : static_cast<uint8_t>(fi + 1);
}

}  // namespace

Result<GaussianCloud> ReadSplat(std::string_view bytes, const std::string& name) {
  if (bytes.size() % kSplatBytes != 0) {
    return Status::Corruption(name + ": " + std::to_string(bytes.size()) +
                              " bytes is not a multiple of the 32 bytes of a .splat splat (" +
                              std::to_string(bytes.size() / kSplatBytes) + " splats and " +
                              std::to_string(bytes.size() % kSplatBytes) +
                              " bytes left over): the file is cut short or not a .splat");
  }
  const size_t n = bytes.size() / kSplatBytes;
  static const char* const kProps[] = {"x", "y", "z", "scale_0", "scale_1", "scale_2"};
  GaussianCloud c;
  c.sh_degree = 0;
  c.Resize(n);
  for (size_t i = 0; i < n; ++i) {
    const char* s = bytes.data() + i * kSplatBytes;
    for (int k = 0; k < 6; ++k) {
      const float v = LoadFloatLE(s + 4 * k);
      if (!std::isfinite(v) || (k >= 3 && v < 0)) {
        return Status::InvalidArgument(
            name + ": splat " + std::to_string(i) + ": " + kProps[k] + " is " +
            (std::isnan(v) ? std::string("nan") : std::isinf(v) ? (v > 0 ? "inf" : "-inf")
                                                                  : std::to_string(v)) +
            (k >= 3 ? " (a .splat scale is linear: finite and not negative)" : ""));
      }
      if (k < 3) {
        c.position[3 * i + k] = v;
      } else {
        // A zero scale (a log scale below float's range when written) reads as the smallest.
        c.scale[3 * i + k - 3] = std::log(std::max(v, std::numeric_limits<float>::denorm_min()));
      }
    }
    const auto* u = reinterpret_cast<const unsigned char*>(s + 24);
    for (int k = 0; k < 3; ++k) {
      c.sh_dc[3 * i + k] = static_cast<float>((u[k] / 255.0 - 0.5) / kShC0);
    }
    // 0 and 255 would be logits of +-infinity: a quarter step inside, which writes back the same.
    const double a = std::clamp(u[3] / 255.0, 0.25 / 255, 254.75 / 255);
    c.opacity[i] = static_cast<float>(std::log(a / (1 - a)));
    for (int k = 0; k < 4; ++k) c.rotation[4 * i + k] = (u[4 + k] - 128) / 128.0f;
  }
  return c;
}

Result<std::string> WriteSplat(const GaussianCloud& c, const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));
  const size_t n = c.size();
  std::string out(n * kSplatBytes, '\0');
  for (size_t i = 0; i < n; ++i) {
    char* s = out.data() + i * kSplatBytes;
    for (int k = 0; k < 3; ++k) StoreFloatLE(c.position[3 * i + k], s + 4 * k);
    for (int k = 0; k < 3; ++k) {
      const auto linear = static_cast<float>(std::exp(static_cast<double>(c.scale[3 * i + k])));
      if (!std::isfinite(linear)) {
        return Status::InvalidArgument(name + ": splat " + std::to_string(i) + ": scale_" +
                                       std::to_string(k) + " " + std::to_string(c.scale[3 * i + k]) +
                                       " is too large for .splat's linear float scale");
      }
      StoreFloatLE(linear, s + 12 + 4 * k);
    }
    auto* u = reinterpret_cast<unsigned char*>(s + 24);
    for (int k = 0; k < 3; ++k) u[k] = ToUint8Clamp((0.5 + kShC0 * c.sh_dc[3 * i + k]) * 255);
    u[3] = ToUint8Clamp(1 / (1 + std::exp(-static_cast<double>(c.opacity[i]))) * 255);
    double q[4], norm2 = 0;
    for (int k = 0; k < 4; ++k) q[k] = c.rotation[4 * i + k], norm2 += q[k] * q[k];
    const double norm = std::sqrt(norm2);
    if (!(norm > 0) || !std::isfinite(norm)) {
      q[0] = 1, q[1] = q[2] = q[3] = 0;  // a zero quaternion: the identity
    } else {
      for (double& v : q) v /= norm;
    }
    for (int k = 0; k < 4; ++k) u[4 + k] = ToUint8Clamp(q[k] * 128 + 128);
  }
  return out;
}

}  // namespace hvdb::formats
