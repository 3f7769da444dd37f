// PSNR, SSIM and the diff image used to compare renderings.
#include "render/metrics.h"

#include <gtest/gtest.h>

#include <cmath>

namespace hvdb::render {
namespace {

TEST(MetricsTest, PsnrAndSsim) {
  Srgb8Image a;
  a.width = 32;
  a.height = 32;
  a.data.resize(32 * 32 * 3);
  for (size_t i = 0; i < a.data.size(); ++i) a.data[i] = static_cast<uint8_t>((i * 7) % 256);
  Srgb8Image b = a;
  EXPECT_TRUE(std::isinf(Psnr(a, b)));
  EXPECT_NEAR(Ssim(a, b), 1.0, 1e-12);
  for (size_t i = 0; i < b.data.size(); i += 3) b.data[i] = static_cast<uint8_t>(b.data[i] ^ 4);
  // Every third sample off by 4: MSE = 16 / 3.
  EXPECT_NEAR(Psnr(a, b), 10 * std::log10(255.0 * 255.0 * 3 / 16), 1e-9);
  EXPECT_LT(Ssim(a, b), 1.0);
  // A mask restricts both.
  std::vector<uint8_t> mask(32 * 32, 0);
  EXPECT_TRUE(std::isnan(Psnr(a, b, &mask)));
  Srgb8Image c = a;
  c.data[0] = static_cast<uint8_t>(c.data[0] + 100);
  mask.assign(32 * 32, 1);
  mask[0] = 0;
  EXPECT_TRUE(std::isinf(Psnr(a, c, &mask)));
  Srgb8Image small = a;
  small.width = 16;
  EXPECT_TRUE(std::isnan(Psnr(a, small)));
  Srgb8Image d = AbsDiff(a, c, 2);
  EXPECT_EQ(d.data[0], 200);
  EXPECT_EQ(d.data[3], 0);
}

}  // namespace
}  // namespace hvdb::render
