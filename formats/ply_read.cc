// PLY reading: the header, then the vertex element's properties converted to Points (the
// writers are in ply_write.cc).
#include "formats/ply.h"

#include <sys/stat.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <limits>
#include <string_view>
#include <utility>

namespace hvdb::formats {
namespace {

// ---------------------------------------------------------------------------------------------
// Header model

enum class Type : uint8_t { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

size_t TypeSize(Type t) {
  switch (t) {
    case Type::kInt8:
    case Type::kUint8:
      return 1;
    case Type::kInt16:
    case Type::kUint16:
      return 2;
    case Type::kInt32:
    case Type::kUint32:
    case Type::kFloat32:
      return 4;
    case Type::kFloat64:
      return 8;
  }
  return 0;
}

bool IsFloatType(Type t) { return t == Type::kFloat32 || t == Type::kFloat64; }

bool ParseType(std::string_view s, Type* t) {
  // The PLY 1.0 names and the sized aliases that VTK, PCL and plyfile write.
  static constexpr std::pair<std::string_view, Type> kNames[] = {
      {"char", Type::kInt8},      {"int8", Type::kInt8},       {"uchar", Type::kUint8},
      {"uint8", Type::kUint8},    {"short", Type::kInt16},     {"int16", Type::kInt16},
      {"ushort", Type::kUint16},  {"uint16", Type::kUint16},   {"int", Type::kInt32},
      {"int32", Type::kInt32},    {"uint", Type::kUint32},     {"uint32", Type::kUint32},
      {"float", Type::kFloat32},  {"float32", Type::kFloat32}, {"double", Type::kFloat64},
      {"float64", Type::kFloat64}};
  for (const auto& [name, type] : kNames) {
    if (s == name) {
      *t = type;
      return true;
    }
  }
  return false;
}

enum class Format { kAscii, kBinaryLE, kBinaryBE };

struct Property {
  std::string name;
  Type type = Type::kFloat32;
  bool is_list = false;
  Type count_type = Type::kUint8;  // lists only
};

struct Element {
  std::string name;
  uint64_t count = 0;
  std::vector<Property> props;
};

struct Header {
  Format format = Format::kAscii;
  std::vector<Element> elements;
};

// A header line quoted in an error: short and printable, whatever the file holds.
std::string Printable(std::string_view s) {
  std::string out;
  for (char c : s.substr(0, 60)) out += std::isprint(static_cast<unsigned char>(c)) ? c : '?';
  if (s.size() > 60) out += "...";
  return out;
}

std::vector<std::string_view> SplitWords(std::string_view s) {
  std::vector<std::string_view> words;
  size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
    size_t j = i;
    while (j < s.size() && !std::isspace(static_cast<unsigned char>(s[j]))) ++j;
    if (j > i) words.push_back(s.substr(i, j - i));
    i = j;
  }
  return words;
}

bool ParseU64(std::string_view s, uint64_t* v) {
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *v);
  return ec == std::errc() && p == s.data() + s.size();
}

bool ParseDouble(std::string_view s, double* v) {
  if (!s.empty() && s[0] == '+') s.remove_prefix(1);  // from_chars rejects a leading '+'
  auto [p, ec] = std::from_chars(s.data(), s.data() + s.size(), *v);
  return ec == std::errc() && p == s.data() + s.size();
}

// ---------------------------------------------------------------------------------------------
// Buffered input: header lines, binary records and ascii tokens from one FILE*.

class Input {
 public:
  explicit Input(std::FILE* f) : f_(f), buf_(kBufSize) {}

  // Makes n bytes available at data(); false when the file ends first.
  bool Ensure(size_t n) {
    if (end_ - pos_ >= n) return true;
    std::memmove(buf_.data(), buf_.data() + pos_, end_ - pos_);
    end_ -= pos_;
    pos_ = 0;
    if (n > buf_.size()) buf_.resize(std::max(n, 2 * buf_.size()));
    while (end_ < n && !eof_) {
      size_t got = std::fread(buf_.data() + end_, 1, buf_.size() - end_, f_);
      if (got == 0) eof_ = true;
      end_ += got;
    }
    return end_ >= n;
  }
  const uint8_t* data() const { return buf_.data() + pos_; }
  void Consume(size_t n) { pos_ += n; }

  // Skips up to n bytes; returns how many there were (< n: the file ended).
  uint64_t Skip(uint64_t n) {
    uint64_t skipped = 0;
    while (skipped < n) {
      if (pos_ == end_ && !Ensure(1)) break;
      size_t take = static_cast<size_t>(std::min<uint64_t>(n - skipped, end_ - pos_));
      pos_ += take;
      skipped += take;
    }
    return skipped;
  }

  // Reads up to '\n' (dropping a '\r' before it). False at the end of the file or when the
  // line passes max_len (then *line holds its start).
  bool ReadLine(std::string* line, size_t max_len) {
    line->clear();
    while (true) {
      if (pos_ == end_ && !Ensure(1)) return !line->empty();
      const char* p = reinterpret_cast<const char*>(data());
      size_t avail = end_ - pos_;
      const void* nl = std::memchr(p, '\n', avail);
      size_t take = nl ? static_cast<size_t>(static_cast<const char*>(nl) - p) : avail;
      line->append(p, take);
      pos_ += take;
      if (line->size() > max_len) return false;
      if (nl) {
        ++pos_;
        if (!line->empty() && line->back() == '\r') line->pop_back();
        return true;
      }
    }
  }

  // The next whitespace-separated token; valid until the next call. False at the end.
  bool Token(std::string_view* tok) {
    while (true) {
      if (pos_ == end_ && !Ensure(1)) return false;
      while (pos_ < end_ && IsSpace(buf_[pos_])) ++pos_;
      if (pos_ < end_) break;
    }
    size_t len = 0;
    while (true) {
      while (pos_ + len < end_ && !IsSpace(buf_[pos_ + len])) ++len;
      // A token longer than any number is not one; stop there and let the parse fail.
      if (pos_ + len < end_ || eof_ || len > kMaxToken) break;
      Ensure(len + 1);  // compacts: the token now starts at pos_ == 0
    }
    *tok = std::string_view(reinterpret_cast<const char*>(data()), len);
    pos_ += len;
    return true;
  }

  bool failed() const { return std::ferror(f_) != 0; }

 private:
  static constexpr size_t kBufSize = 1 << 20;
  static constexpr size_t kMaxToken = 256;
  static bool IsSpace(uint8_t c) { return c == ' ' || c == '\n' || c == '\r' || c == '\t'; }

  std::FILE* f_;
  std::vector<uint8_t> buf_;
  size_t pos_ = 0, end_ = 0;
  bool eof_ = false;
};

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using FilePtr = std::unique_ptr<std::FILE, FileCloser>;

Result<Header> ReadHeader(Input& in, const std::string& path) {
  constexpr size_t kMaxLine = 4096;
  auto bad = [&path](int line_no, const std::string& msg) {
    return Status::InvalidArgument(path + ": header line " + std::to_string(line_no) + ": " + msg);
  };
  std::string line;
  if (!in.ReadLine(&line, kMaxLine) || SplitWords(line).size() != 1 ||
      SplitWords(line)[0] != "ply") {
    if (line.empty() && in.failed()) return Status::IOError(path + ": read error");
    return Status::InvalidArgument(path + ": not a PLY file (first line is '" + Printable(line) +
                                   "', expected 'ply')");
  }
  Header h;
  bool have_format = false;
  for (int n = 2;; ++n) {
    if (!in.ReadLine(&line, kMaxLine)) {
      if (line.size() > kMaxLine) return bad(n, "line too long (not a PLY header?)");
      return Status::InvalidArgument(path +
                                     ": header has no 'end_header' line (file ends at line " +
                                     std::to_string(n - 1) + ")");
    }
    std::vector<std::string_view> w = SplitWords(line);
    if (w.empty()) continue;  // tolerated, though the format has no blank lines
    std::string_view kw = w[0];
    if (kw == "comment" || kw == "obj_info") continue;
    if (kw == "format") {
      if (w.size() != 3) return bad(n, "expected 'format <encoding> 1.0'");
      if (w[1] == "ascii") {
        h.format = Format::kAscii;
      } else if (w[1] == "binary_little_endian") {
        h.format = Format::kBinaryLE;
      } else if (w[1] == "binary_big_endian") {
        h.format = Format::kBinaryBE;
      } else {
        return bad(n, "unknown format '" + Printable(w[1]) +
                          "' (expected ascii, binary_little_endian or binary_big_endian)");
      }
      if (w[2] != "1.0" && w[2] != "1")
        return bad(n, "unsupported version '" + Printable(w[2]) + "'");
      have_format = true;
    } else if (kw == "element") {
      Element e;
      if (w.size() != 3 || !ParseU64(w[2], &e.count)) {
        return bad(n, "expected 'element <name> <count>', got '" + Printable(line) + "'");
      }
      e.name = std::string(w[1]);
      for (const Element& other : h.elements) {
        if (other.name == e.name) return bad(n, "duplicate element '" + e.name + "'");
      }
      h.elements.push_back(std::move(e));
    } else if (kw == "property") {
      if (h.elements.empty()) return bad(n, "property before any element");
      Property p;
      if (w.size() >= 2 && w[1] == "list") {
        if (w.size() != 5) return bad(n, "expected 'property list <count type> <type> <name>'");
        if (!ParseType(w[2], &p.count_type)) {
          return bad(n, "unknown property type '" + Printable(w[2]) + "'");
        }
        if (IsFloatType(p.count_type)) {
          return bad(n, "list count type must be an integer type, not '" + std::string(w[2]) + "'");
        }
        if (!ParseType(w[3], &p.type)) {
          return bad(n, "unknown property type '" + Printable(w[3]) + "'");
        }
        p.is_list = true;
        p.name = std::string(w[4]);
      } else {
        if (w.size() != 3) return bad(n, "expected 'property <type> <name>'");
        if (!ParseType(w[1], &p.type)) {
          return bad(n, "unknown property type '" + Printable(w[1]) + "'");
        }
        p.name = std::string(w[2]);
      }
      h.elements.back().props.push_back(std::move(p));
    } else if (kw == "end_header") {
      if (!have_format) return bad(n, "no 'format' line before end_header");
      return h;
    } else {
      return bad(n, "unknown keyword '" + Printable(kw) + "'");
    }
  }
}

// ---------------------------------------------------------------------------------------------
// Values

template <typename T>
T LoadScalar(const uint8_t* p, bool swap) {
  uint8_t b[sizeof(T)];
  std::memcpy(b, p, sizeof(T));
  if (swap) std::reverse(b, b + sizeof(T));
  T v;
  std::memcpy(&v, b, sizeof(T));
  return v;
}

// Every PLY scalar type converts to double exactly, so one value path serves all of them.
double LoadValue(const uint8_t* p, Type t, bool swap) {
  switch (t) {
    case Type::kInt8:
      return LoadScalar<int8_t>(p, false);
    case Type::kUint8:
      return p[0];
    case Type::kInt16:
      return LoadScalar<int16_t>(p, swap);
    case Type::kUint16:
      return LoadScalar<uint16_t>(p, swap);
    case Type::kInt32:
      return LoadScalar<int32_t>(p, swap);
    case Type::kUint32:
      return LoadScalar<uint32_t>(p, swap);
    case Type::kFloat32:
      return LoadScalar<float>(p, swap);
    case Type::kFloat64:
      return LoadScalar<double>(p, swap);
  }
  return 0;
}

template <typename T>
T ClampTo(double v) {
  if (!(v > 0)) return 0;  // also NaN
  if (v >= static_cast<double>(std::numeric_limits<T>::max())) {
    return std::numeric_limits<T>::max();
  }
  return static_cast<T>(v);
}

uint8_t ToColour(double v, Type t) {
  if (IsFloatType(t)) return ClampTo<uint8_t>(std::round(v * 255.0));
  if (t == Type::kUint16 || t == Type::kInt16) return ClampTo<uint8_t>(std::round(v / 257.0));
  return ClampTo<uint8_t>(v);
}

// The vertex properties hvdb understands.
enum Field : uint8_t {
  kNone,
  kX,
  kY,
  kZ,
  kNx,
  kNy,
  kNz,
  kRed,
  kGreen,
  kBlue,
  kIdLo,
  kIdHi,
  kId,
  kFrame,
  kCovXX,
  kCovXY,
  kCovXZ,
  kCovYY,
  kCovYZ,
  kCovZZ,
  kLabel,
  kCamera,
  kFlags,
  kFieldCount
};

Field FieldFor(std::string_view name) {
  static constexpr std::pair<std::string_view, Field> kNames[] = {{"x", kX},
                                                                  {"y", kY},
                                                                  {"z", kZ},
                                                                  {"nx", kNx},
                                                                  {"ny", kNy},
                                                                  {"nz", kNz},
                                                                  {"red", kRed},
                                                                  {"green", kGreen},
                                                                  {"blue", kBlue},
                                                                  {"r", kRed},
                                                                  {"g", kGreen},
                                                                  {"b", kBlue},
                                                                  {"diffuse_red", kRed},
                                                                  {"diffuse_green", kGreen},
                                                                  {"diffuse_blue", kBlue},
                                                                  {"id_lo", kIdLo},
                                                                  {"id_hi", kIdHi},
                                                                  {"id", kId},
                                                                  {"frame", kFrame},
                                                                  {"cov_xx", kCovXX},
                                                                  {"cov_xy", kCovXY},
                                                                  {"cov_xz", kCovXZ},
                                                                  {"cov_yy", kCovYY},
                                                                  {"cov_yz", kCovYZ},
                                                                  {"cov_zz", kCovZZ},
                                                                  {"label", kLabel},
                                                                  {"camera", kCamera},
                                                                  {"flags", kFlags}};
  for (const auto& [n, f] : kNames) {
    if (name == n) return f;
  }
  return kNone;
}

// Turns the raw values of one vertex into a Point.
class VertexBuilder {
 public:
  VertexBuilder(const Element& e, const ReadOptions& opts) : opts_(opts) {
    for (const Property& p : e.props) {
      Field f = p.is_list ? kNone : FieldFor(p.name);
      fields_.push_back(f);
      if (f != kNone) {
        present_[f] = true;
        types_[f] = p.type;
      }
    }
    s2_ = opts.scale * opts.scale;
    float sigma2 = static_cast<float>(opts.default_sigma * opts.default_sigma);
    default_cov_ = {sigma2, 0, 0, sigma2, 0, sigma2};
  }

  // Field of the i-th property (kNone: ignored).
  Field field(size_t i) const { return fields_[i]; }
  double* values() { return vals_; }

  Status Validate(const std::string& path) const {
    for (Field f : {kX, kY, kZ}) {
      if (!present_[f]) {
        static constexpr const char* kAxis[] = {"x", "y", "z"};
        return Status::InvalidArgument(path + ": the vertex element has no '" + kAxis[f - kX] +
                                       "' property");
      }
    }
    int normals = present_[kNx] + present_[kNy] + present_[kNz];
    if (normals != 0 && normals != 3) {
      return Status::InvalidArgument(path + ": the vertex element has only some of nx ny nz");
    }
    int covs = 0;
    for (int f = kCovXX; f <= kCovZZ; ++f) covs += present_[f];
    if (covs != 0 && covs != 6) {
      return Status::InvalidArgument(
          path + ": the vertex element has only some of cov_xx cov_xy cov_xz cov_yy cov_yz cov_zz");
    }
    return Status::OK();
  }

  // The first of x, y, z (0..2) of values() that is not finite as the stored float, or -1.
  int NonFiniteAxis() const {
    for (int a = 0; a < 3; ++a) {
      if (!std::isfinite(static_cast<float>(vals_[kX + a] * opts_.scale))) return a;
    }
    return -1;
  }
  double value(Field f) const { return vals_[f]; }

  // Builds the point from values().
  void Build(Point* p) const {
    const double* v = vals_;
    *p = Point{};
    p->x = static_cast<float>(v[kX] * opts_.scale);
    p->y = static_cast<float>(v[kY] * opts_.scale);
    p->z = static_cast<float>(v[kZ] * opts_.scale);
    uint8_t flags = 0;
    if (present_[kNx]) {
      float nx = static_cast<float>(v[kNx]), ny = static_cast<float>(v[kNy]),
            nz = static_cast<float>(v[kNz]);
      p->normal_oct = EncodeNormal(nx, ny, nz);
      float l1 = std::fabs(nx) + std::fabs(ny) + std::fabs(nz);
      if (l1 > 0.f && std::isfinite(l1)) flags |= kFlagHasNormal;  // (0,0,0) means "none"
    }
    if (present_[kRed]) p->r = ToColour(v[kRed], types_[kRed]);
    if (present_[kGreen]) p->g = ToColour(v[kGreen], types_[kGreen]);
    if (present_[kBlue]) p->b = ToColour(v[kBlue], types_[kBlue]);
    if (present_[kIdLo] || present_[kIdHi]) {
      p->id = ClampTo<uint32_t>(v[kIdLo]) | uint64_t{ClampTo<uint32_t>(v[kIdHi])} << 32;
    } else if (present_[kId]) {
      p->id = ClampTo<uint64_t>(v[kId]);
    }
    p->frame = present_[kFrame] && !opts_.force_frame ? ClampTo<uint32_t>(v[kFrame]) : opts_.frame;
    if (present_[kCovXX]) {
      for (int i = 0; i < 6; ++i) p->cov[i] = static_cast<float>(v[kCovXX + i] * s2_);
      flags |= kFlagHasCovariance;
    } else {
      p->cov = default_cov_;
    }
    if (present_[kLabel]) p->label = ClampTo<uint32_t>(v[kLabel]);
    if (present_[kCamera]) p->camera = ClampTo<uint16_t>(v[kCamera]);
    // An hvdb file says exactly which fields are valid; trust it over the guesses above.
    p->flags = present_[kFlags] ? ClampTo<uint8_t>(v[kFlags]) : flags;
  }

 private:
  const ReadOptions& opts_;
  std::vector<Field> fields_;
  bool present_[kFieldCount] = {};
  Type types_[kFieldCount] = {};
  double vals_[kFieldCount] = {};
  double s2_ = 1;
  std::array<float, 6> default_cov_{};
};

// Reads or skips the instances of one element.
class ElementReader {
 public:
  ElementReader(Input& in, const std::string& path, Format format)
      : in_(in),
        path_(path),
        ascii_(format == Format::kAscii),
        swap_((format == Format::kBinaryBE) != (std::endian::native == std::endian::big)) {}

  // Reads `e`; for each instance, stores the scalar values whose builder field is set and
  // calls emit(). builder == nullptr: just skip the element.
  template <typename Emit>
  Status Read(const Element& e, VertexBuilder* builder, Emit emit) {
    size_t record = 0;
    bool has_list = false;
    for (const Property& p : e.props) {
      has_list |= p.is_list;
      record += TypeSize(p.type);
    }
    double scratch = 0;
    for (uint64_t i = 0; i < e.count; ++i) {
      if (!ascii_ && !has_list && builder == nullptr) {
        // Fixed-size records of an ignored element: skip them all at once.
        uint64_t bytes = (e.count - i) * record;
        uint64_t skipped = in_.Skip(bytes);
        if (skipped < bytes) return Truncated(e, i + skipped / record);
        break;
      }
      if (!ascii_ && !has_list) {
        if (!in_.Ensure(record)) return Truncated(e, i);
        const uint8_t* d = in_.data();
        for (size_t k = 0; k < e.props.size(); ++k) {
          Field f = builder->field(k);
          if (f != kNone) builder->values()[f] = LoadValue(d, e.props[k].type, swap_);
          d += TypeSize(e.props[k].type);
        }
        in_.Consume(record);
      } else {
        for (size_t k = 0; k < e.props.size(); ++k) {
          const Property& p = e.props[k];
          double* dst = builder && builder->field(k) != kNone
                            ? &builder->values()[builder->field(k)]
                            : &scratch;
          if (p.is_list) {
            HVDB_RETURN_IF_ERROR(SkipList(e, i, p));
          } else {
            bool got = false;
            HVDB_RETURN_IF_ERROR(Value(e, i, p.name, p.type, dst, &got));
            if (!got) return Truncated(e, i);
          }
        }
      }
      if (builder) emit();
    }
    if (in_.failed()) return Status::IOError(path_ + ": read error");
    return Status::OK();
  }

 private:
  // One scalar; *got = false at the end of the file.
  Status Value(const Element& e, uint64_t i, const std::string& prop, Type t, double* v,
               bool* got) {
    *got = false;
    if (ascii_) {
      std::string_view tok;
      if (!in_.Token(&tok)) return Status::OK();
      if (!ParseDouble(tok, v)) {
        return Status::Corruption(path_ + ": " + e.name + " " + std::to_string(i) +
                                  ": bad value '" + Printable(tok) + "' for property '" + prop +
                                  "'");
      }
    } else {
      size_t n = TypeSize(t);
      if (!in_.Ensure(n)) return Status::OK();
      *v = LoadValue(in_.data(), t, swap_);
      in_.Consume(n);
    }
    *got = true;
    return Status::OK();
  }

  Status SkipList(const Element& e, uint64_t i, const Property& p) {
    double count = 0;
    bool got = false;
    HVDB_RETURN_IF_ERROR(Value(e, i, p.name, p.count_type, &count, &got));
    if (!got) return Truncated(e, i);
    if (!(count >= 0) || count != std::floor(count) || count > 1e12) {
      return Status::Corruption(path_ + ": " + e.name + " " + std::to_string(i) +
                                ": bad list length " + std::to_string(count) + " for '" + p.name +
                                "'");
    }
    auto n = static_cast<uint64_t>(count);
    if (!ascii_) {
      if (in_.Skip(n * TypeSize(p.type)) < n * TypeSize(p.type)) return Truncated(e, i);
      return Status::OK();
    }
    double item = 0;
    for (uint64_t k = 0; k < n; ++k) {
      HVDB_RETURN_IF_ERROR(Value(e, i, p.name, p.type, &item, &got));
      if (!got) return Truncated(e, i);
    }
    return Status::OK();
  }

  Status Truncated(const Element& e, uint64_t done) const {
    if (in_.failed()) return Status::IOError(path_ + ": read error");
    std::string what = e.name == "vertex" ? "vertices" : "'" + e.name + "' elements";
    return Status::Corruption(path_ + ": truncated: expected " + std::to_string(e.count) + " " +
                              what + ", file ends after " + std::to_string(done));
  }

  Input& in_;
  const std::string& path_;
  bool ascii_;
  bool swap_;
};

// The error for `bad` vertices with a non-finite coordinate among `total`; `first` describes
// the first of them.
Status NonFiniteError(const std::string& path, uint64_t bad, uint64_t total,
                      const std::string& first) {
  return Status::InvalidArgument(
      path + ": " + std::to_string(bad) + " of " + std::to_string(total) +
      (bad == 1 ? " vertices has" : " vertices have") + " a NaN or infinite coordinate (" + first +
      "); nothing was read. Pass --skip-invalid (Python: skip_invalid=True) to import " +
      "the other " + std::to_string(total - bad) + " and skip these");
}

}  // namespace

Result<std::vector<Point>> ReadPly(const std::string& path, const ReadOptions& opts,
                                   ReadStats* stats) {
  if (!(opts.scale > 0) || !std::isfinite(opts.scale)) {
    return Status::InvalidArgument(path + ": scale must be positive and finite, not " +
                                   std::to_string(opts.scale));
  }
  if (!(opts.default_sigma >= 0) || !std::isfinite(opts.default_sigma)) {
    return Status::InvalidArgument(path + ": default_sigma must be >= 0");
  }
  FilePtr f(std::fopen(path.c_str(), "rb"));
  if (!f) return Status::FromErrno(path, errno);
  struct stat st {};
  uint64_t file_size = fstat(fileno(f.get()), &st) == 0 ? static_cast<uint64_t>(st.st_size) : 0;
  Input in(f.get());
  HVDB_ASSIGN_OR_RETURN(Header h, ReadHeader(in, path));

  const Element* vertex = nullptr;
  for (const Element& e : h.elements) {
    if (e.name == "vertex") vertex = &e;
  }
  if (vertex == nullptr) return Status::InvalidArgument(path + ": no 'vertex' element");
  VertexBuilder builder(*vertex, opts);
  HVDB_RETURN_IF_ERROR(builder.Validate(path));

  std::vector<Point> points;
  // The count comes from the file: reserve no more than the file could hold.
  size_t min_bytes = std::max<size_t>(
      1, h.format == Format::kAscii ? 2 * vertex->props.size() : vertex->props.size());
  points.reserve(static_cast<size_t>(std::min<uint64_t>(vertex->count, file_size / min_bytes + 1)));
  ElementReader reader(in, path, h.format);
  uint64_t index = 0, bad = 0;
  std::string first_bad;
  for (const Element& e : h.elements) {
    if (&e == vertex) {
      Point p;
      HVDB_RETURN_IF_ERROR(reader.Read(e, &builder, [&] {
        if (int axis = builder.NonFiniteAxis(); axis >= 0) {
          if (bad++ == 0) {
            double v = builder.value(static_cast<Field>(kX + axis));
            char buf[96];
            std::snprintf(buf, sizeof buf, "the first: vertex %llu, %c = %g%s",
                          static_cast<unsigned long long>(index), "xyz"[axis], v,
                          std::isfinite(v) ? ", beyond float range" : "");
            first_bad = buf;
          }
        } else if (bad == 0 || opts.skip_invalid) {  // refusing: the rest is only counted
          builder.Build(&p);
          points.push_back(p);
        }
        ++index;
      }));
    } else {
      HVDB_RETURN_IF_ERROR(reader.Read(e, nullptr, [] {}));
    }
  }
  if (bad > 0 && !opts.skip_invalid) return NonFiniteError(path, bad, index, first_bad);
  if (stats) *stats = {index, bad};
  return points;
}

}  // namespace hvdb::formats
