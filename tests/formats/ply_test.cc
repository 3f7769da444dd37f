#include "formats/ply.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace hvdb::formats {
namespace {

namespace fs = std::filesystem;

const std::string kPanopticFrame =
    std::string(HVDB_SHARED_DATA) +
    "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/ptcloud_hd00000380.ply";

class PlyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_ply_test_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string Path(const std::string& name) const { return (fs::path(dir_) / name).string(); }
  void WriteFile(const std::string& path, const std::string& bytes) {
    std::ofstream out(path, std::ios::binary);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    ASSERT_TRUE(out.good());
  }

  std::string dir_;
};

// Points with every field exercised: extreme ids, all flag bits, covariances of any sign,
// normals on the octahedron's fold (where two codes encode one direction).
std::vector<Point> MakePoints(size_t n) {
  std::mt19937_64 rng(42);
  std::normal_distribution<float> gauss;
  std::uniform_real_distribution<float> pos(-50.f, 50.f);
  std::vector<Point> pts(n);
  for (size_t i = 0; i < n; ++i) {
    Point& p = pts[i];
    p.id = rng();
    p.x = pos(rng);
    p.y = pos(rng) * 1e-3f;
    p.z = pos(rng) * 1e5f;
    p.frame = static_cast<uint32_t>(rng());
    for (float& c : p.cov) c = gauss(rng) * 1e-4f;
    float n3[3] = {gauss(rng), gauss(rng), gauss(rng)};
    if (i % 5 == 1) n3[0] = 0;  // fold cases
    if (i % 7 == 2) n3[1] = -0.f;
    if (i % 11 == 3) n3[2] = -std::fabs(n3[2]);
    p.normal_oct = EncodeNormal(n3[0], n3[1], n3[2]);
    p.label = static_cast<uint32_t>(rng());
    p.r = static_cast<uint8_t>(rng());
    p.g = static_cast<uint8_t>(rng());
    p.b = static_cast<uint8_t>(rng());
    p.flags = static_cast<uint8_t>(rng());
    p.camera = static_cast<uint16_t>(rng());
  }
  pts[0].id = 0;
  pts[1].id = std::numeric_limits<uint64_t>::max();
  pts[2].normal_oct = {-19926, 32767};  // codes known to need NormalForOct's sign trick
  pts[3].normal_oct = {32767, -32767};
  pts[4].normal_oct = {0, 0};
  pts[5].x = std::numeric_limits<float>::denorm_min();
  pts[6].cov = {std::numeric_limits<float>::max(), 0, -0.f, 1e-30f, 3, 4};
  return pts;
}

TEST_F(PlyTest, BinaryRoundTripKeepsEveryField) {
  std::vector<Point> pts = MakePoints(5000);
  ASSERT_TRUE(WritePly(Path("a.ply"), pts).ok());
  Result<std::vector<Point>> back = ReadPly(Path("a.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->size(), pts.size());
  for (size_t i = 0; i < pts.size(); ++i) ASSERT_EQ((*back)[i], pts[i]) << "point " << i;
  // 70 bytes per vertex after the header.
  std::ifstream in(Path("a.ply"), std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  size_t body = all.find("end_header\n") + 11;
  EXPECT_EQ(all.size() - body, pts.size() * 70);
}

TEST_F(PlyTest, AsciiRoundTripKeepsEveryField) {
  std::vector<Point> pts = MakePoints(2000);
  ASSERT_TRUE(WritePly(Path("a.ply"), pts, /*ascii=*/true).ok());
  Result<std::vector<Point>> back = ReadPly(Path("a.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->size(), pts.size());
  for (size_t i = 0; i < pts.size(); ++i) ASSERT_EQ((*back)[i], pts[i]) << "point " << i;
}

TEST_F(PlyTest, StreamingWriterPatchesCount) {
  std::vector<Point> pts = MakePoints(40000);  // more than one internal chunk
  PlyWriter w;
  ASSERT_TRUE(w.Open(Path("s.ply")).ok());
  ASSERT_TRUE(w.Append(std::span(pts).first(3)).ok());
  ASSERT_TRUE(w.Append({}).ok());
  ASSERT_TRUE(w.Append(std::span(pts).subspan(3)).ok());
  EXPECT_EQ(w.count(), pts.size());
  ASSERT_TRUE(w.Finish().ok());
  EXPECT_FALSE(w.Append(pts).ok());  // finished
  Result<std::vector<Point>> back = ReadPly(Path("s.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(*back, pts);

  // Zero points is a valid file.
  PlyWriter empty;
  ASSERT_TRUE(empty.Open(Path("e.ply"), /*ascii=*/true).ok());
  ASSERT_TRUE(empty.Finish().ok());
  back = ReadPly(Path("e.ply"));
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_TRUE(back->empty());
}

TEST_F(PlyTest, NormalForOctReproducesCodes) {
  for (int u = -32767; u <= 32767; u += 97) {
    for (int v = -32767; v <= 32767; v += 89) {
      std::array<int16_t, 2> oct{static_cast<int16_t>(u), static_cast<int16_t>(v)};
      std::array<float, 3> n = NormalForOct(oct);
      ASSERT_EQ(EncodeNormal(n[0], n[1], n[2]), oct) << u << " " << v;
    }
  }
  for (int v : {-32767, -1, 0, 1, 32767}) {
    for (int u : {-32767, 32767}) {
      std::array<int16_t, 2> a{static_cast<int16_t>(u), static_cast<int16_t>(v)};
      std::array<int16_t, 2> b{static_cast<int16_t>(v), static_cast<int16_t>(u)};
      for (auto oct : {a, b}) {
        std::array<float, 3> n = NormalForOct(oct);
        EXPECT_EQ(EncodeNormal(n[0], n[1], n[2]), oct) << oct[0] << " " << oct[1];
      }
    }
  }
}

template <typename T>
void PutBE(std::string* s, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  if constexpr (std::endian::native == std::endian::little) std::reverse(b, b + sizeof(T));
  s->append(b, sizeof(T));
}

TEST_F(PlyTest, ReadsBigEndianWithListsAndOtherElements) {
  std::string f =
      "ply\n"
      "format binary_big_endian 1.0\n"
      "comment written by hand\n"
      "element camera 1\n"
      "property list uchar float params\n"
      "element vertex 2\n"
      "property double x\n"
      "property float y\n"
      "property float z\n"
      "property short quality\n"
      "property float nx\n"
      "property float ny\n"
      "property float nz\n"
      "property ushort red\n"
      "property uchar green\n"
      "property float blue\n"
      "property list ushort int extra\n"
      "property uint frame\n"
      "element face 2\n"
      "property list uchar int vertex_indices\n"
      "end_header\n";
  PutBE<uint8_t>(&f, 2);  // camera params
  PutBE<float>(&f, 1.5f);
  PutBE<float>(&f, 2.5f);
  for (int i = 0; i < 2; ++i) {
    PutBE<double>(&f, 1.25 + i);
    PutBE<float>(&f, -2.5f);
    PutBE<float>(&f, 1e3f * static_cast<float>(i + 1));
    PutBE<int16_t>(&f, -7);
    PutBE<float>(&f, 0.f);
    PutBE<float>(&f, i == 0 ? 1.f : 0.f);
    PutBE<float>(&f, i == 0 ? 0.f : -2.f);  // not unit length: still a normal
    PutBE<uint16_t>(&f, 65535);
    PutBE<uint8_t>(&f, 17);
    PutBE<float>(&f, 0.5f);
    PutBE<uint16_t>(&f, static_cast<uint16_t>(i));  // list of i ints
    for (int k = 0; k < i; ++k) PutBE<int32_t>(&f, 99);
    PutBE<uint32_t>(&f, 1000000u + static_cast<uint32_t>(i));
  }
  PutBE<uint8_t>(&f, 3);
  for (int32_t k : {0, 1, 0}) PutBE<int32_t>(&f, k);
  PutBE<uint8_t>(&f, 0);
  WriteFile(Path("be.ply"), f);

  Result<std::vector<Point>> pts = ReadPly(Path("be.ply"));
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  ASSERT_EQ(pts->size(), 2u);
  for (int i = 0; i < 2; ++i) {
    const Point& p = (*pts)[i];
    EXPECT_EQ(p.x, 1.25f + static_cast<float>(i));
    EXPECT_EQ(p.y, -2.5f);
    EXPECT_EQ(p.z, 1e3f * static_cast<float>(i + 1));
    EXPECT_EQ(p.frame, 1000000u + static_cast<uint32_t>(i));
    EXPECT_EQ(p.r, 255);
    EXPECT_EQ(p.g, 17);
    EXPECT_EQ(p.b, 128);  // 0.5 of full scale, rounded
    EXPECT_EQ(p.id, 0u);
    EXPECT_EQ(p.flags, kFlagHasNormal);
    std::array<float, 3> n = DecodeNormal(p.normal_oct);
    EXPECT_NEAR(n[1], i == 0 ? 1.f : 0.f, 1e-4);
    EXPECT_NEAR(n[2], i == 0 ? 0.f : -1.f, 1e-4);
  }
}

TEST_F(PlyTest, AsciiSkipsListsAndAppliesOptions) {
  WriteFile(Path("a.ply"),
            "ply\r\n"
            "format ascii 1.0\r\n"
            "element vertex 3\r\n"
            "property float x\r\n"
            "property float y\r\n"
            "property float z\r\n"
            "property list uchar int junk\r\n"
            "property float red\r\n"
            "property float green\r\n"
            "property float blue\r\n"
            "property float alpha\r\n"
            "element face 2\r\n"
            "property list uchar int vertex_indices\r\n"
            "property uchar quality\r\n"
            "end_header\r\n"
            "100 -200 +3e2 0 0 0.5 1 1\r\n"
            "1 2 3 2 7 8 0 0 0 0\r\n"
            "nan 2 3 0 1 1 1 1\r\n"
            "3 0 1 2 9\r\n"
            "4 0 1 2 2 9\r\n");
  ReadOptions opts;
  opts.scale = 0.01;
  opts.frame = 7;
  opts.default_sigma = 0.002;
  opts.skip_invalid = true;
  ReadStats stats;
  Result<std::vector<Point>> pts = ReadPly(Path("a.ply"), opts, &stats);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  ASSERT_EQ(pts->size(), 2u);  // the NaN vertex is skipped, and counted
  EXPECT_EQ(stats.vertices, 3u);
  EXPECT_EQ(stats.skipped_non_finite, 1u);
  const Point& p = (*pts)[0];
  EXPECT_FLOAT_EQ(p.x, 1.f);
  EXPECT_FLOAT_EQ(p.y, -2.f);
  EXPECT_FLOAT_EQ(p.z, 3.f);
  EXPECT_EQ(p.r, 0);
  EXPECT_EQ(p.g, 128);
  EXPECT_EQ(p.b, 255);
  EXPECT_EQ(p.frame, 7u);
  EXPECT_EQ(p.flags, 0);
  const auto s2 = static_cast<float>(0.002 * 0.002);
  EXPECT_EQ(p.cov, (std::array<float, 6>{s2, 0, 0, s2, 0, s2}));
  EXPECT_FLOAT_EQ((*pts)[1].z, 0.03f);

  opts.skip_invalid = false;  // the default: the NaN makes the read fail
  pts = ReadPly(Path("a.ply"), opts);
  ASSERT_FALSE(pts.ok());
  EXPECT_TRUE(pts.status().IsInvalidArgument()) << pts.status().ToString();
}

// Points never go missing silently: a vertex with a NaN or infinite coordinate fails the read
// with a message that says where, how many and what to do; skip_invalid reads the rest and
// counts what it left out.
TEST_F(PlyTest, NonFiniteCoordinatesFailUnlessSkipped) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n";
  WriteFile(Path("holes.ply"), header +
                                   "0 0 0\n"
                                   "1 2 3\n"
                                   "nan 0 0\n"  // vertex 2: the first bad one
                                   "4 5 6\n"
                                   "0 inf 1\n"
                                   "0 1 -inf\n");
  Result<std::vector<Point>> r = ReadPly(Path("holes.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument()) << r.status().ToString();
  const std::string& m = r.status().message();
  EXPECT_NE(m.find(Path("holes.ply") + ": 3 of 6 vertices have a NaN or infinite coordinate"),
            std::string::npos)
      << m;
  EXPECT_NE(m.find("vertex 2, x = nan"), std::string::npos) << m;
  EXPECT_NE(m.find("--skip-invalid"), std::string::npos) << m;
  EXPECT_NE(m.find("skip_invalid=True"), std::string::npos) << m;
  EXPECT_NE(m.find("the other 3"), std::string::npos) << m;

  ReadOptions opts;
  opts.skip_invalid = true;
  ReadStats stats;
  r = ReadPly(Path("holes.ply"), opts, &stats);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->size(), 3u);
  EXPECT_EQ((*r)[1].z, 3.f);
  EXPECT_EQ((*r)[2].x, 4.f);
  EXPECT_EQ(stats.vertices, 6u);
  EXPECT_EQ(stats.skipped_non_finite, 3u);

  // A clean file reads as before and says it skipped nothing.
  std::vector<Point> pts = MakePoints(20);
  ASSERT_TRUE(WritePly(Path("clean.ply"), pts).ok());
  r = ReadPly(Path("clean.ply"), opts, &stats);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->size(), 20u);
  EXPECT_EQ(stats.vertices, 20u);
  EXPECT_EQ(stats.skipped_non_finite, 0u);

  // Binary files, and a value that is finite as a double but not as the stored float: the one
  // bad vertex is named.
  std::string bin =
      "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty double x\n"
      "property double y\nproperty double z\nend_header\n";
  for (double v : {1.0, 2.0, 3.0, 1.0, 2.0, 1e300}) {
    bin.append(reinterpret_cast<const char*>(&v), 8);
  }
  if constexpr (std::endian::native == std::endian::little) {
    WriteFile(Path("big.ply"), bin);
    r = ReadPly(Path("big.ply"));
    ASSERT_FALSE(r.ok());
    EXPECT_NE(r.status().message().find("1 of 2 vertices has a NaN or infinite coordinate (the "
                                        "first: vertex 1, z = 1e+300, beyond float range)"),
              std::string::npos)
        << r.status().ToString();
    r = ReadPly(Path("big.ply"), opts, &stats);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    EXPECT_EQ(r->size(), 1u);
    EXPECT_EQ(stats.skipped_non_finite, 1u);
  }
}

TEST_F(PlyTest, ScaleAppliesToCovarianceAndForceFrame) {
  Point p;
  p.x = 100;
  p.frame = 3;
  p.cov = {1e4f, 0, 0, 2e4f, 0, 4e4f};
  p.flags = kFlagHasCovariance;
  ASSERT_TRUE(WritePly(Path("c.ply"), std::span(&p, 1)).ok());
  ReadOptions opts;
  opts.scale = 0.01;
  opts.frame = 9;
  Result<std::vector<Point>> pts = ReadPly(Path("c.ply"), opts);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  EXPECT_FLOAT_EQ((*pts)[0].x, 1.f);
  EXPECT_EQ((*pts)[0].frame, 3u);  // from the file
  EXPECT_FLOAT_EQ((*pts)[0].cov[0], 1.f);
  EXPECT_FLOAT_EQ((*pts)[0].cov[3], 2.f);
  EXPECT_FLOAT_EQ((*pts)[0].cov[5], 4.f);
  opts.force_frame = true;
  pts = ReadPly(Path("c.ply"), opts);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  EXPECT_EQ((*pts)[0].frame, 9u);
}

TEST_F(PlyTest, EmptyFaceElementIsSkipped) {
  std::string f =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
      "property float x\nproperty float y\nproperty float z\n"
      "element face 0\nproperty list uchar int vertex_indices\nend_header\n";
  for (float v : {1.f, 2.f, 3.f}) f.append(reinterpret_cast<const char*>(&v), 4);
  if constexpr (std::endian::native == std::endian::little) {
    WriteFile(Path("f.ply"), f);
    Result<std::vector<Point>> pts = ReadPly(Path("f.ply"));
    ASSERT_TRUE(pts.ok()) << pts.status().ToString();
    ASSERT_EQ(pts->size(), 1u);
    EXPECT_EQ((*pts)[0].z, 3.f);
  }
}

TEST_F(PlyTest, TruncatedFileNamesCounts) {
  std::vector<Point> pts = MakePoints(100);
  ASSERT_TRUE(WritePly(Path("points.ply"), pts).ok());
  std::ifstream in(Path("points.ply"), std::ios::binary);
  std::string all((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  size_t body = all.find("end_header\n") + 11;
  WriteFile(Path("points.ply"), all.substr(0, body + size_t{37} * 70 + 12));
  Result<std::vector<Point>> r = ReadPly(Path("points.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsCorruption()) << r.status().ToString();
  EXPECT_NE(r.status().message().find("points.ply: truncated: expected 100 vertices, file ends "
                                      "after 37"),
            std::string::npos)
      << r.status().ToString();

  ASSERT_TRUE(WritePly(Path("t.ply"), pts, /*ascii=*/true).ok());
  std::ifstream in2(Path("t.ply"), std::ios::binary);
  std::string text((std::istreambuf_iterator<char>(in2)), std::istreambuf_iterator<char>());
  size_t cut = text.find("end_header\n");
  for (int line = 0; line < 51; ++line) cut = text.find('\n', cut) + 1;
  WriteFile(Path("t.ply"), text.substr(0, cut));
  r = ReadPly(Path("t.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("expected 100 vertices, file ends after 50"),
            std::string::npos)
      << r.status().ToString();
}

TEST_F(PlyTest, HeaderErrorsNameFileAndLine) {
  WriteFile(Path("points.ply"),
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n1\n");
  Result<std::vector<Point>> r = ReadPly(Path("points.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument());
  EXPECT_NE(r.status().message().find("points.ply: header line 4: unknown property type 'flot'"),
            std::string::npos)
      << r.status().ToString();

  WriteFile(Path("b.ply"), "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n");
  r = ReadPly(Path("b.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("end_header"), std::string::npos) << r.status().ToString();

  WriteFile(Path("c.ply"), "PK\x03\x04 zip file");
  r = ReadPly(Path("c.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("not a PLY file"), std::string::npos);

  WriteFile(Path("d.ply"), "ply\nformat binary_middle_endian 1.0\nelement vertex 0\nend_header\n");
  r = ReadPly(Path("d.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("header line 2: unknown format 'binary_middle_endian'"),
            std::string::npos)
      << r.status().ToString();

  WriteFile(Path("e.ply"),
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            "end_header\n1 2\n");
  r = ReadPly(Path("e.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("no 'z' property"), std::string::npos)
      << r.status().ToString();

  WriteFile(Path("g.ply"),
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
            "property float z\nend_header\n1 2 zz\n");
  r = ReadPly(Path("g.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("vertex 0: bad value 'zz' for property 'z'"),
            std::string::npos)
      << r.status().ToString();

  r = ReadPly(Path("missing.ply"));
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsNotFound());
  EXPECT_NE(r.status().message().find("missing.ply"), std::string::npos);
}

TEST_F(PlyTest, CsvHasHeaderAndOneLinePerPoint) {
  std::vector<Point> pts = MakePoints(10);
  pts[3].flags = kFlagHasNormal;
  ASSERT_TRUE(WriteCsv(Path("p.csv"), pts).ok());
  std::ifstream in(Path("p.csv"));
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line.rfind("id,frame,x,y,z,nx,ny,nz,red,green,blue,label,camera,flags,cov_xx", 0), 0u);
  for (const Point& p : pts) {
    ASSERT_TRUE(std::getline(in, line));
    EXPECT_EQ(std::count(line.begin(), line.end(), ','), 19);
    EXPECT_EQ(line.substr(0, line.find(',')), std::to_string(p.id));
  }
  EXPECT_FALSE(std::getline(in, line));

  Result<std::unique_ptr<PointWriter>> w = OpenPointWriter(Path("x.txt"));
  ASSERT_FALSE(w.ok());
  EXPECT_TRUE(w.status().IsInvalidArgument());
  w = OpenPointWriter(Path("x.CSV"));
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  EXPECT_TRUE((*w)->Finish().ok());
}

TEST_F(PlyTest, ReadsRealPanopticFrame) {
  ASSERT_TRUE(fs::exists(kPanopticFrame)) << "test data not found: " << kPanopticFrame;
  ReadOptions opts;
  opts.scale = 0.01;  // centimetres
  opts.frame = 380;
  Result<std::vector<Point>> pts = ReadPly(kPanopticFrame, opts);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  EXPECT_GE(pts->size(), 72989u);
  EXPECT_LE(pts->size(), 75943u);
  EXPECT_EQ(pts->size(), 73091u);  // the header's count: no vertex is dropped
  float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
  size_t coloured = 0;
  for (const Point& p : *pts) {
    float v[3] = {p.x, p.y, p.z};
    for (int i = 0; i < 3; ++i) {
      lo[i] = std::min(lo[i], v[i]);
      hi[i] = std::max(hi[i], v[i]);
    }
    ASSERT_EQ(p.flags, kFlagHasNormal);
    std::array<float, 3> n = DecodeNormal(p.normal_oct);
    ASSERT_NEAR(std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), 1.f, 1e-4f);
    EXPECT_EQ(p.frame, 380u);
    EXPECT_EQ(p.id, 0u);
    EXPECT_FLOAT_EQ(p.cov[0], 0.005f * 0.005f);
    coloured += (p.r | p.g | p.b) != 0;
  }
  // Metres, y down: the person stands on y = -0.07 and reaches y = -1.73.
  EXPECT_GT(lo[0], -0.82f);
  EXPECT_LT(hi[0], -0.05f);
  EXPECT_GT(lo[1], -1.74f);
  EXPECT_LT(lo[1], -1.5f);
  EXPECT_NEAR(hi[1], -0.07f, 1e-4f);
  EXPECT_GT(lo[2], -0.73f);
  EXPECT_LT(hi[2], 0.79f);
  EXPECT_GT(coloured, pts->size() * 9 / 10);
}

}  // namespace
}  // namespace hvdb::formats
