// The picture codec (libpng/libjpeg) against OpenCV's imread and imdecode on the same files:
// the same pixels in every mode, PNGs that OpenCV reads back exactly, and clear errors for
// missing, truncated, foreign and impossible files.
#include "formats/image_codec.h"

#include <gtest/gtest.h>
#include <png.h>
#include <zlib.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::formats {
namespace {

namespace fs = std::filesystem;

class ImageCodecTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("hvdb-image-codec-" + std::to_string(::getpid()));
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

TEST_F(ImageCodecTest, SamePixelsAsImread) {
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
      auto got = ReadImageFile(Path(name), colour ? ImageMode::kColour : ImageMode::kGrey);
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
  auto w = ReadImageFile(Path("w.png"), ImageMode::kColour);
  ASSERT_TRUE(w.ok()) << w.status().ToString();
  EXPECT_TRUE(Same(*w, image_));
}

TEST_F(ImageCodecTest, BadFilesAreClearErrors) {
  auto missing = ReadImageFile(Path("none.png"), ImageMode::kColour);
  EXPECT_TRUE(missing.status().IsNotFound()) << missing.status().ToString();
  std::ofstream(Path("text.png")) << "not an image at all";
  auto foreign = ReadImageFile(Path("text.png"), ImageMode::kColour);
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
      auto r = ReadImageFile(Path("cut"), ImageMode::kAsStored);
      EXPECT_FALSE(r.ok()) << name << " cut at " << n;
      if (!r.ok()) {
        EXPECT_NE(r.status().message().find(Path("cut")), std::string::npos) << r.status().ToString();
      }
    }
  }
}

// As stored: what imread's IMREAD_UNCHANGED gives, alpha, 16-bit samples and 1-bit grey
// included.
TEST_F(ImageCodecTest, AsStoredIsImreadUnchanged) {
  cv::Mat bgra, wide, wide_alpha, grey;
  cv::cvtColor(image_, bgra, cv::COLOR_BGR2BGRA);
  cv::RNG rng(11);
  for (int y = 0; y < bgra.rows; ++y) {
    for (int x = 0; x < bgra.cols; ++x) {
      bgra.at<cv::Vec4b>(y, x)[3] = static_cast<uint8_t>(rng.uniform(0, 256));
    }
  }
  image_.convertTo(wide, CV_16U, 251);
  bgra.convertTo(wide_alpha, CV_16U, 257);
  cv::cvtColor(image_, grey, cv::COLOR_BGR2GRAY);
  ASSERT_TRUE(cv::imwrite(Path("a.png"), bgra));
  ASSERT_TRUE(cv::imwrite(Path("w.png"), wide));
  ASSERT_TRUE(cv::imwrite(Path("wa.png"), wide_alpha));
  ASSERT_TRUE(cv::imwrite(Path("bits.png"), grey > 128, {cv::IMWRITE_PNG_BILEVEL, 1}));
  ASSERT_TRUE(cv::imwrite(Path("g.jpg"), grey));
  ASSERT_TRUE(cv::imwrite(Path("c.ppm"), image_));
  for (const char* name : {"a.png", "w.png", "wa.png", "bits.png", "g.jpg", "c.ppm"}) {
    auto got = ReadImageFile(Path(name), ImageMode::kAsStored);
    ASSERT_TRUE(got.ok()) << name << ": " << got.status().ToString();
    const cv::Mat want = cv::imread(Path(name), cv::IMREAD_UNCHANGED);
    EXPECT_TRUE(Same(*got, want)) << name << ": " << got->type() << " vs " << want.type();
  }
  // Colour and grey from a file with alpha drop it, as imread does.
  auto colour = ReadImageFile(Path("a.png"), ImageMode::kColour);
  ASSERT_TRUE(colour.ok());
  EXPECT_TRUE(Same(*colour, cv::imread(Path("a.png"), cv::IMREAD_COLOR)));
}

// Encoded PNGs decode in OpenCV to the same samples: 8 and 16 bits, 1, 3 and 4 channels, in
// BGR(A) order or RGB(A) with rgb_order.
TEST_F(ImageCodecTest, EncodedPngsDecodeExactly) {
  cv::Mat bgra, wide, grey;
  cv::cvtColor(image_, bgra, cv::COLOR_BGR2BGRA);
  bgra.forEach<cv::Vec4b>(
      [](cv::Vec4b& p, const int* at) { p[3] = static_cast<uint8_t>(at[1] * 4); });
  image_.convertTo(wide, CV_16U, 263);
  cv::cvtColor(image_, grey, cv::COLOR_BGR2GRAY);
  for (const cv::Mat& m : {image_, bgra, wide, grey}) {
    auto png = EncodePngImage(m);
    ASSERT_TRUE(png.ok()) << png.status().ToString();
    const cv::Mat back =
        cv::imdecode(std::vector<uint8_t>(png->begin(), png->end()), cv::IMREAD_UNCHANGED);
    EXPECT_TRUE(Same(back, m)) << m.type();
    auto ours = DecodeImage(*png, "png", ImageMode::kAsStored);
    ASSERT_TRUE(ours.ok());
    EXPECT_TRUE(Same(*ours, m)) << m.type();
  }
  cv::Mat rgb;
  cv::cvtColor(image_, rgb, cv::COLOR_BGR2RGB);
  auto png = EncodePngImage(rgb, /*rgb_order=*/true);
  ASSERT_TRUE(png.ok());
  EXPECT_TRUE(
      Same(cv::imdecode(std::vector<uint8_t>(png->begin(), png->end()), cv::IMREAD_COLOR), image_));
  EXPECT_FALSE(EncodePngImage(cv::Mat()).ok());
  EXPECT_FALSE(EncodePngImage(cv::Mat(4, 4, CV_32FC3)).ok());
  EXPECT_FALSE(EncodePngImage(cv::Mat(4, 4, CV_8UC2)).ok());
}

// A PNG with a transparency chunk, written with libpng: grey (one transparent level) or
// palette (an alpha per entry; the picture's values index a palette of grey ramps).
void WritePngWithTrns(const std::string& path, const cv::Mat& grey, bool palette) {
  FILE* f = std::fopen(path.c_str(), "wb");
  ASSERT_NE(f, nullptr);
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png_create_info_struct(png);
  png_init_io(png, f);
  png_set_IHDR(png, info, static_cast<png_uint_32>(grey.cols), static_cast<png_uint_32>(grey.rows),
               8, palette ? PNG_COLOR_TYPE_PALETTE : PNG_COLOR_TYPE_GRAY, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  std::vector<png_color> colours(256);
  std::vector<png_byte> alphas(256);
  for (int i = 0; i < 256; ++i) {
    colours[i] = {static_cast<png_byte>(i), static_cast<png_byte>(255 - i),
                  static_cast<png_byte>(i / 2)};
    alphas[i] = static_cast<png_byte>((i * 7) & 255);
  }
  png_color_16 transparent{};
  transparent.gray = 40;
  if (palette) {
    png_set_PLTE(png, info, colours.data(), 256);
    png_set_tRNS(png, info, alphas.data(), 256, nullptr);
  } else {
    png_set_tRNS(png, info, nullptr, 0, &transparent);
  }
  png_write_info(png, info);
  for (int y = 0; y < grey.rows; ++y) png_write_row(png, grey.ptr(y));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  std::fclose(f);
}

// Transparency chunks as imread reads them: a palette's become alpha, a grey file's are
// dropped (one channel), in every mode.
TEST_F(ImageCodecTest, TransparencyChunksAsImread) {
  cv::Mat grey;
  cv::cvtColor(image_, grey, cv::COLOR_BGR2GRAY);
  WritePngWithTrns(Path("gt.png"), grey, false);
  WritePngWithTrns(Path("pt.png"), grey, true);
  for (const char* name : {"gt.png", "pt.png"}) {
    for (auto [mode, flag] : {std::pair{ImageMode::kAsStored, cv::IMREAD_UNCHANGED},
                              std::pair{ImageMode::kColour, cv::IMREAD_COLOR}}) {
      auto got = ReadImageFile(Path(name), mode);
      ASSERT_TRUE(got.ok()) << name << ": " << got.status().ToString();
      const cv::Mat want = cv::imread(Path(name), flag);
      EXPECT_TRUE(Same(*got, want)) << name << " flag " << flag << ": " << got->type() << " vs "
                                    << want.type();
    }
  }
}

// A JPEG's EXIF orientation turns it upright for colour and grey (as imdecode), not as stored.
TEST_F(ImageCodecTest, ExifOrientationAsImdecode) {
  std::vector<uint8_t> jpg;
  ASSERT_TRUE(cv::imencode(".jpg", image_, jpg, {cv::IMWRITE_JPEG_QUALITY, 95}));
  for (int orientation = 1; orientation <= 8; ++orientation) {
    // APP1 after SOI: "Exif\0\0", a little-endian TIFF header, one IFD entry (0x0112, SHORT).
    const uint8_t o = static_cast<uint8_t>(orientation);
    const std::vector<uint8_t> app1 = {0xFF, 0xE1, 0x00, 0x22, 'E', 'x', 'i', 'f', 0, 0,
                                       'I', 'I', 0x2A, 0x00, 0x08, 0, 0, 0, 0x01, 0x00,
                                       0x12, 0x01, 0x03, 0x00, 0x01, 0, 0, 0, o, 0, 0, 0,
                                       0, 0, 0, 0};
    const std::string bytes = std::string(jpg.begin(), jpg.begin() + 2) +
                              std::string(app1.begin(), app1.end()) +
                              std::string(jpg.begin() + 2, jpg.end());
    const std::vector<uint8_t> file(bytes.begin(), bytes.end());
    auto colour = DecodeImage(bytes, "exif.jpg", ImageMode::kColour);
    ASSERT_TRUE(colour.ok()) << colour.status().ToString();
    const cv::Mat want = cv::imdecode(file, cv::IMREAD_COLOR);
    ASSERT_EQ(colour->size(), want.size()) << "orientation " << orientation;
    EXPECT_LE(cv::norm(*colour, want, cv::NORM_INF), 1.0) << "orientation " << orientation;
    auto stored = DecodeImage(bytes, "exif.jpg", ImageMode::kAsStored);
    ASSERT_TRUE(stored.ok());
    EXPECT_EQ(stored->size(), image_.size());
  }
}

// IHDR's CRC (bytes 29..32) over its type and data (12..28), after an edit of its fields.
void FixIhdrCrc(std::string* png) {
  const uLong crc = crc32(0, reinterpret_cast<const Bytef*>(png->data() + 12), 17);
  for (int i = 0; i < 4; ++i) (*png)[29 + i] = static_cast<char>((crc >> (24 - 8 * i)) & 0xFF);
}

// A small file declaring a huge picture is refused before the picture is allocated: PNG by what
// its bytes can inflate to, everything by the side limit.
TEST_F(ImageCodecTest, ImpossibleSizesAreRefused) {
  auto png = EncodePngImage(cv::Mat(64, 64, CV_16UC4, cv::Scalar::all(0)));
  ASSERT_TRUE(png.ok());
  std::string big = *png;
  // IHDR's width and height (bytes 16..23, big-endian) say 16000 x 16000.
  const char side[4] = {0, 0, 0x3e, static_cast<char>(0x80)};
  big.replace(16, 4, side, 4);
  big.replace(20, 4, side, 4);
  FixIhdrCrc(&big);
  auto r = DecodeImage(big, "big.png", ImageMode::kAsStored);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("more than the file's bytes can hold"), std::string::npos)
      << r.status().ToString();
  const char huge[4] = {0, 0, 0x50, 0};  // 20480
  big.replace(16, 4, huge, 4);
  FixIhdrCrc(&big);
  r = DecodeImage(big, "huge.png", ImageMode::kColour);
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("over the limit of 16384 a side"), std::string::npos)
      << r.status().ToString();
}

}  // namespace
}  // namespace hvdb::formats
