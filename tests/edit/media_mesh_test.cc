// Meshes sampled into surfels (media/mesh.cc) checked against the mesh itself: the Stanford
// bunny's samples lie on its triangles with outward normals, the sample is deterministic, and
// an embedded texture's, vertex and material colours come through.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

#include "media/media.h"

namespace hvdb::media {
namespace {

using V3 = std::array<double, 3>;
V3 Sub(const V3& a, const V3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
double Dot(const V3& a, const V3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
V3 Cross(const V3& a, const V3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}

struct Mesh {
  std::vector<V3> v;
  std::vector<std::array<int, 3>> f;
};

// The bunny's ASCII PLY read here, independently of assimp: vertex lines "x y z c i", face
// lines "3 a b c".
Mesh ReadBunny(const std::string& path, std::string* bytes) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  *bytes = ss.str();
  std::istringstream s(*bytes);
  std::string line;
  size_t nv = 0, nf = 0;
  while (std::getline(s, line) && line != "end_header") {
    std::istringstream l(line);
    std::string a, b;
    l >> a >> b;
    if (a == "element" && b == "vertex") l >> nv;
    if (a == "element" && b == "face") l >> nf;
  }
  Mesh m;
  for (size_t i = 0; i < nv && std::getline(s, line); ++i) {
    std::istringstream l(line);
    V3 p;
    l >> p[0] >> p[1] >> p[2];
    m.v.push_back(p);
  }
  for (size_t i = 0; i < nf && std::getline(s, line); ++i) {
    std::istringstream l(line);
    int n;
    std::array<int, 3> t;
    l >> n >> t[0] >> t[1] >> t[2];
    m.f.push_back(t);
  }
  return m;
}

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5).
double PointTriangle(const V3& p, const V3& a, const V3& b, const V3& c) {
  const V3 ab = Sub(b, a), ac = Sub(c, a), ap = Sub(p, a);
  auto dist = [&](const V3& q) { V3 d = Sub(p, q); return std::sqrt(Dot(d, d)); };
  auto at = [&](double v, double w) {
    return V3{a[0] + v * ab[0] + w * ac[0], a[1] + v * ab[1] + w * ac[1],
              a[2] + v * ab[2] + w * ac[2]};
  };
  const double d1 = Dot(ab, ap), d2 = Dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return dist(a);
  const V3 bp = Sub(p, b);
  const double d3 = Dot(ab, bp), d4 = Dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return dist(b);
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return dist(at(d1 / (d1 - d3), 0));
  const V3 cp = Sub(p, c);
  const double d5 = Dot(ab, cp), d6 = Dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return dist(c);
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return dist(at(0, d2 / (d2 - d6)));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return dist(V3{b[0] + w * (c[0] - b[0]), b[1] + w * (c[1] - b[1]), b[2] + w * (c[2] - b[2])});
  }
  const double denom = 1 / (va + vb + vc);
  return dist(at(vb * denom, vc * denom));
}

// Whether the ray o + t d (t > 0) crosses triangle abc (Moeller-Trumbore).
bool RayHits(const V3& o, const V3& d, const V3& a, const V3& b, const V3& c) {
  const V3 e1 = Sub(b, a), e2 = Sub(c, a), h = Cross(d, e2);
  const double det = Dot(e1, h);
  if (std::fabs(det) < 1e-14) return false;
  const V3 s = Sub(o, a);
  const double u = Dot(s, h) / det;
  if (u < 0 || u > 1) return false;
  const V3 q = Cross(s, e1);
  const double v = Dot(d, q) / det;
  if (v < 0 || u + v > 1) return false;
  return Dot(e2, q) / det > 1e-9;
}

TEST(MediaMeshTest, TheBunnysSamplesLieOnItWithOutwardNormals) {
  std::string bytes;
  const Mesh mesh =
      ReadBunny(HVDB_SHARED_DATA "/stanford-bunny/reconstruction/bun_zipper.ply", &bytes);
  ASSERT_EQ(mesh.v.size(), 35947u);
  ASSERT_EQ(mesh.f.size(), 69451u);
  Placement place;
  place.at = {1, 0, 2};
  place.scale = 2;
  auto pts = SampleMesh(bytes, "ply", place, 0, 1u << 3);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  // The same mesh placed as SampleMesh places it: bounding-box centre to `at`, scaled.
  V3 lo{1e9, 1e9, 1e9}, hi{-1e9, -1e9, -1e9};
  for (const V3& p : mesh.v) {
    for (int k = 0; k < 3; ++k) {
      lo[k] = std::min(lo[k], p[k]);
      hi[k] = std::max(hi[k], p[k]);
    }
  }
  std::vector<V3> v;
  double area = 0;
  for (const V3& p : mesh.v) {
    v.push_back({place.at[0] + 2 * (p[0] - (lo[0] + hi[0]) / 2),
                 place.at[1] + 2 * (p[1] - (lo[1] + hi[1]) / 2),
                 place.at[2] + 2 * (p[2] - (lo[2] + hi[2]) / 2)});
  }
  for (const auto& t : mesh.f) {
    const V3 n = Cross(Sub(v[t[1]], v[t[0]]), Sub(v[t[2]], v[t[0]]));
    area += 0.5 * std::sqrt(Dot(n, n));
  }
  // 2 mm spacing over the scaled surface (~0.23 m^2).
  const double h = MeshSpacing(area);
  EXPECT_DOUBLE_EQ(h, 0.002);
  EXPECT_NEAR(static_cast<double>(pts->size()), area / (h * h), 1.0);
  // A spread-out subset, checked by brute force against every triangle.
  size_t outward = 0, checked = 0;
  for (size_t i = 0; i < pts->size(); i += pts->size() / 150) {
    const Point& p = (*pts)[i];
    EXPECT_EQ(p.label, 1u << 3);
    const V3 q{p.x, p.y, p.z};
    double best = 1e9;
    for (const auto& t : mesh.f) best = std::min(best, PointTriangle(q, v[t[0]], v[t[1]], v[t[2]]));
    EXPECT_LT(best, 2e-6) << "sample " << i << " is off the surface";  // float positions
    // Outward: a ray from just outside along the normal leaves the surface an even number of
    // times (the bunny's base is open, so a few rays through it may miss).
    const auto nf = DecodeNormal(p.normal_oct);
    const V3 n{nf[0], nf[1], nf[2]};
    const V3 o{q[0] + 1e-4 * n[0], q[1] + 1e-4 * n[1], q[2] + 1e-4 * n[2]};
    int hits = 0;
    for (const auto& t : mesh.f) hits += RayHits(o, n, v[t[0]], v[t[1]], v[t[2]]);
    outward += hits % 2 == 0;
    ++checked;
  }
  EXPECT_GE(checked, 150u);
  EXPECT_GE(static_cast<double>(outward), 0.95 * checked) << outward << " of " << checked;
  // Deterministic: the same file and placement give the same points.
  auto again = SampleMesh(bytes, "ply", place, 0, 1u << 3);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(*again, *pts);
  // A given spacing sets the density.
  auto coarse = SampleMesh(bytes, "ply", place, 0.01, 0);
  ASSERT_TRUE(coarse.ok());
  EXPECT_NEAR(static_cast<double>(coarse->size()), area / 1e-4, 1.0);
}

std::string Base64(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const uint32_t v = (uint8_t(in[i]) << 16) | (uint8_t(in[i + 1]) << 8) | uint8_t(in[i + 2]);
    for (int s = 18; s >= 0; s -= 6) out += k[(v >> s) & 63];
  }
  if (i < in.size()) {
    uint32_t v = uint8_t(in[i]) << 16;
    if (i + 1 < in.size()) v |= uint8_t(in[i + 1]) << 8;
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

template <typename T>
std::string Bytes(const std::vector<T>& v) {
  return std::string(reinterpret_cast<const char*>(v.data()), v.size() * sizeof(T));
}

TEST(MediaMeshTest, AGltfsEmbeddedTextureColoursItsSurface) {
  // A unit quad in a self-contained glTF (data URIs): its texture is red on the left half and
  // blue on the right (u = x).
  const std::vector<float> pos = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  const std::vector<float> uv = {0, 1, 1, 1, 1, 0, 0, 0};
  const std::vector<uint16_t> idx = {0, 1, 2, 0, 2, 3};
  const std::string buf = Bytes(pos) + Bytes(uv) + Bytes(idx);
  cv::Mat tex(1, 2, CV_8UC3);
  tex.at<cv::Vec3b>(0, 0) = {0, 0, 255};  // BGR: red
  tex.at<cv::Vec3b>(0, 1) = {255, 0, 0};  // blue
  std::vector<uint8_t> png;
  ASSERT_TRUE(cv::imencode(".png", tex, png));
  const std::string gltf = R"({"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
    "nodes":[{"mesh":0}],
    "meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"indices":2,
      "material":0}]}],
    "materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}],
    "textures":[{"source":0}],
    "images":[{"uri":"data:image/png;base64,)" + Base64(std::string(png.begin(), png.end())) +
                           R"("}],
    "buffers":[{"byteLength":)" + std::to_string(buf.size()) +
                           R"(,"uri":"data:application/octet-stream;base64,)" + Base64(buf) +
                           R"("}],
    "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":48},
      {"buffer":0,"byteOffset":48,"byteLength":32},
      {"buffer":0,"byteOffset":80,"byteLength":12}],
    "accessors":[
      {"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]},
      {"bufferView":1,"componentType":5126,"count":4,"type":"VEC2"},
      {"bufferView":2,"componentType":5123,"count":6,"type":"SCALAR"}]})";
  auto pts = SampleMesh(gltf, "gltf", {}, 0.05, 0);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  ASSERT_EQ(pts->size(), 400u);
  for (const Point& p : *pts) {
    if (std::fabs(p.x) < 0.01) continue;  // on the seam
    const std::array<int, 3> rgb{p.r, p.g, p.b};
    const std::array<int, 3> red{255, 0, 0}, blue{0, 0, 255};
    EXPECT_EQ(rgb, p.x < 0 ? red : blue) << p.x;
  }
}

TEST(MediaMeshTest, VertexColoursAndMaterialColoursComeThrough) {
  // A unit quad, red at x = 0 and blue at x = 1, as a PLY with vertex colours.
  const std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
      "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
      "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0 255 0 0\n1 0 0 0 0 255\n1 1 0 0 0 255\n0 1 0 255 0 0\n3 0 1 2\n3 0 2 3\n";
  auto pts = SampleMesh(ply, "ply", {}, 0.05, 0);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  EXPECT_EQ(pts->size(), 400u);
  for (const Point& p : *pts) {
    // Centred on the origin; the colour runs from red to blue with x.
    const double t = p.x + 0.5;
    EXPECT_NEAR(p.r, 255 * (1 - t), 1.5);
    EXPECT_NEAR(p.b, 255 * t, 1.5);
    EXPECT_EQ(p.g, 0);
    EXPECT_NEAR(DecodeNormal(p.normal_oct)[2], 1.0, 1e-4);  // counter-clockwise: +z
  }
  // An OBJ with an inline material colour is not possible without its .mtl; its default
  // material's colour is used (assimp: 0.6 grey).
  auto obj = SampleMesh("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj", {}, 0.1, 0);
  ASSERT_TRUE(obj.ok()) << obj.status().ToString();
  ASSERT_FALSE(obj->empty());
  EXPECT_EQ((*obj)[0].r, (*obj)[0].g);
}

}  // namespace
}  // namespace hvdb::media
