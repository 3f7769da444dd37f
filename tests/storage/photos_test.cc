// Photos (storage/photos.h, docs/FORMAT.md "Photos"): stored per (frame, camera), replaced,
// kept across reopening, read by a follower but not written by one; a damaged file is a
// Corruption naming it; the decoder survives any truncation or flipped byte.
#include "storage/photos.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <random>

#include "storage/database.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using testing::TempDir;

Photo Make(uint16_t id, size_t bytes, uint8_t fill) {
  Photo p;
  p.camera.id = id;
  p.camera.name = "cam" + std::to_string(id);
  p.camera.width = 64;
  p.camera.height = 48;
  p.camera.fx = p.camera.fy = 50;
  p.camera.cx = 31.5;
  p.camera.cy = 23.5;
  p.camera.distortion = {0.1, -0.01, 0.001, 0.002, 0};
  p.camera.world_from_camera[3] = 0.25 * id;
  p.image.assign(bytes, static_cast<char>(fill));
  return p;
}

void ExpectSame(const Photo& a, const Photo& b) {
  EXPECT_EQ(a.camera.id, b.camera.id);
  EXPECT_EQ(a.camera.name, b.camera.name);
  EXPECT_EQ(a.camera.width, b.camera.width);
  EXPECT_EQ(a.camera.fx, b.camera.fx);
  EXPECT_EQ(a.camera.cy, b.camera.cy);
  EXPECT_EQ(a.camera.distortion, b.camera.distortion);
  EXPECT_EQ(a.camera.world_from_camera, b.camera.world_from_camera);
  EXPECT_EQ(a.image, b.image);
}

TEST(PhotosTest, StoredPerFrameAndCameraReplacedAndKept) {
  TempDir dir;
  {
    auto db = Database::Open(dir.path());
    ASSERT_TRUE(db.ok());
    DatasetInfo info;
    info.name = "p";
    auto ds = (*db)->CreateDataset(info);
    ASSERT_TRUE(ds.ok());
    EXPECT_TRUE((*ds)->Photos(0)->empty());
    ASSERT_TRUE((*ds)->PutPhoto(0, Make(2, 1000, 7)).ok());
    ASSERT_TRUE((*ds)->PutPhoto(0, Make(1, 10, 1)).ok());
    ASSERT_TRUE((*ds)->PutPhoto(3, Make(1, 20, 3)).ok());
    ASSERT_TRUE((*ds)->PutPhoto(0, Make(1, 30, 9)).ok());  // replaces camera 1's
    Photo bad = Make(4, 10, 0);
    bad.camera.fx = 0;
    EXPECT_TRUE((*ds)->PutPhoto(0, bad).IsInvalidArgument());
    EXPECT_TRUE((*ds)->PutPhoto(0, Make(5, 0, 0)).IsInvalidArgument());
  }
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("p");
  ASSERT_TRUE(ds.ok());
  auto f0 = (*ds)->Photos(0);
  ASSERT_TRUE(f0.ok()) << f0.status().ToString();
  ASSERT_EQ(f0->size(), 2u);
  ExpectSame((*f0)[0], Make(1, 30, 9));  // by camera id
  ExpectSame((*f0)[1], Make(2, 1000, 7));
  ASSERT_EQ((*ds)->Photos(3)->size(), 1u);
  EXPECT_TRUE((*ds)->Photos(1)->empty());

  // A follower reads them and may not write.
  Options fo;
  fo.follow = true;
  auto follower = Database::Open(dir.path(), fo);
  ASSERT_TRUE(follower.ok()) << follower.status().ToString();
  ASSERT_TRUE((*follower)->follower());  // the writer above holds the directory
  auto fds = (*follower)->GetDataset("p");
  ASSERT_TRUE(fds.ok());
  EXPECT_EQ((*fds)->Photos(0)->size(), 2u);
  EXPECT_EQ((*fds)->PutPhoto(0, Make(1, 5, 5)).code(), StatusCode::kNotLeader);

  // A damaged file: Corruption naming it.
  const std::string path = dir.path() + "/p/photos/" + PhotoFileName(0, 2);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(300);
    f.put('\x55');
  }
  auto damaged = (*ds)->Photos(0);
  ASSERT_FALSE(damaged.ok());
  EXPECT_TRUE(damaged.status().IsCorruption());
  EXPECT_NE(damaged.status().ToString().find(PhotoFileName(0, 2)), std::string::npos);
}

TEST(PhotosTest, DecoderRejectsEveryTruncationAndFlippedByte) {
  const std::string good = EncodePhoto(Make(7, 40, 3));
  ASSERT_TRUE(DecodePhoto(good, "x").ok());
  for (size_t n = 0; n < good.size(); ++n) {
    EXPECT_FALSE(DecodePhoto(good.substr(0, n), "x").ok()) << n;
  }
  std::mt19937 rng(5);
  for (size_t i = 0; i < good.size(); ++i) {
    std::string bad = good;
    bad[i] = static_cast<char>(bad[i] ^ (1 + rng() % 255));
    EXPECT_FALSE(DecodePhoto(bad, "x").ok()) << i;
  }
}

}  // namespace
}  // namespace hvdb
