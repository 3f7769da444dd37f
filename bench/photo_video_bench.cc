// photo-video-bench: the video tier of photos (storage/photo_video.h, issue 36 part 2a) against
// per-frame images, on the real Panoptic Kinect views (16 frames x 10 cameras, 1920x1080 JPEG
// as recorded) and on a generated structured-light recording (4 bricks' colour cameras, PNG as
// recorded), each figure beside its peer from the same run:
//   - bytes: the images as recorded, lossless PNG of the same pixels, per-frame JPEG at the
//     video's mean Y-PSNR (libjpeg quality by bisection: the lowest whose mean reaches it), and
//     the video tier (Dataset::CompactPhotos); target video <= 0.7 x JPEG at equal PSNR;
//   - time: the compaction (code + verify + write), the read back through Dataset::Photos
//     (decode + PNG for the caller), and JPEG coding/decoding at the matched quality, per
//     picture; median of --reps whole runs.
// Writes bench/results/photo_video.json (--out). bench/README.md shows the table.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "bench/util.h"
#include "ingest/generator.h"
#include "media/media.h"
#include "storage/database.h"
#include "storage/photo_video.h"

using namespace hvdb;
using namespace hvdb::bench;
using json = nlohmann::json;

namespace {

struct View {
  uint16_t camera;
  uint32_t frame;
  std::string file;  // as recorded
  cv::Mat bgr;
};

std::string ReadFile(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

cv::Mat Decode(const std::string& bytes) {
  return cv::imdecode(cv::Mat(1, int(bytes.size()), CV_8U, const_cast<char*>(bytes.data())),
                      cv::IMREAD_COLOR);
}

// Y-PSNR (BT.601 luma), as the video tier's bound is stated.
double LumaPsnr(const cv::Mat& a, const cv::Mat& b) {
  double sse = 0;
  for (int y = 0; y < a.rows; ++y) {
    const uint8_t* p = a.ptr<uint8_t>(y);
    const uint8_t* q = b.ptr<uint8_t>(y);
    for (int x = 0; x < a.cols; ++x, p += 3, q += 3) {
      const double d = (0.114 * p[0] + 0.587 * p[1] + 0.299 * p[2]) -
                       (0.114 * q[0] + 0.587 * q[1] + 0.299 * q[2]);
      sse += d * d;
    }
  }
  const double mse = sse / (double(a.rows) * a.cols);
  return mse <= 1e-10 ? 100 : 10 * std::log10(255.0 * 255.0 / mse);
}

json Stat(const std::vector<double>& v) {
  return {{"median", Median(v)},
          {"min", *std::min_element(v.begin(), v.end())},
          {"max", *std::max_element(v.begin(), v.end())},
          {"samples", v}};
}

Photo MakePhoto(const View& v) {
  Photo p;
  p.camera.id = v.camera;
  p.camera.name = "cam" + std::to_string(v.camera);
  p.camera.width = uint32_t(v.bgr.cols);
  p.camera.height = uint32_t(v.bgr.rows);
  p.camera.fx = p.camera.fy = 0.8 * v.bgr.cols;
  p.camera.cx = v.bgr.cols / 2.0;
  p.camera.cy = v.bgr.rows / 2.0;
  p.image = v.file;
  return p;
}

// One data set's figures.
json Measure(const std::string& label, const std::vector<View>& views, const std::string& scratch,
             int reps) {
  const size_t n = views.size();
  uint64_t recorded = 0, png = 0;
  for (const View& v : views) {
    recorded += v.file.size();
    std::vector<uint8_t> buf;
    cv::imencode(".png", v.bgr, buf);
    png += buf.size();
  }
  std::vector<double> compact_ms, read_ms;
  uint64_t video_bytes = 0;
  double mean_psnr = 0, min_psnr = 100;
  for (int rep = 0; rep < reps; ++rep) {
    RemoveAll(scratch);
    auto db = Check(Database::Open(scratch), "open");
    DatasetInfo info;
    info.name = "pv";
    auto ds = Check(db->CreateDataset(info), "create");
    for (const View& v : views) Check(ds->PutPhoto(v.frame, MakePhoto(v)), "put photo");
    Timer tc;
    CompactInfo ci = Check(ds->CompactPhotos(0, UINT32_MAX), "compact --photos");
    compact_ms.push_back(tc.Ms());
    video_bytes = ci.photo_bytes_after;
    std::map<std::pair<uint16_t, uint32_t>, const View*> by;
    std::set<uint32_t> frames;
    for (const View& v : views) by[{v.camera, v.frame}] = &v, frames.insert(v.frame);
    Timer tr;
    std::vector<std::vector<Photo>> got;
    for (uint32_t f : frames) got.push_back(Check(ds->Photos(f), "photos"));
    read_ms.push_back(tr.Ms());
    double sum = 0;
    size_t i = 0;
    for (uint32_t f : frames) {
      for (const Photo& p : got[i]) {
        const double psnr = LumaPsnr(by.at({p.camera.id, f})->bgr, Decode(p.image));
        sum += psnr;
        min_psnr = std::min(min_psnr, psnr);
      }
      ++i;
    }
    mean_psnr = sum / double(n);
    Log("%s rep %d: video %.2f MiB, compact %.1f s, read %.1f s, mean Y-PSNR %.2f dB", label.c_str(),
        rep, video_bytes / 1048576.0, compact_ms.back() / 1e3, read_ms.back() / 1e3, mean_psnr);
  }
  // Per-frame JPEG at the video's mean Y-PSNR: the lowest libjpeg quality that reaches it.
  auto jpeg_at = [&](int q, uint64_t* bytes) {
    double sum = 0;
    *bytes = 0;
    for (const View& v : views) {
      std::vector<uint8_t> buf;
      cv::imencode(".jpg", v.bgr, buf, {cv::IMWRITE_JPEG_QUALITY, q});
      *bytes += buf.size();
      sum += LumaPsnr(v.bgr, cv::imdecode(buf, cv::IMREAD_COLOR));
    }
    return sum / double(n);
  };
  int lo = 1, hi = 100;
  uint64_t jpeg_bytes = 0;
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    uint64_t b;
    if (jpeg_at(mid, &b) >= mean_psnr) hi = mid; else lo = mid + 1;
  }
  const double jpeg_psnr = jpeg_at(lo, &jpeg_bytes);
  std::vector<double> jpeg_enc_ms, jpeg_dec_ms;
  for (int rep = 0; rep < reps; ++rep) {
    std::vector<std::vector<uint8_t>> coded(n);
    Timer te;
    for (size_t i = 0; i < n; ++i) cv::imencode(".jpg", views[i].bgr, coded[i], {cv::IMWRITE_JPEG_QUALITY, lo});
    jpeg_enc_ms.push_back(te.Ms());
    Timer td;
    for (size_t i = 0; i < n; ++i) (void)cv::imdecode(coded[i], cv::IMREAD_COLOR);
    jpeg_dec_ms.push_back(td.Ms());
  }
  const double vs_jpeg = double(video_bytes) / double(jpeg_bytes);
  Log("%s: recorded %.2f MiB, PNG %.2f MiB, JPEG q%d (%.2f dB) %.2f MiB, video %.2f MiB (%.3f of "
      "JPEG)", label.c_str(), recorded / 1048576.0, png / 1048576.0, lo, jpeg_psnr,
      jpeg_bytes / 1048576.0, video_bytes / 1048576.0, vs_jpeg);
  const double per = 1.0 / double(n);
  return {{"pictures", n},
          {"width", views[0].bgr.cols},
          {"height", views[0].bgr.rows},
          {"bytes",
           {{"recorded", recorded},
            {"png", png},
            {"jpeg_same_psnr", jpeg_bytes},
            {"video", video_bytes}}},
          {"jpeg_quality", lo},
          {"psnr_db",
           {{"video_mean", mean_psnr}, {"video_min", min_psnr}, {"jpeg_mean", jpeg_psnr},
            {"bound", kPhotoVideoMinPsnr}}},
          {"ratio",
           {{"video_vs_recorded", double(video_bytes) / double(recorded)},
            {"video_vs_png", double(video_bytes) / double(png)},
            {"video_vs_jpeg_same_psnr", vs_jpeg}}},
          {"target", "video <= 0.7 x per-frame JPEG at equal PSNR"},
          {"met", vs_jpeg <= 0.7},
          {"ms_per_picture",
           {{"video_compact", Median(compact_ms) * per},
            {"video_read", Median(read_ms) * per},
            {"jpeg_encode", Median(jpeg_enc_ms) * per},
            {"jpeg_decode", Median(jpeg_dec_ms) * per}}},
          {"ms_whole",
           {{"video_compact", Stat(compact_ms)},
            {"video_read", Stat(read_ms)},
            {"jpeg_encode", Stat(jpeg_enc_ms)},
            {"jpeg_decode", Stat(jpeg_dec_ms)}}}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"photo-video-bench: the video tier of photos against per-frame images"};
  std::string out_path = std::string(HVDB_SOURCE_DIR) + "/bench/results/photo_video.json";
  std::string scratch = "/tmp/hvdb-photo-video-bench";
  int reps = 3, gen_width = 640, gen_height = 480, frames = 16;
  app.add_option("--out", out_path, "JSON output");
  app.add_option("--scratch", scratch, "Scratch folder (removed)");
  app.add_option("--reps", reps, "Whole runs per figure (median)")->check(CLI::Range(1, 50));
  app.add_option("--frames", frames, "Frames of each data set")->check(CLI::Range(2, 16));
  app.add_option("--gen-size", gen_width, "Generated recording's width (height 3/4 of it)")
      ->check(CLI::Range(64, 1920));
  CLI11_PARSE(app, argc, argv);
  gen_height = gen_width * 3 / 4;
  media::InstallPhotoVideoCodec();
  MakeDirs(scratch);

  // Panoptic: 10 Kinect colour views x `frames`, as recorded (JPEG).
  std::vector<View> panoptic;
  const std::string base =
      std::string(HVDB_SHARED_DATA) + "/cmu-panoptic-kinoptic-171026-pose3/kinectImgs";
  for (uint16_t c = 0; c < 10; ++c) {
    for (int f = 0; f < frames; ++f) {
      char name[80];
      std::snprintf(name, sizeof name, "/50_%02u/50_%02u_%08d.jpg", unsigned(c + 1), unsigned(c + 1), 380 + f);
      View v{c, uint32_t(f), ReadFile(base + name), {}};
      v.bgr = Decode(v.file);
      if (v.bgr.empty()) {
        std::fprintf(stderr, "photo-video-bench: cannot read %s%s\n", base.c_str(), name);
        return 1;
      }
      panoptic.push_back(std::move(v));
    }
  }
  // Generated: 4 bricks' colour cameras (ingest/generator.h), as recorded (PNG).
  ingest::GeneratorOptions g;
  g.bricks = 4;
  g.frames = frames;
  g.width = gen_width;
  g.height = gen_height;
  g.seed = 11;
  const std::string gen_dir = scratch + "-generated";
  RemoveAll(gen_dir);
  Check(ingest::GenerateRecording(g, gen_dir).status(), "generate");
  std::vector<View> generated;
  for (int b = 0; b < g.bricks; ++b) {
    for (int f = 0; f < frames; ++f) {
      // The generator's layout (ingest/generator.h): frames/<ffffff>/b<k>_colour.png.
      char name[64];
      std::snprintf(name, sizeof name, "/frames/%06d/b%d_colour.png", f, b);
      View v{uint16_t(b), uint32_t(f), ReadFile(gen_dir + name), {}};
      v.bgr = Decode(v.file);
      if (v.bgr.empty()) {
        std::fprintf(stderr, "photo-video-bench: cannot read %s%s\n", gen_dir.c_str(), name);
        return 1;
      }
      generated.push_back(std::move(v));
    }
  }
  RemoveAll(gen_dir);

  json pan = Measure("panoptic", panoptic, scratch + "/db", reps);
  json gen = Measure("generated", generated, scratch + "/db", reps);
  json out = {
      {"schema", "hvdb-photo-video-bench/1"},
      {"command", "build/bench/photo-video-bench --reps " + std::to_string(reps) + " --frames " +
                      std::to_string(frames) + " --gen-size " + std::to_string(gen_width)},
      {"machine", MachineInfo(scratch)},
      {"codec", "AV1 (libsvtav1 preset 8, CRF searched per run) in IVF; bound: every picture "
                ">= 40 dB Y-PSNR (BT.601 luma)"},
      {"panoptic", pan},
      {"generated", gen},
  };
  RemoveAll(scratch);
  std::ofstream(out_path) << out.dump(2) << "\n";
  std::printf("video vs per-frame JPEG at equal PSNR: panoptic %.3f, generated %.3f -> %s\n",
              pan["ratio"]["video_vs_jpeg_same_psnr"].get<double>(),
              gen["ratio"]["video_vs_jpeg_same_psnr"].get<double>(), out_path.c_str());
  return 0;  // targets are results, not assertions (bench/README.md)
}
