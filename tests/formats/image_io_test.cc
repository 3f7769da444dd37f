// PNG (8-bit sRGB) and OpenEXR (float colour, alpha, depth) output.
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <gtest/gtest.h>

#include <cmath>

#include "formats/image_io.h"
#include "tests/storage/test_util.h"

namespace hvdb::formats {
namespace {

// A 4 x 3 gradient with one transparent pixel when `transparent`.
Image Gradient(bool transparent) {
  Image img;
  img.width = 4;
  img.height = 3;
  img.rgba.resize(img.pixels() * 4);
  img.coverage.assign(img.pixels(), 1);
  img.depth.resize(img.pixels());
  for (size_t i = 0; i < img.pixels(); ++i) {
    img.rgba[i * 4] = static_cast<float>(i) / 11;
    img.rgba[i * 4 + 1] = 0.5f;
    img.rgba[i * 4 + 2] = 1 - static_cast<float>(i) / 11;
    img.rgba[i * 4 + 3] = 1;
    img.depth[i] = 1.5f + static_cast<float>(i);
  }
  if (transparent) {
    for (int c = 0; c < 4; ++c) img.rgba[5 * 4 + c] *= 0.5f;  // premultiplied, alpha 0.5
    img.depth[7] = INFINITY;
  }
  return img;
}

TEST(ImageIoTest, SrgbTransferFunction) {
  EXPECT_FLOAT_EQ(SrgbToLinear(0), 0);
  EXPECT_NEAR(SrgbToLinear(1), 1, 1e-6);
  EXPECT_NEAR(SrgbToLinear(0.5f), 0.21404f, 1e-4);
  for (float v : {0.001f, 0.02f, 0.3f, 0.9f}) EXPECT_NEAR(LinearToSrgb(SrgbToLinear(v)), v, 1e-5);
}

TEST(ImageIoTest, PngRoundTrip) {
  testing::TempDir dir;
  for (bool transparent : {false, true}) {
    Image img = Gradient(transparent);
    std::string path = dir.path() + "/a.png";
    ASSERT_TRUE(WritePng(img, path).ok());
    auto back = ReadSrgb8(path);
    ASSERT_TRUE(back.ok()) << back.status().ToString();
    Srgb8Image want = ToSrgb8(img);
    EXPECT_EQ(back->channels, transparent ? 4u : 3u);
    EXPECT_EQ(back->data, want.data);
    // Straight alpha in the file: the half-transparent pixel keeps its colour.
    if (transparent) {
      EXPECT_EQ(back->data[5 * 4 + 3], 128);
      EXPECT_EQ(back->data[5 * 4 + 1], static_cast<uint8_t>(std::lround(LinearToSrgb(0.5f) * 255)));
    }
  }
  EXPECT_TRUE(WriteImage(Gradient(false), dir.path() + "/a.jpg").IsInvalidArgument());
  EXPECT_FALSE(WritePng(Image{}, dir.path() + "/b.png").ok());
  EXPECT_EQ(WritePng(Gradient(false), "/nonexistent-dir/x.png").code(), StatusCode::kIOError);
}

TEST(ImageIoTest, ExrHoldsFloatColourAlphaAndDepth) {
  testing::TempDir dir;
  Image img = Gradient(true);
  std::string path = dir.path() + "/a.exr";
  ASSERT_TRUE(WriteImage(img, path).ok());
  Imf::InputFile file(path.c_str());
  const Imf::ChannelList& ch = file.header().channels();
  for (const char* c : {"R", "G", "B", "A", "Z"}) {
    ASSERT_NE(ch.findChannel(c), nullptr) << c;
    EXPECT_EQ(ch.findChannel(c)->type, Imf::FLOAT);
  }
  std::vector<float> r(img.pixels()), a(img.pixels()), z(img.pixels());
  Imf::FrameBuffer fb;
  fb.insert("R", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(r.data()), 4, 16));
  fb.insert("A", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(a.data()), 4, 16));
  fb.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(z.data()), 4, 16));
  file.setFrameBuffer(fb);
  file.readPixels(0, 2);
  for (size_t i = 0; i < img.pixels(); ++i) {
    EXPECT_EQ(r[i], img.rgba[i * 4]);
    EXPECT_EQ(a[i], img.rgba[i * 4 + 3]);
    if (i == 7) {
      EXPECT_TRUE(std::isinf(z[i]));
    } else {
      EXPECT_EQ(z[i], img.depth[i]);
    }
  }
  auto bytes = EncodeExr(img);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(static_cast<uint8_t>((*bytes)[0]), 0x76);  // the OpenEXR magic number
  EXPECT_EQ(static_cast<uint8_t>((*bytes)[1]), 0x2f);
}

TEST(ImageIoTest, SrgbBytesAreTheTransferFunctionRounded) {
  // ToSrgb8's table-driven encoder against the formula on every value around each of the 256
  // levels' boundaries and a sweep of [0, 1]: equal, except by one level on a boundary itself,
  // where float rounding of either side decides.
  std::vector<float> values = {0.0f, 1.0f, -0.5f, 2.0f, std::nanf(""), 1e-30f, 1e-7f}, edges;
  for (int i = 0; i <= 100000; ++i) values.push_back(static_cast<float>(i) / 100000.0f);
  for (int k = 0; k <= 255; ++k) {
    float edge = SrgbToLinear((static_cast<float>(k) + 0.5f) / 255.0f);
    for (float f : {0.999f, 0.99999f, 1.00001f, 1.001f}) values.push_back(edge * f);
    edges.push_back(edge);
  }
  const size_t first_edge = values.size();
  values.insert(values.end(), edges.begin(), edges.end());
  Image img;
  img.width = static_cast<uint32_t>(values.size());
  img.height = 1;
  img.rgba.assign(img.pixels() * 4, 1.0f);
  for (size_t i = 0; i < values.size(); ++i) img.rgba[i * 4] = values[i];
  img.coverage.assign(img.pixels(), 1);
  img.depth.assign(img.pixels(), 1);
  Srgb8Image s = ToSrgb8(img);
  ASSERT_EQ(s.channels, 3u);
  for (size_t i = 0; i < values.size(); ++i) {
    float v = values[i];
    float c = std::isnan(v) ? 0.0f : std::clamp(LinearToSrgb(std::clamp(v, 0.0f, 1.0f)), 0.0f, 1.0f);
    int want = static_cast<int>(std::lround(c * 255.0f));
    int got = s.data[i * 3];
    float level = c * 255.0f;
    bool on_edge = std::abs(level - std::floor(level) - 0.5f) < 1e-4f;
    if (i >= first_edge || on_edge) {
      ASSERT_LE(std::abs(got - want), 1) << "value " << v;
    } else {
      ASSERT_EQ(got, want) << "value " << v;
    }
  }
}

TEST(ImageIoTest, ExrDecodesWhatItEncodes) {
  Image img = Gradient(true);
  auto bytes = EncodeExr(img);
  ASSERT_TRUE(bytes.ok());
  auto back = DecodeExr(*bytes);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->width, img.width);
  EXPECT_EQ(back->height, img.height);
  EXPECT_EQ(back->rgba, img.rgba);
  EXPECT_EQ(back->depth, img.depth);
  // Garbage, and a truncated file, are refused without crashing.
  EXPECT_TRUE(DecodeExr("not an exr").status().IsInvalidArgument());
  EXPECT_TRUE(DecodeExr(bytes->substr(0, bytes->size() / 2)).status().IsInvalidArgument());
  EXPECT_TRUE(DecodeExr("").status().IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb::formats
