// PNG and JPEG through libpng and libjpeg (formats/image_codec.cc), differential against
// OpenCV's imgcodecs, which the served paths no longer link.
#include <gtest/gtest.h>

#include <fstream>
#include <iterator>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "formats/image_io.h"

namespace hvdb::formats {
namespace {

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

Srgb8Image Noise(uint32_t w, uint32_t h, uint32_t channels, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Srgb8Image s;
  s.width = w;
  s.height = h;
  s.channels = channels;
  s.data.resize(size_t{w} * h * channels);
  for (auto& v : s.data) v = static_cast<uint8_t>(rng());
  return s;
}

TEST(ImageCodecTest, PngRoundTripsAndOpenCvReadsWhatItWrites) {
  for (uint32_t ch : {1u, 3u, 4u}) {
    SCOPED_TRACE("channels " + std::to_string(ch));
    Srgb8Image s = Noise(37, 21, ch, ch);
    auto png = EncodePngBytes(s);
    ASSERT_TRUE(png.ok()) << png.status().ToString();
    auto back = DecodePngOrJpeg(*png, "png");
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    EXPECT_EQ(back->channels, ch);
    EXPECT_EQ(back->data, s.data);
    // OpenCV (BGR order) decodes the same pixels, and DecodeToMat gives what imdecode gives.
    std::vector<uint8_t> raw(png->begin(), png->end());
    cv::Mat cv_mat = cv::imdecode(raw, cv::IMREAD_UNCHANGED);
    cv::Mat ours = DecodeToMat(*png, /*colour=*/false);
    ASSERT_EQ(cv_mat.size(), ours.size());
    ASSERT_EQ(cv_mat.type(), ours.type());
    EXPECT_EQ(cv::norm(cv_mat, ours, cv::NORM_INF), 0);
    cv::Mat cv_colour = cv::imdecode(raw, cv::IMREAD_COLOR);
    cv::Mat ours_colour = DecodeToMat(*png, /*colour=*/true);
    ASSERT_EQ(cv_colour.type(), ours_colour.type());
    if (ch != 4) {
      EXPECT_EQ(cv::norm(cv_colour, ours_colour, cv::NORM_INF), 0);
    }
  }
}

TEST(ImageCodecTest, SixteenBitPngsKeepTheirSamples) {
  // Billboards store displacement maps as 16-bit grey PNGs: every sample as written.
  std::mt19937_64 rng(16);
  for (int type : {CV_16UC1, CV_16UC3, CV_16UC4}) {
    SCOPED_TRACE("type " + std::to_string(type));
    cv::Mat m(23, 31, type);
    for (int y = 0; y < m.rows; ++y) {
      auto* row = m.ptr<uint16_t>(y);
      for (int x = 0; x < m.cols * m.channels(); ++x) row[x] = static_cast<uint16_t>(rng());
    }
    std::vector<uint8_t> png;
    ASSERT_TRUE(cv::imencode(".png", m, png));
    const std::string bytes(png.begin(), png.end());
    cv::Mat got = DecodeToMat(bytes, /*colour=*/false);
    ASSERT_EQ(got.type(), type);
    EXPECT_EQ(cv::norm(m, got, cv::NORM_INF), 0);
    cv::Mat want_colour = cv::imdecode(png, cv::IMREAD_COLOR);
    cv::Mat got_colour = DecodeToMat(bytes, /*colour=*/true);
    ASSERT_EQ(got_colour.type(), want_colour.type());
    if (type != CV_16UC4) {
      EXPECT_LE(cv::norm(want_colour, got_colour, cv::NORM_INF), 1);
    }
  }
  std::string cut(200, '\0');
  EXPECT_TRUE(DecodeToMat(cut, false).empty());
}

TEST(ImageCodecTest, RealPngAndJpegFilesDecodeAsOpenCvDecodesThem) {
  const std::string data = HVDB_SHARED_DATA;
  for (const std::string& path :
       {data + "/opencv-stereo-chessboard/left11.jpg",
        data + "/sevenscenes-redkitchen-rgbd/rgbd-frames/frame-000150.color.png"}) {
    SCOPED_TRACE(path);
    const std::string bytes = ReadBytes(path);
    ASSERT_FALSE(bytes.empty());
    std::vector<uint8_t> raw(bytes.begin(), bytes.end());
    for (bool colour : {false, true}) {
      cv::Mat want = cv::imdecode(raw, colour ? cv::IMREAD_COLOR : cv::IMREAD_UNCHANGED);
      cv::Mat got = DecodeToMat(bytes, colour);
      ASSERT_EQ(want.size(), got.size());
      ASSERT_EQ(want.type(), got.type());
      // libjpeg-turbo under both; rounding of the colour conversion may differ by one.
      EXPECT_LE(cv::norm(want, got, cv::NORM_INF), 1);
    }
  }
}

TEST(ImageCodecTest, BadBytesAreAClearError) {
  auto r = DecodePngOrJpeg("GIF89a....", "poster.gif");
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument());
  EXPECT_NE(r.status().message().find("not a PNG or JPEG"), std::string::npos);
  auto png = EncodePngBytes(Noise(16, 16, 3, 1));
  ASSERT_TRUE(png.ok());
  std::string cut = png->substr(0, png->size() / 2);
  r = DecodePngOrJpeg(cut, "poster.png");
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("poster.png"), std::string::npos) << r.status().ToString();
  std::string jpeg = ReadBytes(std::string(HVDB_SHARED_DATA) + "/opencv-stereo-chessboard/left11.jpg");
  jpeg.resize(600);
  EXPECT_FALSE(DecodePngOrJpeg(jpeg, "photo.jpg").ok());
  EXPECT_TRUE(DecodeToMat(jpeg, true).empty());
  Srgb8Image wrong = Noise(4, 4, 3, 2);
  wrong.data.pop_back();
  EXPECT_TRUE(EncodePngBytes(wrong).status().IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb::formats
