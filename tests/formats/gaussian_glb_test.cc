// GLB with KHR_gaussian_splatting (formats/gaussian_glb.cc): round trips, the stored bytes
// checked against the extension's conventions by parsing the GLB here, the covariance of a
// Gaussian built in glTF's frame, quantised and interleaved files, and malformed files.
// Deterministic: the clouds come from fixed seeds.
//
// Round-trip bounds: positions and SH exact (negations); rotation the normalised quaternion (the
// writer normalises, as the extension asks) within float rounding; log scale within
// 2e-6 * max(1, |s|) (float exp then log); opacity within the float error of logit(sigmoid(x)),
// about 1.2e-7 / (p (1 - p)), and its sigmoid within 1e-6 however far it saturates.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "formats/gaussian_transform.h"
#include "formats/gaussians.h"
#include "tests/formats/random_cloud.h"

namespace hvdb::formats {
namespace {

static_assert(std::endian::native == std::endian::little, "the tests build GLBs by memcpy");

using json = nlohmann::json;
namespace fs = std::filesystem;
using test_clouds::RandomCloud;
using test_clouds::Rng;

constexpr const char* kExt = "KHR_gaussian_splatting";
std::string Attr(const std::string& s) { return std::string(kExt) + ":" + s; }
std::string ShAttr(int l, int n) {
  return Attr("SH_DEGREE_" + std::to_string(l) + "_COEF_" + std::to_string(n));
}


std::string Bytes(const void* p, size_t n) { return std::string(static_cast<const char*>(p), n); }
template <typename T>
std::string Bytes(const std::vector<T>& v) {
  return Bytes(v.data(), v.size() * sizeof(T));
}

// A GLB from JSON text and a BIN chunk (none when `bin` is empty and `with_bin` false).
std::string PackText(std::string text, const std::string& bin, bool with_bin = true) {
  while (text.size() % 4 != 0) text += ' ';
  std::string padded = bin;
  while (padded.size() % 4 != 0) padded += '\0';
  auto u32 = [](uint32_t v) { return Bytes(&v, 4); };
  const size_t total = 12 + 8 + text.size() + (with_bin ? 8 + padded.size() : 0);
  std::string out = u32(0x46546C67) + u32(2) + u32(static_cast<uint32_t>(total));
  out += u32(static_cast<uint32_t>(text.size())) + u32(0x4E4F534A) + text;
  if (with_bin) out += u32(static_cast<uint32_t>(padded.size())) + u32(0x004E4942) + padded;
  return out;
}
std::string Pack(const json& gltf, const std::string& bin) { return PackText(gltf.dump(), bin); }

// A GLB taken apart: its JSON and BIN chunk, every header field checked on the way.
struct Glb {
  json gltf;
  nlohmann::ordered_json ordered;  // the same, in the file's key order
  std::string bin;
};

Glb Unpack(const std::string& bytes) {
  Glb g;
  auto u32 = [&](size_t at) {
    uint32_t v;
    std::memcpy(&v, bytes.data() + at, 4);
    return v;
  };
  EXPECT_GE(bytes.size(), 28u);
  EXPECT_EQ(u32(0), 0x46546C67u);
  EXPECT_EQ(u32(4), 2u);
  EXPECT_EQ(u32(8), bytes.size());
  const uint32_t jlen = u32(12);
  EXPECT_EQ(u32(16), 0x4E4F534Au);
  EXPECT_EQ(jlen % 4, 0u);
  const std::string text = bytes.substr(20, jlen);
  g.gltf = json::parse(text);
  g.ordered = nlohmann::ordered_json::parse(text);
  const uint32_t blen = u32(20 + jlen);
  EXPECT_EQ(u32(24 + jlen), 0x004E4942u);
  EXPECT_EQ(blen % 4, 0u);
  EXPECT_EQ(28 + jlen + blen, bytes.size());
  g.bin = bytes.substr(28 + jlen, blen);
  return g;
}

// The byte offset in the BIN chunk of element i of a primitive attribute (tightly packed).
size_t ElementAt(const Glb& g, const std::string& attr, size_t i, size_t elem_bytes) {
  const json& a =
      g.gltf["accessors"][g.gltf["meshes"][0]["primitives"][0]["attributes"][attr].get<size_t>()];
  const json& v = g.gltf["bufferViews"][a["bufferView"].get<size_t>()];
  return v.value("byteOffset", size_t{0}) + a.value("byteOffset", size_t{0}) + i * elem_bytes;
}

float FloatAt(const Glb& g, const std::string& attr, size_t i, int comps, int k) {
  float v;
  std::memcpy(&v, g.bin.data() + ElementAt(g, attr, i, 4 * comps) + 4 * k, 4);
  return v;
}

// Splats in glTF's own conventions: x left, y up, z forward; quaternion x y z w; linear scale
// and opacity; per SH coefficient (degree 1 up, order -l..l) r g b of each splat.
struct GltfSplats {
  std::vector<float> position, rotation, scale, opacity, dc;
  std::vector<std::vector<float>> rest;
};

GltfSplats RandomGltf(uint64_t seed, int degree, size_t n) {
  Rng rng(seed);
  GltfSplats s;
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) s.position.push_back(rng.Uniform(-20, 20));
    double q[4], norm = 0;
    for (double& v : q) v = rng.Uniform(-1, 1), norm += v * v;
    for (double v : q) s.rotation.push_back(static_cast<float>(v / std::sqrt(norm)));
    for (int k = 0; k < 3; ++k) s.scale.push_back(rng.Uniform(0.01f, 2));
    s.opacity.push_back(rng.Uniform(0.05f, 0.95f));
    for (int k = 0; k < 3; ++k) s.dc.push_back(rng.Uniform(-1, 1));
  }
  s.rest.resize(ShRestPerChannel(degree));
  for (auto& coef : s.rest) {
    for (size_t i = 0; i < 3 * n; ++i) coef.push_back(rng.Uniform(-0.5f, 0.5f));
  }
  return s;
}

// Builds a glTF document and its BIN chunk by hand.
class Builder {
 public:
  Builder() {
    gltf = {{"asset", {{"version", "2.0"}}}, {"extensionsUsed", json::array({kExt})}};
    gltf["bufferViews"] = json::array();
    gltf["accessors"] = json::array();
    gltf["meshes"] = json::array();
  }
  // A bufferView of `bytes` (appended 4-aligned); stride 0 for none.
  size_t View(const std::string& bytes, size_t stride = 0) {
    while (bin.size() % 4 != 0) bin += '\0';
    json v = {{"buffer", 0}, {"byteOffset", bin.size()}, {"byteLength", bytes.size()}};
    if (stride != 0) v["byteStride"] = stride;
    bin += bytes;
    gltf["bufferViews"].push_back(v);
    return gltf["bufferViews"].size() - 1;
  }
  size_t Accessor(size_t view, int component_type, const char* type, size_t count,
                  size_t offset = 0, bool normalized = false) {
    json a = {
        {"bufferView", view}, {"componentType", component_type}, {"type", type}, {"count", count}};
    if (offset != 0) a["byteOffset"] = offset;
    if (normalized) a["normalized"] = true;
    gltf["accessors"].push_back(a);
    return gltf["accessors"].size() - 1;
  }
  size_t Floats(const std::vector<float>& v, const char* type, size_t comps) {
    return Accessor(View(Bytes(v)), 5126, type, v.size() / comps);
  }
  // A splat primitive of float accessors.
  json Primitive(const GltfSplats& s) {
    json attrs = {{"POSITION", Floats(s.position, "VEC3", 3)},
                  {Attr("ROTATION"), Floats(s.rotation, "VEC4", 4)},
                  {Attr("SCALE"), Floats(s.scale, "VEC3", 3)},
                  {Attr("OPACITY"), Floats(s.opacity, "SCALAR", 1)},
                  {Attr("SH_DEGREE_0_COEF_0"), Floats(s.dc, "VEC3", 3)}};
    for (size_t k = 0; k < s.rest.size(); ++k) {
      const int l = k < 3 ? 1 : k < 8 ? 2 : 3;
      attrs[ShAttr(l, static_cast<int>(k) + 1 - l * l)] = Floats(s.rest[k], "VEC3", 3);
    }
    return PrimitiveWith(attrs);
  }
  static json PrimitiveWith(const json& attrs) {
    json p = {{"attributes", attrs}, {"mode", 0}};
    p["extensions"][kExt] = {{"kernel", "ellipse"}, {"colorSpace", "srgb_rec709_display"}};
    return p;
  }
  void Mesh(const std::vector<json>& primitives) {
    gltf["meshes"].push_back({{"primitives", primitives}});
  }
  std::string Finish() {
    gltf["buffers"] = json::array({{{"byteLength", bin.size()}}});
    gltf["nodes"] = json::array();
    for (size_t m = 0; m < gltf["meshes"].size(); ++m) gltf["nodes"].push_back({{"mesh", m}});
    return Pack(gltf, bin);
  }
  json gltf;
  std::string bin;
};

// ---------------------------------------------------------------------------------------------

TEST(GaussianGlb, RoundTripForEveryDegree) {
  for (int degree = 0; degree <= 3; ++degree) {
    SCOPED_TRACE(degree);
    GaussianCloud c = RandomCloud(200 + degree, degree, 301);
    c.opacity[0] = 20, c.opacity[1] = -20, c.opacity[2] = 15;  // saturated logits
    std::fill_n(c.rotation.begin() + 4 * 3, 4, 0.0f);          // a zero quaternion
    c.position[3 * 4] = 0;                                     // -0 in the file
    auto bytes = WriteGlb(c, "rt.glb");
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    auto back = ReadGlb(*bytes, "rt.glb");
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ASSERT_EQ(back->size(), c.size());
    EXPECT_EQ(back->sh_degree, degree);
    EXPECT_FALSE(back->antialiased);
    EXPECT_TRUE(back->ignored.empty());
    EXPECT_EQ(std::memcmp(back->position.data(), c.position.data(), 4 * c.position.size()), 0);
    EXPECT_EQ(back->sh_dc, c.sh_dc);
    EXPECT_EQ(back->sh_rest, c.sh_rest);
    EXPECT_EQ(std::bit_cast<uint32_t>(back->position[3 * 4]), 0u);  // +0 again, not -0
    for (size_t i = 0; i < c.size(); ++i) {
      double q[4], norm = 0;
      for (int k = 0; k < 4; ++k) q[k] = c.rotation[4 * i + k], norm += q[k] * q[k];
      norm = std::sqrt(norm);
      if (norm == 0) q[0] = 1, norm = 1;
      for (int k = 0; k < 4; ++k) {
        EXPECT_FLOAT_EQ(back->rotation[4 * i + k], static_cast<float>(q[k] / norm)) << i;
      }
      for (int k = 0; k < 3; ++k) {
        const float s = c.scale[3 * i + k];
        EXPECT_NEAR(back->scale[3 * i + k], s, 2e-6 * std::max(1.0f, std::abs(s))) << i;
      }
      const float o = c.opacity[i];
      const double p = 1 / (1 + std::exp(-static_cast<double>(o)));
      EXPECT_NEAR(Sigmoid(back->opacity[i]), p, 1e-6) << i;
      if (std::abs(o) <= 15) {
        EXPECT_NEAR(back->opacity[i], o, 1.2e-7 / (p * (1 - p)) + 1e-6 * std::abs(o)) << i;
      }
    }
    auto again = WriteGlb(*back, "rt.glb");  // normalised already: the same file
    ASSERT_TRUE(again.ok());
    EXPECT_EQ(Unpack(*again).gltf, Unpack(*bytes).gltf);
  }
}

// One splat's stored values, read from the file here, against the extension's conventions.
TEST(GaussianGlb, BytesFollowTheExtensionsConventions) {
  const GaussianCloud c = RandomCloud(7, 3, 5);
  auto bytes = WriteGlb(c, "conv.glb");
  ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
  const Glb g = Unpack(*bytes);
  const json& j = g.gltf;
  EXPECT_EQ(j["asset"]["version"], "2.0");
  EXPECT_EQ(j["asset"]["generator"], "hvdb");
  EXPECT_EQ(j["extensionsUsed"], json::array({kExt}));
  EXPECT_FALSE(j.contains("extensionsRequired"));
  EXPECT_EQ(j["scene"], 0);
  EXPECT_EQ(j["scenes"], json::parse(R"([{"nodes":[0]}])"));
  EXPECT_EQ(j["nodes"], json::parse(R"([{"mesh":0}])"));
  EXPECT_EQ(j["buffers"][0]["byteLength"], g.bin.size());
  ASSERT_EQ(j["meshes"].size(), 1u);
  ASSERT_EQ(j["meshes"][0]["primitives"].size(), 1u);
  const json& prim = j["meshes"][0]["primitives"][0];
  EXPECT_EQ(prim["mode"], 0);
  EXPECT_EQ(prim["extensions"][kExt],
            json::parse(R"({"kernel":"ellipse","colorSpace":"srgb_rec709_display",
                            "sortingMethod":"cameraDistance","projection":"perspective"})"));
  // Attributes in splat-transform's order, accessor i in bufferView i, 4-aligned, in order.
  std::vector<std::string> want = {"POSITION",    "COLOR_0",       Attr("ROTATION"),
                                   Attr("SCALE"), Attr("OPACITY"), Attr("SH_DEGREE_0_COEF_0")};
  for (int l = 1; l <= 3; ++l) {
    for (int n = 0; n <= 2 * l; ++n) want.push_back(ShAttr(l, n));
  }
  std::vector<std::string> got;
  for (const auto& [key, value] : g.ordered["meshes"][0]["primitives"][0]["attributes"].items()) {
    got.push_back(key);
    EXPECT_EQ(value, got.size() - 1);
  }
  EXPECT_EQ(got, want);
  size_t end = 0;
  for (size_t i = 0; i < want.size(); ++i) {
    const json& a = j["accessors"][i];
    const json& v = j["bufferViews"][i];
    EXPECT_EQ(a["bufferView"], i);
    EXPECT_EQ(a["count"], c.size());
    EXPECT_EQ(a["componentType"], i == 1 ? 5121 : 5126);
    EXPECT_EQ(a.value("normalized", false), i == 1);
    EXPECT_EQ(a["type"], i == 1 || i == 2 ? "VEC4" : i == 4 ? "SCALAR" : "VEC3");
    EXPECT_EQ(v["target"], 34962);
    EXPECT_EQ(v["byteOffset"].get<size_t>() % 4, 0u);
    EXPECT_EQ(v["byteOffset"], end);
    end += v["byteLength"].get<size_t>();
  }
  EXPECT_EQ(end, g.bin.size());

  // POSITION's min and max, in glTF's frame.
  for (int k = 0; k < 3; ++k) {
    float lo = std::numeric_limits<float>::max(), hi = -lo;
    for (size_t i = 0; i < c.size(); ++i) {
      const float v = k < 2 ? -c.position[3 * i + k] : c.position[3 * i + k];
      lo = std::min(lo, v), hi = std::max(hi, v);
    }
    EXPECT_EQ(j["accessors"][0]["min"][k].get<double>(), lo);
    EXPECT_EQ(j["accessors"][0]["max"][k].get<double>(), hi);
  }

  const size_t i = 3;
  const float x = c.position[3 * i], y = c.position[3 * i + 1], z = c.position[3 * i + 2];
  EXPECT_EQ(FloatAt(g, "POSITION", i, 3, 0), -x);
  EXPECT_EQ(FloatAt(g, "POSITION", i, 3, 1), -y);
  EXPECT_EQ(FloatAt(g, "POSITION", i, 3, 2), z);
  // Rotation: q_z * q, stored x y z w = (-qy, qx, qw, -qz), normalised.
  const double w = c.rotation[4 * i], qx = c.rotation[4 * i + 1], qy = c.rotation[4 * i + 2],
               qz = c.rotation[4 * i + 3];
  const double norm = std::sqrt(w * w + qx * qx + qy * qy + qz * qz);
  const double want_rot[4] = {-qy / norm, qx / norm, w / norm, -qz / norm};
  for (int k = 0; k < 4; ++k) {
    EXPECT_FLOAT_EQ(FloatAt(g, Attr("ROTATION"), i, 4, k), static_cast<float>(want_rot[k]));
  }
  for (int k = 0; k < 3; ++k) {  // linear scale
    EXPECT_FLOAT_EQ(FloatAt(g, Attr("SCALE"), i, 3, k), std::exp(c.scale[3 * i + k]));
  }
  EXPECT_FLOAT_EQ(FloatAt(g, Attr("OPACITY"), i, 1, 0),
                  static_cast<float>(1 / (1 + std::exp(-static_cast<double>(c.opacity[i])))));
  for (int ch = 0; ch < 3; ++ch) {
    EXPECT_EQ(FloatAt(g, Attr("SH_DEGREE_0_COEF_0"), i, 3, ch), c.sh_dc[3 * i + ch]);
  }
  // SH: channel-major in the cloud (15 a channel), RGB per coefficient in the file; order m
  // odd flips sign. Degree 1 (m = -1, 0, 1): y z x -> - + -, as splat-transform writes.
  const float* rest = c.sh_rest.data() + i * 45;
  for (int ch = 0; ch < 3; ++ch) {
    EXPECT_EQ(FloatAt(g, ShAttr(1, 0), i, 3, ch), -rest[15 * ch + 0]);
    EXPECT_EQ(FloatAt(g, ShAttr(1, 1), i, 3, ch), rest[15 * ch + 1]);
    EXPECT_EQ(FloatAt(g, ShAttr(1, 2), i, 3, ch), -rest[15 * ch + 2]);
    EXPECT_EQ(FloatAt(g, ShAttr(2, 0), i, 3, ch), rest[15 * ch + 3]);    // xy
    EXPECT_EQ(FloatAt(g, ShAttr(2, 1), i, 3, ch), -rest[15 * ch + 4]);   // yz
    EXPECT_EQ(FloatAt(g, ShAttr(3, 1), i, 3, ch), rest[15 * ch + 9]);    // xyz
    EXPECT_EQ(FloatAt(g, ShAttr(3, 6), i, 3, ch), -rest[15 * ch + 14]);  // x(x^2 - 3y^2)
  }
  // COLOR_0: the fallback, 0.5 + C0 f_dc and the opacity in normalised bytes.
  const auto* color =
      reinterpret_cast<const unsigned char*>(g.bin.data() + ElementAt(g, "COLOR_0", i, 4));
  for (int ch = 0; ch < 3; ++ch) {
    const double v = std::round((0.5 + kShC0 * c.sh_dc[3 * i + ch]) * 255);
    EXPECT_EQ(color[ch], std::clamp(v, 0.0, 255.0)) << ch;
  }
  EXPECT_EQ(color[3], std::round(static_cast<double>(Sigmoid(c.opacity[i])) * 255));
}

// The covariance of a Gaussian given in glTF's frame, worked out here from the extension's
// formulas, turned to the cloud's frame by C = diag(-1, -1, 1): Sigma_RDF = C Sigma_LUF C^T.
TEST(GaussianGlb, CovarianceOfAHandBuiltGaussianIsTurnedToTheCloudsFrame) {
  const GltfSplats s = RandomGltf(31, 1, 50);
  Builder b;
  b.Mesh({b.Primitive(s)});
  auto c = ReadGlb(b.Finish(), "cov.glb");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->size(), 50u);
  ASSERT_EQ(c->sh_degree, 1);
  for (size_t i = 0; i < 50; ++i) {
    const double x = s.rotation[4 * i], y = s.rotation[4 * i + 1], z = s.rotation[4 * i + 2],
                 w = s.rotation[4 * i + 3];
    const double r[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                            {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                            {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
    double sigma[3][3] = {};
    for (int a = 0; a < 3; ++a) {
      for (int bb = 0; bb < 3; ++bb) {
        for (int k = 0; k < 3; ++k) {
          const double sk = s.scale[3 * i + k];
          sigma[a][bb] += r[a][k] * r[bb][k] * sk * sk;
        }
      }
    }
    const double flip[3] = {-1, -1, 1};
    const int idx[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
    const std::array<float, 6> got = c->Covariance(i);
    for (int e = 0; e < 6; ++e) {
      const int a = idx[e][0], bb = idx[e][1];
      EXPECT_NEAR(got[e], flip[a] * flip[bb] * sigma[a][bb], 2e-6 * 4) << i << " " << e;
    }
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(c->position[3 * i + k], flip[k] * s.position[3 * i + k]);
      EXPECT_FLOAT_EQ(std::exp(c->scale[3 * i + k]), s.scale[3 * i + k]);
      EXPECT_EQ(c->sh_dc[3 * i + k], s.dc[3 * i + k]);
      for (int n = 0; n < 3; ++n) {  // y z x: odd in (x, y) for n = 0 and 2
        EXPECT_EQ(c->sh_rest[i * 9 + 3 * k + n], (n == 1 ? 1 : -1) * s.rest[n][3 * i + k]);
      }
    }
    EXPECT_NEAR(Sigmoid(c->opacity[i]), s.opacity[i], 1e-6);
  }
}

// Quantised component types, an interleaved bufferView and two primitives, concatenated.
TEST(GaussianGlb, ReadsQuantisedInterleavedAndSeveralPrimitives) {
  Builder b;
  // Primitive 1: 3 splats. POSITION and SH_DEGREE_0_COEF_0 interleaved, 24 bytes a splat.
  std::vector<float> inter = {1,    2,    3,    0.1f, 0.2f, 0.3f, -4,    5,     -6,
                              0.4f, 0.5f, 0.6f, 7,    8,    9,    -0.1f, -0.2f, -0.3f};
  const size_t iv = b.View(Bytes(inter), 24);
  const size_t pos = b.Accessor(iv, 5126, "VEC3", 3);
  const size_t dc = b.Accessor(iv, 5126, "VEC3", 3, 12);
  // ROTATION as normalised signed shorts (x y z w); -32768 is -1 as well as -32767.
  const std::vector<int16_t> rot = {0, 0, 0, 32767, -32768, 0, 0, 0, 16384, -16384, 0, 32767};
  const size_t rv = b.Accessor(b.View(Bytes(rot)), 5122, "VEC4", 3, 0, true);
  // SCALE as plain signed bytes, in 4-byte strides (glTF aligns vertex attributes to 4).
  const std::vector<int8_t> scale = {1, 2, 3, 99, 4, 0, 1, 99, 1, 1, 1, 99};
  const size_t sv = b.Accessor(b.View(Bytes(scale), 4), 5120, "VEC3", 3);
  // OPACITY as normalised unsigned bytes.
  const std::vector<uint8_t> opacity = {0, 128, 255};
  const size_t ov = b.Accessor(b.View(Bytes(opacity)), 5121, "SCALAR", 3, 0, true);
  json first = Builder::PrimitiveWith({{"POSITION", pos},
                                       {Attr("ROTATION"), rv},
                                       {Attr("SCALE"), sv},
                                       {Attr("OPACITY"), ov},
                                       {Attr("SH_DEGREE_0_COEF_0"), dc},
                                       {"NORMAL", pos}});
  // Primitive 2: 2 splats of floats, in a second mesh; and a triangle mesh between, passed over.
  const GltfSplats s = RandomGltf(5, 0, 2);
  b.Mesh({first});
  b.Mesh({json{{"attributes", {{"POSITION", pos}}}, {"mode", 4}}});
  b.Mesh({b.Primitive(s)});
  auto c = ReadGlb(b.Finish(), "quant.glb");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  ASSERT_EQ(c->size(), 5u);
  EXPECT_EQ(c->sh_degree, 0);
  EXPECT_EQ(c->ignored, std::vector<std::string>{"NORMAL"});
  const std::vector<float> want_pos = {-1, -2, 3, 4, -5, -6, -7, -8, 9};
  EXPECT_EQ(std::vector<float>(c->position.begin(), c->position.begin() + 9), want_pos);
  const std::vector<float> want_dc = {0.1f, 0.2f, 0.3f, 0.4f, 0.5f, 0.6f, -0.1f, -0.2f, -0.3f};
  EXPECT_EQ(std::vector<float>(c->sh_dc.begin(), c->sh_dc.begin() + 9), want_dc);
  // (w, x, y, z) = (z', y', -x', -w').
  const float h = 16384 / 32767.0f;
  const std::vector<float> want_rot = {0, 0, 0, -1, 0, 0, 1, 0, 0, -h, -h, -1};
  EXPECT_EQ(std::vector<float>(c->rotation.begin(), c->rotation.begin() + 12), want_rot);
  const float log0 = std::log(std::numeric_limits<float>::min());  // a flat splat
  const std::vector<float> want_scale = {
      0, std::log(2.0f), std::log(3.0f), std::log(4.0f), log0, 0, 0, 0, 0};
  EXPECT_EQ(std::vector<float>(c->scale.begin(), c->scale.begin() + 9), want_scale);
  EXPECT_EQ(c->opacity[0], Logit(0));
  EXPECT_EQ(c->opacity[1], Logit(128 / 255.0f));
  EXPECT_EQ(c->opacity[2], Logit(1));
  EXPECT_TRUE(std::isfinite(c->opacity[0]) && std::isfinite(c->opacity[2]));
  for (size_t i = 0; i < 2; ++i) {  // the float primitive follows
    EXPECT_EQ(c->position[3 * (3 + i)], -s.position[3 * i]);
    EXPECT_EQ(c->position[3 * (3 + i) + 2], s.position[3 * i + 2]);
    EXPECT_EQ(c->rotation[4 * (3 + i)], s.rotation[4 * i + 2]);
    EXPECT_NEAR(Sigmoid(c->opacity[3 + i]), s.opacity[i], 1e-6);
  }
}

// The ratified table's other types: SCALE normalised unsigned byte, OPACITY normalised
// unsigned short, ROTATION normalised signed byte; and types it does not allow.
TEST(GaussianGlb, ReadsTheRatifiedTypesAndRefusesOthers) {
  auto build = [](int rot_type, bool rot_norm) {
    Builder b;
    const size_t pos = b.Floats({1, 2, 3}, "VEC3", 3);
    const size_t dc = b.Floats({0, 0, 0}, "VEC3", 3);
    const std::vector<int8_t> rot = {0, 127, -128, 0};
    const size_t rv = b.Accessor(b.View(Bytes(rot)), rot_type, "VEC4", 1, 0, rot_norm);
    const std::vector<uint8_t> scale = {255, 51, 0, 0};
    const size_t sv = b.Accessor(b.View(Bytes(scale)), 5121, "VEC3", 1, 0, true);
    const std::vector<uint16_t> opacity = {65535, 0};
    const size_t ov = b.Accessor(b.View(Bytes(opacity)), 5123, "SCALAR", 1, 0, true);
    b.Mesh({Builder::PrimitiveWith({{"POSITION", pos},
                                    {Attr("ROTATION"), rv},
                                    {Attr("SCALE"), sv},
                                    {Attr("OPACITY"), ov},
                                    {Attr("SH_DEGREE_0_COEF_0"), dc}})});
    return b.Finish();
  };
  auto c = ReadGlb(build(5120, true), "types.glb");
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->rotation, (std::vector<float>{-1, 1, 0, 0}));  // x' y' z' w' = 0 1 -1 0
  EXPECT_EQ(c->scale[0], 0);
  EXPECT_FLOAT_EQ(c->scale[1], std::log(0.2f));
  EXPECT_EQ(c->opacity[0], Logit(1));
  auto bad = ReadGlb(build(5120, false), "types.glb");  // a rotation must be normalized
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kUnsupported);
  EXPECT_NE(bad.status().message().find("types.glb: mesh 0 primitive 0: " + Attr("ROTATION") +
                                        " (accessor 2): component type signed byte"),
            std::string::npos)
      << bad.status().message();
  bad = ReadGlb(build(5121, true), "types.glb");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("normalized unsigned byte; allowed: float, or "
                                        "normalized signed byte or short"),
            std::string::npos)
      << bad.status().message();
}

// The node tree places the splats: a node's translation, rotation and uniform scale, and its
// parents', move them as TransformCloud moves a cloud, in glTF's axes (x left, y up).
TEST(GaussianGlb, NodeTransformsPlaceTheSplats) {
  const GaussianCloud c = RandomCloud(40, 3, 5);
  const std::string good = *WriteGlb(c, "x");
  const GaussianCloud plain = *ReadGlb(good, "plain.glb");
  auto edit = [&](auto change) {
    Glb g = Unpack(good);
    change(g.gltf);
    return Pack(g.gltf, g.bin);
  };
  // A translation of (1, 2, 3) in glTF's axes is (-1, -2, 3) in the cloud's; nothing else moves.
  auto moved = ReadGlb(edit([](json& j) { j["nodes"][0]["translation"] = {1, 2, 3}; }), "t.glb");
  ASSERT_TRUE(moved.ok()) << moved.status().ToString();
  for (size_t i = 0; i < plain.size(); ++i) {
    EXPECT_FLOAT_EQ(moved->position[3 * i], plain.position[3 * i] - 1);
    EXPECT_FLOAT_EQ(moved->position[3 * i + 1], plain.position[3 * i + 1] - 2);
    EXPECT_FLOAT_EQ(moved->position[3 * i + 2], plain.position[3 * i + 2] + 3);
  }
  EXPECT_EQ(moved->rotation, plain.rotation);
  EXPECT_EQ(moved->scale, plain.scale);
  EXPECT_EQ(moved->sh_rest, plain.sh_rest);
  // A parent's scale of 2 and 90 degrees about glTF's y (up) over a child's translation:
  // world = T_parent R_parent S_parent T_child.
  const double h = std::sqrt(0.5);
  auto nested = ReadGlb(edit([&](json& j) {
                          j["nodes"][0]["translation"] = {0.5, 0, 0};
                          j["nodes"].push_back({{"children", {0}},
                                                {"translation", {0, 1, 0}},
                                                {"rotation", {0, h, 0, h}},
                                                {"scale", {2, 2, 2}}});
                        }),
                        "n.glb");
  ASSERT_TRUE(nested.ok()) << nested.status().ToString();
  // In glTF's axes: p -> 2 R p + (0, 1, -1), R about y by 90 degrees (x -> -z, z -> x). In the
  // cloud's, C M C with C = diag(-1, -1, 1): the turn is about -y (x -> z, z -> -x), the
  // translation C (0, 1, -1) = (0, -1, -1).
  Similarity m;
  m.rotation = {0, 0, -1, 0, 1, 0, 1, 0, 0};
  m.scale = 2;
  m.translation = {0, -1, -1};
  GaussianCloud want = plain;
  ASSERT_TRUE(TransformCloud(&want, m, "want").ok());
  for (size_t i = 0; i < want.position.size(); ++i) {
    EXPECT_NEAR(nested->position[i], want.position[i], 1e-5) << i;
  }
  for (size_t i = 0; i < want.scale.size(); ++i) EXPECT_NEAR(nested->scale[i], want.scale[i], 1e-5);
  for (size_t i = 0; i < want.size(); ++i) {  // the same rotation, up to the quaternion's sign
    double dot = 0;
    for (int k = 0; k < 4; ++k) dot += nested->rotation[4 * i + k] * want.rotation[4 * i + k];
    EXPECT_NEAR(std::abs(dot), 1.0, 1e-5) << i;
  }
  for (size_t i = 0; i < want.sh_rest.size(); ++i) {
    EXPECT_NEAR(nested->sh_rest[i], want.sh_rest[i], 1e-5) << i;
  }
  EXPECT_EQ(nested->opacity, plain.opacity);
  EXPECT_EQ(nested->sh_dc, plain.sh_dc);
  // A column-major matrix is the same placement as its T R S.
  auto by_matrix = ReadGlb(edit([](json& j) {
                             j["nodes"][0]["matrix"] = {0, 0, -2, 0, 0, 2, 0, 0,
                                                        2, 0, 0, 0, 1, 1, 0, 1};
                           }),
                           "m.glb");
  auto by_trs = ReadGlb(edit([&](json& j) {
                          j["nodes"][0]["translation"] = {1, 1, 0};
                          j["nodes"][0]["rotation"] = {0, h, 0, h};
                          j["nodes"][0]["scale"] = {2, 2, 2};
                        }),
                        "trs.glb");
  ASSERT_TRUE(by_matrix.ok()) << by_matrix.status().ToString();
  ASSERT_TRUE(by_trs.ok()) << by_trs.status().ToString();
  for (size_t i = 0; i < by_trs->position.size(); ++i) {
    EXPECT_NEAR(by_matrix->position[i], by_trs->position[i], 1e-5) << i;
  }
}

// Each malformed file: not ok, the message names the file and says what is wrong.
TEST(GaussianGlb, MalformedFilesAreClearErrors) {
  const GaussianCloud c = RandomCloud(40, 2, 4);
  const std::string good = *WriteGlb(c, "x");
  ASSERT_TRUE(ReadGlb(good, "bad.glb").ok());
  auto expect_error = [](const std::string& bytes, const std::string& fragment, StatusCode code) {
    auto r = ReadGlb(bytes, "bad.glb");
    ASSERT_FALSE(r.ok()) << fragment;
    EXPECT_TRUE(r.status().message().starts_with("bad.glb: ")) << r.status().message();
    EXPECT_NE(r.status().message().find(fragment), std::string::npos) << r.status().message();
    EXPECT_EQ(r.status().code(), code) << r.status().ToString();
  };
  // Edits the JSON (and BIN) of the good file.
  auto edit = [&](auto change) {
    Glb g = Unpack(good);
    change(g.gltf, g.bin);
    return Pack(g.gltf, g.bin);
  };
  auto attr_accessor = [](json& j, const std::string& attr) -> json& {
    return j["accessors"][j["meshes"][0]["primitives"][0]["attributes"][attr].get<size_t>()];
  };
  auto set_float = [&](const std::string& attr, size_t i, int comps, int k, float v) {
    return edit([&](json& j, std::string& bin) {
      Glb g{j, {}, bin};
      std::memcpy(bin.data() + ElementAt(g, attr, i, 4 * comps) + 4 * k, &v, 4);
    });
  };
  const auto kCorrupt = StatusCode::kCorruption, kInvalid = StatusCode::kInvalidArgument,
             kUnsupported = StatusCode::kUnsupported;

  expect_error(good.substr(0, 8), "truncated: 8 bytes", kCorrupt);
  expect_error(good.substr(0, good.size() - 16), "truncated: the GLB header declares", kCorrupt);
  std::string short_bin = good.substr(0, good.size() - 16);  // the header made to agree
  const uint32_t len = static_cast<uint32_t>(short_bin.size());
  std::memcpy(short_bin.data() + 8, &len, 4);
  expect_error(short_bin, "truncated: the BIN chunk at byte", kCorrupt);
  expect_error(good + "abcd", "4 bytes follow", kCorrupt);
  expect_error("glTX" + good.substr(4), "not a GLB", kInvalid);
  std::string v1 = good;
  v1[4] = 1;
  expect_error(v1, "GLB version 1", kUnsupported);
  expect_error(PackText(R"({"asset": {"version": "2.0"},)", ""), "does not parse", kCorrupt);
  expect_error(PackText("[1, 2]", ""), "not an object", kInvalid);
  // A million-deep nesting: an error, not a stack overflow (messages never dump() a structure).
  const std::string deep = std::string(1000000, '[') + std::string(1000000, ']');
  expect_error(PackText(R"({"extensionsRequired": [)" + deep + "]}", ""),
               "requires the glTF extension an array", kUnsupported);
  expect_error(
      edit([](json& j, std::string&) { j["meshes"][0]["primitives"][0].erase("extensions"); }),
      "a glTF file without KHR_gaussian_splatting primitives", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["attributes"].erase(Attr("OPACITY"));
               }),
               "mesh 0 primitive 0: no " + Attr("OPACITY") + " attribute", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["attributes"].erase(ShAttr(2, 3));
               }),
               "SH degree 2 is partial: " + ShAttr(2, 3) + " is missing", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["attributes"][ShAttr(4, 0)] = 0;
               }),
               ShAttr(4, 0) + ": SH degree above 3", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["attributes"][Attr("SH_DEGREE_1_COEF_3")] = 0;
               }),
               "unknown attribute " + Attr("SH_DEGREE_1_COEF_3"), kInvalid);
  expect_error(
      edit([&](json& j, std::string&) { attr_accessor(j, Attr("SCALE"))["byteOffset"] = 8; }),
      "(stride 12) from byte 8 pass the end of bufferView 3", kCorrupt);
  expect_error(edit([](json& j, std::string&) { j["bufferViews"][2]["byteOffset"] = 1u << 30; }),
               "bufferView 2: byteOffset 1073741824 and byteLength 64 pass the end of buffer 0",
               kCorrupt);
  expect_error(
      edit([](json& j, std::string& bin) { j["buffers"][0]["byteLength"] = bin.size() + 4; }),
      "buffer 0 declares", kCorrupt);
  expect_error(edit([&](json& j, std::string&) {
                 attr_accessor(j, "POSITION")["count"] = uint64_t{1} << 31;
               }),
               "2147483648 elements of 12 bytes", kCorrupt);
  expect_error(
      edit([&](json& j, std::string&) { attr_accessor(j, "POSITION")["count"] = ~uint64_t{0}; }),
      "18446744073709551615 elements", kCorrupt);
  expect_error(edit([&](json& j, std::string&) { attr_accessor(j, Attr("SCALE"))["count"] = 3; }),
               Attr("SCALE") + " has 3 elements, POSITION 4", kInvalid);
  expect_error(set_float(Attr("OPACITY"), 1, 1, 0, std::numeric_limits<float>::quiet_NaN()),
               "splat 1: " + Attr("OPACITY") + " nan is outside 0 to 1", kInvalid);
  expect_error(set_float(Attr("OPACITY"), 2, 1, 0, 1.5f),
               "splat 2: " + Attr("OPACITY") + " 1.5 is outside 0 to 1", kInvalid);
  expect_error(set_float(Attr("SCALE"), 3, 3, 1, -1.0f),
               "splat 3: " + Attr("SCALE") + " -1 (a linear scale", kInvalid);
  expect_error(set_float(Attr("SCALE"), 0, 3, 0, std::numeric_limits<float>::infinity()),
               "splat 0: " + Attr("SCALE") + " inf", kInvalid);
  expect_error(set_float("POSITION", 2, 3, 1, std::numeric_limits<float>::quiet_NaN()),
               "splat 2: y is nan", kInvalid);
  // Node transforms a Gaussian cannot follow, or that are not one place for the splats.
  expect_error(edit([](json& j, std::string&) { j["nodes"][0]["scale"] = {1, 2, 1}; }),
               "node 0 (over the splats of mesh 0): a non-uniform scale or shear", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["nodes"].push_back({{"children", {0}}, {"scale", {-1, 1, 1}}});
               }),
               "a mirroring transform", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["nodes"][0]["matrix"] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0.5, 0, 0, 0, 1};
               }),
               "a projective transform", kUnsupported);
  expect_error(edit([](json& j, std::string&) { j["nodes"].push_back({{"mesh", 0}}); }),
               "the splats of mesh 0 are instanced by nodes 0 and 1", kUnsupported);
  expect_error(edit([](json& j, std::string&) { j["nodes"][0]["rotation"] = {0, 0, 0, 2}; }),
               "node 0: rotation is not a unit quaternion", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 j["nodes"][0]["children"] = {1};
                 j["nodes"].push_back({{"children", {0}}});
               }),
               "form a cycle", kInvalid);
  // Identity transforms, and transforms of nodes over no splats, are fine.
  EXPECT_TRUE(ReadGlb(edit([](json& j, std::string&) {
                        j["nodes"][0]["rotation"] = {0, 0, 0, 1};
                        j["nodes"][0]["matrix"] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
                        j["nodes"].push_back({{"translation", {5, 5, 5}}});
                      }),
                      "ok.glb")
                  .ok());
  expect_error(edit([](json& j, std::string&) { j["buffers"][0]["uri"] = "splats.bin"; }),
               "only a GLB with its BIN chunk is read", kUnsupported);
  expect_error(edit([&](json& j, std::string&) {
                 attr_accessor(j, Attr("ROTATION"))["sparse"] = {{"count", 1}};
               }),
               "sparse accessors are not read", kUnsupported);
  expect_error(edit([](json& j, std::string&) { j["meshes"][0]["primitives"][0]["mode"] = 4; }),
               "mode 4; a KHR_gaussian_splatting primitive must be POINTS", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["extensions"][kExt]["kernel"] = "box";
               }),
               "kernel \"box\"", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["extensions"][kExt]["projection"] = "ortho";
               }),
               "projection \"ortho\"", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["meshes"][0]["primitives"][0]["extensions"][kExt]["colorSpace"] =
                     "lin_rec709_display";
               }),
               "colorSpace \"lin_rec709_display\": hvdb composites", kUnsupported);
  expect_error(edit([](json& j, std::string&) {
                 j["extensionsRequired"] = {kExt, "KHR_draco_mesh_compression"};
               }),
               "requires the glTF extension \"KHR_draco_mesh_compression\"", kUnsupported);
  expect_error(
      edit([&](json& j, std::string&) { attr_accessor(j, Attr("OPACITY"))["type"] = "VEC2"; }),
      "type \"VEC2\", expected \"SCALAR\"", kInvalid);
  expect_error(
      edit([&](json& j, std::string&) { attr_accessor(j, "POSITION")["componentType"] = 5122; }),
      "POSITION (accessor 0): component type signed short", kUnsupported);
  expect_error(edit([&](json& j, std::string&) { attr_accessor(j, "POSITION")["count"] = -1; }),
               "\"count\" is -1, not a non-negative integer", kInvalid);
  expect_error(
      edit([&](json& j, std::string&) { attr_accessor(j, "POSITION")["bufferView"] = "zero"; }),
      "\"bufferView\" is \"zero\"", kInvalid);
  expect_error(edit([](json& j, std::string&) {
                 json second = j["meshes"][0]["primitives"][0];
                 for (int n = 0; n < 5; ++n) second["attributes"].erase(ShAttr(2, n));
                 j["meshes"][0]["primitives"].push_back(second);
               }),
               "mesh 0 primitive 1 has SH degree 1, mesh 0 primitive 0 degree 2", kUnsupported);
  expect_error(PackText(Unpack(good).gltf.dump(), "", false), "the GLB has none", kCorrupt);
}

// Bytes changed at random, in the JSON and the BIN chunk: an error or a cloud, never a crash or
// an exception (the fuzz target does more of the same).
TEST(GaussianGlb, RandomlyDamagedFilesNeverCrash) {
  const std::string good = *WriteGlb(RandomCloud(60, 1, 3), "x");
  Rng rng(61);
  size_t read = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::string bytes = good;
    const int changes = 1 + static_cast<int>(rng.Next() % 4);
    for (int k = 0; k < changes; ++k) {
      const size_t at = rng.Next() % bytes.size();
      bytes[at] =
          trial % 2 == 0 ? static_cast<char>(rng.Next()) : "0123456789:,{}[]\"-e."[rng.Next() % 20];
    }
    if (trial % 7 == 0) bytes.resize(rng.Next() % bytes.size());
    auto r = ReadGlb(bytes, "damaged.glb");
    if (r.ok()) {
      ++read;
      EXPECT_TRUE(ValidateGaussianCloud(*r, "damaged.glb").ok());
    } else {
      EXPECT_TRUE(r.status().message().starts_with("damaged.glb: ")) << r.status().message();
    }
  }
  EXPECT_GT(read, 0u);
}

TEST(GaussianGlb, WriteRefusesWhatGltfCannotHold) {
  GaussianCloud empty;
  auto r = WriteGlb(empty, "empty.glb");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("empty.glb: no splats"), std::string::npos);
  GaussianCloud c = RandomCloud(3, 1, 3);
  c.opacity[1] = std::numeric_limits<float>::quiet_NaN();
  r = WriteGlb(c, "nan.glb");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().message(), "nan.glb: splat 1: opacity is nan");
  c = RandomCloud(3, 1, 3);
  c.scale[4] = 100;  // e^100 is beyond float
  r = WriteGlb(c, "big.glb");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("big.glb: splat 1: scale_1 100 is too large"),
            std::string::npos)
      << r.status().message();
  // A scale below float's range writes 0, a flat splat, and reads as the smallest normal's log.
  c.scale[4] = -200;
  auto bytes = WriteGlb(c, "flat.glb");
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(FloatAt(Unpack(*bytes), Attr("SCALE"), 1, 3, 1), 0.0f);
  auto back = ReadGlb(*bytes, "flat.glb");
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->scale[4], std::log(std::numeric_limits<float>::min()));
}

// A million splats of degree 3 (240 MB of GLB) each way in well under a second (Release).
TEST(GaussianGlb, AMillionSplatsAreFast) {
  const GaussianCloud c = RandomCloud(50, 3, 1000000);
  auto t0 = std::chrono::steady_clock::now();
  auto bytes = WriteGlb(c, "big.glb");
  auto t1 = std::chrono::steady_clock::now();
  ASSERT_TRUE(bytes.ok());
  auto back = ReadGlb(*bytes, "big.glb");
  auto t2 = std::chrono::steady_clock::now();
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->sh_rest, c.sh_rest);
  const double write_s = std::chrono::duration<double>(t1 - t0).count();
  const double read_s = std::chrono::duration<double>(t2 - t1).count();
  std::printf("1M splats, degree 3, %zu bytes: write %.3f s, read %.3f s\n", bytes->size(), write_s,
              read_s);
#ifdef NDEBUG
  EXPECT_LT(write_s, 3.0);  // loose: a shared, loaded test machine
  EXPECT_LT(read_s, 3.0);
#endif
}

// The fuzz corpus's GLB seed (tests/formats/gaussian_fuzz_corpus/deg1.glb, as
// GaussianCorpus.SeedsAreSmallValidFiles writes it: 2 splats of degree 1). With
// HVDB_GAUSSIAN_CORPUS_OUT=<dir> the same bytes are written there first.
TEST(GaussianGlb, CorpusSeedIsASmallValidFile) {
  const fs::path seed = fs::path(HVDB_GAUSSIAN_CORPUS) / "deg1.glb";
  if (const char* out = std::getenv("HVDB_GAUSSIAN_CORPUS_OUT")) {
    fs::create_directories(out);
    std::ofstream(fs::path(out) / "deg1.glb", std::ios::binary)
        << *WriteGlb(RandomCloud(22, 1, 2), "x");
  }
  std::ifstream f(seed, std::ios::binary);
  ASSERT_TRUE(f.good()) << seed;
  const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  EXPECT_LT(bytes.size(), 4096u);
  auto r = ReadGlb(bytes, seed.string());
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_GE(r->size(), 1u);
  EXPECT_EQ(r->sh_degree, 1);
}

}  // namespace
}  // namespace hvdb::formats
