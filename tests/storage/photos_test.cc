// Photos (storage/photos.h, docs/FORMAT.md "Photos"): stored per (frame, camera), replaced,
// kept across reopening, read by a follower but not written by one; a damaged file is a
// Corruption naming it; the decoder survives any truncation or flipped byte.
#include "storage/photos.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <limits>
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
  EXPECT_EQ(a.billboard.scale, b.billboard.scale);
  EXPECT_EQ(a.billboard.plane, b.billboard.plane);
  EXPECT_EQ(a.billboard.displacement, b.billboard.displacement);
  EXPECT_EQ(a.billboard.alpha, b.billboard.alpha);
}

Photo WithBillboard(Photo p) {
  p.billboard.scale = 12.5;
  p.billboard.plane = {0.01, -0.02, 9.5};
  p.billboard.displacement.assign(33, '\x11');
  p.billboard.alpha.assign(17, '\x22');
  return p;
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
  for (const Photo& photo : {Make(7, 40, 3), WithBillboard(Make(7, 40, 3))}) {
    const std::string good = EncodePhoto(photo);
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
}

// Version 2 (docs/FORMAT.md "Photo"): a photo with its billboard round-trips through the
// dataset; a photo without one stays version 1; a billboard without a scale or maps is refused.
TEST(PhotosTest, BillboardsRoundTripAndAreChecked) {
  const Photo plain = Make(3, 20, 1), board = WithBillboard(Make(4, 20, 2));
  EXPECT_EQ(EncodePhoto(plain)[8], 1);
  EXPECT_EQ(EncodePhoto(board)[8], 2);
  auto decoded = DecodePhoto(EncodePhoto(board), "x");
  ASSERT_TRUE(decoded.ok()) << decoded.status().ToString();
  ExpectSame(board, *decoded);
  TempDir dir;
  auto db = Database::Open(dir.path());
  ASSERT_TRUE(db.ok());
  DatasetInfo info;
  info.name = "v";
  auto ds = (*db)->CreateDataset(info);
  ASSERT_TRUE(ds.ok());
  ASSERT_TRUE((*ds)->PutPhoto(0, board).ok());
  ASSERT_TRUE((*ds)->PutPhoto(0, plain).ok());
  auto photos = (*ds)->Photos(0);
  ASSERT_TRUE(photos.ok());
  ASSERT_EQ(photos->size(), 2u);
  ExpectSame(plain, (*photos)[0]);
  ExpectSame(board, (*photos)[1]);
  Photo bad = board;
  bad.billboard.alpha.clear();
  EXPECT_TRUE((*ds)->PutPhoto(0, bad).IsInvalidArgument());
  bad = board;
  bad.billboard.scale = -1;
  EXPECT_TRUE((*ds)->PutPhoto(0, bad).IsInvalidArgument());
  bad = board;
  bad.billboard.plane[1] = std::numeric_limits<double>::infinity();
  EXPECT_TRUE((*ds)->PutPhoto(0, bad).IsInvalidArgument());
}

}  // namespace
}  // namespace hvdb
