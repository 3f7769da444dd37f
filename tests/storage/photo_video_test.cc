// The video tier of photos (storage/photo_video.h, media/photo_video.cc, docs/FORMAT.md "Photo
// video run"): the real Panoptic Kinect views coded per camera read back within the PSNR bound,
// the videos decode with ffprobe and ffmpeg, damage is a Corruption naming the file while other
// cameras still read, a PutPhoto afterwards replaces its frame, and a crash at any point of a
// compaction loses no photo.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "media/media.h"
#include "storage/database.h"
#include "storage/dataset_impl.h"
#include "storage/photo_video.h"
#include "tests/storage/fault_env.h"
#include "tests/storage/test_util.h"

namespace hvdb {
namespace {

using testing::TempDir;

const std::string kPanoptic =
    std::string(HVDB_SHARED_DATA) + "/cmu-panoptic-kinoptic-171026-pose3/kinectImgs";

std::string ReadFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

// Y-PSNR (BT.601 luma) of image file b against image file a.
double LumaPsnr(const std::string& a, const std::string& b) {
  cv::Mat ma = cv::imdecode(cv::Mat(1, int(a.size()), CV_8U, const_cast<char*>(a.data())), cv::IMREAD_COLOR);
  cv::Mat mb = cv::imdecode(cv::Mat(1, int(b.size()), CV_8U, const_cast<char*>(b.data())), cv::IMREAD_COLOR);
  EXPECT_FALSE(ma.empty());
  EXPECT_FALSE(mb.empty());
  if (ma.empty() || mb.empty() || ma.size() != mb.size()) return 0;
  double sse = 0;
  for (int y = 0; y < ma.rows; ++y) {
    for (int x = 0; x < ma.cols; ++x) {
      const cv::Vec3b p = ma.at<cv::Vec3b>(y, x), q = mb.at<cv::Vec3b>(y, x);
      const double d = (0.114 * p[0] + 0.587 * p[1] + 0.299 * p[2]) -
                       (0.114 * q[0] + 0.587 * q[1] + 0.299 * q[2]);
      sse += d * d;
    }
  }
  const double mse = sse / (double(ma.rows) * ma.cols);
  return mse <= 1e-10 ? 100 : 10 * std::log10(255.0 * 255.0 / mse);
}

// Camera `c`'s photo of frame `f`, with calibration scalars that differ per frame (they must
// come back exactly).
Photo MakePhoto(uint16_t c, uint32_t f, std::string image, uint32_t w, uint32_t h) {
  Photo p;
  p.camera.id = c;
  p.camera.name = "50_" + std::to_string(c + 1);
  p.camera.width = w;
  p.camera.height = h;
  p.camera.fx = 1050.5 + c;
  p.camera.fy = 1049.25 + f * 0.001;
  p.camera.cx = w / 2.0 - 0.5;
  p.camera.cy = h / 2.0 + 0.125;
  p.camera.distortion = {0.01 * c, -0.002, 0.0001 * f, 0, 0.3};
  p.camera.world_from_camera[3] = 0.1 * c + 0.001 * f;
  if (f % 2 == 1) {  // every other frame has a billboard (its maps stay exact)
    p.billboard.scale = 100.0 + f;
    p.billboard.plane = {0.001 * c, -0.002, 3.5};
    p.billboard.displacement = "disp" + std::to_string(f);
    p.billboard.alpha = "alpha" + std::to_string(c);
  }
  p.image = std::move(image);
  return p;
}

void ExpectSameMeta(const Photo& a, const Photo& b) {
  EXPECT_EQ(a.camera.id, b.camera.id);
  EXPECT_EQ(a.camera.name, b.camera.name);
  EXPECT_EQ(a.camera.width, b.camera.width);
  EXPECT_EQ(a.camera.fx, b.camera.fx);
  EXPECT_EQ(a.camera.fy, b.camera.fy);
  EXPECT_EQ(a.camera.cy, b.camera.cy);
  EXPECT_EQ(a.camera.distortion, b.camera.distortion);
  EXPECT_EQ(a.camera.world_from_camera, b.camera.world_from_camera);
  EXPECT_EQ(a.billboard.scale, b.billboard.scale);
  EXPECT_EQ(a.billboard.plane, b.billboard.plane);
  EXPECT_EQ(a.billboard.displacement, b.billboard.displacement);
  EXPECT_EQ(a.billboard.alpha, b.billboard.alpha);
}

// A generated view: a smooth gradient with a moving disc and a little noise, as PNG.
std::string Synthetic(int w, int h, uint32_t f, uint16_t c) {
  cv::Mat m(h, w, CV_8UC3);
  std::mt19937 rng(f * 31 + c);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const int n = int(rng() % 5) - 2;
      m.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(x * 255 / w + n),
                                        cv::saturate_cast<uint8_t>(y * 255 / h + n),
                                        cv::saturate_cast<uint8_t>(128 + 40 * c + n));
    }
  }
  cv::circle(m, cv::Point(10 + 6 * int(f), h / 2), h / 5, cv::Scalar(30, 200, 90), cv::FILLED);
  std::vector<uint8_t> buf;
  cv::imencode(".png", m, buf);
  return std::string(buf.begin(), buf.end());
}

int Shell(const std::string& cmd, std::string* out = nullptr) {
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (p == nullptr) return -1;
  char buf[4096];
  size_t n;
  std::string s;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) s.append(buf, n);
  const int rc = pclose(p);
  if (out != nullptr) *out = s;
  return rc;
}

std::vector<std::string> Files(const std::string& dir, const std::string& ext) {
  std::vector<std::string> out;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    if (e.path().extension() == ext) out.push_back(e.path().string());
  }
  std::sort(out.begin(), out.end());
  return out;
}

// The video of camera c's run over [a, b] (its name ends in the video's CRC).
std::string RunVideo(const std::string& dir, uint32_t a, uint32_t b, uint16_t c) {
  const std::string prefix = PhotoVideoIndexName(a, b, c).substr(0, 23) + "-";
  std::string found;
  for (const std::string& f : Files(dir, ".ivf")) {
    if (std::filesystem::path(f).filename().string().rfind(prefix, 0) == 0) {
      EXPECT_TRUE(found.empty()) << "two videos of one run: " << found << " " << f;
      found = f;
    }
  }
  EXPECT_FALSE(found.empty()) << prefix;
  return found;
}

class PhotoVideoTest : public ::testing::Test {
 protected:
  void SetUp() override { media::InstallPhotoVideoCodec(); }
  std::shared_ptr<Dataset> Open(Env* env = nullptr) {
    ds_.reset();
    db_.reset();
    Options o;
    o.env = env;
    auto db = Database::Open(dir_.path() + "/db", o);
    EXPECT_TRUE(db.ok()) << db.status().ToString();
    db_ = std::move(*db);
    if (db_->ListDatasets().empty()) {
      DatasetInfo info;
      info.name = "pv";
      EXPECT_TRUE(db_->CreateDataset(info).ok());
    }
    ds_ = *db_->GetDataset("pv");
    return ds_;
  }
  std::string PhotoDir() const { return dir_.path() + "/db/pv/photos"; }

  TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
};

TEST_F(PhotoVideoTest, PanopticViewsReadBackWithinTheBoundAndDecodeWithFfmpeg) {
  Open();
  std::map<std::pair<uint16_t, uint32_t>, Photo> put;
  uint64_t jpeg_bytes = 0;
  for (uint16_t c = 0; c < 10; ++c) {
    char cam[16];
    std::snprintf(cam, sizeof cam, "50_%02u", unsigned(c + 1));
    for (uint32_t f = 0; f < 16; ++f) {
      char name[64];
      std::snprintf(name, sizeof name, "/%s/%s_%08u.jpg", cam, cam, 380 + f);
      std::string jpeg = ReadFile(kPanoptic + name);
      ASSERT_FALSE(jpeg.empty()) << kPanoptic + name;
      jpeg_bytes += jpeg.size();
      Photo p = MakePhoto(c, f, std::move(jpeg), 1920, 1080);
      ASSERT_TRUE(ds_->PutPhoto(f, p).ok());
      put[{c, f}] = std::move(p);
    }
  }
  auto info = ds_->CompactPhotos(0, 15);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 10u);
  EXPECT_EQ(info->photo_pictures, 160u);
  EXPECT_EQ(info->photo_bytes_before, jpeg_bytes);
  EXPECT_GE(info->photo_min_psnr, kPhotoVideoMinPsnr);
  // The target: at least 30 % fewer bytes than the recorded per-frame JPEGs.
  EXPECT_LT(double(info->photo_bytes_after), 0.7 * double(jpeg_bytes));
  EXPECT_TRUE(Files(PhotoDir(), ".photo").empty());
  ASSERT_EQ(Files(PhotoDir(), ".ivf").size(), 10u);
  ASSERT_EQ(Files(PhotoDir(), ".pvx").size(), 10u);

  // Reopened: every frame's 10 photos, exact calibration, every picture within the bound.
  Open();
  double worst = 100;
  for (uint32_t f = 0; f < 16; ++f) {
    auto photos = ds_->Photos(f);
    ASSERT_TRUE(photos.ok()) << photos.status().ToString();
    ASSERT_EQ(photos->size(), 10u);
    for (const Photo& p : *photos) {
      const Photo& orig = put[{p.camera.id, f}];
      ExpectSameMeta(orig, p);
      const double psnr = LumaPsnr(orig.image, p.image);
      EXPECT_GE(psnr, kPhotoVideoMinPsnr) << "camera " << p.camera.id << " frame " << f;
      worst = std::min(worst, psnr);
    }
  }
  std::printf("[ photo video ] 160 Panoptic views: %.2f MiB JPEG -> %.2f MiB AV1 (%.3f), "
              "worst Y-PSNR %.2f dB\n", jpeg_bytes / 1048576.0, info->photo_bytes_after / 1048576.0,
              double(info->photo_bytes_after) / double(jpeg_bytes), worst);

  // Standard files: ffprobe sees one AV1 stream of 16 pictures, ffmpeg decodes them cleanly.
  for (const std::string& video : Files(PhotoDir(), ".ivf")) {
    std::string out;
    ASSERT_EQ(Shell(std::string(HVDB_FFPROBE) + " -v error -count_frames -select_streams v:0 "
                  "-show_entries stream=codec_name,width,height,nb_read_frames -of csv=p=0 " + video,
                  &out), 0) << out;
    EXPECT_EQ(out, "av1,1920,1080,16\n") << video;
    ASSERT_EQ(Shell(std::string(HVDB_FFMPEG) + " -v error -xerror -i " + video + " -f null -", &out), 0)
        << out;
    EXPECT_EQ(out, "") << video;
  }

  // Compacting again changes nothing: each camera is one run already.
  auto again = ds_->CompactPhotos(0, 15);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->photo_runs, 0u);
  EXPECT_EQ(again->photo_already, 10u);
}

TEST_F(PhotoVideoTest, PutPhotoAfterCompactionReplacesItsFrame) {
  Open();
  std::map<std::pair<uint16_t, uint32_t>, std::string> images;
  for (uint16_t c = 0; c < 2; ++c) {
    for (uint32_t f = 0; f < 4; ++f) {
      char name[64];
      std::snprintf(name, sizeof name, "/50_%02u/50_%02u_%08u.jpg", unsigned(c + 1),
                    unsigned(c + 1), 380 + f);
      images[{c, f}] = ReadFile(kPanoptic + name);
      ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(c, f, images[{c, f}], 1920, 1080)).ok());
    }
  }
  ASSERT_TRUE(ds_->CompactPhotos(0, 3).ok());
  // Frame 2 of camera 1 gets another picture (a later frame's) and other calibration.
  std::string replacement = ReadFile(kPanoptic + "/50_02/50_02_00000395.jpg");
  Photo edited = MakePhoto(1, 2, replacement, 1920, 1080);
  edited.camera.fx = 999.5;
  ASSERT_TRUE(ds_->PutPhoto(2, edited).ok());
  auto photos = ds_->Photos(2);
  ASSERT_TRUE(photos.ok()) << photos.status().ToString();
  ASSERT_EQ(photos->size(), 2u);
  EXPECT_EQ((*photos)[1].image, replacement);  // the per-frame file wins, exactly
  EXPECT_EQ((*photos)[1].camera.fx, 999.5);
  EXPECT_GE(LumaPsnr(images[{0, 2}], (*photos)[0].image), kPhotoVideoMinPsnr);

  // Compacting again folds the edit into camera 1's run; camera 0 is left as it is.
  auto info = ds_->CompactPhotos(0, 3);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 1u);
  EXPECT_EQ(info->photo_already, 1u);
  EXPECT_TRUE(Files(PhotoDir(), ".photo").empty());
  EXPECT_EQ(Files(PhotoDir(), ".ivf").size(), 2u);  // camera 1's old video is gone
  Open();
  for (uint32_t f = 0; f < 4; ++f) {
    auto got = ds_->Photos(f);
    ASSERT_TRUE(got.ok()) << got.status().ToString();
    ASSERT_EQ(got->size(), 2u);
    const std::string& want = f == 2 ? replacement : images[{1, f}];
    EXPECT_GE(LumaPsnr(want, (*got)[1].image), kPhotoVideoMinPsnr - 0.5) << "frame " << f;
    EXPECT_EQ((*got)[1].camera.fx, f == 2 ? 999.5 : 1051.5);
  }
}

TEST_F(PhotoVideoTest, DamagedVideoIsCorruptionNamingItOtherCamerasStillRead) {
  Open();
  for (uint16_t c = 0; c < 3; ++c) {
    for (uint32_t f = 0; f < 4; ++f) {
      ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(c, f, Synthetic(96, 72, f, c), 96, 72)).ok());
    }
  }
  ASSERT_TRUE(ds_->CompactPhotos(0, 3).ok());
  const std::string video = RunVideo(PhotoDir(), 0, 3, 1);
  std::string bytes = ReadFile(video);
  ASSERT_GT(bytes.size(), 100u);
  bytes[bytes.size() / 2] ^= 0x5A;
  std::ofstream(video, std::ios::binary | std::ios::trunc) << bytes;
  Open();
  auto photos = ds_->Photos(2);
  ASSERT_FALSE(photos.ok());
  EXPECT_TRUE(photos.status().IsCorruption()) << photos.status().ToString();
  EXPECT_NE(photos.status().message().find(video), std::string::npos) << photos.status().ToString();
  for (uint16_t c : {0, 2}) {
    auto p = ds_->impl()->PhotoOf(2, c);
    ASSERT_TRUE(p.ok()) << p.status().ToString();
    ASSERT_TRUE(p->has_value());
    EXPECT_GE(LumaPsnr(Synthetic(96, 72, 2, c), (*p)->image), kPhotoVideoMinPsnr);
  }
  // A damaged index too.
  const std::string index = PhotoDir() + "/" + PhotoVideoIndexName(0, 3, 2);
  std::string ib = ReadFile(index);
  ib[20] ^= 1;
  std::ofstream(index, std::ios::binary | std::ios::trunc) << ib;
  auto p2 = ds_->impl()->PhotoOf(1, 2);
  ASSERT_FALSE(p2.ok());
  EXPECT_TRUE(p2.status().IsCorruption());
  EXPECT_NE(p2.status().message().find(index), std::string::npos);
}

TEST_F(PhotoVideoTest, BadRequestsWriteNothing) {
  Open();
  ASSERT_TRUE(ds_->PutPhoto(0, MakePhoto(0, 0, Synthetic(80, 64, 0, 0), 80, 64)).ok());
  auto r = ds_->CompactPhotos(5, 2);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument());
  EXPECT_NE(r.status().message().find("first <= last"), std::string::npos);
  // An image the codec cannot decode: nothing written, the photo still there.
  ASSERT_TRUE(ds_->PutPhoto(1, MakePhoto(0, 1, "not an image", 80, 64)).ok());
  r = ds_->CompactPhotos(0, 1);
  ASSERT_FALSE(r.ok());
  EXPECT_TRUE(r.status().IsInvalidArgument()) << r.status().ToString();
  EXPECT_NE(r.status().message().find("camera 0"), std::string::npos) << r.status().ToString();
  EXPECT_TRUE(Files(PhotoDir(), ".ivf").empty());
  EXPECT_EQ(Files(PhotoDir(), ".photo").size(), 2u);
  // Without a codec: Unsupported, saying what to link.
  SetPhotoVideoCodec(nullptr);
  r = ds_->CompactPhotos(0, 0);
  media::InstallPhotoVideoCodec();
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kUnsupported);
  // Odd, tiny pictures are padded for the coder and cropped back.
  ASSERT_TRUE(ds_->PutPhoto(1, MakePhoto(0, 1, Synthetic(33, 21, 1, 0), 33, 21)).ok());
  ASSERT_TRUE(ds_->PutPhoto(0, MakePhoto(0, 0, Synthetic(33, 21, 0, 0), 33, 21)).ok());
  ASSERT_TRUE(ds_->CompactPhotos(0, 1).ok());
  auto p = ds_->Photos(1);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  ASSERT_EQ(p->size(), 1u);
  EXPECT_GE(LumaPsnr(Synthetic(33, 21, 1, 0), (*p)[0].image), kPhotoVideoMinPsnr);
}

// Long stretches are cut into runs of kPhotoVideoMaxPictures; an edit codes again only the run
// it falls in, and a run never reaches over one left as it is.
TEST_F(PhotoVideoTest, RunsAreBoundedAndOnlyEditedRunsAreCodedAgain) {
  Open();
  constexpr uint32_t kFrames = kPhotoVideoMaxPictures + 8;
  for (uint32_t f = 0; f < kFrames; ++f) {
    ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(0, f, Synthetic(64, 64, f % 9, 0), 64, 64)).ok());
  }
  auto info = ds_->CompactPhotos(0, kFrames - 1);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 2u);
  const std::string first_run = RunVideo(PhotoDir(), 0, kPhotoVideoMaxPictures - 1, 0);
  const std::string first_bytes = ReadFile(first_run);
  ASSERT_FALSE(first_bytes.empty());
  // An edit in the second run, and a new frame past both.
  ASSERT_TRUE(ds_->PutPhoto(kFrames - 3, MakePhoto(0, kFrames - 3, Synthetic(64, 64, 5, 1), 64, 64)).ok());
  ASSERT_TRUE(ds_->PutPhoto(kFrames + 4, MakePhoto(0, kFrames + 4, Synthetic(64, 64, 2, 0), 64, 64)).ok());
  info = ds_->CompactPhotos(0, kFrames + 10);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 1u);  // the second run with its edit and the new frame
  EXPECT_EQ(info->photo_pictures, 9u);
  EXPECT_EQ(ReadFile(first_run), first_bytes);  // left as it was
  EXPECT_EQ(Files(PhotoDir(), ".ivf").size(), 2u);
  for (uint32_t f = 0; f < kFrames + 5; ++f) {
    auto p = ds_->Photos(f);
    ASSERT_TRUE(p.ok()) << p.status().ToString();
    if (f >= kFrames && f != kFrames + 4) {
      EXPECT_TRUE(p->empty()) << f;
      continue;
    }
    ASSERT_EQ(p->size(), 1u) << f;
    const std::string want = f == kFrames - 3   ? Synthetic(64, 64, 5, 1)
                             : f == kFrames + 4 ? Synthetic(64, 64, 2, 0)
                                                : Synthetic(64, 64, f % 9, 0);
    EXPECT_GE(LumaPsnr(want, (*p)[0].image), kPhotoVideoMinPsnr - 0.5) << f;
  }
  // Camera 1: a run over frames 10-13, then photos of frames 5 and 20 on either side of it make
  // two runs, not one reaching over it.
  for (uint32_t f = 10; f < 14; ++f) {
    ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(1, f, Synthetic(64, 64, f % 9, 1), 64, 64)).ok());
  }
  ASSERT_TRUE(ds_->CompactPhotos(0, 100).ok());
  for (uint32_t f : {5u, 20u}) {
    ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(1, f, Synthetic(64, 64, f % 9, 1), 64, 64)).ok());
  }
  info = ds_->CompactPhotos(0, 100);
  ASSERT_TRUE(info.ok()) << info.status().ToString();
  EXPECT_EQ(info->photo_runs, 2u);
  EXPECT_EQ(info->photo_already, 1u);  // camera 0
  EXPECT_TRUE(std::filesystem::exists(PhotoDir() + "/" + PhotoVideoIndexName(5, 5, 1)));
  EXPECT_TRUE(std::filesystem::exists(PhotoDir() + "/" + PhotoVideoIndexName(10, 13, 1)));
  EXPECT_TRUE(std::filesystem::exists(PhotoDir() + "/" + PhotoVideoIndexName(20, 20, 1)));
}

// The index decoder: what it encodes comes back exactly; any truncation or flipped byte is a
// Corruption naming the file, never a crash.
TEST(PhotoVideoIndexTest, RoundTripsAndRejectsDamage) {
  PhotoVideoIndex index;
  index.camera = 7;
  index.first = 100;
  index.last = 103;
  index.video_bytes = 12345;
  index.video_crc = 0xDEADBEEF;
  index.width = 640;
  index.height = 480;
  index.min_psnr = 40;
  index.codec = "libsvtav1 preset 8 crf 50";
  for (uint32_t f : {100u, 101u, 103u}) {
    PhotoVideoEntry e;
    e.frame = f;
    e.psnr = 41.5 + f;
    e.meta = MakePhoto(7, f, "", 640, 480);
    index.entries.push_back(e);
  }
  const std::string bytes = EncodePhotoVideoIndex(index);
  auto back = DecodePhotoVideoIndex(bytes, "x.pvx");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_EQ(back->camera, 7);
  EXPECT_EQ(back->last, 103u);
  EXPECT_EQ(back->video_crc, 0xDEADBEEFu);
  EXPECT_EQ(back->height, 480u);
  EXPECT_EQ(back->codec, index.codec);
  ASSERT_EQ(back->entries.size(), 3u);
  EXPECT_EQ(back->entries[2].frame, 103u);
  EXPECT_EQ(back->entries[2].psnr, 41.5 + 103);
  ExpectSameMeta(index.entries[1].meta, back->entries[1].meta);
  for (size_t n = 0; n < bytes.size(); ++n) {
    auto cut = DecodePhotoVideoIndex(bytes.substr(0, n), "x.pvx");
    ASSERT_FALSE(cut.ok()) << n;
    EXPECT_TRUE(cut.status().IsCorruption());
    std::string flipped = bytes;
    flipped[n] ^= 0x10;
    auto bad = DecodePhotoVideoIndex(flipped, "x.pvx");
    ASSERT_FALSE(bad.ok()) << n;
    EXPECT_NE(bad.status().message().find("x.pvx"), std::string::npos);
  }
  uint32_t f, l;
  uint16_t c;
  EXPECT_TRUE(ParsePhotoVideoName(PhotoVideoIndexName(5, 9, 3), &f, &l, &c));
  EXPECT_EQ(f, 5u);
  EXPECT_EQ(l, 9u);
  EXPECT_EQ(c, 3);
  EXPECT_FALSE(ParsePhotoVideoName(PhotoVideoFileName(5, 9, 3, 0xABCDEF), &f, &l, &c));
  EXPECT_EQ(PhotoVideoFileName(5, 9, 3, 0xABCDEF), "00000005-00000009-00003-00abcdef.ivf");
  EXPECT_FALSE(ParsePhotoVideoName("00000009-00000005-00003.pvx", &f, &l, &c));
}

// Two compactions: the first codes per-frame files; the second, after an edit of frame 1 of
// camera 0 and a new frame 3 of camera 1, codes camera 0's run again and replaces it. A crash at
// any point of either (the power lost with it) keeps every photo, the edit included.
TEST_F(PhotoVideoTest, CrashAtAnyPointOfACompactionLosesNoPhoto) {
  constexpr int kW = 96, kH = 64;
  for (bool second : {false, true}) {
    int crashes = 0;
    for (uint64_t k = 1;; ++k) {
      SCOPED_TRACE(std::string(second ? "second" : "first") + " compaction, crash after call " +
                   std::to_string(k));
      std::filesystem::remove_all(dir_.path() + "/db");
      testing::FaultEnv env(dir_.path() + "/aside-" + std::to_string(second) + "-" + std::to_string(k));
      Open(&env);
      for (uint16_t c = 0; c < 2; ++c) {
        for (uint32_t f = 0; f < 3; ++f) {
          ASSERT_TRUE(ds_->PutPhoto(f, MakePhoto(c, f, Synthetic(kW, kH, f, c), kW, kH)).ok());
        }
      }
      // What each photo must look like afterwards, and how close (a run coded again was
      // decoded first).
      std::map<std::pair<uint16_t, uint32_t>, std::pair<std::string, double>> want;
      for (uint16_t c = 0; c < 2; ++c) {
        for (uint32_t f = 0; f < 3; ++f) want[{c, f}] = {Synthetic(kW, kH, f, c), kPhotoVideoMinPsnr};
      }
      if (second) {
        ASSERT_TRUE(ds_->CompactPhotos(0, 2).ok());
        ASSERT_TRUE(ds_->PutPhoto(1, MakePhoto(0, 1, Synthetic(kW, kH, 7, 0), kW, kH)).ok());
        ASSERT_TRUE(ds_->PutPhoto(3, MakePhoto(1, 3, Synthetic(kW, kH, 3, 1), kW, kH)).ok());
        want[{0, 1}].first = Synthetic(kW, kH, 7, 0);
        want[{0, 0}].second = want[{0, 2}].second = kPhotoVideoMinPsnr - 1;
        want[{1, 3}] = {Synthetic(kW, kH, 3, 1), kPhotoVideoMinPsnr};
      }
      env.CrashAfter(k);
      auto r = ds_->CompactPhotos(0, 5);
      const bool crashed = env.crashed();
      ds_.reset();
      db_.reset();  // the "dead process" is torn down
      env.PowerLoss();
      env.Reset();
      Open(&env);
      size_t seen = 0;
      for (uint32_t f = 0; f < 4; ++f) {
        auto photos = ds_->Photos(f);
        ASSERT_TRUE(photos.ok()) << photos.status().ToString();
        for (const Photo& p : *photos) {
          auto it = want.find({p.camera.id, f});
          ASSERT_NE(it, want.end()) << "camera " << p.camera.id << " frame " << f;
          EXPECT_GE(LumaPsnr(it->second.first, p.image), it->second.second)
              << "camera " << p.camera.id << " frame " << f;
          ++seen;
        }
      }
      EXPECT_EQ(seen, want.size());
      ds_.reset();
      db_.reset();
      if (!crashed) {
        ASSERT_TRUE(r.ok()) << r.status().ToString();
        // No video left over: one per index.
        EXPECT_EQ(Files(PhotoDir(), ".ivf").size(), Files(PhotoDir(), ".pvx").size());
        EXPECT_TRUE(Files(PhotoDir(), ".photo").empty());
        break;
      }
      ++crashes;
    }
    std::printf("[ photo video ] %s compaction: %d crash points, no photo lost\n",
                second ? "second" : "first", crashes);
    EXPECT_GT(crashes, 8);
  }
}

}  // namespace
}  // namespace hvdb
