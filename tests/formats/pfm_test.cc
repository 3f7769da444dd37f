// PFM files (formats/pfm.h): round trips, byte order, malformed files, and the orientation of a
// real Middlebury 2014 ground truth.
#include "formats/pfm.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <opencv2/imgcodecs.hpp>
#include <string>

namespace hvdb::formats {
namespace {

namespace fs = std::filesystem;

std::string TempPath(const std::string& name) {
  return (fs::temp_directory_path() / ("hvdb_pfm_test_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

TEST(Pfm, RoundTripWithInfAndRowOrder) {
  const std::string path = TempPath("a.pfm");
  cv::Mat m(2, 3, CV_32F);
  m.at<float>(0, 0) = 1.5f, m.at<float>(0, 1) = -2, m.at<float>(0, 2) = 3;
  m.at<float>(1, 0) = 4, m.at<float>(1, 1) = std::numeric_limits<float>::infinity(),
  m.at<float>(1, 2) = 6.25f;
  ASSERT_TRUE(WritePfm(path, m).ok());
  // The file: header, then the BOTTOM row first, little-endian.
  std::ifstream f(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const std::string header = "Pf\n3 2\n-1\n";
  ASSERT_EQ(bytes.size(), header.size() + 6 * 4);
  EXPECT_EQ(bytes.substr(0, header.size()), header);
  float first;
  std::memcpy(&first, bytes.data() + header.size(), 4);
  EXPECT_EQ(first, 4.0f);
  auto back = ReadPfm(path);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->type(), CV_32FC1);
  ASSERT_EQ(back->size(), m.size());
  for (int y = 0; y < 2; ++y) {
    for (int x = 0; x < 3; ++x) EXPECT_EQ(back->at<float>(y, x), m.at<float>(y, x));
  }
  // Three channels.
  cv::Mat c(4, 5, CV_32FC3);
  cv::randu(c, -100, 100);
  ASSERT_TRUE(WritePfm(path, c).ok());
  auto cb = ReadPfm(path);
  ASSERT_TRUE(cb.ok());
  ASSERT_EQ(cb->type(), CV_32FC3);
  EXPECT_EQ(cv::norm(*cb, c, cv::NORM_INF), 0.0);
  EXPECT_TRUE(WritePfm(path, cv::Mat(2, 2, CV_8U)).IsInvalidArgument());
  fs::remove(path);
}

TEST(Pfm, BigEndianFilesAreRead) {
  const std::string path = TempPath("be.pfm");
  std::ofstream f(path, std::ios::binary);
  f << "Pf\n1 1\n1.0\n";
  const unsigned char be_two[4] = {0x40, 0, 0, 0};  // 2.0f big-endian
  f.write(reinterpret_cast<const char*>(be_two), 4);
  f.close();
  auto r = ReadPfm(path);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->at<float>(0, 0), 2.0f);
  fs::remove(path);
}

TEST(Pfm, MalformedFilesGiveErrorsNamingTheFile) {
  const std::string path = TempPath("bad.pfm");
  auto write = [&](const std::string& s) { std::ofstream(path, std::ios::binary) << s; };
  auto expect_corrupt = [&](const std::string& content, const std::string& needle) {
    write(content);
    auto r = ReadPfm(path);
    ASSERT_FALSE(r.ok()) << needle;
    EXPECT_TRUE(r.status().IsCorruption()) << r.status().ToString();
    EXPECT_NE(r.status().message().find(path), std::string::npos);
    EXPECT_NE(r.status().message().find(needle), std::string::npos) << r.status().message();
  };
  expect_corrupt("P6\n2 2\n255\n", "not a PFM");
  expect_corrupt("", "not a PFM");
  expect_corrupt("Pf\n2 x\n-1\n", "width/height");
  expect_corrupt("Pf\n-2 2\n-1\n", "width/height");
  expect_corrupt("Pf\n2 2\nabc\n", "scale");
  expect_corrupt("Pf\n2 2\n0\n", "scale");
  expect_corrupt("Pf\n2 2\n-1", "not terminated");
  expect_corrupt(std::string("Pf\n2 2\n-1\n") + std::string(12, '\0'), "truncated");
  fs::remove(path);
  auto missing = ReadPfm(path);
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(missing.status().IsNotFound());
  EXPECT_NE(missing.status().message().find(path), std::string::npos);
}

// ---- Real data: Middlebury 2014, quarter size ----

const std::string kScene =
    std::string(HVDB_SHARED_DATA) + "/middlebury-2014-quarter/trainingQ/Teddy/";

TEST(Pfm, MiddleburyGroundTruthOrientation) {
  // mask0nocc is 0 exactly where the GT is inf: with the rows the wrong way up they disagree.
  auto gt = ReadPfm(kScene + "disp0GT.pfm");
  ASSERT_TRUE(gt.ok()) << gt.status().ToString();
  cv::Mat mask = cv::imread(kScene + "mask0nocc.png", cv::IMREAD_GRAYSCALE);
  ASSERT_FALSE(mask.empty());
  ASSERT_EQ(gt->size(), mask.size());
  int disagree = 0;
  for (int y = 0; y < mask.rows; ++y) {
    for (int x = 0; x < mask.cols; ++x) {
      disagree += std::isinf(gt->at<float>(y, x)) != (mask.at<uint8_t>(y, x) == 0);
    }
  }
  EXPECT_EQ(disagree, 0);
}

}  // namespace
}  // namespace hvdb::formats
