// What the three Gaussian-splat formats share: the cloud's covariance and validation, the
// activations, detection by content and the dispatching reader (the formats are
// gaussian_ply.cc, gaussian_splat.cc and gaussian_spz.cc).
#include "formats/gaussians.h"

#include <zlib.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>

namespace hvdb::formats {
namespace {

std::string FloatText(float v) {
  if (std::isnan(v)) return "nan";
  return v > 0 ? "inf" : "-inf";
}

// Whether every value is finite: the exponent bits of none are all ones.
bool AllFinite(const std::vector<float>& a) {
  uint32_t bad = 0;
  for (float v : a) bad |= (std::bit_cast<uint32_t>(v) & 0x7f800000u) == 0x7f800000u;
  return bad == 0;
}

// The first non-finite value of splat i, as "splat i: <property> is nan", or "".
std::string NonFiniteIn(const GaussianCloud& c, size_t i) {
  auto check = [&](const std::vector<float>& a, size_t per, const char* prefix,
                   const char* const* names) -> std::string {
    for (size_t k = 0; k < per; ++k) {
      const float v = a[i * per + k];
      if (std::isfinite(v)) continue;
      std::string prop = names != nullptr ? names[k] : prefix + std::to_string(k);
      return "splat " + std::to_string(i) + ": " + prop + " is " + FloatText(v);
    }
    return {};
  };
  static const char* const kXyz[] = {"x", "y", "z"};
  static const char* const kOpacity[] = {"opacity"};
  std::string m = check(c.position, 3, "", kXyz);
  if (m.empty()) m = check(c.sh_dc, 3, "f_dc_", nullptr);
  if (m.empty()) m = check(c.sh_rest, c.sh_rest_per_splat(), "f_rest_", nullptr);
  if (m.empty()) m = check(c.opacity, 1, "", kOpacity);
  if (m.empty()) m = check(c.scale, 3, "scale_", nullptr);
  if (m.empty()) m = check(c.rotation, 4, "rot_", nullptr);
  return m;
}

// Inflates the start of a gzip stream into out[0..n); true when n bytes came out.
bool InflatePrefix(std::string_view bytes, unsigned char* out, size_t n) {
  z_stream z{};
  if (inflateInit2(&z, 16 + MAX_WBITS) != Z_OK) return false;
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data()));
  z.avail_in = static_cast<uInt>(std::min<size_t>(bytes.size(), 1u << 20));
  z.next_out = out;
  z.avail_out = static_cast<uInt>(n);
  while (z.avail_out > 0) {
    const int rc = inflate(&z, Z_NO_FLUSH);
    if (rc != Z_OK) break;  // the end, an error, or no progress possible
  }
  const bool full = z.avail_out == 0;
  inflateEnd(&z);
  return full;
}

bool LooksLikeGaussianPly(std::string_view bytes) {
  if (!bytes.starts_with("ply\n") && !bytes.starts_with("ply\r\n")) return false;
  std::string_view head = bytes.substr(0, 64 * 1024);
  const size_t end = head.find("end_header");
  if (end == std::string_view::npos) return false;
  head = head.substr(0, end);
  // Whole words of property lines: "property float f_dc_0" and so on.
  auto has = [&head](std::string_view prop) {
    for (size_t at = head.find(prop); at != std::string_view::npos;
         at = head.find(prop, at + 1)) {
      const bool before = at > 0 && (head[at - 1] == ' ' || head[at - 1] == '\t');
      const size_t after = at + prop.size();
      const bool ends = after == head.size() || head[after] == '\n' || head[after] == '\r' ||
                        head[after] == ' ' || head[after] == '\t';
      if (before && ends) return true;
    }
    return false;
  };
  return has("f_dc_0") && has("opacity") && has("rot_0");
}

bool LooksLikeSplat(std::string_view bytes) {
  if (bytes.empty() || bytes.size() % 32 != 0) return false;
  const size_t n = std::min<size_t>(bytes.size() / 32, 1024);
  for (size_t i = 0; i < n; ++i) {
    for (size_t k = 0; k < 6; ++k) {
      uint32_t u;
      std::memcpy(&u, bytes.data() + i * 32 + k * 4, 4);
      if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
      const float v = std::bit_cast<float>(u);
      if (!std::isfinite(v) || (k >= 3 && v < 0)) return false;
    }
  }
  return true;
}

}  // namespace

void GaussianCloud::Resize(size_t n) {
  position.resize(3 * n);
  scale.resize(3 * n);
  rotation.resize(4 * n);
  opacity.resize(n);
  sh_dc.resize(3 * n);
  sh_rest.resize(n * sh_rest_per_splat());
}

std::array<float, 6> GaussianCloud::Covariance(size_t i) const {
  double w = rotation[4 * i], x = rotation[4 * i + 1], y = rotation[4 * i + 2],
         z = rotation[4 * i + 3];
  const double norm = std::sqrt(w * w + x * x + y * y + z * z);
  if (norm > 0 && std::isfinite(norm)) {
    w /= norm, x /= norm, y /= norm, z /= norm;
  } else {
    w = 1, x = y = z = 0;
  }
  // The rotation matrix of the Inria code's build_rotation (r = w).
  const double r[3][3] = {
      {1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
      {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
      {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
  double s2[3];
  for (int k = 0; k < 3; ++k) {
    const double s = std::exp(static_cast<double>(scale[3 * i + k]));
    s2[k] = s * s;
  }
  auto sigma = [&](int a, int b) {
    return static_cast<float>(r[a][0] * r[b][0] * s2[0] + r[a][1] * r[b][1] * s2[1] +
                              r[a][2] * r[b][2] * s2[2]);
  };
  return {sigma(0, 0), sigma(0, 1), sigma(0, 2), sigma(1, 1), sigma(1, 2), sigma(2, 2)};
}

float Sigmoid(float x) { return 1.0f / (1.0f + std::exp(-x)); }

float Logit(float p) {
  p = std::clamp(p, 1e-7f, 1.0f - 1e-7f);
  return std::log(p / (1.0f - p));
}

Status ValidateGaussianCloud(const GaussianCloud& c, const std::string& name) {
  if (c.sh_degree < 0 || c.sh_degree > kMaxShDegree) {
    return Status::InvalidArgument(name + ": SH degree " + std::to_string(c.sh_degree) +
                                   " (degrees 0 to 3 are supported)");
  }
  const size_t n = c.size();
  auto bad_length = [&](const char* what, size_t got, size_t per) {
    return Status::InvalidArgument(name + ": " + what + " has " + std::to_string(got) +
                                   " values, expected " + std::to_string(per) + " for each of " +
                                   std::to_string(n) + " splats (the length of opacity)");
  };
  if (c.position.size() != 3 * n) return bad_length("position", c.position.size(), 3);
  if (c.scale.size() != 3 * n) return bad_length("scale", c.scale.size(), 3);
  if (c.rotation.size() != 4 * n) return bad_length("rotation", c.rotation.size(), 4);
  if (c.sh_dc.size() != 3 * n) return bad_length("sh_dc", c.sh_dc.size(), 3);
  if (c.sh_rest.size() != n * c.sh_rest_per_splat()) {
    return bad_length("sh_rest", c.sh_rest.size(), c.sh_rest_per_splat());
  }
  // A branch-free pass over every array first (a million splats hold 59 million values); the
  // splat and property are looked for only when it finds a non-finite one.
  if (AllFinite(c.position) && AllFinite(c.sh_dc) && AllFinite(c.sh_rest) &&
      AllFinite(c.opacity) && AllFinite(c.scale) && AllFinite(c.rotation)) {
    return Status::OK();
  }
  for (size_t i = 0; i < n; ++i) {
    std::string m = NonFiniteIn(c, i);
    if (!m.empty()) return Status::InvalidArgument(name + ": " + m);
  }
  return Status::OK();
}

const char* GaussianFormatName(GaussianFormat format) {
  switch (format) {
    case GaussianFormat::k3dgsPly:
      return "3DGS PLY";
    case GaussianFormat::kSpz:
      return "SPZ";
    case GaussianFormat::kSplat:
      return ".splat";
    case GaussianFormat::kGlb:
      return "GLB";
    case GaussianFormat::kUnknown:
      break;
  }
  return "unknown";
}

GaussianFormat DetectGaussianFormat(std::string_view bytes) {
  if (bytes.starts_with("ply")) {
    return LooksLikeGaussianPly(bytes) ? GaussianFormat::k3dgsPly : GaussianFormat::kUnknown;
  }
  if (bytes.starts_with("NGSP")) return GaussianFormat::kSpz;
  if (bytes.starts_with("glTF")) return GaussianFormat::kGlb;
  if (bytes.size() >= 2 && static_cast<unsigned char>(bytes[0]) == 0x1f &&
      static_cast<unsigned char>(bytes[1]) == 0x8b) {
    unsigned char magic[4];
    if (InflatePrefix(bytes, magic, 4) && std::memcmp(magic, "NGSP", 4) == 0) {
      return GaussianFormat::kSpz;
    }
    return GaussianFormat::kUnknown;
  }
  return LooksLikeSplat(bytes) ? GaussianFormat::kSplat : GaussianFormat::kUnknown;
}

Result<GaussianCloud> ReadGaussians(std::string_view bytes, const std::string& name) {
  switch (DetectGaussianFormat(bytes)) {
    case GaussianFormat::k3dgsPly:
      return ReadGaussianPly(bytes, name);
    case GaussianFormat::kSpz:
      return ReadSpz(bytes, name);
    case GaussianFormat::kSplat:
      return ReadSplat(bytes, name);
    case GaussianFormat::kGlb:
      return ReadGlb(bytes, name);
    case GaussianFormat::kUnknown:
      break;
  }
  return Status::InvalidArgument(
      name + ": not a Gaussian-splat file: neither a 3DGS PLY (a PLY header with f_dc_0, "
             "opacity and rot_0), an SPZ (NGSP, or gzip of an NGSP stream), a GLB (glTF with "
             "KHR_gaussian_splatting) nor a .splat (32-byte splats with finite positions and "
             "scales)");
}

}  // namespace hvdb::formats
