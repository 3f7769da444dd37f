// GLB (binary glTF 2.0) with KHR_gaussian_splatting (formats/gaussians.h), the ratified Khronos
// extension (KhronosGroup/glTF, extensions/2.0/Khronos/KHR_gaussian_splatting): a POINTS
// primitive with POSITION and KHR_gaussian_splatting:ROTATION (a unit quaternion x y z w),
// :SCALE (LINEAR, exp of the cloud's log scale: the ratified text and splat-transform; a review
// draft said log), :OPACITY (linear 0..1, the sigmoid of the logit) and :SH_DEGREE_l_COEF_n (r g b
// of the coefficient of degree l, order m = n - l). Written: PlayCanvas splat-transform's layout,
// one node, mesh and primitive, a bufferView per attribute. Read: every splat primitive, placed
// by its node's world transform when that is a similarity (gaussian_glb_nodes.h).
//
// Coordinates: glTF is x left, y up, z forward (LUF), the cloud x right, y down, z forward (RDF):
// a 180-degree turn about z, C = diag(-1, -1, 1), its own inverse, so both directions apply it.
//   position  (x, y, z) -> (-x, -y, z)
//   rotation  left-multiplied by q_z = (w 0, x 0, y 0, z 1): R(q_z q) = C R(q), so the
//             covariance becomes C R S S^T R^T C^T = C Sigma C^T. Cloud (w, x, y, z) ->
//             stored x y z w = (-y, x, w, -z); stored (x', y', z', w') -> cloud
//             (w, x, y, z) = (z', y', -x', -w')
//   SH        the real SH Y_lm is a polynomial in the direction's x, y, z: one in z and r^2 times
//             Re or Im of (x + iy)^|m|, homogeneous of degree |m| in (x, y). (x, y) -> (-x, -y)
//             thus gives Y_lm(C d) = (-1)^m Y_lm(d), and the coefficient flips with it so the
//             colour in every direction is kept: degree 1 - + -, degree 2 + - + - +, degree 3
//             - + - + - + -, DC unchanged (splat-transform writes COEF_0 = -f_rest_0).
// Nothing throws: nlohmann's exceptions are caught here and become Status errors.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <new>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "formats/gaussian_glb_nodes.h"
#include "formats/gaussians.h"

namespace hvdb::formats {
namespace {

using json = nlohmann::json;

constexpr uint32_t kGlbMagic = 0x46546C67;   // "glTF"
constexpr uint32_t kChunkJson = 0x4E4F534A;  // "JSON"
constexpr uint32_t kChunkBin = 0x004E4942;   // "BIN\0"
constexpr uint64_t kByte = 5120, kUnsignedByte = 5121, kShort = 5122, kFloat = 5126;
constexpr const char* kExt = "KHR_gaussian_splatting";
constexpr std::string_view kPrefix = "KHR_gaussian_splatting:";

uint32_t Load32(const char* p) {
  uint32_t u;
  std::memcpy(&u, p, 4);
  if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
  return u;
}

uint16_t Load16(const char* p) {
  uint16_t u;
  std::memcpy(&u, p, 2);
  if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap16(u);
  return u;
}

void Store32(uint32_t v, char* p) {
  if constexpr (std::endian::native == std::endian::big) v = __builtin_bswap32(v);
  std::memcpy(p, &v, 4);
}

void StoreFloat(float v, char* p) { Store32(std::bit_cast<uint32_t>(v), p); }

std::string S(uint64_t v) { return std::to_string(v); }

std::string Num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  return buf;
}

// A JSON value for a message, cut short; arrays and objects by kind (dump() recurses, and a
// hostile file may nest a million deep).
std::string Show(const json& v) {
  if (v.is_structured()) return v.is_array() ? "an array" : "an object";
  std::string s = v.dump();
  return s.size() > 60 ? s.substr(0, 57) + "..." : s;
}

const json* Member(const json* j, const char* key) {
  if (j == nullptr || !j->is_object()) return nullptr;
  auto it = j->find(key);
  return it == j->end() ? nullptr : &*it;
}

// A non-negative integer member: `fallback` when absent (an error without one).
Status GetUint(const json& j, const char* key, std::optional<uint64_t> fallback,
               const std::string& where, uint64_t* out) {
  const json* v = Member(&j, key);
  if (v == nullptr && fallback) *out = *fallback;
  if (v == nullptr) {
    return fallback ? Status::OK() : Status::InvalidArgument(where + ": no \"" + key + "\"");
  }
  const double d = v->is_number_float() ? v->get<double>() : -1;  // 12.0 is an integer too
  if (v->is_number_unsigned() || (d >= 0 && d < 0x1p53 && d == std::floor(d))) {
    *out = v->is_number_unsigned() ? v->get<uint64_t>() : static_cast<uint64_t>(d);
    return Status::OK();
  }
  return Status::InvalidArgument(where + ": \"" + key + "\" is " + Show(*v) +
                                 ", not a non-negative integer");
}

// A string member; `fallback` when absent.
Status GetString(const json& j, const char* key, const char* fallback, const std::string& where,
                 std::string* out) {
  const json* v = Member(&j, key);
  if (v != nullptr && !v->is_string()) {
    return Status::InvalidArgument(where + ": \"" + key + "\" is " + Show(*v) + ", not a string");
  }
  *out = v != nullptr ? v->get<std::string>() : fallback;
  return Status::OK();
}

// glTF's component types 5120 + t, t = 0..6 (5124 is none): name and size.
constexpr const char* kComponentNames[] = {"signed byte",    "unsigned byte", "signed short",
                                           "unsigned short", nullptr,         "unsigned int",
                                           "float"};
constexpr uint64_t kComponentSizes[] = {1, 1, 2, 2, 0, 4, 4};

// The component types the extension allows each kind of attribute, as masks of
// 1 << (type - 5120), plain and normalized.
enum Kind { kPosition, kRotation, kScale, kOpacity, kSh };
struct Rule {
  unsigned plain, normalized;
  const char* text;
};
constexpr Rule kRules[] = {
    {0x40, 0x40, "float (quantised positions, KHR_mesh_quantization, are not read)"},
    {0x40, 0x45, "float, or normalized signed byte or short"},
    // Signed (as earlier drafts) and unsigned (the ratified table) integers alike.
    {0x4F, 0x4F, "float, or byte or short (signed or unsigned, normalized or not)"},
    {0x40, 0x4A, "float, or normalized unsigned byte or short"},
    {0x40, 0x40, "float"},
};

// A splat primitive's attributes by slot: 0 POSITION, 1 ROTATION, 2 SCALE, 3 OPACITY,
// 4 SH_DEGREE_0_COEF_0, 5 + k the SH coefficient k = l * l - 1 + n of degree l >= 1 (the
// cloud's index of it within a channel).
constexpr int kSlots = 5 + ShRestPerChannel(kMaxShDegree);
constexpr Kind kSlotKinds[5] = {kPosition, kRotation, kScale, kOpacity, kSh};
constexpr const char* kSlotTypes[5] = {"VEC3", "VEC4", "VEC3", "SCALAR", "VEC3"};
constexpr uint64_t kSlotComps[5] = {3, 4, 3, 1, 3};

constexpr int DegreeOf(int k) { return k < 3 ? 1 : k < 8 ? 2 : 3; }

// Whether SH coefficient k flips between RDF and LUF: its order m = k + 1 - l * l - l is odd.
constexpr bool ShFlips(int k) {
  const int l = DegreeOf(k);
  return (k + 1 - l * l - l) % 2 != 0;
}
static_assert(ShFlips(0) && !ShFlips(1) && ShFlips(2) && !ShFlips(3) && ShFlips(4) && !ShFlips(9) &&
              ShFlips(14));

std::string Attr(std::string_view suffix) { return std::string(kPrefix) + std::string(suffix); }

std::string SlotName(int slot) {
  static const char* const kNames[] = {"POSITION", "ROTATION", "SCALE", "OPACITY",
                                       "SH_DEGREE_0_COEF_0"};
  if (slot == 0) return kNames[0];
  if (slot < 5) return Attr(kNames[slot]);
  const int k = slot - 5, l = DegreeOf(k);
  return Attr("SH_DEGREE_" + S(l) + "_COEF_" + S(k + 1 - l * l));
}

// The slot of an attribute: -1 for one not read (COLOR_0, NORMAL, ...), -2 for an unknown
// KHR_gaussian_splatting one, -3 for SH beyond degree 3.
int SlotOf(const std::string& key) {
  if (key == "POSITION") return 0;
  if (!key.starts_with(kPrefix)) return -1;
  const std::string_view s = std::string_view(key).substr(kPrefix.size());
  if (s == "ROTATION") return 1;
  if (s == "SCALE") return 2;
  if (s == "OPACITY") return 3;
  constexpr std::string_view kDeg = "SH_DEGREE_", kCoef = "_COEF_";
  if (!s.starts_with(kDeg)) return -2;
  int l = -1, n = -1;
  const char* end = s.data() + s.size();
  auto r = std::from_chars(s.data() + kDeg.size(), end, l);
  if (r.ec != std::errc() || !std::string_view(r.ptr, end - r.ptr).starts_with(kCoef)) return -2;
  r = std::from_chars(r.ptr + kCoef.size(), end, n);
  if (r.ec != std::errc() || r.ptr != end || l < 0 || n < 0 || n > 2 * l) return -2;
  if (l > kMaxShDegree) return -3;
  return l == 0 ? 4 : 5 + l * l - 1 + n;
}

// An accessor resolved to bytes of the BIN chunk, every element of it checked in range.
struct View {
  const char* base = nullptr;  // element 0
  uint64_t stride = 0, count = 0, type = kFloat, comps = 0;
  bool normalized = false;
};

// Element i as floats, by glTF's rules for normalized integers (max(c / 127, -1) and so on).
inline void Load(const View& v, uint64_t i, float* out) {
  const char* p = v.base + i * v.stride;
  for (uint64_t c = 0; c < v.comps; ++c) {
    if (v.type == kFloat) {
      out[c] = std::bit_cast<float>(Load32(p + 4 * c));
      continue;
    }
    float x, top;
    if (v.type == kByte) {
      x = static_cast<int8_t>(p[c]), top = 127;
    } else if (v.type == kUnsignedByte) {
      x = static_cast<uint8_t>(p[c]), top = 255;
    } else if (v.type == kShort) {
      x = static_cast<int16_t>(Load16(p + 2 * c)), top = 32767;
    } else {  // unsigned short: kRules admit nothing else
      x = Load16(p + 2 * c), top = 65535;
    }
    out[c] = v.normalized ? std::max(x / top, -1.0f) : x;
  }
}

struct Doc {
  const std::string& name;
  const json& root;
  std::string_view bin;
  bool has_bin;
};

// Resolves accessor `index` for `slot`: its type, and every element in its bufferView, the view
// in buffer 0, buffer 0 in the BIN chunk; in 64 bits without overflow, before anything is read
// or allocated.
Status Resolve(const Doc& d, uint64_t index, int slot, const std::string& where, View* out) {
  const int kind = std::min(slot, 4);
  const std::string at = where + ": " + SlotName(slot) + " (accessor " + S(index) + ")";
  const json* accessors = Member(&d.root, "accessors");
  if (accessors == nullptr || !accessors->is_array() || index >= accessors->size()) {
    return Status::InvalidArgument(at + ": no such accessor");
  }
  const json& a = (*accessors)[index];
  if (!a.is_object()) return Status::InvalidArgument(at + ": not an object");
  if (Member(&a, "sparse") != nullptr) {
    return Status::Unsupported(at + ": sparse accessors are not read");
  }
  if (Member(&a, "bufferView") == nullptr) {
    return Status::Unsupported(at + ": an accessor without a bufferView (all zeros) is not read");
  }
  uint64_t ctype, count, offset, vi, bi, voff, vlen, stride, blen;
  HVDB_RETURN_IF_ERROR(GetUint(a, "componentType", std::nullopt, at, &ctype));
  if (ctype < 5120 || ctype > 5126 || kComponentSizes[ctype - 5120] == 0) {
    return Status::InvalidArgument(at + ": componentType " + S(ctype) + " is not glTF's");
  }
  const json* norm = Member(&a, "normalized");
  if (norm != nullptr && !norm->is_boolean()) {
    return Status::InvalidArgument(at + ": \"normalized\" is " + Show(*norm) + ", not a boolean");
  }
  const bool normalized = norm != nullptr && norm->get<bool>();
  const Rule& rule = kRules[kSlotKinds[kind]];
  if (((normalized ? rule.normalized : rule.plain) & (1u << (ctype - 5120))) == 0) {
    return Status::Unsupported(at + ": component type " + (normalized ? "normalized " : "") +
                               kComponentNames[ctype - 5120] + "; allowed: " + rule.text);
  }
  std::string type;
  HVDB_RETURN_IF_ERROR(GetString(a, "type", "", at, &type));
  if (type != kSlotTypes[kind]) {
    return Status::InvalidArgument(at + ": type \"" + type + "\", expected \"" + kSlotTypes[kind] +
                                   "\"");
  }
  HVDB_RETURN_IF_ERROR(GetUint(a, "count", std::nullopt, at, &count));
  if (count == 0) return Status::InvalidArgument(at + ": count 0 (glTF needs at least 1)");
  HVDB_RETURN_IF_ERROR(GetUint(a, "byteOffset", 0, at, &offset));
  HVDB_RETURN_IF_ERROR(GetUint(a, "bufferView", std::nullopt, at, &vi));
  const json* views = Member(&d.root, "bufferViews");
  if (views == nullptr || !views->is_array() || vi >= views->size()) {
    return Status::InvalidArgument(at + ": bufferView " + S(vi) + " does not exist");
  }
  const json& v = (*views)[vi];
  const std::string vat = d.name + ": bufferView " + S(vi);
  const uint64_t elem = kSlotComps[kind] * kComponentSizes[ctype - 5120];
  HVDB_RETURN_IF_ERROR(GetUint(v, "buffer", std::nullopt, vat, &bi));
  HVDB_RETURN_IF_ERROR(GetUint(v, "byteOffset", 0, vat, &voff));
  HVDB_RETURN_IF_ERROR(GetUint(v, "byteLength", std::nullopt, vat, &vlen));
  HVDB_RETURN_IF_ERROR(GetUint(v, "byteStride", elem, vat, &stride));
  if (stride < elem) {
    return Status::InvalidArgument(vat + ": byteStride " + S(stride) + " is less than the " +
                                   S(elem) + " bytes of " + SlotName(slot) + "'s elements");
  }
  const json* buffers = Member(&d.root, "buffers");
  if (buffers == nullptr || !buffers->is_array() || bi >= buffers->size()) {
    return Status::InvalidArgument(vat + ": buffer " + S(bi) + " does not exist");
  }
  const json& b = (*buffers)[bi];
  if (const json* uri = Member(&b, "uri")) {
    return Status::Unsupported(d.name + ": buffer " + S(bi) + " has the uri " + Show(*uri) +
                               ": only a GLB with its BIN chunk is read (no external files or "
                               "data: URIs)");
  }
  if (bi != 0) {
    return Status::InvalidArgument(d.name + ": buffer " + S(bi) +
                                   " has no uri; only buffer 0 may be a GLB's BIN chunk");
  }
  if (!d.has_bin) {
    return Status::Corruption(d.name + ": buffer 0 is the BIN chunk, and the GLB has none");
  }
  HVDB_RETURN_IF_ERROR(GetUint(b, "byteLength", std::nullopt, d.name + ": buffer 0", &blen));
  if (blen > d.bin.size()) {
    return Status::Corruption(d.name + ": buffer 0 declares " + S(blen) +
                              " bytes, the BIN chunk holds " + S(d.bin.size()));
  }
  if (voff > blen || vlen > blen - voff) {
    return Status::Corruption(vat + ": byteOffset " + S(voff) + " and byteLength " + S(vlen) +
                              " pass the end of buffer 0 (" + S(blen) + " bytes)");
  }
  // The last element ends at offset + stride * (count - 1) + elem, within the view.
  if (offset > vlen || elem > vlen - offset || (count - 1) > (vlen - offset - elem) / stride) {
    return Status::Corruption(at + ": " + S(count) + " elements of " + S(elem) + " bytes (stride " +
                              S(stride) + ") from byte " + S(offset) + " pass the end of " +
                              "bufferView " + S(vi) + " (" + S(vlen) + " bytes)");
  }
  *out = View{d.bin.data() + voff + offset, stride, count, ctype, kSlotComps[kind], normalized};
  return Status::OK();
}

// One splat primitive, its accessors resolved.
struct Splats {
  const json* prim = nullptr;
  std::string where;  // "<name>: mesh 0 primitive 0"
  size_t mesh = 0;
  std::array<View, kSlots> views;
  int degree = 0;
};

Status ParsePrimitive(const Doc& d, Splats* s, std::vector<std::string>* ignored) {
  const json& prim = *s->prim;
  const std::string& where = s->where;
  uint64_t mode = 0;  // absent: glTF's default is triangles, but the extension says points
  HVDB_RETURN_IF_ERROR(GetUint(prim, "mode", 0, where, &mode));
  if (mode != 0) {
    return Status::InvalidArgument(where + ": mode " + S(mode) +
                                   "; a KHR_gaussian_splatting primitive must be POINTS (0)");
  }
  const json* ext = Member(Member(&prim, "extensions"), kExt);
  if (!ext->is_object()) {
    return Status::InvalidArgument(where + ": the KHR_gaussian_splatting extension is " +
                                   Show(*ext) + ", not an object");
  }
  // kernel and colorSpace are required by the ratified text; absent (drafts), the only values
  // there were are taken.
  static const char* const kProps[][3] = {{"kernel", "ellipse", ", the 3DGS Gaussian,"},
                                          {"projection", "perspective", ""},
                                          {"colorSpace", "srgb_rec709_display", ""}};
  for (const auto& [key, want, why] : kProps) {
    std::string value;
    HVDB_RETURN_IF_ERROR(GetString(*ext, key, want, where, &value));
    if (value == "lin_rec709_display" && std::string_view(key) == "colorSpace") {
      return Status::Unsupported(where +
                                 ": colorSpace \"lin_rec709_display\": hvdb composites "
                                 "splats in their stored colour space, as 3DGS trains them "
                                 "(srgb_rec709_display); linear colours would blend differently");
    }
    if (value != want) {
      return Status::Unsupported(where + ": " + key + " \"" + value + "\" (only \"" + want + "\"" +
                                 why + " is read)");
    }
  }
  const json* attrs = Member(&prim, "attributes");
  if (attrs == nullptr || !attrs->is_object()) {
    return Status::InvalidArgument(where + ": no \"attributes\" object");
  }
  std::array<std::optional<uint64_t>, kSlots> index;
  for (const auto& item : attrs->items()) {
    const std::string& key = item.key();
    uint64_t i;
    HVDB_RETURN_IF_ERROR(GetUint(*attrs, key.c_str(), std::nullopt, where + ": attributes", &i));
    const int slot = SlotOf(key);
    if (slot >= 0) {
      index[slot] = i;
    } else if (slot == -2) {
      return Status::InvalidArgument(where + ": unknown attribute " + key);
    } else if (slot == -3) {
      return Status::Unsupported(where + ": " + key + ": SH degree above 3 (0 to 3 are read)");
    } else if (key != "COLOR_0" &&  // the point-cloud fallback, derived from the others
               std::find(ignored->begin(), ignored->end(), key) == ignored->end()) {
      ignored->push_back(key);
    }
  }
  for (int slot = 0; slot < 5; ++slot) {
    if (!index[slot]) {
      return Status::InvalidArgument(where + ": no " + SlotName(slot) + " attribute (required)");
    }
  }
  for (int k = 0; k < ShRestPerChannel(kMaxShDegree); ++k) {
    if (index[5 + k]) s->degree = std::max(s->degree, DegreeOf(k));
  }
  for (int slot = 0; slot < 5 + ShRestPerChannel(s->degree); ++slot) {
    if (!index[slot]) {
      return Status::InvalidArgument(where + ": SH degree " + S(DegreeOf(slot - 5)) +
                                     " is partial: " + SlotName(slot) + " is missing (degrees 1 " +
                                     "to " + S(s->degree) + " must be whole)");
    }
    HVDB_RETURN_IF_ERROR(Resolve(d, *index[slot], slot, where, &s->views[slot]));
    if (s->views[slot].count != s->views[0].count) {
      return Status::InvalidArgument(where + ": " + SlotName(slot) + " has " +
                                     S(s->views[slot].count) + " elements, POSITION " +
                                     S(s->views[0].count));
    }
  }
  return Status::OK();
}

// The extension allows a linear scale of 0 (a flat splat), whose log, -inf, no cloud may hold:
// the log of the smallest normal float (-87.3) stands in for it, as flat as any renderer tells.
const float kLogZeroScale = std::log(std::numeric_limits<float>::min());

Status Decode(const Splats& s, size_t base, GaussianCloud* c) {
  const size_t dim = static_cast<size_t>(ShRestPerChannel(c->sh_degree));
  const auto& v = s.views;
  float e[4];
  for (uint64_t i = 0; i < v[0].count; ++i) {
    const size_t j = base + i;
    Load(v[0], i, e);
    c->position[3 * j] = -e[0];
    c->position[3 * j + 1] = -e[1];
    c->position[3 * j + 2] = e[2];
    Load(v[1], i, e);  // x' y' z' w'
    c->rotation[4 * j] = e[2];
    c->rotation[4 * j + 1] = e[1];
    c->rotation[4 * j + 2] = -e[0];
    c->rotation[4 * j + 3] = -e[3];
    Load(v[2], i, e);
    for (int k = 0; k < 3; ++k) {
      if (!(e[k] >= 0 && std::isfinite(e[k]))) {
        return Status::InvalidArgument(s.where + ": splat " + S(i) + ": " + SlotName(2) + " " +
                                       Num(e[k]) + " (a linear scale is finite and not negative)");
      }
      c->scale[3 * j + k] = e[k] == 0 ? kLogZeroScale : std::log(e[k]);
    }
    Load(v[3], i, e);
    if (!(e[0] >= 0 && e[0] <= 1)) {
      return Status::InvalidArgument(s.where + ": splat " + S(i) + ": " + SlotName(3) + " " +
                                     Num(e[0]) + " is outside 0 to 1 (a linear opacity)");
    }
    c->opacity[j] = Logit(e[0]);
    Load(v[4], i, e);
    std::copy_n(e, 3, &c->sh_dc[3 * j]);
    float* rest = c->sh_rest.data() + j * 3 * dim;
    for (size_t k = 0; k < dim; ++k) {
      Load(v[5 + k], i, e);
      const bool flip = ShFlips(static_cast<int>(k));
      for (size_t ch = 0; ch < 3; ++ch) rest[ch * dim + k] = flip ? -e[ch] : e[ch];
    }
  }
  return Status::OK();
}

// The GLB container: its header, the JSON chunk and the first BIN chunk (others are skipped,
// as glTF asks).
Status SplitGlb(std::string_view bytes, const std::string& name, std::string_view* text,
                std::string_view* bin, bool* has_bin) {
  if (bytes.size() < 12) {
    return Status::Corruption(name + ": truncated: " + S(bytes.size()) +
                              " bytes, fewer than a GLB header's 12");
  }
  if (Load32(bytes.data()) != kGlbMagic) {
    return Status::InvalidArgument(name + ": not a GLB: it does not start with \"glTF\"");
  }
  if (const uint32_t version = Load32(bytes.data() + 4); version != 2) {
    return Status::Unsupported(name + ": GLB version " + S(version) +
                               " (only version 2, glTF 2.0, is read)");
  }
  const uint64_t length = Load32(bytes.data() + 8);
  if (length > bytes.size()) {
    return Status::Corruption(name + ": truncated: the GLB header declares " + S(length) +
                              " bytes, the file has " + S(bytes.size()));
  }
  if (length < bytes.size()) {
    return Status::Corruption(name + ": " + S(bytes.size() - length) + " bytes follow the " +
                              S(length) + " the GLB header declares");
  }
  if (length < 20 || Load32(bytes.data() + 16) != kChunkJson) {
    return Status::Corruption(name + ": the GLB does not begin with a JSON chunk");
  }
  const uint64_t json_len = Load32(bytes.data() + 12);
  if (json_len > length - 20) {
    return Status::Corruption(name + ": truncated: the JSON chunk declares " + S(json_len) +
                              " bytes, " + S(length - 20) + " follow its header");
  }
  *text = bytes.substr(20, json_len);
  for (uint64_t at = 20 + json_len; at < length;) {
    if (length - at < 8) {
      return Status::Corruption(name + ": truncated: the chunk header at byte " + S(at));
    }
    const uint64_t len = Load32(bytes.data() + at);
    const bool is_bin = Load32(bytes.data() + at + 4) == kChunkBin;
    if (len > length - at - 8) {
      return Status::Corruption(name + ": truncated: the " + (is_bin ? "BIN " : "") +
                                "chunk at byte " + S(at) + " declares " + S(len) + " bytes, " +
                                S(length - at - 8) + " follow its header");
    }
    if (is_bin && !*has_bin) *bin = bytes.substr(at + 8, len), *has_bin = true;
    at += 8 + len;
  }
  return Status::OK();
}

Result<GaussianCloud> ReadGlbImpl(std::string_view bytes, const std::string& name) {
  std::string_view text, bin;
  bool has_bin = false;
  HVDB_RETURN_IF_ERROR(SplitGlb(bytes, name, &text, &bin, &has_bin));
  while (!text.empty() && (text.back() == ' ' || text.back() == '\0')) text.remove_suffix(1);
  json root;
  try {
    root = json::parse(text);
  } catch (const json::exception& e) {
    return Status::Corruption(name + ": the GLB's JSON chunk does not parse: " + e.what());
  }
  if (!root.is_object()) return Status::InvalidArgument(name + ": the glTF JSON is not an object");
  const json* required = Member(&root, "extensionsRequired");
  for (size_t k = 0; required != nullptr && required->is_array() && k < required->size(); ++k) {
    const json& e = (*required)[k];
    if (!e.is_string() || e.get<std::string>() != kExt) {
      return Status::Unsupported(name + ": the file requires the glTF extension " + Show(e) +
                                 ", which is not read");
    }
  }
  std::vector<Splats> prims;  // every primitive with the extension, in mesh order
  std::vector<bool> splat_mesh;
  if (const json* meshes = Member(&root, "meshes"); meshes != nullptr && meshes->is_array()) {
    splat_mesh.resize(meshes->size());
    for (size_t m = 0; m < meshes->size(); ++m) {
      const json* ps = Member(&(*meshes)[m], "primitives");
      for (size_t p = 0; ps != nullptr && ps->is_array() && p < ps->size(); ++p) {
        if (Member(Member(&(*ps)[p], "extensions"), kExt) == nullptr) continue;
        splat_mesh[m] = true;
        prims.push_back({&(*ps)[p], name + ": mesh " + S(m) + " primitive " + S(p), m, {}, 0});
      }
    }
  }
  if (prims.empty()) {
    return Status::InvalidArgument(name +
                                   ": a glTF file without KHR_gaussian_splatting "
                                   "primitives (a mesh or point cloud, not splats)");
  }
  HVDB_ASSIGN_OR_RETURN(const std::vector<Similarity> placed,
                        glb::SplatMeshPlacements(root, splat_mesh, name));
  const Doc doc{name, root, bin, has_bin};
  GaussianCloud c;
  uint64_t total = 0;
  for (Splats& s : prims) {
    HVDB_RETURN_IF_ERROR(ParsePrimitive(doc, &s, &c.ignored));
    if (s.degree != prims[0].degree) {
      return Status::Unsupported(s.where + " has SH degree " + S(s.degree) + ", " +
                                 prims[0].where.substr(name.size() + 2) + " degree " +
                                 S(prims[0].degree) +
                                 " (primitives of different degrees are not read)");
    }
    total += s.views[0].count;
  }
  // Each primitive's accessors fit the BIN chunk; shared ones must not multiply the allocation.
  if (total > bin.size() / 12) {
    return Status::InvalidArgument(name + ": the primitives declare " + S(total) +
                                   " splats, more than the BIN chunk's " + S(bin.size()) +
                                   " bytes hold (12 bytes of POSITION each; accessors shared " +
                                   "between primitives are not read)");
  }
  c.sh_degree = prims[0].degree;
  c.Resize(total);
  size_t base = 0;
  for (const Splats& s : prims) {
    HVDB_RETURN_IF_ERROR(Decode(s, base, &c));
    // Where the node tree puts the mesh (its one node's world transform).
    if (!placed[s.mesh].IsIdentity()) {
      HVDB_RETURN_IF_ERROR(glb::PlaceSplats(&c, base, s.views[0].count, placed[s.mesh], s.where));
    }
    base += s.views[0].count;
  }
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));  // NaN or infinite positions, SH, ...
  return c;
}

Result<std::string> WriteGlbImpl(const GaussianCloud& c, const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));
  const size_t n = c.size();
  if (n == 0) {
    return Status::InvalidArgument(name + ": no splats (a glTF accessor holds at least one)");
  }
  // One bufferView and accessor each, in splat-transform's order: POSITION, COLOR_0, the slots.
  struct Segment {
    std::string semantic;
    uint64_t component_type;
    const char* type;
    uint64_t bytes;  // a splat; all multiples of 4
  };
  std::vector<Segment> segs = {{SlotName(0), kFloat, "VEC3", 12},
                               {"COLOR_0", kUnsignedByte, "VEC4", 4}};
  for (int slot = 1; slot < 5 + ShRestPerChannel(c.sh_degree); ++slot) {
    const int kind = std::min(slot, 4);
    segs.push_back({SlotName(slot), kFloat, kSlotTypes[kind], 4 * kSlotComps[kind]});
  }
  std::vector<uint64_t> offset;  // in the BIN chunk
  uint64_t per_splat = 0;
  for (const Segment& s : segs) offset.push_back(per_splat * n), per_splat += s.bytes;
  if (n > (uint64_t{0xFFFFFFFF} - (1u << 16)) / per_splat) {  // the JSON takes a few KiB
    return Status::InvalidArgument(name + ": " + S(n) + " splats of SH degree " + S(c.sh_degree) +
                                   " need " + S(n * per_splat) + " bytes, more than a GLB's 4 GiB");
  }
  const uint64_t bin_len = n * per_splat;
  std::array<double, 3> lo, hi;  // POSITION's bounds, which glTF requires
  for (int k = 0; k < 3; ++k) {
    const float sign = k < 2 ? -1.0f : 1.0f;
    float a = sign * c.position[k], b = a;
    for (size_t i = 1; i < n; ++i) {
      a = std::min(a, sign * c.position[3 * i + k]), b = std::max(b, sign * c.position[3 * i + k]);
    }
    lo[k] = a, hi[k] = b;
  }
  using ojson = nlohmann::ordered_json;
  ojson views = ojson::array(), accessors = ojson::array(), attributes = ojson::object();
  for (size_t i = 0; i < segs.size(); ++i) {
    views.push_back({{"buffer", 0},
                     {"byteOffset", offset[i]},
                     {"byteLength", segs[i].bytes * n},
                     {"target", 34962}});
    ojson a = {{"bufferView", i},
               {"byteOffset", 0},
               {"componentType", segs[i].component_type},
               {"count", n},
               {"type", segs[i].type}};
    if (segs[i].component_type == kUnsignedByte) a["normalized"] = true;
    if (i == 0) a["min"] = lo, a["max"] = hi;
    accessors.push_back(std::move(a));
    attributes[segs[i].semantic] = i;
  }
  ojson prim = {{"attributes", std::move(attributes)}, {"mode", 0}};
  prim["extensions"][kExt] = {{"kernel", "ellipse"},
                              {"colorSpace", "srgb_rec709_display"},
                              {"sortingMethod", "cameraDistance"},
                              {"projection", "perspective"}};
  ojson gltf = ojson::object();
  gltf["asset"] = {{"version", "2.0"}, {"generator", "hvdb"}};
  gltf["extensionsUsed"] = ojson::array({kExt});
  gltf["scene"] = 0;
  gltf["scenes"] = ojson::array({{{"nodes", ojson::array({0})}}});
  gltf["nodes"] = ojson::array({{{"mesh", 0}}});
  gltf["buffers"] = ojson::array({{{"byteLength", bin_len}}});
  gltf["bufferViews"] = std::move(views);
  gltf["accessors"] = std::move(accessors);
  gltf["meshes"] = ojson::array({{{"primitives", ojson::array({std::move(prim)})}}});
  std::string text = gltf.dump();
  text.resize((text.size() + 3) & ~size_t{3}, ' ');

  std::string out(12 + 8 + text.size() + 8 + bin_len, '\0');
  char* p = out.data();
  Store32(kGlbMagic, p);
  Store32(2, p + 4);
  Store32(static_cast<uint32_t>(out.size()), p + 8);
  Store32(static_cast<uint32_t>(text.size()), p + 12);
  Store32(kChunkJson, p + 16);
  std::memcpy(p + 20, text.data(), text.size());
  p += 20 + text.size();
  Store32(static_cast<uint32_t>(bin_len), p);
  Store32(kChunkBin, p + 4);
  p += 8;
  char *pos = p + offset[0], *rot = p + offset[2], *scale = p + offset[3];
  char *opacity = p + offset[4], *dc = p + offset[5];
  auto* color = reinterpret_cast<unsigned char*>(p + offset[1]);
  auto to_byte = [](double x) {
    return static_cast<unsigned char>(std::clamp(std::round(x * 255), 0.0, 255.0));
  };
  for (size_t i = 0; i < n; ++i) {
    StoreFloat(-c.position[3 * i], pos + 12 * i);
    StoreFloat(-c.position[3 * i + 1], pos + 12 * i + 4);
    StoreFloat(c.position[3 * i + 2], pos + 12 * i + 8);
    for (int k = 0; k < 3; ++k) color[4 * i + k] = to_byte(0.5 + kShC0 * c.sh_dc[3 * i + k]);
    color[4 * i + 3] = to_byte(Sigmoid(c.opacity[i]));
    // The extension stores unit quaternions (renderers need not normalise): normalised here,
    // in double; a zero quaternion is the identity, as Covariance takes it.
    double w = c.rotation[4 * i], x = c.rotation[4 * i + 1], y = c.rotation[4 * i + 2],
           z = c.rotation[4 * i + 3];
    double norm = std::sqrt(w * w + x * x + y * y + z * z);
    if (!(norm > 0 && std::isfinite(norm))) w = 1, x = y = z = 0, norm = 1;
    const double q[4] = {-y / norm, x / norm, w / norm, -z / norm};
    for (int k = 0; k < 4; ++k) StoreFloat(static_cast<float>(q[k]), rot + 16 * i + 4 * k);
    for (int k = 0; k < 3; ++k) {
      const float s = std::exp(c.scale[3 * i + k]);
      if (!std::isfinite(s)) {
        return Status::InvalidArgument(name + ": splat " + S(i) + ": scale_" + S(k) + " " +
                                       Num(c.scale[3 * i + k]) +
                                       " is too large for glTF's linear float scale");
      }
      StoreFloat(s, scale + 12 * i + 4 * k);
    }
    StoreFloat(Sigmoid(c.opacity[i]), opacity + 4 * i);
    for (int k = 0; k < 3; ++k) StoreFloat(c.sh_dc[3 * i + k], dc + 12 * i + 4 * k);
  }
  // SH in one pass over the cloud, each coefficient to its own view (RGB), signs (-1)^m.
  const size_t dim = static_cast<size_t>(ShRestPerChannel(c.sh_degree));
  for (size_t i = 0; i < n; ++i) {
    const float* src = c.sh_rest.data() + i * 3 * dim;
    for (size_t k = 0; k < dim; ++k) {
      char* dst = p + offset[6 + k] + 12 * i;
      const float sign = ShFlips(static_cast<int>(k)) ? -1.0f : 1.0f;
      for (size_t ch = 0; ch < 3; ++ch) StoreFloat(sign * src[ch * dim + k], dst + 4 * ch);
    }
  }
  return out;
}

}  // namespace

Result<GaussianCloud> ReadGlb(std::string_view bytes, const std::string& name) {
  try {
    return ReadGlbImpl(bytes, name);
  } catch (const json::exception& e) {  // a type the checks above let through
    return Status::InvalidArgument(name + ": malformed glTF JSON: " + e.what());
  } catch (const std::bad_alloc&) {
    return Status::LimitExceeded(name + ": out of memory reading the GLB");
  }
}

Result<std::string> WriteGlb(const GaussianCloud& cloud, const std::string& name) {
  try {
    return WriteGlbImpl(cloud, name);
  } catch (const json::exception& e) {
    return Status::Internal(name + ": writing the glTF JSON: " + e.what());
  } catch (const std::bad_alloc&) {
    return Status::LimitExceeded(name + ": out of memory writing the GLB");
  }
}

}  // namespace hvdb::formats
