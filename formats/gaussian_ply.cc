// The 3DGS PLY (formats/gaussians.h): the vertex element of the Inria reference code's
// save_ply, every property a float. Read in any property order and in the three PLY encodings;
// written in exactly the Inria layout, so that such a file reads and writes back byte for byte.
#include <algorithm>
#include <bit>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <optional>
#include <thread>
#include <string_view>
#include <vector>

#include "formats/gaussians.h"

namespace hvdb::formats {
namespace {

enum class Encoding { kAscii, kBinaryLE, kBinaryBE };

// Where a vertex property's value goes.
enum class Slot : uint8_t { kPosition, kScale, kRotation, kOpacity, kDc, kRest, kIgnored };

struct Prop {
  std::string name;
  Slot slot;
  int index;  // within the slot: 0..2 of x y z, k of f_rest_k, ...
  int bytes = 4;  // binary: its size (a float, or an ignored property's scalar type)
};

// The bytes of a PLY scalar type (both spellings), 0 for none.
int ScalarBytes(std::string_view t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "int32" || t == "uint32" || t == "float" ||
      t == "float32") {
    return 4;
  }
  if (t == "double" || t == "float64") return 8;
  return 0;
}

struct Header {
  Encoding encoding = Encoding::kBinaryLE;
  uint64_t count = 0;  // vertices
  std::vector<Prop> props;
  int sh_degree = 0;
  size_t data_offset = 0;  // of the first vertex, after "end_header\n"
};

constexpr size_t kMaxHeaderLine = 4096;
constexpr size_t kMaxHeaderLines = 4096;
constexpr int kMaxRest = 3 * 15;  // f_rest_* of degree 3

// s as it may appear in a message: at most 40 characters, others than printable ASCII as \xNN.
std::string Printable(std::string_view s) {
  std::string out;
  for (size_t i = 0; i < s.size() && i < 40; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c >= 0x20 && c < 0x7f) {
      out += static_cast<char>(c);
    } else {
      static const char kHex[] = "0123456789abcdef";
      out += "\\x";
      out += kHex[c >> 4];
      out += kHex[c & 15];
    }
  }
  if (s.size() > 40) out += "...";
  return out;
}

std::vector<std::string_view> SplitWords(std::string_view line) {
  std::vector<std::string_view> words;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    const size_t start = i;
    while (i < line.size() && line[i] != ' ' && line[i] != '\t') ++i;
    if (i > start) words.push_back(line.substr(start, i - start));
  }
  return words;
}

// A decimal number of digits only (no sign, no spaces).
std::optional<uint64_t> ParseCount(std::string_view s) {
  uint64_t v = 0;
  if (s.empty() || s.size() > 20) return std::nullopt;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || end != s.data() + s.size()) return std::nullopt;
  return v;
}

// The k of "<prefix>k" when it is written canonically (no sign, no leading zero) and k < limit.
std::optional<int> Suffix(std::string_view name, std::string_view prefix, int limit) {
  if (!name.starts_with(prefix)) return std::nullopt;
  const std::string_view digits = name.substr(prefix.size());
  if (digits.empty() || digits.size() > 2 || (digits.size() > 1 && digits[0] == '0')) {
    return std::nullopt;
  }
  int k = 0;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), k);
  if (ec != std::errc() || end != digits.data() + digits.size() || k >= limit) {
    return std::nullopt;
  }
  return k;
}

std::optional<Prop> PropOf(std::string_view name) {
  const std::string n(name);
  if (name == "x" || name == "y" || name == "z") return Prop{n, Slot::kPosition, name[0] - 'x'};
  if (name == "nx" || name == "ny" || name == "nz") return Prop{n, Slot::kIgnored, 0};
  if (name == "opacity") return Prop{n, Slot::kOpacity, 0};
  if (auto k = Suffix(name, "f_dc_", 3)) return Prop{n, Slot::kDc, *k};
  if (auto k = Suffix(name, "f_rest_", kMaxRest)) return Prop{n, Slot::kRest, *k};
  if (auto k = Suffix(name, "scale_", 3)) return Prop{n, Slot::kScale, *k};
  if (auto k = Suffix(name, "rot_", 4)) return Prop{n, Slot::kRotation, *k};
  return std::nullopt;
}

// The required properties present, and f_rest_* forming a whole degree.
Status CheckProps(Header* h, const std::string& name) {
  static const char* const kRequired[] = {"x",       "y",       "z",       "f_dc_0", "f_dc_1",
                                          "f_dc_2",  "opacity", "scale_0", "scale_1", "scale_2",
                                          "rot_0",   "rot_1",   "rot_2",   "rot_3"};
  auto has = [h](std::string_view p) {
    return std::any_of(h->props.begin(), h->props.end(),
                       [p](const Prop& q) { return q.name == p; });
  };
  for (const char* p : kRequired) {
    if (!has(p)) {
      return Status::InvalidArgument(name + ": the vertex element has no '" + p +
                                     "' property (a 3DGS PLY has x y z, f_dc_0..2, f_rest_*, "
                                     "opacity, scale_0..2 and rot_0..3)");
    }
  }
  int rest = 0, max_rest = -1;
  for (const Prop& p : h->props) {
    if (p.slot == Slot::kRest) ++rest, max_rest = std::max(max_rest, p.index);
  }
  if (rest == 0) {
    h->sh_degree = 0;
    return Status::OK();
  }
  int degree = 1;
  while (degree < kMaxShDegree && 3 * ShRestPerChannel(degree) < std::max(rest, max_rest + 1)) {
    ++degree;
  }
  const int want = 3 * ShRestPerChannel(degree);
  for (int k = 0; k < want; ++k) {
    if (!has("f_rest_" + std::to_string(k))) {
      return Status::InvalidArgument(
          name + ": f_rest_" + std::to_string(k) + " is missing: the vertex element has " +
          std::to_string(rest) + " f_rest properties, and SH degree " + std::to_string(degree) +
          " needs f_rest_0..f_rest_" + std::to_string(want - 1) +
          " (degrees 0 to 3 need 0, 9, 24 or 45); the file is cut or was not written by a "
          "3DGS trainer");
    }
  }
  h->sh_degree = degree;
  return Status::OK();
}

Result<Header> ParseHeader(std::string_view bytes, const std::string& name) {
  Header h;
  size_t pos = 0;
  int line_no = 0;
  auto next_line = [&](std::string_view* line) {
    const size_t nl = bytes.find('\n', pos);
    if (nl == std::string_view::npos) return false;
    *line = bytes.substr(pos, nl - pos);
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    pos = nl + 1;
    ++line_no;
    return true;
  };
  auto bad = [&](const std::string& msg) {
    return Status::InvalidArgument(name + ": header line " + std::to_string(line_no) + ": " + msg);
  };
  std::string_view line;
  if (!next_line(&line) || line != "ply") {
    return Status::InvalidArgument(name + ": not a PLY file (it does not start with a 'ply' line)");
  }
  bool have_format = false, have_vertex = false, have_element = false, in_vertex = false;
  for (;;) {
    if (!next_line(&line)) {
      return Status::InvalidArgument(name + ": the PLY header has no 'end_header' line (file cut "
                                            "short, or not a PLY file)");
    }
    if (line.size() > kMaxHeaderLine || line_no > static_cast<int>(kMaxHeaderLines)) {
      return bad("header too long (not a 3DGS PLY?)");
    }
    const std::vector<std::string_view> w = SplitWords(line);
    if (w.empty() || w[0] == "comment" || w[0] == "obj_info") continue;
    if (w[0] == "end_header") break;
    if (w[0] == "format") {
      if (w.size() != 3 || w[2] != "1.0") return bad("expected 'format <encoding> 1.0'");
      if (w[1] == "ascii") {
        h.encoding = Encoding::kAscii;
      } else if (w[1] == "binary_little_endian") {
        h.encoding = Encoding::kBinaryLE;
      } else if (w[1] == "binary_big_endian") {
        h.encoding = Encoding::kBinaryBE;
      } else {
        return bad("unknown encoding '" + Printable(w[1]) + "'");
      }
      have_format = true;
    } else if (w[0] == "element") {
      if (w.size() != 3) return bad("expected 'element <name> <count>'");
      const std::optional<uint64_t> count = ParseCount(w[2]);
      if (!count) return bad("element count '" + Printable(w[2]) + "' is not a number");
      have_element = true;
      in_vertex = w[1] == "vertex";
      if (in_vertex) {
        if (have_vertex) return bad("a second 'vertex' element");
        have_vertex = true;
        h.count = *count;
      } else if (*count > 0) {
        return bad("element '" + Printable(w[1]) + "' has " + std::to_string(*count) +
                   " items; a 3DGS PLY holds only its vertex element");
      }
    } else if (w[0] == "property") {
      if (!have_element) return bad("a property before any element");
      if (!in_vertex) continue;  // of an empty element: nothing to read
      if (w.size() >= 2 && w[1] == "list") {
        return bad("list property in the vertex element; a 3DGS PLY has float properties only");
      }
      if (w.size() != 3) return bad("expected 'property <type> <name>'");
      std::optional<Prop> p = PropOf(w[2]);
      if (!p) {
        // Trainers add their own per-splat values (Mip-Splatting's filter_3D, colours as
        // uchar, ...): read over and named in GaussianCloud::ignored, not refused.
        const int size = ScalarBytes(w[1]);
        if (size == 0) {
          return bad("vertex property '" + Printable(w[2]) + "' has unknown type '" +
                     Printable(w[1]) + "'");
        }
        for (const Prop& q : h.props) {
          if (q.name == w[2]) return bad("vertex property '" + q.name + "' appears twice");
        }
        h.props.push_back(Prop{std::string(w[2]), Slot::kIgnored, 0, size});
        continue;
      }
      if (w[1] != "float" && w[1] != "float32") {
        return bad("vertex property '" + p->name + "' is '" + Printable(w[1]) +
                   "'; the 3DGS layout has float properties only");
      }
      for (const Prop& q : h.props) {
        if (q.name == p->name) return bad("vertex property '" + p->name + "' appears twice");
      }
      h.props.push_back(std::move(*p));
    } else {
      return bad("unknown header keyword '" + Printable(w[0]) + "'");
    }
  }
  if (!have_format) return Status::InvalidArgument(name + ": the PLY header has no format line");
  if (!have_vertex) return Status::InvalidArgument(name + ": the PLY header has no vertex element");
  HVDB_RETURN_IF_ERROR(CheckProps(&h, name));
  h.data_offset = pos;
  return h;
}

float LoadFloat(const char* p, bool big_endian) {
  uint32_t u;
  std::memcpy(&u, p, 4);
  if (big_endian != (std::endian::native == std::endian::big)) u = __builtin_bswap32(u);
  return std::bit_cast<float>(u);
}

void StoreFloatLE(float v, std::string* out) {
  uint32_t u = std::bit_cast<uint32_t>(v);
  if constexpr (std::endian::native == std::endian::big) u = __builtin_bswap32(u);
  char b[4];
  std::memcpy(b, &u, 4);
  out->append(b, 4);
}

float* Target(GaussianCloud* c, const Prop& p, size_t i) {
  switch (p.slot) {
    case Slot::kPosition:
      return &c->position[3 * i + p.index];
    case Slot::kScale:
      return &c->scale[3 * i + p.index];
    case Slot::kRotation:
      return &c->rotation[4 * i + p.index];
    case Slot::kOpacity:
      return &c->opacity[i];
    case Slot::kDc:
      return &c->sh_dc[3 * i + p.index];
    case Slot::kRest:
      return &c->sh_rest[i * c->sh_rest_per_splat() + p.index];
    case Slot::kIgnored:
      break;
  }
  return nullptr;
}

Status ReadBinary(const Header& h, std::string_view data, GaussianCloud* c,
                  const std::string& name) {
  size_t stride = 0;
  std::vector<size_t> offset(h.props.size());
  for (size_t k = 0; k < h.props.size(); ++k) {
    offset[k] = stride;
    stride += static_cast<size_t>(h.props[k].bytes);
  }
  if (h.count > data.size() / stride) {
    return Status::Corruption(name + ": truncated: the header declares " +
                              std::to_string(h.count) + " vertices of " + std::to_string(stride) +
                              " bytes, but only " + std::to_string(data.size()) +
                              " bytes follow it");
  }
  const size_t n = h.count;
  if (n * stride != data.size()) {
    return Status::Corruption(name + ": " + std::to_string(data.size() - n * stride) +
                              " bytes follow the " + std::to_string(n) +
                              " vertices the header declares (a wrong vertex count?)");
  }
  c->Resize(n);
  const bool big = h.encoding == Encoding::kBinaryBE;
  // Where each kept property goes: its array's splat 0 and the step between splats (Target of
  // splat 0 and 1), so that the row loop does no switch per value.
  struct Dest {
    size_t from;
    float* base;
    size_t step;
  };
  std::vector<Dest> dests;
  if (n > 0) {
    GaussianCloud probe;
    probe.sh_degree = c->sh_degree;
    probe.Resize(2);
    for (size_t k = 0; k < h.props.size(); ++k) {
      float* t0 = Target(&probe, h.props[k], 0);
      if (t0 == nullptr) continue;
      float* t1 = Target(&probe, h.props[k], 1);
      // The same array of *c: the offset of splat 0 within it.
      float* base = Target(c, h.props[k], 0);
      dests.push_back({offset[k], base, static_cast<size_t>(t1 - t0)});
    }
  }
  // Two halves on two threads: a million splats are 250 MB to spread into six arrays.
  auto rows = [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      const char* row = data.data() + i * stride;
      for (const Dest& d : dests) d.base[i * d.step] = LoadFloat(row + d.from, big);
    }
  };
  if (n >= (size_t{1} << 16)) {
    std::thread other([&] { rows(n / 2, n); });
    rows(0, n / 2);
    other.join();
  } else {
    rows(0, n);
  }
  return Status::OK();
}

Status ReadAscii(const Header& h, std::string_view data, GaussianCloud* c,
                 const std::string& name) {
  const size_t per = h.props.size();
  // Each value takes at least one character and one separator.
  if (h.count > (data.size() + 1) / (2 * per)) {
    return Status::Corruption(name + ": truncated: the header declares " +
                              std::to_string(h.count) + " vertices of " + std::to_string(per) +
                              " values, more than the " + std::to_string(data.size()) +
                              " bytes after it can hold");
  }
  const size_t n = h.count;
  c->Resize(n);
  size_t pos = 0;
  auto space = [&data, &pos] {
    while (pos < data.size() &&
           (data[pos] == ' ' || data[pos] == '\t' || data[pos] == '\r' || data[pos] == '\n')) {
      ++pos;
    }
  };
  for (size_t i = 0; i < n; ++i) {
    for (size_t k = 0; k < per; ++k) {
      space();
      if (pos < data.size() && data[pos] == '+') ++pos;
      float v = 0;
      const char* first = data.data() + pos;
      const auto [end, ec] = std::from_chars(first, data.data() + data.size(), v);
      const bool ends = end == data.data() + data.size() || *end == ' ' || *end == '\t' ||
                        *end == '\r' || *end == '\n';
      if (end == first || !ends || (ec != std::errc() && ec != std::errc::result_out_of_range)) {
        if (pos >= data.size()) {
          return Status::Corruption(name + ": truncated: the data ends within vertex " +
                                    std::to_string(i) + " of " + std::to_string(n));
        }
        return Status::InvalidArgument(name + ": vertex " + std::to_string(i) + ": property '" +
                                       h.props[k].name + "' is not a number");
      }
      if (ec == std::errc::result_out_of_range) {
        return Status::InvalidArgument(name + ": splat " + std::to_string(i) + ": " +
                                       h.props[k].name + " is beyond float range");
      }
      pos = static_cast<size_t>(end - data.data());
      if (float* t = Target(c, h.props[k], i)) *t = v;
    }
  }
  space();
  if (pos != data.size()) {
    return Status::Corruption(name + ": " + std::to_string(data.size() - pos) +
                              " bytes follow the " + std::to_string(n) +
                              " vertices the header declares (a wrong vertex count?)");
  }
  return Status::OK();
}

}  // namespace

Result<GaussianCloud> ReadGaussianPly(std::string_view bytes, const std::string& name) {
  HVDB_ASSIGN_OR_RETURN(Header h, ParseHeader(bytes, name));
  GaussianCloud c;
  c.sh_degree = h.sh_degree;
  for (const Prop& p : h.props) {
    if (p.slot == Slot::kIgnored && p.name != "nx" && p.name != "ny" && p.name != "nz") {
      c.ignored.push_back(p.name);
    }
  }
  const std::string_view data = bytes.substr(h.data_offset);
  if (h.encoding == Encoding::kAscii) {
    HVDB_RETURN_IF_ERROR(ReadAscii(h, data, &c, name));
  } else {
    HVDB_RETURN_IF_ERROR(ReadBinary(h, data, &c, name));
  }
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));
  return c;
}

Result<std::string> WriteGaussianPly(const GaussianCloud& c, const std::string& name) {
  HVDB_RETURN_IF_ERROR(ValidateGaussianCloud(c, name));
  const size_t n = c.size();
  const size_t rest = c.sh_rest_per_splat();
  std::string out = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(n) +
                    "\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float nx\nproperty float ny\nproperty float nz\n"
                    "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n";
  for (size_t k = 0; k < rest; ++k) out += "property float f_rest_" + std::to_string(k) + "\n";
  out +=
      "property float opacity\n"
      "property float scale_0\nproperty float scale_1\nproperty float scale_2\n"
      "property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n"
      "end_header\n";
  out.reserve(out.size() + n * 4 * (17 + rest));
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) StoreFloatLE(c.position[3 * i + k], &out);
    for (int k = 0; k < 3; ++k) StoreFloatLE(0.0f, &out);  // normals, as the Inria code writes
    for (int k = 0; k < 3; ++k) StoreFloatLE(c.sh_dc[3 * i + k], &out);
    for (size_t k = 0; k < rest; ++k) StoreFloatLE(c.sh_rest[i * rest + k], &out);
    StoreFloatLE(c.opacity[i], &out);
    for (int k = 0; k < 3; ++k) StoreFloatLE(c.scale[3 * i + k], &out);
    for (int k = 0; k < 4; ++k) StoreFloatLE(c.rotation[4 * i + k], &out);
  }
  return out;
}

}  // namespace hvdb::formats
