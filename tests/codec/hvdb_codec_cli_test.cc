// The hvdb-codec command line, run as a user would: encode, info, decode (whole and a
// progressive prefix), compare, temporal coding with --reference, and its errors.
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "formats/ply.h"
#include "tests/run_command.h"

namespace {

namespace fs = std::filesystem;

const std::string kFrames = HVDB_SHARED_DATA "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/";

using CliRun = hvdb::testing::CommandRun;

CliRun Cli(const std::string& args) {
  return hvdb::testing::RunCommand(std::string(HVDB_CODEC_CLI) + " " + args);
}

class HvdbCodecCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string t = (fs::temp_directory_path() / "hvdb_codec_cli_XXXXXX").string();
    ASSERT_NE(mkdtemp(t.data()), nullptr);
    dir_ = t;
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string P(const std::string& n) const { return dir_ + "/" + n; }
  std::string dir_;
};

TEST_F(HvdbCodecCliTest, EncodeDecodeInfoCompare) {
  const std::string f380 = kFrames + "ptcloud_hd00000380.ply";
  CliRun r = Cli("encode " + f380 + " " + P("a.hv7") + " --qp 12 --qc 7 --qn 9 --progressive");
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("bits/point"), std::string::npos) << r.out;
  r = Cli("info " + P("a.hv7"));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("progressive"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("qp 12  qc 7  qn 9"), std::string::npos) << r.out;
  r = Cli("decode " + P("a.hv7") + " " + P("a.ply"));
  ASSERT_EQ(r.code, 0) << r.out;
  auto orig = hvdb::formats::ReadPly(f380), dec = hvdb::formats::ReadPly(P("a.ply"));
  ASSERT_TRUE(orig.ok() && dec.ok());
  EXPECT_EQ(orig->size(), dec->size());
  r = Cli("compare " + f380 + " " + P("a.ply"));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("position PSNR"), std::string::npos) << r.out;
  // A prefix (past the geometry, which comes first): fewer points, still a valid PLY.
  r = Cli("decode " + P("a.hv7") + " " + P("half.ply") + " --bytes " +
          std::to_string(fs::file_size(P("a.hv7")) * 3 / 4));
  ASSERT_EQ(r.code, 0) << r.out;
  auto half = hvdb::formats::ReadPly(P("half.ply"));
  ASSERT_TRUE(half.ok());
  EXPECT_LT(half->size(), orig->size());
  EXPECT_GT(half->size(), orig->size() / 16);
}

TEST_F(HvdbCodecCliTest, TemporalWithReference) {
  CliRun r = Cli("encode " + kFrames + "ptcloud_hd00000380.ply " + P("f0.hv7") + " --qp 11");
  ASSERT_EQ(r.code, 0) << r.out;
  ASSERT_EQ(Cli("decode " + P("f0.hv7") + " " + P("f0.ply")).code, 0);
  r = Cli("encode " + kFrames + "ptcloud_hd00000381.ply " + P("f1.hv7") + " --qp 11 --reference " +
          P("f0.ply"));
  ASSERT_EQ(r.code, 0) << r.out;
  EXPECT_NE(r.out.find("temporal"), std::string::npos) << r.out;
  r = Cli("decode " + P("f1.hv7") + " " + P("f1.ply"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("reference"), std::string::npos) << r.out;
  // The reference may be the intra stream itself.
  r = Cli("decode " + P("f1.hv7") + " " + P("f1.ply") + " --reference " + P("f0.hv7"));
  EXPECT_EQ(r.code, 0) << r.out;
}

TEST_F(HvdbCodecCliTest, Errors) {
  EXPECT_EQ(Cli("encode").code, 2);
  EXPECT_EQ(Cli("encode " + kFrames + "ptcloud_hd00000380.ply " + P("x") + " --qp 40").code, 2);
  CliRun r = Cli("encode " + kFrames + "ptcloud_hd00000380.ply " + P("x") + " --attributes foo");
  EXPECT_EQ(r.code, 2);
  EXPECT_NE(r.out.find("unknown attribute"), std::string::npos) << r.out;
  std::ofstream(P("junk.hv7")) << "not a stream";
  r = Cli("decode " + P("junk.hv7") + " " + P("out.ply"));
  EXPECT_EQ(r.code, 1);
  EXPECT_NE(r.out.find("not an hvdb7 point stream"), std::string::npos) << r.out;
  EXPECT_FALSE(fs::exists(P("out.ply")));
  r = Cli("--help");
  EXPECT_EQ(r.code, 0);
  EXPECT_NE(r.out.find("encode"), std::string::npos);
}

}  // namespace
