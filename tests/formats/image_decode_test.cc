// ReadImageFile (libpng/libjpeg) against OpenCV's imread on the same files: the same pixels,
// and clear errors for missing, truncated and foreign files.
#include "formats/image_decode.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::formats {
namespace {

namespace fs = std::filesystem;

class ImageDecodeTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("hvdb-image-decode-" + std::to_string(::getpid()));
    fs::create_directories(dir_);
    // A seeded noise image with a gradient: every sample differs.
    cv::RNG rng(7);
    image_.create(37, 53, CV_8UC3);
    rng.fill(image_, cv::RNG::UNIFORM, 0, 256);
    for (int y = 0; y < image_.rows; ++y) image_.at<cv::Vec3b>(y, 0) = cv::Vec3b(y, 2 * y, 255 - y);
  }
  void TearDown() override { fs::remove_all(dir_); }
  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  static bool Same(const cv::Mat& a, const cv::Mat& b) {
    return a.size() == b.size() && a.type() == b.type() && cv::norm(a, b, cv::NORM_INF) == 0;
  }

  fs::path dir_;
  cv::Mat image_;
};

TEST_F(ImageDecodeTest, SamePixelsAsImread) {
  cv::Mat grey;
  cv::cvtColor(image_, grey, cv::COLOR_BGR2GRAY);
  cv::Mat wide;
  image_.convertTo(wide, CV_16U, 257);
  ASSERT_TRUE(cv::imwrite(Path("c.png"), image_));
  ASSERT_TRUE(cv::imwrite(Path("g.png"), grey));
  ASSERT_TRUE(cv::imwrite(Path("w.png"), wide));
  ASSERT_TRUE(cv::imwrite(Path("c.jpg"), image_, {cv::IMWRITE_JPEG_QUALITY, 90}));
  ASSERT_TRUE(cv::imwrite(Path("c.ppm"), image_));
  ASSERT_TRUE(cv::imwrite(Path("g.pgm"), grey));
  for (const char* name : {"c.png", "g.png", "c.jpg", "c.ppm", "g.pgm"}) {
    for (bool colour : {true, false}) {
      auto got = ReadImageFile(Path(name), colour);
      ASSERT_TRUE(got.ok()) << name << ": " << got.status().ToString();
      const cv::Mat want = cv::imread(Path(name), colour ? cv::IMREAD_COLOR : cv::IMREAD_GRAYSCALE);
      if (std::string(name) == "c.jpg" || !colour) {
        // Colour conversions (YCbCr, BGR to grey) may round differently by one level.
        ASSERT_EQ(got->size(), want.size()) << name;
        ASSERT_EQ(got->type(), want.type()) << name;
        EXPECT_LE(cv::norm(*got, want, cv::NORM_INF), 1.0) << name << " colour " << colour;
      } else {
        EXPECT_TRUE(Same(*got, want)) << name;
      }
    }
  }
  // 16-bit PNG samples become their high byte.
  auto w = ReadImageFile(Path("w.png"), true);
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  EXPECT_TRUE(Same(*w, image_));
}

TEST_F(ImageDecodeTest, BadFilesAreClearErrors) {
  auto missing = ReadImageFile(Path("none.png"), true);
  EXPECT_TRUE(missing.status().IsNotFound()) << missing.status().ToString();
  std::ofstream(Path("text.png")) << "not an image at all";
  auto foreign = ReadImageFile(Path("text.png"), true);
  ASSERT_FALSE(foreign.ok());
  EXPECT_NE(foreign.status().message().find("not a PNG, JPEG or binary PGM/PPM"), std::string::npos);
  // Every truncation of each format is an error naming the file, never a crash.
  ASSERT_TRUE(cv::imwrite(Path("c.png"), image_));
  ASSERT_TRUE(cv::imwrite(Path("c.jpg"), image_));
  ASSERT_TRUE(cv::imwrite(Path("c.ppm"), image_));
  for (const char* name : {"c.png", "c.jpg", "c.ppm"}) {
    std::ifstream in(Path(name), std::ios::binary);
    const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    // (A PNG cut inside its final IEND chunk still holds every pixel: not counted.)
    const size_t last = std::string(name) == "c.png" ? bytes.size() - 13 : bytes.size() - 1;
    for (size_t n : {size_t{3}, size_t{9}, size_t{40}, bytes.size() / 2, last}) {
      std::ofstream(Path("cut"), std::ios::binary) << bytes.substr(0, n);
      auto r = ReadImageFile(Path("cut"), true);
      EXPECT_FALSE(r.ok()) << name << " cut at " << n;
      if (!r.ok()) {
        EXPECT_NE(r.status().message().find(Path("cut")), std::string::npos) << r.status().ToString();
      }
    }
  }
}

}  // namespace
}  // namespace hvdb::formats
