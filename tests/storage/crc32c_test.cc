#include "storage/crc32c.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

namespace hvdb::crc32c {
namespace {

TEST(Crc32cTest, KnownVectors) {
  // RFC 3720 (iSCSI) B.4 test vectors.
  std::string zeros(32, '\0');
  EXPECT_EQ(Value(zeros.data(), zeros.size()), 0x8a9136aau);
  std::string ones(32, '\xff');
  EXPECT_EQ(Value(ones.data(), ones.size()), 0x62a8ab43u);
  std::string inc(32, '\0');
  for (int i = 0; i < 32; ++i) inc[static_cast<size_t>(i)] = static_cast<char>(i);
  EXPECT_EQ(Value(inc.data(), inc.size()), 0x46dd794eu);
  EXPECT_EQ(Value("123456789", 9), 0xe3069283u);
}

TEST(Crc32cTest, HardwareMatchesPortable) {
  std::mt19937_64 rng(7);
  for (size_t n : {0u, 1u, 7u, 8u, 9u, 63u, 4096u, 65537u}) {
    std::string s(n, '\0');
    for (char& c : s) c = static_cast<char>(rng());
    EXPECT_EQ(Value(s.data(), n), ExtendPortable(0, s.data(), n)) << n;
  }
}

TEST(Crc32cTest, ExtendEqualsWhole) {
  std::string s = "hello hypervolume";
  uint32_t part = Extend(Value(s.data(), 5), s.data() + 5, s.size() - 5);
  EXPECT_EQ(part, Value(s.data(), s.size()));
}

TEST(Crc32cTest, MaskRoundTrip) {
  uint32_t c = Value("foo", 3);
  EXPECT_NE(Mask(c), c);
  EXPECT_EQ(Unmask(Mask(c)), c);
}

}  // namespace
}  // namespace hvdb::crc32c
