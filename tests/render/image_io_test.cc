// PNG (8-bit sRGB) and OpenEXR (float colour, alpha, depth) output.
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <gtest/gtest.h>

#include <cmath>

#include "render/metrics.h"
#include "render/renderer.h"
#include "tests/storage/test_util.h"

namespace hvdb::render {
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

}  // namespace
}  // namespace hvdb::render
