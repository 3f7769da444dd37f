// hvdb import-media's decoders and insertion (media/media.h) on real files: a PNG's surfels
// carry its pixels, a video written here with libavcodec gives per-frame colours that follow
// it, and corrupt files are refused with nothing written.
#include "media/media.h"

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include <opencv2/imgcodecs.hpp>

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
#include <libavutil/imgutils.h>
#include <libavutil/opt.h>
}

#include "tests/storage/test_util.h"

namespace hvdb::media {
namespace {

std::vector<Point> ReadAll(Dataset& ds) {
  std::vector<Point> out;
  auto c = ds.Query(testing::EverythingWindow());
  EXPECT_TRUE(c.ok());
  Batch b;
  while (*(*c)->Next(&b)) out.insert(out.end(), b.points.begin(), b.points.end());
  return out;
}

std::string Slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// A random w x h picture (BGR, as OpenCV keeps it) and its PNG bytes.
cv::Mat RandomImage(int w, int h, uint32_t seed) {
  cv::Mat m(h, w, CV_8UC3);
  std::mt19937 rng(seed);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      m.at<cv::Vec3b>(y, x) = {static_cast<uint8_t>(rng()), static_cast<uint8_t>(rng()),
                               static_cast<uint8_t>(rng())};
    }
  }
  return m;
}

std::string Png(const cv::Mat& m) {
  std::vector<uint8_t> buf;
  EXPECT_TRUE(cv::imencode(".png", m, buf));
  return std::string(buf.begin(), buf.end());
}

// A video file (`container`: "mp4", "webm") of `codec` frames, frame k filled with colours[k]
// (RGB).
std::string WriteVideo(const std::string& path, const char* container, AVCodecID codec_id,
                       int w, int h, const std::vector<std::array<uint8_t, 3>>& colours) {
  AVFormatContext* fmt = nullptr;
  EXPECT_GE(avformat_alloc_output_context2(&fmt, nullptr, container, path.c_str()), 0);
  const AVCodec* codec = avcodec_find_encoder(codec_id);
  EXPECT_NE(codec, nullptr);
  AVStream* st = avformat_new_stream(fmt, nullptr);
  AVCodecContext* enc = avcodec_alloc_context3(codec);
  enc->width = w;
  enc->height = h;
  enc->pix_fmt = AV_PIX_FMT_YUV420P;
  enc->time_base = {1, 10};
  enc->framerate = {10, 1};
  enc->gop_size = 2;
  enc->bit_rate = 2'000'000;
  if (fmt->oformat->flags & AVFMT_GLOBALHEADER) enc->flags |= AV_CODEC_FLAG_GLOBAL_HEADER;
  EXPECT_GE(avcodec_open2(enc, codec, nullptr), 0);
  avcodec_parameters_from_context(st->codecpar, enc);
  st->time_base = enc->time_base;
  EXPECT_GE(avio_open(&fmt->pb, path.c_str(), AVIO_FLAG_WRITE), 0);
  EXPECT_GE(avformat_write_header(fmt, nullptr), 0);
  AVFrame* frame = av_frame_alloc();
  frame->format = enc->pix_fmt;
  frame->width = w;
  frame->height = h;
  av_frame_get_buffer(frame, 0);
  AVPacket* pkt = av_packet_alloc();
  auto drain = [&]() {
    while (avcodec_receive_packet(enc, pkt) == 0) {
      // Each frame lasts one tick: with 0 the MP4's edit list would cut the last frame off.
      pkt->duration = 1;
      av_packet_rescale_ts(pkt, enc->time_base, st->time_base);
      pkt->stream_index = st->index;
      av_interleaved_write_frame(fmt, pkt);
    }
  };
  for (size_t k = 0; k < colours.size(); ++k) {
    av_frame_make_writable(frame);
    // BT.601 limited range, as libswscale reads it back.
    const double r = colours[k][0], g = colours[k][1], b = colours[k][2];
    const auto Y = static_cast<uint8_t>(std::lround(16 + 0.257 * r + 0.504 * g + 0.098 * b));
    const auto U = static_cast<uint8_t>(std::lround(128 - 0.148 * r - 0.291 * g + 0.439 * b));
    const auto V = static_cast<uint8_t>(std::lround(128 + 0.439 * r - 0.368 * g - 0.071 * b));
    for (int y = 0; y < h; ++y) std::memset(frame->data[0] + y * frame->linesize[0], Y, w);
    for (int y = 0; y < h / 2; ++y) {
      std::memset(frame->data[1] + y * frame->linesize[1], U, w / 2);
      std::memset(frame->data[2] + y * frame->linesize[2], V, w / 2);
    }
    frame->pts = static_cast<int64_t>(k);
    EXPECT_GE(avcodec_send_frame(enc, frame), 0);
    drain();
  }
  avcodec_send_frame(enc, nullptr);
  drain();
  av_write_trailer(fmt);
  avio_closep(&fmt->pb);
  av_packet_free(&pkt);
  av_frame_free(&frame);
  avcodec_free_context(&enc);
  avformat_free_context(fmt);
  return Slurp(path);
}

// MPEG-4 Part 2 in MP4.
std::string WriteMp4(const std::string& path, int w, int h,
                     const std::vector<std::array<uint8_t, 3>>& colours) {
  return WriteVideo(path, "mp4", AV_CODEC_ID_MPEG4, w, h, colours);
}

class MediaTest : public ::testing::Test {
 protected:
  void SetUp() override {
    Options o;
    o.cache_bytes = 32u << 20;
    auto db = Database::Open(dir_.path(), o);
    ASSERT_TRUE(db.ok());
    db_ = std::move(*db);
    DatasetInfo info;
    info.name = "scene";
    info.fps = 10;
    ds_ = *db_->CreateDataset(info);
  }
  testing::TempDir dir_;
  std::unique_ptr<Database> db_;
  std::shared_ptr<Dataset> ds_;
};

TEST_F(MediaTest, AnImagesSurfelsCarryItsPixelsWherePlaced) {
  const int w = 40, h = 30;
  const cv::Mat img = RandomImage(w, h, 7);
  ImportRequest req;
  req.data = Png(img);
  req.format = "png";
  req.first_frame = 2;
  req.last_frame = 4;
  req.place.at = {1, 2, 3};
  req.place.scale = 2;  // 2 m wide
  req.label_bit = 5;
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, uint64_t{w} * h * 3);
  const std::vector<Point> pts = ReadAll(*ds_);
  ASSERT_EQ(pts.size(), size_t{w} * h * 3);
  const double s = 2.0 / w;  // texel spacing
  std::map<uint32_t, int> per_frame;
  for (const Point& p : pts) {
    ++per_frame[p.frame];
    EXPECT_EQ(p.label, 1u << 5);
    EXPECT_FLOAT_EQ(p.z, 3.0f);
    // Texel (i, j): x = at + (i + 0.5) s - 1, y = at + h s / 2 - (j + 0.5) s.
    const int i = static_cast<int>(std::floor((p.x - 1 + 1) / s));
    const int j = static_cast<int>(std::floor((2 + h * s / 2 - p.y) / s));
    ASSERT_GE(i, 0);
    ASSERT_LT(i, w);
    ASSERT_GE(j, 0);
    ASSERT_LT(j, h);
    const cv::Vec3b px = img.at<cv::Vec3b>(j, i);
    EXPECT_EQ(p.r, px[2]);
    EXPECT_EQ(p.g, px[1]);
    EXPECT_EQ(p.b, px[0]);
    const auto n = DecodeNormal(p.normal_oct);
    EXPECT_NEAR(n[2], 1.0, 1e-4);
    EXPECT_EQ(p.flags, kFlagHasNormal | kFlagHasCovariance);
    // The footprint: 0.6 texel spacing along the plane, thin across it.
    EXPECT_NEAR(std::sqrt(p.cov[0]), 0.6 * s, 1e-6);
    EXPECT_LT(p.cov[5], p.cov[0] * 0.01);
  }
  EXPECT_EQ(per_frame, (std::map<uint32_t, int>{{2, w * h}, {3, w * h}, {4, w * h}}));
  // The extent: 2 m by 1.5 m around (1, 2), texel centres half a spacing inside.
  float lo_x = 1e9f, hi_x = -1e9f, lo_y = 1e9f, hi_y = -1e9f;
  for (const Point& p : pts) {
    lo_x = std::min(lo_x, p.x);
    hi_x = std::max(hi_x, p.x);
    lo_y = std::min(lo_y, p.y);
    hi_y = std::max(hi_y, p.y);
  }
  EXPECT_NEAR(lo_x, 0 + s / 2, 1e-5);
  EXPECT_NEAR(hi_x, 2 - s / 2, 1e-5);
  EXPECT_NEAR(lo_y, 2 - 0.75 + s / 2, 1e-5);
  EXPECT_NEAR(hi_y, 2 + 0.75 - s / 2, 1e-5);
  // One transaction: undo removes all of it.
  ASSERT_TRUE(ds_->Revert(ci->lsn).ok());
  EXPECT_TRUE(ReadAll(*ds_).empty());
}

TEST_F(MediaTest, RotationTurnsThePlaneAndAnEmptyDatasetGetsFrameZero) {
  ImportRequest req;
  req.data = Png(RandomImage(8, 8, 1));
  req.place.rotate_deg = {90, 0, 0};  // the image now faces -y, its top towards +z
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  const std::vector<Point> pts = ReadAll(*ds_);
  ASSERT_EQ(pts.size(), 64u);
  for (const Point& p : pts) {
    EXPECT_EQ(p.frame, 0u);
    EXPECT_NEAR(p.y, 0, 1e-6);
    const auto n = DecodeNormal(p.normal_oct);
    EXPECT_NEAR(n[1], -1.0, 1e-4);
  }
}

TEST_F(MediaTest, ALargeImageIsAreaAveragedToTheTexelGridAndDefaultsToAllFrames) {
  // Three frames of data, so that the default range is 0..2.
  for (uint32_t f = 0; f < 3; ++f) {
    Point p;
    p.frame = f;
    ASSERT_TRUE(ds_->BulkLoad(f, {p}).ok());
  }
  cv::Mat img(500, 1000, CV_8UC3, cv::Scalar(10, 20, 30));
  ImportRequest req;
  req.data = Png(img);
  req.texels = 100;
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, 100u * 50 * 3);
  for (const Point& p : ReadAll(*ds_)) {
    if (p.label == 0 && p.r == 0) continue;  // the frames' own point
    EXPECT_EQ(p.r, 30);
    EXPECT_EQ(p.b, 10);
  }
}

TEST_F(MediaTest, TransparentPixelsLeaveNoSurfel) {
  cv::Mat img(4, 4, CV_8UC4, cv::Scalar(0, 0, 255, 255));
  img.at<cv::Vec4b>(0, 0)[3] = 0;
  img.at<cv::Vec4b>(3, 3)[3] = 10;
  ImportRequest req;
  req.data = Png(img);
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, 14u);
}

TEST_F(MediaTest, AVideosFramesFollowItFrameByFrameThenItsLastFrameHolds) {
  const std::vector<std::array<uint8_t, 3>> colours = {
      {220, 30, 30}, {30, 200, 40}, {40, 40, 210}, {230, 220, 40}, {200, 200, 200}};
  const std::string mp4 = WriteMp4(dir_.path() + "/clip.mp4", 64, 48, colours);
  ASSERT_GT(mp4.size(), 100u);
  ImportRequest req;
  req.data = mp4;
  req.format = "mp4";
  req.first_frame = 10;
  req.last_frame = 16;  // 7 frames from a 5-frame video
  req.place.width = 0.64;
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, 64u * 48 * 7);
  std::map<uint32_t, std::array<double, 4>> sums;  // r, g, b, n
  for (const Point& p : ReadAll(*ds_)) {
    auto& s = sums[p.frame];
    s[0] += p.r;
    s[1] += p.g;
    s[2] += p.b;
    s[3] += 1;
  }
  ASSERT_EQ(sums.size(), 7u);
  for (uint32_t f = 10; f <= 16; ++f) {
    SCOPED_TRACE(f);
    const auto& want = colours[std::min<size_t>(f - 10, colours.size() - 1)];
    const auto& s = sums[f];
    EXPECT_EQ(s[3], 64 * 48);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(s[c] / s[3], want[c], 8.0);
  }
  // 10,000 frames of 64 x 48 surfels pass the 20 M points of one import: refused after the
  // first frame is decoded, nothing written.
  const uint64_t lsn = ds_->Info().last_lsn;
  req.first_frame = 0;
  req.last_frame = 9999;
  auto big = Import(*ds_, req);
  ASSERT_FALSE(big.ok());
  EXPECT_NE(big.status().message().find("import_media.frames: 3072 points a frame in 10000"),
            std::string::npos)
      << big.status().message();
  req.data = Png(RandomImage(64, 48, 2));
  req.format = "png";
  big = Import(*ds_, req);
  EXPECT_NE(big.status().message().find("import_media.frames: 3072 points a frame in 10000"),
            std::string::npos)
      << big.status().message();
  EXPECT_EQ(ds_->Info().last_lsn, lsn);
}

TEST_F(MediaTest, AWebmVideoToo) {
  const std::vector<std::array<uint8_t, 3>> colours = {{200, 40, 40}, {40, 40, 200}};
  const std::string webm =
      WriteVideo(dir_.path() + "/clip.webm", "webm", AV_CODEC_ID_VP8, 32, 32, colours);
  ImportRequest req;
  req.data = webm;
  req.format = "webm";
  req.first_frame = 0;
  req.last_frame = 1;
  auto ci = Import(*ds_, req);
  ASSERT_TRUE(ci.ok()) << ci.status().ToString();
  EXPECT_EQ(ci->inserted, 32u * 32 * 2);
  std::map<uint32_t, std::array<double, 4>> sums;
  for (const Point& p : ReadAll(*ds_)) {
    auto& s = sums[p.frame];
    s[0] += p.r;
    s[1] += p.g;
    s[2] += p.b;
    s[3] += 1;
  }
  for (uint32_t f = 0; f < 2; ++f) {
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(sums[f][c] / sums[f][3], colours[f][c], 12.0);
  }
}

TEST_F(MediaTest, CorruptFilesAreRefusedWithTheirKindAndNothingIsWritten) {
  Point p;
  ASSERT_TRUE(ds_->BulkLoad(0, {p}).ok());
  const uint64_t lsn = ds_->Info().last_lsn;
  std::string png = Png(RandomImage(32, 32, 3));
  std::string mp4 = WriteMp4(dir_.path() + "/c.mp4", 32, 32, {{1, 2, 3}, {4, 5, 6}});
  struct Bad {
    std::string data, format, kind_word;
    Kind kind = Kind::kAuto;
  };
  std::mt19937 rng(3);
  std::string noise(4096, '\0');
  for (char& c : noise) c = static_cast<char>(rng());
  const std::vector<Bad> bad = {
      {png.substr(0, png.size() / 2), "png", "image"},              // truncated PNG
      {"\x89PNG\r\n\x1a\n" + noise, "png", "image"},                // a PNG signature on noise
      {"\xff\xd8\xff\xe0" + noise, "jpg", "image"},                 // a JPEG one
      {noise, "mp4", "video"},                                      // noise called a video
      {mp4.substr(0, 200), "mp4", "video"},                         // a video cut short
      {"v 0 0 0\nv 1 0 0\nf 1 2 9\n", "obj", "mesh"},               // a face past the vertices
      {"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n", "ply", "mesh"},
      {noise, "", "image", Kind::kImage},                           // the kind given
  };
  for (const Bad& b : bad) {
    SCOPED_TRACE(b.format + " / " + b.kind_word);
    ImportRequest req;
    req.data = b.data;
    req.format = b.format;
    req.kind = b.kind;
    auto r = Import(*ds_, req);
    ASSERT_FALSE(r.ok());
    EXPECT_TRUE(r.status().IsInvalidArgument()) << r.status().ToString();
    EXPECT_NE(r.status().message().find("the " + b.kind_word), std::string::npos)
        << r.status().message();
  }
  // Bad placements are refused before anything is decoded.
  ImportRequest req;
  req.data = png;
  req.label_bit = 32;
  EXPECT_NE(Import(*ds_, req).status().message().find("import_media.label_bit"),
            std::string::npos);
  req.label_bit.reset();
  req.place.scale = 0;
  EXPECT_NE(Import(*ds_, req).status().message().find("import_media.scale"), std::string::npos);
  req.place.scale = 1;
  req.first_frame = 5;
  req.last_frame = 4;
  EXPECT_NE(Import(*ds_, req).status().message().find("import_media.frames"), std::string::npos);
  req.first_frame.reset();
  req.last_frame.reset();
  req.data.clear();
  EXPECT_NE(Import(*ds_, req).status().message().find("import_media.data"), std::string::npos);
  EXPECT_EQ(ds_->Info().last_lsn, lsn);
  EXPECT_EQ(ReadAll(*ds_).size(), 1u);
}

}  // namespace
}  // namespace hvdb::media
