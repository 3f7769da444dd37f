// Gaussian-splat files (formats/gaussians.h): the 3DGS PLY round trip to the byte, .splat and
// SPZ round trips within their quantisation, bytes of each format checked by hand against the
// reference conventions, detection, the covariance, and malformed files. Deterministic: the
// clouds come from fixed seeds.
//
// Quantisation bounds checked (SPZ at fractional bits f = 12):
//   SPZ      position within 2^-(f+1) (exact rounding to the 24-bit grid); log scale within
//            1/32; opacity within 0.5/255 after the sigmoid; colour (0.5 + C0 f_dc) within
//            0.5/255 * C0/0.15 < 1/255; SH degree 1 within 4.5/128, degrees 2-3 within 8.5/128
//            (|x| <= 0.9); rotation v3 within 0.003 a component (the same sign), v2 x y z
//            within 0.5/127.5 and w within 0.12 (w is derived from x y z)
//   .splat   position and scale exact up to float exp/log (1e-6 relative); colour and opacity
//            within 0.5/255 after activation; rotation within 1/128 a component of the
//            normalised quaternion
#include "formats/gaussians.h"
#include "tests/formats/random_cloud.h"

#include <gtest/gtest.h>
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <array>
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

namespace hvdb::formats {
namespace {

namespace fs = std::filesystem;
using test_clouds::RandomCloud;
using test_clouds::Rng;


bool BitIdentical(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() &&
         (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0);
}

void ExpectBitIdentical(const GaussianCloud& a, const GaussianCloud& b) {
  EXPECT_EQ(a.sh_degree, b.sh_degree);
  EXPECT_TRUE(BitIdentical(a.position, b.position));
  EXPECT_TRUE(BitIdentical(a.scale, b.scale));
  EXPECT_TRUE(BitIdentical(a.rotation, b.rotation));
  EXPECT_TRUE(BitIdentical(a.opacity, b.opacity));
  EXPECT_TRUE(BitIdentical(a.sh_dc, b.sh_dc));
  EXPECT_TRUE(BitIdentical(a.sh_rest, b.sh_rest));
}

std::string Gzip(const std::string& raw) {
  z_stream z{};
  EXPECT_EQ(deflateInit2(&z, 9, Z_DEFLATED, 16 + MAX_WBITS, 9, Z_DEFAULT_STRATEGY), Z_OK);
  std::string out(deflateBound(&z, raw.size()), '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(raw.data()));
  z.avail_in = static_cast<uInt>(raw.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  EXPECT_EQ(deflate(&z, Z_FINISH), Z_STREAM_END);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

std::string Gunzip(const std::string& gz) {
  z_stream z{};
  EXPECT_EQ(inflateInit2(&z, 16 + MAX_WBITS), Z_OK);
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(gz.data()));
  z.avail_in = static_cast<uInt>(gz.size());
  std::string out;
  char buf[4096];
  int rc = Z_OK;
  while (rc == Z_OK) {
    z.next_out = reinterpret_cast<Bytef*>(buf);
    z.avail_out = sizeof buf;
    rc = inflate(&z, Z_NO_FLUSH);
    out.append(buf, sizeof buf - z.avail_out);
  }
  EXPECT_EQ(rc, Z_STREAM_END);
  inflateEnd(&z);
  return out;
}

std::string Le32(uint32_t v) {
  std::string s(4, '\0');
  for (int k = 0; k < 4; ++k) s[k] = static_cast<char>(v >> (8 * k));
  return s;
}

std::string Bytes(std::initializer_list<int> b) {
  std::string s;
  for (int v : b) s += static_cast<char>(v);
  return s;
}

std::string F32(float v) {
  std::string s(4, '\0');
  std::memcpy(s.data(), &v, 4);  // the tests run on little-endian machines
  return s;
}

// ---------------------------------------------------------------------------------------------
// 3DGS PLY

TEST(GaussianPly, RoundTripIsByteExactForEveryDegree) {
  for (int degree = 0; degree <= 3; ++degree) {
    SCOPED_TRACE(degree);
    const GaussianCloud c = RandomCloud(100 + degree, degree, 257);
    auto bytes = WriteGaussianPly(c, "a.ply");
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    const size_t rest = 3 * ShRestPerChannel(degree);
    auto back = ReadGaussianPly(*bytes, "a.ply");
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ExpectBitIdentical(c, *back);
    auto again = WriteGaussianPly(*back, "a.ply");
    ASSERT_TRUE(again.ok());
    EXPECT_EQ(*again, *bytes);
    EXPECT_EQ(DetectGaussianFormat(*bytes), GaussianFormat::k3dgsPly);
    const size_t header = bytes->find("end_header\n") + 11;
    EXPECT_EQ(bytes->size(), header + 257 * 4 * (17 + rest));
  }
}

TEST(GaussianPly, WritesTheInriaHeader) {
  GaussianCloud c = RandomCloud(7, 1, 2);
  auto bytes = WriteGaussianPly(c, "a.ply");
  ASSERT_TRUE(bytes.ok());
  std::string want = "ply\nformat binary_little_endian 1.0\nelement vertex 2\n";
  for (const char* p : {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"}) {
    want += std::string("property float ") + p + "\n";
  }
  for (int k = 0; k < 9; ++k) want += "property float f_rest_" + std::to_string(k) + "\n";
  for (const char* p : {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2",
                        "rot_3"}) {
    want += std::string("property float ") + p + "\n";
  }
  want += "end_header\n";
  ASSERT_EQ(bytes->substr(0, want.size()), want);
  // Splat 1: x y z, zero normals, f_dc, f_rest_0..8 channel-major, opacity, scales, rot w x y z.
  std::string row;
  for (int k = 0; k < 3; ++k) row += F32(c.position[3 + k]);
  row += F32(0) + F32(0) + F32(0);
  for (int k = 0; k < 3; ++k) row += F32(c.sh_dc[3 + k]);
  for (int k = 0; k < 9; ++k) row += F32(c.sh_rest[9 + k]);
  row += F32(c.opacity[1]);
  for (int k = 0; k < 3; ++k) row += F32(c.scale[3 + k]);
  for (int k = 0; k < 4; ++k) row += F32(c.rotation[4 + k]);
  EXPECT_EQ(bytes->substr(want.size() + row.size()), row);
}

// A PLY with the given vertex properties, in any order, and values per vertex by name.
std::string HandPly(const std::string& encoding, const std::vector<std::string>& props,
                    const GaussianCloud& c) {
  std::string s = "ply\nformat " + encoding + " 1.0\ncomment by hand\nelement vertex " +
                  std::to_string(c.size()) + "\n";
  for (const std::string& p : props) s += "property float " + p + "\n";
  s += "element face 0\nproperty list uchar int vertex_indices\nend_header\n";
  const size_t rest = c.sh_rest_per_splat();
  for (size_t i = 0; i < c.size(); ++i) {
    for (const std::string& p : props) {
      float v = 0;
      if (p == "x" || p == "y" || p == "z") v = c.position[3 * i + (p[0] - 'x')];
      if (p == "opacity") v = c.opacity[i];
      if (p.starts_with("f_dc_")) v = c.sh_dc[3 * i + std::stoi(p.substr(5))];
      if (p.starts_with("f_rest_")) v = c.sh_rest[i * rest + std::stoi(p.substr(7))];
      if (p.starts_with("scale_")) v = c.scale[3 * i + std::stoi(p.substr(6))];
      if (p.starts_with("rot_")) v = c.rotation[4 * i + std::stoi(p.substr(4))];
      if (encoding == "ascii") {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%.9g ", static_cast<double>(v));
        s += buf;
      } else {
        std::string f = F32(v);
        if (encoding == "binary_big_endian") f = std::string(f.rbegin(), f.rend());
        s += f;
      }
    }
    if (encoding == "ascii") s += "\n";
  }
  return s;
}

TEST(GaussianPly, ReadsAnyOrderAsciiAndBigEndian) {
  const GaussianCloud c = RandomCloud(8, 2, 5);
  std::vector<std::string> props = {"rot_3", "scale_1", "opacity", "z", "y", "x", "rot_0"};
  for (int k = 23; k >= 0; --k) props.push_back("f_rest_" + std::to_string(k));
  for (const char* p : {"f_dc_2", "f_dc_0", "f_dc_1", "scale_0", "scale_2", "rot_1", "rot_2"}) {
    props.push_back(p);
  }
  for (const char* encoding : {"ascii", "binary_big_endian", "binary_little_endian"}) {
    SCOPED_TRACE(encoding);
    const std::string ply = HandPly(encoding, props, c);
    EXPECT_EQ(DetectGaussianFormat(ply), GaussianFormat::k3dgsPly);
    auto back = ReadGaussianPly(ply, "hand.ply");
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    ExpectBitIdentical(c, *back);  // %.9g gives floats back exactly
  }
}

// Trainers' own extra values (Mip-Splatting's filter_3D, colours as uchar, a double) are read
// over, whatever their size, and named; the splats read as without them.
TEST(GaussianPly, ExtraScalarPropertiesAreReadOverAndNamed) {
  const GaussianCloud c = RandomCloud(21, 1, 7);
  const std::string plain = *WriteGaussianPly(c, "x");
  const size_t header = plain.find("end_header\n") + 11;
  std::string extra = plain.substr(0, header);
  extra.replace(extra.find("property float opacity\n"), 23,
                "property uchar red\nproperty float opacity\nproperty double filter_3D\n"
                "property short s\n");
  const size_t stride = 4 * (6 + 3 + 9 + 1 + 3 + 4);
  const size_t before = 4 * (6 + 3 + 9);  // x .. f_rest_8, then red, opacity, filter_3D, s
  for (size_t i = 0; i < c.size(); ++i) {
    const char* row = plain.data() + header + i * stride;
    extra.append(row, before);
    extra.push_back(static_cast<char>(200 + i));
    extra.append(row + before, 4);  // opacity
    const double f = 0.125 * static_cast<double>(i);
    extra.append(reinterpret_cast<const char*>(&f), 8);
    const int16_t sh = static_cast<int16_t>(-7 * static_cast<int>(i));
    extra.append(reinterpret_cast<const char*>(&sh), 2);
    extra.append(row + before + 4, stride - before - 4);
  }
  auto back = ReadGaussianPly(extra, "mip.ply");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ExpectBitIdentical(c, *back);
  EXPECT_EQ(back->ignored, (std::vector<std::string>{"red", "filter_3D", "s"}));
  // A list property is still refused: a 3DGS vertex is one row of scalars.
  std::string list = plain;
  list.replace(list.find("property float nx"), 17, "property list uchar int nx");
  EXPECT_FALSE(ReadGaussianPly(list, "list.ply").ok());
}

TEST(GaussianPly, MalformedFilesAreClearErrors) {
  const GaussianCloud c3 = RandomCloud(9, 3, 4);
  std::vector<std::string> props = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (int k = 0; k < 44; ++k) props.push_back("f_rest_" + std::to_string(k));  // no f_rest_44
  for (const char* p : {"opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2",
                        "rot_3"}) {
    props.push_back(p);
  }
  auto r = ReadGaussianPly(HandPly("binary_little_endian", props, c3), "deg3.ply");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument());
  EXPECT_NE(r.status().message().find("deg3.ply: f_rest_44 is missing"), std::string::npos)
      << r.status().message();
  EXPECT_NE(r.status().message().find("SH degree 3"), std::string::npos);

  // NaN opacity of splat 2: the read names the splat and the property.
  const GaussianCloud c = RandomCloud(10, 0, 4);
  std::string good = *WriteGaussianPly(c, "x");
  const size_t header = good.find("end_header\n") + 11;
  std::string nan = good;
  const float q = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(nan.data() + header + 2 * 17 * 4 + 9 * 4, &q, 4);  // opacity: the 10th float
  r = ReadGaussianPly(nan, "nan.ply");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().message(), "nan.ply: splat 2: opacity is nan");

  // A header that claims 10^12 vertices in about a kilobyte: refused before allocating.
  std::string huge = good;
  huge.replace(huge.find("element vertex 4"), 16, "element vertex 1000000000000");
  r = ReadGaussianPly(huge, "huge.ply");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsCorruption());
  EXPECT_NE(r.status().message().find("huge.ply: truncated: the header declares 1000000000000 "
                                      "vertices"),
            std::string::npos)
      << r.status().message();
  std::string huge_ascii = huge;
  huge_ascii.replace(huge_ascii.find("binary_little_endian"), 20, "ascii");
  EXPECT_TRUE(ReadGaussianPly(huge_ascii, "huge.ply").status().IsCorruption());

  auto expect_error = [](const std::string& bytes, const std::string& fragment) {
    auto res = ReadGaussianPly(bytes, "bad.ply");
    ASSERT_FALSE(res.ok()) << fragment;
    EXPECT_NE(res.status().message().find("bad.ply"), std::string::npos);
    EXPECT_NE(res.status().message().find(fragment), std::string::npos)
        << res.status().message();
  };
  expect_error(good.substr(0, good.size() - 3), "truncated");
  expect_error(good + "xyz", "3 bytes follow the 4 vertices");
  expect_error(good.substr(0, header - 20), "no 'end_header'");
  std::string unknown = good;
  unknown.replace(unknown.find("property float nx"), 17, "property fl0at qq");
  expect_error(unknown, "vertex property 'qq' has unknown type 'fl0at'");
  std::string dbl = good;
  dbl.replace(dbl.find("property float opacity"), 22, "property double opacity");
  expect_error(dbl, "'opacity' is 'double'");
  std::string missing = good;
  missing.replace(missing.find("property float rot_3"), 20, "property float nx");
  expect_error(missing, "appears twice");
  std::string face = good;
  face.replace(face.find("end_header"), 10, "element face 1\nproperty uchar a\nend_header");
  expect_error(face, "element 'face' has 1 items");
  expect_error("ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n"
               "end_header\n",
               "no 'y' property");
  expect_error("PLY\n", "not a PLY file");

  // Writers refuse what readers would: NaN, arrays of the wrong length.
  GaussianCloud broken = c;
  broken.scale[5] = std::numeric_limits<float>::infinity();
  auto w = WriteGaussianPly(broken, "out.ply");
  ASSERT_FALSE(w.ok());
  EXPECT_EQ(w.status().message(), "out.ply: splat 1: scale_2 is inf");
  broken = c;
  broken.sh_rest.push_back(0);
  EXPECT_TRUE(WriteGaussianPly(broken, "out.ply").status().IsInvalidArgument());
  EXPECT_TRUE(WriteSplat(broken, "out.splat").status().IsInvalidArgument());
  EXPECT_TRUE(WriteSpz(broken, "out.spz").status().IsInvalidArgument());
}

// ---------------------------------------------------------------------------------------------
// .splat

TEST(Splat, RoundTripWithinQuantisation) {
  for (int degree = 0; degree <= 3; ++degree) {
    SCOPED_TRACE(degree);
    const GaussianCloud c = RandomCloud(200 + degree, degree, 300);
    auto bytes = WriteSplat(c, "a.splat");
    ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
    ASSERT_EQ(bytes->size(), 32u * 300);
    EXPECT_EQ(DetectGaussianFormat(*bytes), GaussianFormat::kSplat);
    auto back = ReadSplat(*bytes, "a.splat");
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    EXPECT_EQ(back->sh_degree, 0);
    EXPECT_TRUE(back->sh_rest.empty());
    ASSERT_EQ(back->size(), c.size());
    EXPECT_TRUE(BitIdentical(back->position, c.position));
    for (size_t i = 0; i < c.size(); ++i) {
      for (int k = 0; k < 3; ++k) {
        EXPECT_NEAR(std::exp(back->scale[3 * i + k]), std::exp(c.scale[3 * i + k]),
                    1e-6 * std::exp(c.scale[3 * i + k]));
        const double colour = 0.5 + kShC0 * c.sh_dc[3 * i + k];
        EXPECT_NEAR(0.5 + kShC0 * back->sh_dc[3 * i + k], colour, 0.5 / 255 + 1e-6);
      }
      EXPECT_NEAR(Sigmoid(back->opacity[i]), Sigmoid(c.opacity[i]), 0.5 / 255 + 1e-6);
      double norm = 0;
      for (int k = 0; k < 4; ++k) norm += double{c.rotation[4 * i + k]} * c.rotation[4 * i + k];
      for (int k = 0; k < 4; ++k) {
        EXPECT_NEAR(back->rotation[4 * i + k], c.rotation[4 * i + k] / std::sqrt(norm),
                    1.0 / 128 + 1e-6);
      }
    }
    // Colour and opacity bytes come back the same (rotations are renormalised).
    auto again = WriteSplat(*back, "a.splat");
    ASSERT_TRUE(again.ok());
    for (size_t i = 0; i < c.size(); ++i) {
      EXPECT_EQ(again->substr(32 * i, 12), bytes->substr(32 * i, 12));
      EXPECT_EQ(again->substr(32 * i + 24, 4), bytes->substr(32 * i + 24, 4));
    }
  }
}

TEST(Splat, BytesFollowTheViewersConversion) {
  GaussianCloud c;
  c.Resize(1);
  c.position = {1, -2, 0.5f};
  c.scale = {0, 0, 0};
  c.sh_dc = {0, 5, -5};     // 127.5 (ties to even: 128), beyond 1 (255), below 0 (0)
  c.opacity = {0};          // 127.5: 128
  c.rotation = {2, 0, 0, 2};  // normalised 0.7071: 218.5: 219
  auto bytes = WriteSplat(c, "a.splat");
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, F32(1) + F32(-2) + F32(0.5f) + F32(1) + F32(1) + F32(1) +
                        Bytes({128, 255, 0, 128, 219, 128, 128, 219}));
}

TEST(Splat, MalformedFilesAreClearErrors) {
  auto r = ReadSplat(std::string(33, '\0'), "odd.splat");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsCorruption());
  EXPECT_NE(r.status().message().find("odd.splat: 33 bytes is not a multiple of the 32"),
            std::string::npos)
      << r.status().message();
  std::string nan = *WriteSplat(RandomCloud(11, 0, 3), "x");
  const float q = std::numeric_limits<float>::quiet_NaN();
  std::memcpy(nan.data() + 32 + 4, &q, 4);
  r = ReadSplat(nan, "nan.splat");
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().message(), "nan.splat: splat 1: y is nan");
  EXPECT_EQ(DetectGaussianFormat(nan), GaussianFormat::kUnknown);
  std::string negative = *WriteSplat(RandomCloud(11, 0, 3), "x");
  const float minus = -1;
  std::memcpy(negative.data() + 64 + 12, &minus, 4);
  r = ReadSplat(negative, "neg.splat");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("neg.splat: splat 2: scale_0"), std::string::npos);
  // A zero scale (a log scale below float range) reads as the smallest one.
  std::string zero = *WriteSplat(RandomCloud(11, 0, 3), "x");
  std::memset(zero.data() + 12, 0, 4);
  r = ReadSplat(zero, "zero.splat");
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(std::isfinite(r->scale[0]));
  EXPECT_TRUE(ReadSplat("", "empty.splat").ok());
}

// ---------------------------------------------------------------------------------------------
// SPZ

void ExpectSpzWithinBounds(const GaussianCloud& c, const GaussianCloud& back, int version) {
  ASSERT_EQ(back.size(), c.size());
  ASSERT_EQ(back.sh_degree, c.sh_degree);
  EXPECT_EQ(back.antialiased, c.antialiased);
  const size_t rest = c.sh_rest_per_splat();
  const size_t dim = rest / 3;
  for (size_t i = 0; i < c.size(); ++i) {
    SCOPED_TRACE(i);
    for (int k = 0; k < 3; ++k) {
      EXPECT_LE(std::fabs(back.position[3 * i + k] - c.position[3 * i + k]), 0x1p-13);
      EXPECT_LE(std::fabs(back.scale[3 * i + k] - c.scale[3 * i + k]), 1.0 / 32 + 1e-5);
      EXPECT_LE(kShC0 * std::fabs(back.sh_dc[3 * i + k] - c.sh_dc[3 * i + k]),
                kShC0 * (0.5 / 255 / 0.15) + 1e-6);
    }
    EXPECT_LE(std::fabs(Sigmoid(back.opacity[i]) - Sigmoid(c.opacity[i])), 0.5 / 255 + 1e-6);
    double q[4], norm = 0, dot = 0;
    for (int k = 0; k < 4; ++k) q[k] = c.rotation[4 * i + k], norm += q[k] * q[k];
    for (int k = 0; k < 4; ++k) q[k] /= std::sqrt(norm), dot += q[k] * back.rotation[4 * i + k];
    const double sign = dot < 0 ? -1 : 1;
    for (int k = 0; k < 4; ++k) {
      const double err = std::fabs(sign * back.rotation[4 * i + k] - q[k]);
      if (version >= 3) {
        EXPECT_LE(err, 0.003) << "rot_" << k;
      } else {
        EXPECT_LE(err, k == 0 ? 0.12 : 0.5 / 127.5 + 1e-6) << "rot_" << k;
      }
    }
    for (size_t j = 0; j < rest; ++j) {
      const double bound = j % dim < 3 ? 4.5 / 128 : 8.5 / 128;
      EXPECT_LE(std::fabs(back.sh_rest[i * rest + j] - c.sh_rest[i * rest + j]), bound + 1e-6)
          << "f_rest_" << j;
    }
  }
}

TEST(Spz, RoundTripWithinQuantisationForEveryDegreeAndVersion) {
  for (int version : {2, 3}) {
    for (int degree = 0; degree <= 3; ++degree) {
      SCOPED_TRACE(testing::Message() << "version " << version << " degree " << degree);
      GaussianCloud c = RandomCloud(300 + 10 * version + degree, degree, 500);
      c.antialiased = degree % 2 == 1;
      SpzWriteOptions options;
      options.version = version;
      auto bytes = WriteSpz(c, "a.spz", options);
      ASSERT_TRUE(bytes.ok()) << bytes.status().ToString();
      EXPECT_EQ(DetectGaussianFormat(*bytes), GaussianFormat::kSpz);
      const std::string raw = Gunzip(*bytes);
      const size_t per_point = 9 + 1 + 3 + 3 + (version >= 3 ? 4 : 3) + 3 * ShRestPerChannel(degree);
      ASSERT_EQ(raw.size(), 16 + 500 * per_point);
      EXPECT_EQ(raw.substr(0, 12), "NGSP" + Le32(version) + Le32(500));
      EXPECT_EQ(raw.substr(12, 4), Bytes({degree, 12, c.antialiased ? 1 : 0, 0}));
      auto back = ReadSpz(*bytes, "a.spz");
      ASSERT_TRUE(back.ok()) << back.status().ToString();
      ExpectSpzWithinBounds(c, *back, version);
      // The decoded values are on the quantisation grid: writing them again gives the same
      // bytes, but for rotations (renormalised; a near tie of the largest component, or a
      // small w in version 2, may take another code of about the same rotation).
      auto again = WriteSpz(*back, "a.spz", options);
      ASSERT_TRUE(again.ok());
      std::string raw2 = Gunzip(*again);
      ASSERT_EQ(raw2.size(), raw.size());
      const size_t rotations = 16 + 500 * (9 + 1 + 3 + 3);
      const size_t rotation_bytes = 500 * (version >= 3 ? 4 : 3);
      EXPECT_TRUE(raw2.substr(0, rotations) == raw.substr(0, rotations));
      EXPECT_TRUE(raw2.substr(rotations + rotation_bytes) == raw.substr(rotations + rotation_bytes));
      auto back2 = ReadSpz(*again, "a.spz");
      ASSERT_TRUE(back2.ok());
      ExpectSpzWithinBounds(*back, *back2, version);
    }
  }
}

// One splat of degree 1, by hand from the reference's formulas (load-spz.cc): in SPZ's RUB
// coordinates y and z are negated, as are SH coefficients 0 and 1 of degree 1 (odd in y, z).
TEST(Spz, BytesFollowTheReference) {
  GaussianCloud c;
  c.sh_degree = 1;
  c.Resize(1);
  c.position = {1, 2, -3};
  c.scale = {0, -10, -2.5f};
  c.opacity = {0};
  c.sh_dc = {0, 1, -1};
  c.rotation = {0.8f, 0, 0.6f, 0};  // w x y z: a turn about y
  c.sh_rest = {0.5f, 0.25f, -0.5f, 0, 0, 0, 1, -1, 0.125f};  // R, G, B; 3 coefficients each
  const std::string sh = Bytes({64, 128, 0, 96, 128, 255, 64, 128, 144});
  const std::string common = Bytes({0x00, 0x10, 0x00, 0x00, 0xe0, 0xff, 0x00, 0x30, 0x00}) +
                             Bytes({128}) + Bytes({128, 166, 89}) + Bytes({160, 0, 120});
  SpzWriteOptions v3;
  auto bytes = WriteSpz(c, "one.spz", v3);
  ASSERT_TRUE(bytes.ok());
  EXPECT_TRUE(bytes->starts_with("\x1f\x8b"));
  const std::string header3 = "NGSP" + Le32(3) + Le32(1) + Bytes({1, 12, 0, 0});
  // Smallest three: largest w (index 3); x: 0; y: -0.6 -> +0.6 negated: sign bit, 434; z: 0.
  EXPECT_EQ(Gunzip(*bytes), header3 + common + Bytes({0x00, 0xc8, 0x0e, 0xc0}) + sh);
  SpzWriteOptions v2;
  v2.version = 2;
  bytes = WriteSpz(c, "one.spz", v2);
  ASSERT_TRUE(bytes.ok());
  const std::string header2 = "NGSP" + Le32(2) + Le32(1) + Bytes({1, 12, 0, 0});
  // x y z of the (w >= 0) quaternion, (q + 1) * 127.5: 0 -> 128 (127.5 rounds away from 0),
  // y -0.6 -> 51.
  EXPECT_EQ(Gunzip(*bytes), header2 + common + Bytes({128, 51, 128}) + sh);
  auto back = ReadSpz(*bytes, "one.spz");
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->position, (std::vector<float>{1, 2, -3}));
  EXPECT_EQ(back->scale, (std::vector<float>{0, -10, -2.5f}));
  // B of coefficient 1: -1 quantised to 255 (0.9921875), negated.
  EXPECT_EQ(back->sh_rest,
            (std::vector<float>{0.5f, 0.25f, -0.5f, 0, 0, 0, 1, -0.9921875f, 0.125f}));
  EXPECT_NEAR(back->rotation[2], 0.6f, 0.5 / 127.5);
}

TEST(Spz, FarPositionsLowerTheFractionBits) {
  GaussianCloud c = RandomCloud(12, 0, 50);
  c.position[7] = 3000.3f;  // beyond 2048: 11 fraction bits
  auto bytes = WriteSpz(c, "far.spz");
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(Gunzip(*bytes)[13], 11);
  auto back = ReadSpz(*bytes, "far.spz");
  ASSERT_TRUE(back.ok());
  for (size_t i = 0; i < c.position.size(); ++i) {
    EXPECT_LE(std::fabs(back->position[i] - c.position[i]), 0x1p-12);
  }
  c.position[7] = 1e7f;  // beyond 2^23 even as an integer
  auto r = WriteSpz(c, "far.spz");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("far.spz: splat 2:"), std::string::npos)
      << r.status().message();
  EXPECT_TRUE(WriteSpz(GaussianCloud{}, "empty.spz").status().IsInvalidArgument());
}

TEST(Spz, MalformedFilesAreClearErrors) {
  const std::string good = *WriteSpz(RandomCloud(13, 2, 200), "x");
  auto expect_error = [](const std::string& bytes, StatusCode code, const std::string& fragment) {
    auto r = ReadSpz(bytes, "bad.spz");
    ASSERT_FALSE(r.ok()) << fragment;
    EXPECT_EQ(r.status().code(), code) << r.status().ToString();
    EXPECT_NE(r.status().message().find("bad.spz: "), std::string::npos);
    EXPECT_NE(r.status().message().find(fragment), std::string::npos) << r.status().message();
  };
  expect_error(good.substr(0, good.size() / 2), StatusCode::kCorruption, "truncated");
  expect_error(good.substr(0, 12), StatusCode::kCorruption, "truncated");
  expect_error(good + "junk", StatusCode::kCorruption, "4 bytes follow the end of the gzip");
  std::string crc = good;
  crc[crc.size() - 6] ^= 0x55;  // the CRC-32 of the gzip trailer
  expect_error(crc, StatusCode::kCorruption, "gzip data error");
  // A header claiming 4 billion points in a few bytes of gzip: refused before inflating.
  const std::string lie = "NGSP" + Le32(3) + Le32(4000000000u) + Bytes({0, 12, 0, 0});
  expect_error(Gzip(lie + std::string(100, '\0')), StatusCode::kCorruption,
               "declares 4000000000 points");
  // A real bomb: one point declared, 64 MiB of zeros behind it; inflating stops at the declared
  // size, long before the end.
  const std::string one = "NGSP" + Le32(3) + Le32(1) + Bytes({0, 12, 0, 0});
  expect_error(Gzip(one + std::string(64u << 20, '\0')), StatusCode::kCorruption,
               "inflates to more than the 36 bytes");
  expect_error(Gzip("NGSQ" + one.substr(4)), StatusCode::kInvalidArgument, "NGSP");
  expect_error(Gzip("NGSP" + Le32(3) + Le32(1) + Bytes({4, 12, 0, 0})), StatusCode::kUnsupported,
               "SH degree 4");
  expect_error(Gzip("NGSP" + Le32(3) + Le32(1) + Bytes({0, 12, 2, 0})), StatusCode::kUnsupported,
               "extensions");
  expect_error(Gzip("NGSP" + Le32(1) + Le32(1) + Bytes({0, 12, 0, 0})), StatusCode::kUnsupported,
               "version 1");
  expect_error("NGSP" + Le32(5) + std::string(24, '\0'), StatusCode::kUnsupported, "version 5");
  expect_error("hello", StatusCode::kInvalidArgument, "not an SPZ file");
  // An empty file of zero points reads (the writer refuses to make one).
  auto empty = ReadSpz(Gzip("NGSP" + Le32(2) + Le32(0) + Bytes({0, 12, 0, 0})), "empty.spz");
  ASSERT_TRUE(empty.ok()) << empty.status().ToString();
  EXPECT_EQ(empty->size(), 0u);
}

// Version 4 by hand: the streams of the version-3 payload (positions, alphas, colours, scales,
// rotations, SH), each its own zstd frame, behind the 32-byte header and the table of contents.
std::string SpzV4FromV3(const std::string& gz, int streams_at_degree) {
  const std::string raw = Gunzip(gz);
  const uint32_t n = static_cast<uint32_t>(static_cast<unsigned char>(raw[8]) |
                                           (static_cast<unsigned char>(raw[9]) << 8));
  std::vector<size_t> sizes = {9u * n, n, 3u * n, 3u * n, 4u * n};
  if (raw.size() > 16 + 20u * n) sizes.push_back(raw.size() - 16 - 20u * n);
  EXPECT_EQ(static_cast<int>(sizes.size()), streams_at_degree);
  std::string toc, frames;
  size_t at = 16;
  for (size_t size : sizes) {
    std::string frame(ZSTD_compressBound(size), '\0');
    frame.resize(ZSTD_compress(frame.data(), frame.size(), raw.data() + at, size, 3));
    toc += Le32(static_cast<uint32_t>(frame.size())) + Le32(0) + Le32(static_cast<uint32_t>(size)) +
           Le32(0);
    frames += frame;
    at += size;
  }
  return "NGSP" + Le32(4) + raw.substr(8, 4) + raw.substr(12, 3) +
         Bytes({static_cast<int>(sizes.size())}) + Le32(32) + std::string(12, '\0') + toc + frames;
}

// Version 4 quantises as version 3 does: the same cloud reads back bit for bit the same from
// both, from hvdb's writer and from a file assembled here stream by stream.
TEST(Spz, Version4ReadsAsVersion3) {
  for (int degree = 0; degree <= 3; ++degree) {
    SCOPED_TRACE(testing::Message() << "degree " << degree);
    GaussianCloud c = RandomCloud(340 + degree, degree, 700);
    c.antialiased = degree == 2;
    SpzWriteOptions v3, v4;
    v4.version = 4;
    auto b3 = WriteSpz(c, "a.spz", v3);
    auto b4 = WriteSpz(c, "a.spz", v4);
    ASSERT_TRUE(b3.ok() && b4.ok()) << b4.status().ToString();
    EXPECT_EQ(DetectGaussianFormat(*b4), GaussianFormat::kSpz);
    const int streams = degree == 0 ? 5 : 6;
    EXPECT_EQ(b4->substr(0, 20), "NGSP" + Le32(4) + Le32(700) +
                                     Bytes({degree, 12, degree == 2 ? 1 : 0, streams}) + Le32(32));
    EXPECT_EQ(b4->substr(20, 12), std::string(12, '\0'));
    auto from3 = ReadSpz(*b3, "a.spz");
    auto from4 = ReadSpz(*b4, "a.spz");
    auto by_hand = ReadSpz(SpzV4FromV3(*b3, streams), "a.spz");
    ASSERT_TRUE(from3.ok() && from4.ok()) << from4.status().ToString();
    ASSERT_TRUE(by_hand.ok()) << by_hand.status().ToString();
    ExpectBitIdentical(*from3, *from4);
    ExpectBitIdentical(*from3, *by_hand);
    EXPECT_EQ(from4->antialiased, c.antialiased);
    ExpectSpzWithinBounds(c, *from4, 4);
  }
}

TEST(Spz, MalformedVersion4FilesAreClearErrors) {
  const std::string good = *WriteSpz(RandomCloud(15, 1, 300), "x", SpzWriteOptions{.version = 4});
  auto expect_error = [](const std::string& bytes, StatusCode code, const std::string& fragment) {
    auto r = ReadSpz(bytes, "bad.spz");
    ASSERT_FALSE(r.ok()) << fragment;
    EXPECT_EQ(r.status().code(), code) << r.status().ToString();
    EXPECT_NE(r.status().message().find("bad.spz: "), std::string::npos);
    EXPECT_NE(r.status().message().find(fragment), std::string::npos) << r.status().message();
  };
  expect_error(good.substr(0, 20), StatusCode::kCorruption, "32-byte header");
  expect_error(good.substr(0, 60), StatusCode::kCorruption, "table of contents");
  expect_error(good.substr(0, good.size() - 1), StatusCode::kCorruption, "truncated: stream 5");
  expect_error(good + "x", StatusCode::kCorruption, "1 bytes follow the last zstd stream");
  std::string streams = good;
  streams[15] = 5;
  expect_error(streams, StatusCode::kCorruption, "5 streams");
  std::string size = good;
  size[32 + 8] ^= 1;  // stream 0's uncompressed size
  expect_error(size, StatusCode::kCorruption, "stream 0 declares");
  std::string frame = good;
  frame[32 + 6 * 16] ^= 0x5a;  // the first frame's magic
  expect_error(frame, StatusCode::kCorruption, "zstd stream 0");
  std::string count = good;
  count[8] = count[9] = count[10] = static_cast<char>(0xff), count[11] = 0x7f;
  expect_error(count, StatusCode::kCorruption, "damaged header");
  // 2 M degree-3 points (130 MB of streams) declared in 20 kB of junk frames: refused before
  // anything is allocated or inflated.
  {
    const uint64_t n = 2000000;
    const uint64_t sizes[6] = {9 * n, n, 3 * n, 3 * n, 4 * n, 45 * n};
    std::string bomb = "NGSP" + Le32(4) + Le32(static_cast<uint32_t>(n)) + Bytes({3, 12, 0, 6}) +
                       Le32(32) + std::string(12, '\0');
    for (uint64_t bytes : sizes) {
      bomb += Le32(3000) + Le32(0) + Le32(static_cast<uint32_t>(bytes)) +
              Le32(static_cast<uint32_t>(bytes >> 32));
    }
    bomb += std::string(6 * 3000, 'z');
    expect_error(bomb, StatusCode::kCorruption, "refused before inflating");
  }
  std::string toc = good;
  toc[16] = 40;
  expect_error(toc, StatusCode::kCorruption, "table of contents at byte 40");
  std::string ext = good;
  ext[14] = 2;
  expect_error(ext, StatusCode::kUnsupported, "extensions");
  std::string degree = good;
  degree[12] = 4;
  expect_error(degree, StatusCode::kUnsupported, "SH degree 4");
  EXPECT_TRUE(WriteSpz(RandomCloud(15, 1, 3), "x", SpzWriteOptions{.version = 5})
                  .status()
                  .IsInvalidArgument());
}

// ---------------------------------------------------------------------------------------------
// Shared

TEST(Gaussians, DetectByContent) {
  const GaussianCloud c = RandomCloud(14, 1, 10);
  EXPECT_EQ(DetectGaussianFormat(*WriteGaussianPly(c, "x")), GaussianFormat::k3dgsPly);
  EXPECT_EQ(DetectGaussianFormat(*WriteSplat(c, "x")), GaussianFormat::kSplat);
  EXPECT_EQ(DetectGaussianFormat(*WriteSpz(c, "x")), GaussianFormat::kSpz);
  EXPECT_EQ(DetectGaussianFormat("NGSP" + Le32(4)), GaussianFormat::kSpz);
  EXPECT_EQ(DetectGaussianFormat("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                                 "property float y\nproperty float z\nend_header\n1 2 3\n"),
            GaussianFormat::kUnknown);  // points, not splats
  EXPECT_EQ(DetectGaussianFormat(Gzip("hello")), GaussianFormat::kUnknown);
  EXPECT_EQ(DetectGaussianFormat(""), GaussianFormat::kUnknown);
  EXPECT_EQ(DetectGaussianFormat(std::string(33, '\0')), GaussianFormat::kUnknown);
  EXPECT_STREQ(GaussianFormatName(GaussianFormat::kSpz), "SPZ");
  for (const std::string& bytes :
       {*WriteGaussianPly(c, "x"), *WriteSplat(c, "x"), *WriteSpz(c, "x")}) {
    auto r = ReadGaussians(bytes, "any");
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    EXPECT_EQ(r->size(), 10u);
  }
  auto r = ReadGaussians("hello", "what.bin");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().message().starts_with("what.bin: not a Gaussian-splat file"));
}

// The covariance against R S S^T R^T built by brute force: R's columns are the quaternion's
// rotations of the basis vectors (q v q*), the products written out.
TEST(Gaussians, CovarianceIsRotatedScaleSquared) {
  GaussianCloud c = RandomCloud(15, 0, 200);
  c.rotation[4 * 7] = c.rotation[4 * 7 + 1] = c.rotation[4 * 7 + 2] = c.rotation[4 * 7 + 3] = 0;
  for (size_t i = 0; i < c.size(); ++i) {
    double q[4], norm = 0;
    for (int k = 0; k < 4; ++k) q[k] = c.rotation[4 * i + k], norm += q[k] * q[k];
    if (norm == 0) q[0] = 1, norm = 1;  // a zero quaternion: the identity
    for (double& v : q) v /= std::sqrt(norm);
    auto mul = [](const double a[4], const double b[4], double out[4]) {
      out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
      out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
      out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
      out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    };
    const double conj[4] = {q[0], -q[1], -q[2], -q[3]};
    double r[3][3];
    for (int col = 0; col < 3; ++col) {
      double v[4] = {0, 0, 0, 0}, t[4], u[4];
      v[1 + col] = 1;
      mul(q, v, t);
      mul(t, conj, u);
      for (int row = 0; row < 3; ++row) r[row][col] = u[1 + row];
    }
    double s[3][3] = {};
    for (int k = 0; k < 3; ++k) s[k][k] = std::exp(double{c.scale[3 * i + k]});
    double m[3][3] = {}, sigma[3][3] = {};
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        for (int k = 0; k < 3; ++k) m[a][b] += r[a][k] * s[k][b];
      }
    }
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) {
        for (int k = 0; k < 3; ++k) sigma[a][b] += m[a][k] * m[b][k];  // M M^T
      }
    }
    const std::array<float, 6> got = c.Covariance(i);
    const double want[6] = {sigma[0][0], sigma[0][1], sigma[0][2],
                            sigma[1][1], sigma[1][2], sigma[2][2]};
    const double scale = std::max({sigma[0][0], sigma[1][1], sigma[2][2]});
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(got[k], want[k], 1e-6 * scale) << i << " " << k;
  }
  EXPECT_NEAR(Sigmoid(0), 0.5f, 0);
  EXPECT_NEAR(Sigmoid(Logit(0.3f)), 0.3f, 1e-6);
}

// The fuzzer's seed corpus (tests/formats/gaussian_fuzz_corpus): tiny valid files of each
// format. With HVDB_GAUSSIAN_CORPUS_OUT=<dir> the seeds are written there first; either way
// every file of the corpus must read, and stay under 4 KB.
TEST(GaussianCorpus, SeedsAreSmallValidFiles) {
  GaussianCloud ply3 = RandomCloud(16, 3, 1);
  GaussianCloud ply0 = RandomCloud(17, 0, 2);
  SpzWriteOptions v2, v4;
  v2.version = 2;
  v4.version = 4;
  const std::vector<std::pair<std::string, std::string>> seeds = {
      {"deg0.ply", *WriteGaussianPly(ply0, "x")},
      {"deg3.ply", *WriteGaussianPly(ply3, "x")},
      {"ascii.ply", HandPly("ascii",
                            {"x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                             "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"},
                            ply0)},
      {"three.splat", *WriteSplat(RandomCloud(18, 0, 3), "x")},
      {"v2_deg1.spz", *WriteSpz(RandomCloud(19, 1, 2), "x", v2)},
      {"v3_deg2.spz", *WriteSpz(RandomCloud(20, 2, 2), "x")},
      {"v4_deg1.spz", *WriteSpz(RandomCloud(21, 1, 3), "x", v4)},
      {"deg1.glb", *WriteGlb(RandomCloud(22, 1, 2), "x")},
  };
  if (const char* out = std::getenv("HVDB_GAUSSIAN_CORPUS_OUT")) {
    fs::create_directories(out);
    for (const auto& [name, bytes] : seeds) {
      std::ofstream(fs::path(out) / name, std::ios::binary) << bytes;
    }
  }
  size_t files = 0;
  for (const auto& entry : fs::directory_iterator(HVDB_GAUSSIAN_CORPUS)) {
    std::ifstream f(entry.path(), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    EXPECT_LT(bytes.size(), 4096u) << entry.path();
    auto r = ReadGaussians(bytes, entry.path().string());
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    ++files;
  }
  EXPECT_GE(files, seeds.size());
}

}  // namespace
}  // namespace hvdb::formats
