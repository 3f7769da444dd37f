// A mesh file's declared structure checked before assimp reads it.
//
// assimp trusts what a file declares: a GLB chunk length is allocated as given, a PLY or OFF
// element count sizes its arrays, and its glTF parser, node importer and validator recurse
// once per level of JSON and of the node tree (a 4 MB file of nested arrays overflows a
// thread's stack). These checks are ours because no library offers them: each declared size is
// held against the bytes sent, and nesting is measured without recursion.
#include <algorithm>
#include <cctype>
#include <cstring>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "media/media.h"

namespace hvdb::media {
namespace {

using json = nlohmann::json;

Status Bad(const std::string& what, const std::string& why) {
  return Status::InvalidArgument(what + " " + why);
}

uint32_t Le32(const char* p) {
  const auto* b = reinterpret_cast<const uint8_t*>(p);
  return uint32_t{b[0]} | uint32_t{b[1]} << 8 | uint32_t{b[2]} << 16 | uint32_t{b[3]} << 24;
}

// JSON nesting by a scan of the bytes (strings and their escapes skipped): no recursion.
Status CheckJsonDepth(std::string_view text, const std::string& what) {
  int depth = 0;
  bool in_string = false;
  for (size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      if (c == '\\') {
        ++i;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > kMaxJsonDepth) {
        return Status::LimitExceeded(what + " nests its JSON deeper than " +
                                     std::to_string(kMaxJsonDepth) + " levels");
      }
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return Status::OK();
}

// A data: URI's payload size (base64 or percent-encoded: at most its characters).
uint64_t DataUriBytes(const std::string& uri) {
  const size_t comma = uri.find(',');
  if (comma == std::string::npos) return 0;
  const uint64_t n = uri.size() - comma - 1;
  const bool base64 = comma >= 7 && uri.compare(comma - 7, 7, ";base64") == 0;
  return base64 ? n / 4 * 3 + 3 : n;
}

bool IsDataUri(const std::string& uri) { return uri.rfind("data:", 0) == 0; }

Status Outside(const std::string& what, const std::string& field, const std::string& uri) {
  return Bad(what, "refers to '" + uri + "' (" + field +
                       "), outside the bytes sent: only the file itself and data: URIs are "
                       "read; embed it (GLB, or a data: URI)");
}

// What the checks need of a glTF, read by nlohmann's SAX parser (iterative) into flat records:
// a DOM of a 2 MB file of nested nodes takes ~50 MB, these a few.
constexpr uint64_t kBadNumber = UINT64_MAX;  // a negative, fractional or non-number value

struct GltfFacts {
  struct Buffer {
    bool has_uri = false;
    std::string uri;
    uint64_t length = 0;
  };
  struct View {
    uint64_t buffer = kBadNumber, offset = 0, length = 0, stride = 0;
  };
  struct Accessor {
    bool has_view = false;
    uint64_t view = kBadNumber, offset = 0, count = 0, component = 0;
    std::string type;
  };
  std::string version;
  std::vector<Buffer> buffers;
  std::vector<View> views;
  std::vector<Accessor> accessors;
  std::vector<std::string> image_uris;  // "" for an image without one
  std::vector<std::vector<uint64_t>> children;  // per node
  bool shape_error = false;  // a tracked collection that is not an array of objects
};

class GltfSax : public nlohmann::json_sax<json> {
 public:
  explicit GltfSax(GltfFacts* f) : f_(f) {}
  bool null() override { return Scalar(kBadNumber, nullptr); }
  bool boolean(bool) override { return Scalar(kBadNumber, nullptr); }
  bool number_integer(number_integer_t v) override {
    return Scalar(v < 0 ? kBadNumber : static_cast<uint64_t>(v), nullptr);
  }
  bool number_unsigned(number_unsigned_t v) override { return Scalar(v, nullptr); }
  bool number_float(number_float_t, const string_t&) override { return Scalar(kBadNumber, nullptr); }
  bool string(string_t& v) override { return Scalar(kBadNumber, &v); }
  bool binary(binary_t&) override { return Scalar(kBadNumber, nullptr); }
  bool start_object(std::size_t) override { return Open(false); }
  bool end_object() override { return Close(); }
  bool start_array(std::size_t) override { return Open(true); }
  bool end_array() override { return Close(); }
  bool key(string_t& k) override {
    stack_.back().key = k;
    return true;
  }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override {
    return false;
  }

 private:
  struct Frame {
    bool array;
    std::string key;
  };
  const std::string& Root() const { return stack_[0].key; }
  // A container opens: an element of a tracked collection starts a record.
  bool Open(bool array) {
    if (stack_.size() == 2 && stack_[1].array) {
      const std::string& r = Root();
      if (r == "buffers" || r == "bufferViews" || r == "accessors" || r == "images" ||
          r == "nodes") {
        if (array) f_->shape_error = true;
        if (r == "buffers") f_->buffers.emplace_back();
        if (r == "bufferViews") f_->views.emplace_back();
        if (r == "accessors") f_->accessors.emplace_back();
        if (r == "images") f_->image_uris.emplace_back();
        if (r == "nodes") f_->children.emplace_back();
      }
    }
    if (stack_.size() == 1 && !array && (Root() == "buffers" || Root() == "nodes" ||
                                         Root() == "accessors" || Root() == "bufferViews")) {
      f_->shape_error = true;
    }
    stack_.push_back({array, {}});
    return true;
  }
  bool Close() {
    stack_.pop_back();
    return true;
  }
  bool Scalar(uint64_t n, const std::string* str) {
    const size_t d = stack_.size();
    if (d == 2 && Root() == "asset" && stack_[1].key == "version" && str != nullptr) {
      f_->version = *str;
    }
    if (d == 3 && stack_[1].array && !stack_[2].array) {
      const std::string& r = Root();
      const std::string& k = stack_[2].key;
      if (r == "buffers" && !f_->buffers.empty()) {
        GltfFacts::Buffer& b = f_->buffers.back();
        if (k == "uri") {
          b.has_uri = true;
          b.uri = str != nullptr ? *str : "";
        }
        if (k == "byteLength") b.length = n;
      } else if (r == "bufferViews" && !f_->views.empty()) {
        GltfFacts::View& v = f_->views.back();
        if (k == "buffer") v.buffer = n;
        if (k == "byteOffset") v.offset = n;
        if (k == "byteLength") v.length = n;
        if (k == "byteStride") v.stride = n;
      } else if (r == "accessors" && !f_->accessors.empty()) {
        GltfFacts::Accessor& a = f_->accessors.back();
        if (k == "bufferView") {
          a.has_view = true;
          a.view = n;
        }
        if (k == "byteOffset") a.offset = n;
        if (k == "count") a.count = n;
        if (k == "componentType") a.component = n;
        if (k == "type" && str != nullptr) a.type = *str;
      } else if (r == "images" && !f_->image_uris.empty() && k == "uri") {
        f_->image_uris.back() = str != nullptr ? *str : "(not a string)";
      }
    }
    if (d == 4 && Root() == "nodes" && stack_[2].key == "children" && stack_[3].array &&
        !f_->children.empty()) {
      f_->children.back().push_back(n);
    }
    return true;
  }

  GltfFacts* f_;
  std::vector<Frame> stack_;
};

// glTF 2.0's JSON: buffers within the bytes sent, views and accessors within their buffers,
// images embedded, and the node tree a tree no deeper than kMaxNodeDepth.
Status CheckGltfJson(std::string_view text, uint64_t bin_bytes, bool glb, const std::string& what) {
  HVDB_RETURN_IF_ERROR(CheckJsonDepth(text, what));
  GltfFacts f;
  GltfSax sax(&f);
  if (!json::sax_parse(text.begin(), text.end(), &sax, json::input_format_t::json, true)) {
    return Bad(what, "is not valid glTF JSON");
  }
  if (f.shape_error) return Bad(what, "is not glTF: a list of objects is not one");
  if (f.version.rfind("2", 0) != 0) {
    return Bad(what, "is glTF version '" + f.version + "'; glTF 2.0 is read");
  }
  std::vector<uint64_t> buffer_len;
  for (size_t i = 0; i < f.buffers.size(); ++i) {
    const GltfFacts::Buffer& b = f.buffers[i];
    const std::string field = "buffers[" + std::to_string(i) + "]";
    uint64_t have = 0;
    if (b.has_uri) {
      if (!IsDataUri(b.uri)) return Outside(what, field + ".uri", b.uri);
      have = DataUriBytes(b.uri);
    } else if (glb && i == 0) {
      have = bin_bytes;
    } else {
      return Bad(what, field + " has no uri and no GLB binary chunk to be");
    }
    if (b.length > have) {
      return Bad(what, field + ".byteLength is " + std::to_string(b.length) +
                           ", more than the " + std::to_string(have) + " bytes it has");
    }
    buffer_len.push_back(b.length);
  }
  for (size_t i = 0; i < f.views.size(); ++i) {
    const GltfFacts::View& v = f.views[i];
    if (v.buffer >= buffer_len.size() || v.offset > buffer_len[v.buffer] ||
        v.length > buffer_len[v.buffer] - v.offset) {
      return Bad(what, "bufferViews[" + std::to_string(i) + "] lies outside its buffer");
    }
  }
  uint64_t unbacked = 0;  // bytes of accessors without a view (zeros, made by the reader)
  for (size_t i = 0; i < f.accessors.size(); ++i) {
    const GltfFacts::Accessor& a = f.accessors[i];
    const std::string field = "accessors[" + std::to_string(i) + "]";
    const std::string& type = a.type;
    const uint64_t comps = type == "SCALAR" ? 1 : type == "VEC2" ? 2 : type == "VEC3" ? 3
                         : type == "VEC4" || type == "MAT2" ? 4 : type == "MAT3" ? 9
                         : type == "MAT4" ? 16 : 0;
    const uint64_t ct = a.component;
    const uint64_t size = ct == 5120 || ct == 5121 ? 1 : ct == 5122 || ct == 5123 ? 2
                        : ct == 5125 || ct == 5126 ? 4 : 0;
    if (comps == 0 || size == 0) return Bad(what, field + " has no valid type/componentType");
    if (a.count > (uint64_t{1} << 32)) return Bad(what, field + ".count is too large");
    const uint64_t elem = comps * size;
    if (a.has_view) {
      if (a.view >= f.views.size()) return Bad(what, field + ".bufferView does not exist");
      const uint64_t len = f.views[a.view].length;
      const uint64_t stride = std::max(elem, f.views[a.view].stride);
      if (stride > (uint64_t{1} << 16)) return Bad(what, field + ": its view's byteStride is too large");
      if (a.count > 0 && (a.offset > len || (a.count - 1) * stride + elem > len - a.offset)) {
        return Bad(what, field + " (" + std::to_string(a.count) + " elements) lies outside its "
                                 "buffer view");
      }
    } else {
      unbacked += a.count * elem;
    }
  }
  if (unbacked > 4 * static_cast<uint64_t>(text.size() + bin_bytes) + (1u << 20)) {
    return Bad(what, "declares " + std::to_string(unbacked) +
                         " bytes of accessors without data, out of proportion to its size");
  }
  for (size_t i = 0; i < f.image_uris.size(); ++i) {
    const std::string& uri = f.image_uris[i];
    if (!uri.empty() && !IsDataUri(uri)) {
      return Outside(what, "images[" + std::to_string(i) + "].uri", uri);
    }
  }
  // The node tree, walked with an explicit stack: every node has at most one parent, every
  // child exists, no cycles, depth bounded.
  const size_t nodes = f.children.size();
  std::vector<int> parents(nodes, 0);
  for (size_t i = 0; i < nodes; ++i) {
    for (uint64_t k : f.children[i]) {
      if (k >= nodes) {
        return Bad(what, "nodes[" + std::to_string(i) + "] has a child that does not exist");
      }
      if (++parents[k] > 1) {
        return Bad(what, "nodes[" + std::to_string(k) + "] has two parents (the nodes are not a tree)");
      }
    }
  }
  size_t seen = 0;
  std::vector<std::pair<size_t, int>> stack;
  for (size_t i = 0; i < nodes; ++i) {
    if (parents[i] == 0) stack.push_back({i, 1});
  }
  while (!stack.empty()) {
    const auto [n, depth] = stack.back();
    stack.pop_back();
    ++seen;
    if (depth > kMaxNodeDepth) {
      return Status::LimitExceeded(what + " nests its nodes deeper than " +
                                   std::to_string(kMaxNodeDepth) + " levels");
    }
    for (uint64_t c : f.children[n]) stack.push_back({static_cast<size_t>(c), depth + 1});
  }
  if (seen != nodes) return Bad(what, "has nodes that form a cycle");
  return Status::OK();
}

Status CheckGlb(std::string_view data, const std::string& what) {
  if (data.size() < 20) return Bad(what, "is a GLB too short for its header");
  const uint32_t version = Le32(data.data() + 4), length = Le32(data.data() + 8);
  if (version != 2) return Bad(what, "is GLB version " + std::to_string(version) + "; version 2 is read");
  if (length != data.size()) {
    return Bad(what, "is a GLB that declares " + std::to_string(length) + " bytes but has " +
                         std::to_string(data.size()));
  }
  std::string_view json_chunk;
  uint64_t bin = 0;
  bool has_bin = false;
  for (size_t at = 12; at < data.size();) {
    if (data.size() - at < 8) return Bad(what, "is a GLB whose last chunk has no header");
    const uint64_t len = Le32(data.data() + at);
    const uint32_t type = Le32(data.data() + at + 4);
    if (len > data.size() - at - 8) {
      return Bad(what, "is a GLB with a chunk of " + std::to_string(len) +
                           " bytes, more than the file's " + std::to_string(data.size() - at - 8) +
                           " left");
    }
    if (at == 12) {
      if (type != 0x4E4F534A) return Bad(what, "is a GLB whose first chunk is not JSON");
      json_chunk = data.substr(at + 8, len);
    } else if (type == 0x004E4942 && !has_bin) {
      has_bin = true;
      bin = len;
    }
    at += 8 + len;
  }
  return CheckGltfJson(json_chunk, bin, true, what);
}

// PLY: a header in the grammar of the format, line by line (assimp's header parser loops
// without end on some malformed ones: found by media_import_fuzz); a vertex element with x, y
// and z; each element's count times the fewest bytes one can take within the bytes after it.
Status CheckPly(std::string_view data, const std::string& what) {
  const size_t end = data.find("\nend_header");
  if (end == std::string_view::npos) return Bad(what, "is a PLY without end_header");
  const std::string_view header = data.substr(0, end + 1);
  for (char c : header) {
    if (c != '\n' && c != '\r' && (c < 0x20 || c > 0x7e)) {
      return Bad(what, "has a PLY header with a byte that is not printable text");
    }
  }
  std::istringstream in{std::string(header)};
  std::string line, format, element;
  uint64_t need = 0, count = 0, per = 0;
  bool vx = false, vy = false, vz = false;
  auto close = [&]() {
    need += count * per;
    count = per = 0;
  };
  auto scalar = [](const std::string& t) -> uint64_t {
    if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
    if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
    if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" ||
        t == "float32") return 4;
    if (t == "double" || t == "float64") return 8;
    return 0;
  };
  const auto bad_line = [&](const std::string& l) {
    return Bad(what, "has a PLY header line that is not PLY: '" + l.substr(0, 60) + "'");
  };
  int n = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string key, extra;
    words >> key;
    if (n++ == 0) {
      if (key != "ply") return bad_line(line);
      continue;
    }
    if (key == "comment" || key == "obj_info") continue;
    if (key == "format") {
      std::string version;
      words >> format >> version;
      if ((format != "ascii" && format != "binary_little_endian" &&
           format != "binary_big_endian") || version.empty() || (words >> extra)) {
        return bad_line(line);
      }
    } else if (key == "element") {
      close();
      std::string number;
      words >> element >> number;
      if (element.empty() || number.empty() || number.size() > 10 ||
          number.find_first_not_of("0123456789") != std::string::npos || (words >> extra)) {
        return bad_line(line);
      }
      count = std::stoull(number);
    } else if (key == "property") {
      if (element.empty()) return bad_line(line);
      std::string type, name;
      words >> type;
      const bool list = type == "list";
      std::string item;
      if (list) words >> type >> item;  // the count's type, then the items'
      words >> name;
      if (scalar(type) == 0 || (list && scalar(item) == 0) || name.empty() || (words >> extra)) {
        return bad_line(line);
      }
      if (element == "vertex" && !list) {
        vx |= name == "x";
        vy |= name == "y";
        vz |= name == "z";
      }
      // ASCII: a number and a separator at least; binary: the scalar (or the list's count).
      per += format == "ascii" ? 2 : scalar(type);
    } else {
      return bad_line(line);
    }
  }
  close();
  if (format.empty()) return Bad(what, "is a PLY without a format line");
  if (!(vx && vy && vz)) return Bad(what, "is a PLY whose vertex element lacks x, y or z");
  const uint64_t body = data.size() - end;
  if (need > body) {
    return Bad(what, "declares PLY elements that need at least " + std::to_string(need) +
                         " bytes, more than the " + std::to_string(body) + " it has");
  }
  return Status::OK();
}

// OFF: "OFF" then vertex, face and edge counts; a vertex takes 6 bytes at least, a face 2.
Status CheckOff(std::string_view data, const std::string& what) {
  std::istringstream in(std::string(data.substr(0, std::min<size_t>(data.size(), 4096))));
  std::string word;
  in >> word;
  if (word.find("OFF") == std::string::npos) in.seekg(0);
  uint64_t nv = 0, nf = 0;
  in >> nv >> nf;
  if (!in) return Status::OK();  // assimp says what is wrong with it
  if (nv > (uint64_t{1} << 32) || nf > (uint64_t{1} << 32) || nv * 6 + nf * 2 > data.size()) {
    return Bad(what, "declares " + std::to_string(nv) + " vertices and " + std::to_string(nf) +
                         " faces, more than its " + std::to_string(data.size()) + " bytes hold");
  }
  return Status::OK();
}

}  // namespace

Status CheckMeshFile(std::string_view data, const std::string& format, const std::string& what) {
  const std::string_view sig = data.substr(0, 4);
  if (sig == "glTF" || format == "glb") {
    if (sig != "glTF") return Bad(what, "is not a GLB (no glTF signature)");
    return CheckGlb(data, what);
  }
  if (sig == "ply\n" || sig == "ply\r" || format == "ply") return CheckPly(data, what);
  if (format == "gltf") return CheckGltfJson(data, 0, false, what);
  if (format == "off") return CheckOff(data, what);
  // OBJ and ASCII STL declare no sizes; binary STL's facet count is checked by assimp.
  if (format == "obj" || format == "stl") return Status::OK();
  return Bad(what, "is not in a mesh format read here: OBJ, PLY, STL, OFF, glTF or GLB (give "
                   "the file's extension as its format)");
}

}  // namespace hvdb::media
