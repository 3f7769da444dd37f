// Gaussian-splat datasets through the real binaries: `hvdb create --gaussians`, `hvdb import`
// of a directory of 3DGS PLY, SPZ and .splat files, `hvdb export --codec 3dgs|spz|splat|glb`,
// crops with `hvdb window --codec`,
// embedded and through hvdb-server; a 3DGS PLY comes back byte for byte, the others within their
// quantisation; bad files are errors that name the file and load nothing of it.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>

#include <nlohmann/json.hpp>

#include "formats/gaussian_transform.h"
#include "formats/gaussians.h"
#include "tests/run_command.h"
#include "tests/server/server_process.h"

namespace hvdb {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;
using formats::GaussianCloud;

// n anisotropic splats of SH degree `degree`, varied opacity (seeded).
GaussianCloud MakeCloud(uint64_t seed, size_t n, int degree) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> g(0.f, 1.f);
  GaussianCloud c;
  c.sh_degree = degree;
  c.Resize(n);
  for (float& v : c.position) v = 2 * g(rng);
  for (float& v : c.scale) v = -4 + 0.7f * g(rng);
  for (float& v : c.rotation) v = g(rng);
  for (float& v : c.opacity) v = 2 * g(rng);
  for (float& v : c.sh_dc) v = g(rng);
  for (float& v : c.sh_rest) v = 0.2f * g(rng);
  return c;
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

class SplatCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string tmpl = (fs::temp_directory_path() / "hvdb_splat_cli_XXXXXX").string();
    ASSERT_NE(mkdtemp(tmpl.data()), nullptr);
    dir_ = tmpl;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  testing::SplitRun Run(const std::string& args) {
    return testing::RunInDir(dir_, "'" HVDB_CLI_PATH "' " + args);
  }
  json Json(const std::string& args) {
    testing::SplitRun r = Run(args + " --json");
    EXPECT_EQ(r.code, 0) << "hvdb " << args << "\n" << r.err;
    json j = json::parse(r.out, nullptr, false);
    EXPECT_FALSE(j.is_discarded()) << r.out;
    return j;
  }
  std::string Write(const std::string& name, const std::string& bytes) {
    const std::string path = dir_ + "/" + name;
    fs::create_directories(fs::path(path).parent_path());
    std::ofstream(path, std::ios::binary) << bytes;
    return path;
  }
  // A sequence: frame 0 a degree-3 3DGS PLY, frame 1 an SPZ (degree 1), frame 2 a .splat.
  void WriteSequence() {
    ply_ = *formats::WriteGaussianPly(MakeCloud(1, 3000, 3), "f0");
    spz_ = *formats::WriteSpz(MakeCloud(2, 1500, 1), "f1");
    splat_ = *formats::WriteSplat(MakeCloud(3, 700, 0), "f2");
    // Names that sort wrongly as text: frame_2 must come before frame_10.
    Write("seq/frame_1.ply", ply_);
    Write("seq/frame_2.spz", spz_);
    Write("seq/frame_10.splat", splat_);
  }
  void ExpectRoundTrips(const std::string& db, const std::string& out) {
    ASSERT_EQ(Run(db + " export s " + out + "_ply --codec 3dgs").code, 0);
    EXPECT_TRUE(ReadAll(dir_ + "/" + out + "_ply/s_000000.ply") == ply_);  // byte for byte
    ASSERT_EQ(Run(db + " export s " + out + "_spz --codec spz").code, 0);
    // SPZ decoded, re-coded and decoded again: the same values (its quantisation is idempotent
    // up to float rounding).
    auto a = formats::ReadSpz(spz_, "in");
    auto b = formats::ReadSpz(ReadAll(dir_ + "/" + out + "_spz/s_000001.spz"), "out");
    ASSERT_TRUE(a.ok() && b.ok());
    ASSERT_EQ(a->size(), b->size());
    EXPECT_EQ(a->sh_degree, b->sh_degree);
    for (size_t i = 0; i < a->position.size(); ++i) {
      EXPECT_NEAR(a->position[i], b->position[i], 1.0 / 4096) << i;
    }
    for (size_t i = 0; i < a->opacity.size(); ++i) {
      EXPECT_NEAR(formats::Sigmoid(a->opacity[i]), formats::Sigmoid(b->opacity[i]), 1.0 / 255);
    }
    ASSERT_EQ(Run(db + " export s " + out + "_splat --codec splat").code, 0);
    // .splat: positions exact, scales to float rounding (stored linear, kept as logs), colours
    // and the 8-bit quaternion to one step.
    auto c = formats::ReadSplat(splat_, "in");
    auto d = formats::ReadSplat(ReadAll(dir_ + "/" + out + "_splat/s_000002.splat"), "out");
    ASSERT_TRUE(c.ok() && d.ok());
    ASSERT_EQ(c->size(), d->size());
    EXPECT_EQ(c->position, d->position);
    for (size_t i = 0; i < c->scale.size(); ++i) {
      EXPECT_NEAR(c->scale[i], d->scale[i], 1e-5) << i;
    }
    for (size_t i = 0; i < c->sh_dc.size(); ++i) EXPECT_NEAR(c->sh_dc[i], d->sh_dc[i], 0.015) << i;
    for (size_t i = 0; i < c->rotation.size(); ++i) {
      EXPECT_NEAR(c->rotation[i], d->rotation[i], 1.5 / 128) << i;
    }
  }
  std::string dir_, ply_, spz_, splat_;
};

TEST_F(SplatCliTest, ImportAndExportEmbeddedAndServed) {
  WriteSequence();
  ASSERT_EQ(Run("--data emb create s --fps 30 --gaussians").code, 0);
  json imp = Json("--data emb import s --frame 0 seq");
  EXPECT_EQ(imp["points"], 3000 + 1500 + 700);
  ASSERT_EQ(imp["frames"].size(), 3u);
  EXPECT_EQ(imp["frames"][1]["file"], "seq/frame_2.spz");
  json d = Json("--data emb describe s");
  EXPECT_EQ(d["gaussians"], true);
  EXPECT_EQ(d["storage"]["gaussians"]["records"], 5200);
  ExpectRoundTrips("--data emb", "emb");

  fs::create_directories(dir_ + "/srv");
  testing::ServerProcess server(dir_ + "/srv");
  ASSERT_TRUE(server.running());
  const std::string remote = "--server 127.0.0.1:" + std::to_string(server.port());
  ASSERT_EQ(Run(remote + " create s --fps 30 --gaussians").code, 0);
  EXPECT_EQ(Json(remote + " import s --frame 0 seq")["points"], 5200);
  EXPECT_EQ(Json(remote + " describe s")["storage"]["gaussians"]["records"], 5200);
  ExpectRoundTrips(remote, "srv");
}

// GLB and SPZ version 4 exports, and crops: `hvdb window --codec 3dgs|spz|glb|splat` writes the
// splats of a box of one frame as one file, records and all.
TEST_F(SplatCliTest, GlbSpzV4AndCropsOfAFrame) {
  WriteSequence();
  ASSERT_EQ(Run("--data d create s --fps 30 --gaussians").code, 0);
  ASSERT_EQ(Run("--data d import s --frame 0 seq").code, 0);
  ASSERT_EQ(Run("--data d export s glb --codec glb --count 1").code, 0);
  auto in = formats::ReadGaussianPly(ply_, "in");
  auto glb = formats::ReadGlb(ReadAll(dir_ + "/glb/s_000000.glb"), "s_000000.glb");
  ASSERT_TRUE(in.ok() && glb.ok()) << glb.status().ToString();
  EXPECT_EQ(glb->sh_degree, 3);
  EXPECT_EQ(glb->position, in->position);  // exact: a half turn negates
  EXPECT_EQ(glb->sh_rest, in->sh_rest);
  ASSERT_EQ(Run("--data d export s v4 --codec spz --spz-version 4 --first 1 --count 1").code, 0);
  const std::string v4 = ReadAll(dir_ + "/v4/s_000001.spz");
  EXPECT_EQ(v4.substr(0, 5), std::string("NGSP\x04", 5));
  auto a = formats::ReadSpz(spz_, "in");
  auto b = formats::ReadSpz(v4, "out");
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->position, b->position);  // the same grid: SPZ's quantisation is idempotent
  EXPECT_TRUE(Run("--data d export s x --codec spz --spz-version 5").code != 0);

  // The splats of frame 0 with x >= 0, as SPZ and as a 3DGS PLY: the same splats as the file's.
  size_t want = 0;
  for (size_t i = 0; i < in->size(); ++i) want += in->position[3 * i] >= 0;
  json j = Json("--data d window s --box 0 1e9 -1e9 1e9 -1e9 1e9 0 0.001 --codec 3dgs "
                "--out crop.ply");
  EXPECT_EQ(j["points"], want);
  auto crop = formats::ReadGaussianPly(ReadAll(dir_ + "/crop.ply"), "crop.ply");
  ASSERT_TRUE(crop.ok()) << crop.status().ToString();
  ASSERT_EQ(crop->size(), want);
  EXPECT_EQ(crop->sh_degree, 3);
  for (size_t i = 0, k = 0; i < in->size(); ++i) {  // in load order: the ids ascend
    if (in->position[3 * i] < 0) continue;
    EXPECT_EQ(crop->opacity[k], in->opacity[i]);
    EXPECT_EQ(crop->sh_rest[k * 45 + 44], in->sh_rest[i * 45 + 44]);
    ++k;
  }
  ASSERT_EQ(Run("--data d window s --box 0 1e9 -1e9 1e9 -1e9 1e9 0 0.001 --codec spz "
                "--out crop.spz").code, 0);
  auto crop_spz = formats::ReadSpz(ReadAll(dir_ + "/crop.spz"), "crop.spz");
  ASSERT_TRUE(crop_spz.ok());
  EXPECT_EQ(crop_spz->size(), want);
  // Several frames, a plain dataset, a slice: clear refusals, nothing written.
  testing::SplitRun r = Run("--data d window s --box -1e9 1e9 -1e9 1e9 -1e9 1e9 0 1 --codec glb "
                            "--out all.glb");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("several frames"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ + "/all.glb"));
  ASSERT_EQ(Run("--data d create plain --fps 30").code, 0);
  r = Run("--data d window plain --box 0 1 0 1 0 1 0 1 --codec spz --out p.spz");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("not a Gaussian-splat dataset"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir_ + "/p.spz"));
}

// `hvdb import --rotate X Y Z --units-scale S` moves splat files as they load: what comes back is
// the file moved by formats::TransformCloud (the SH turned with the splats), to the bit.
TEST_F(SplatCliTest, ImportRotatesAndScalesSplats) {
  WriteSequence();
  ASSERT_EQ(Run("--data d create s --fps 30 --gaussians").code, 0);
  ASSERT_EQ(Run("--data d import s --frame 0 --rotate 180 0 90 --units-scale 0.5 "
                "seq/frame_1.ply").code, 0);
  ASSERT_EQ(Run("--data d export s out --codec 3dgs").code, 0);
  auto got = formats::ReadGaussianPly(ReadAll(dir_ + "/out/s_000000.ply"), "got");
  auto want = formats::ReadGaussianPly(ply_, "want");
  ASSERT_TRUE(got.ok() && want.ok());
  formats::Similarity m = formats::Similarity::FromEulerDegrees(180, 0, 90);
  m.scale = 0.5;
  ASSERT_TRUE(formats::TransformCloud(&*want, m, "want").ok());
  EXPECT_EQ(got->position, want->position);
  EXPECT_EQ(got->scale, want->scale);
  EXPECT_EQ(got->rotation, want->rotation);
  EXPECT_EQ(got->sh_rest, want->sh_rest);
  ASSERT_EQ(Run("--data d create plain --fps 30").code, 0);
  testing::SplitRun r = Run("--data d import plain --frame 0 --rotate 0 0 90 x.ply");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.err.find("--rotate is for splat files"), std::string::npos) << r.err;
}

// `hvdb composite --ply SPLATS` puts a splat object into every frame of a range, records and
// all, embedded and through hvdb-server: each frame exports as the file, byte for byte. A
// .splat object goes in by its name; a plain dataset refuses splats as import does.
TEST_F(SplatCliTest, CompositeKeepsTheObjectsSplats) {
  WriteSequence();
  fs::create_directories(dir_ + "/srv");
  testing::ServerProcess server(dir_ + "/srv");
  ASSERT_TRUE(server.running());
  for (const std::string& db : {std::string("--data d"),
                               "--server 127.0.0.1:" + std::to_string(server.port())}) {
    SCOPED_TRACE(db);
    ASSERT_EQ(Run(db + " create s --fps 30 --gaussians").code, 0);
    json j = Json(db + " composite s --ply seq/frame_1.ply --first-frame 4 --frames 3");
    EXPECT_EQ(j["inserted"], 3 * 3000);
    json d = Json(db + " describe s");
    EXPECT_EQ(d["storage"]["gaussians"]["records"], 3 * 3000);
    const std::string out = db == "--data d" ? "emb" : "srv";
    ASSERT_EQ(Run(db + " export s " + out + " --codec 3dgs").code, 0);
    for (int f = 4; f <= 6; ++f) {
      EXPECT_TRUE(ReadAll(dir_ + "/" + out + "/s_00000" + std::to_string(f) + ".ply") == ply_)
          << "frame " << f;
    }
    json k = Json(db + " composite s --ply seq/frame_10.splat --first-frame 9 --frames 1");
    EXPECT_EQ(k["inserted"], 700);
    ASSERT_EQ(Run(db + " create plain --fps 30").code, 0);
    testing::SplitRun r = Run(db + " composite plain --ply seq/frame_2.spz --first-frame 0 "
                              "--frames 1");
    EXPECT_EQ(r.code, 1);
    EXPECT_NE(r.err.find("holds plain points"), std::string::npos) << r.err;
  }
}

// `hvdb window --out FILE.csv` of a Gaussian-splat dataset: each line carries the splat's record
// after the point's columns, as the 3DGS PLY names them, exactly (degree 1 padded to 3).
TEST_F(SplatCliTest, CsvOfSplatsCarriesTheirRecords) {
  WriteSequence();
  ASSERT_EQ(Run("--data d create s --fps 30 --gaussians").code, 0);
  ASSERT_EQ(Run("--data d import s --frame 0 seq/frame_2.spz").code, 0);
  ASSERT_EQ(Run("--data d window s --box -1e9 1e9 -1e9 1e9 -1e9 1e9 0 0 --out all.csv").code, 0);
  std::istringstream csv(ReadAll(dir_ + "/all.csv"));
  std::string line;
  ASSERT_TRUE(std::getline(csv, line));
  std::vector<std::string> header;
  for (std::istringstream h(line); std::getline(h, line, ',');) header.push_back(line);
  ASSERT_EQ(header.size(), 20u + 11 + 45);
  EXPECT_EQ(header[20], "opacity");
  EXPECT_EQ(header[28], "f_dc_0");
  EXPECT_EQ(header.back(), "f_rest_44");
  auto in = formats::ReadSpz(spz_, "in");
  ASSERT_TRUE(in.ok());
  std::map<uint64_t, std::vector<double>> rows;  // by id: load order
  while (std::getline(csv, line)) {
    std::vector<double> v;
    std::istringstream r(line);
    for (std::string cell; std::getline(r, cell, ',');) v.push_back(cell.empty() ? 0 : std::stod(cell));
    ASSERT_EQ(v.size(), header.size());
    rows[static_cast<uint64_t>(v[0])] = v;
  }
  ASSERT_EQ(rows.size(), in->size());
  size_t i = 0;
  for (const auto& [id, v] : rows) {
    EXPECT_EQ(static_cast<float>(v[20]), in->opacity[i]);
    EXPECT_EQ(static_cast<float>(v[21]), in->scale[3 * i]);
    EXPECT_EQ(static_cast<float>(v[28]), in->sh_dc[3 * i]);
    EXPECT_EQ(static_cast<float>(v[31]), in->sh_rest[9 * i]);       // R's first coefficient
    EXPECT_EQ(static_cast<float>(v[31 + 15]), in->sh_rest[9 * i + 3]);  // G's first
    EXPECT_EQ(v[31 + 3], 0.0);  // R's degree-2 coefficients: above the file's degree
    ++i;
  }
}

TEST_F(SplatCliTest, BadFilesNameTheFileAndLoadNothingOfIt) {
  WriteSequence();
  ASSERT_EQ(Run("--data d create s --fps 30 --gaussians").code, 0);
  ASSERT_EQ(Run("--data d create plain --fps 30").code, 0);

  // A splat file into a plain dataset: refused, with what to do.
  testing::SplitRun r = Run("--data d import plain --frame 0 seq/frame_1.ply");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("seq/frame_1.ply is a 3DGS PLY file of Gaussian splats"),
            std::string::npos) << r.err;
  EXPECT_NE(r.err.find("--gaussians"), std::string::npos) << r.err;

  // A truncated SPZ, a PLY with f_rest cut short, a NaN opacity: each named, nothing loaded.
  const std::string trunc = Write("bad/trunc.spz", spz_.substr(0, spz_.size() / 2));
  r = Run("--data d import s --frame 0 " + trunc);
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("trunc.spz"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("no frame was loaded"), std::string::npos) << r.err;

  std::string ply = ply_;
  const size_t at = ply.find("property float f_rest_44\n");
  ASSERT_NE(at, std::string::npos);
  ply.erase(at, std::string("property float f_rest_44\n").size());
  r = Run("--data d import s --frame 0 " + Write("bad/rest.ply", ply));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("rest.ply"), std::string::npos) << r.err;

  std::string nan_ply = *formats::WriteGaussianPly(MakeCloud(4, 10, 0), "x");
  // Patch splat 3's opacity (the 10th float of its 17: x y z nx ny nz f_dc_0..2 opacity ...) in the written file to a NaN.
  const size_t body = nan_ply.find("end_header\n") + 11;
  const float qnan = std::nanf("");
  std::memcpy(nan_ply.data() + body + (3 * 17 + 9) * 4, &qnan, 4);
  r = Run("--data d import s --frame 0 " + Write("bad/nan.ply", nan_ply));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("nan.ply"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("splat 3: opacity"), std::string::npos) << r.err;

  // A sequence with a bad file after a good one: the error says which frames made it.
  fs::copy_file(dir_ + "/seq/frame_1.ply", dir_ + "/bad/a_0.ply");
  fs::rename(trunc, dir_ + "/bad/a_1.spz");
  fs::remove(dir_ + "/bad/rest.ply");
  fs::remove(dir_ + "/bad/nan.ply");
  r = Run("--data d import s --frame 5 bad");
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.err.find("frames 5..5 were loaded"), std::string::npos) << r.err;
  json d = Json("--data d describe s");
  EXPECT_EQ(d["points"], 3000);
  EXPECT_EQ(d["storage"]["gaussians"]["records"], 3000);  // (before the two-splat imports)
  EXPECT_EQ(Json("--data d describe plain")["points"], 0);

  // A trainer's extra vertex property is read over and named, not refused.
  std::string mip = "ply\nformat ascii 1.0\nelement vertex 2\n";
  for (const char* p : {"x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0",
                        "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "filter_3D"}) {
    mip += std::string("property float ") + p + "\n";
  }
  mip += "end_header\n0 0 0 1 0 0 2 -4 -4 -4 1 0 0 0 0.1\n1 0 0 0 1 0 2 -4 -4 -4 1 0 0 0 0.2\n";
  r = Run("--data d import s --frame 20 " + Write("mip.ply", mip));
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_NE(r.err.find("mip.ply: vertex properties not kept (hvdb stores 3DGS's own): filter_3D"),
            std::string::npos) << r.err;
  json mj = Json("--data d import s --frame 21 mip.ply");
  EXPECT_EQ(mj["frames"][0]["ignored_properties"], json::array({"filter_3D"}));

  // Options that make no sense for splats, or are malformed.
  r = Run("--data d import s --frame 0 seq --rotate 90 0");
  EXPECT_EQ(r.code, 2) << r.err;
  r = Run("--data d export s out --codec spz --temporal");
  EXPECT_EQ(r.code, 2) << r.err;
}

}  // namespace
}  // namespace hvdb
