// See codec_time.h.
#include "bench/codec_time.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <vector>

#include "codec/codec.h"
#include "ingest/generator.h"

namespace hvdb::bench {
namespace {

[[noreturn]] void Die(const std::string& what) {
  std::fprintf(stderr, "codec-bench: %s\n", what.c_str());
  std::exit(1);
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// Frame f's points: every colour camera's ground-truth depth back-projected (pinhole: the
// recording has no distortion), coloured by that camera's image.
std::vector<Point> FramePoints(const std::string& dir, const ingest::Calibration& cal, int f) {
  char frame[16];
  std::snprintf(frame, sizeof frame, "%06d", f);
  std::vector<Point> pts;
  for (const ingest::Brick& b : cal.bricks) {
    const ingest::CameraModel& c = cal.cameras[static_cast<size_t>(b.colour)];
    auto depth = ingest::ReadDepthExr(dir + "/groundtruth/" + frame + "/" + c.name + ".depth.exr");
    if (!depth.ok()) Die(depth.status().ToString());
    const cv::Mat bgr = cv::imread(dir + "/frames/" + frame + "/" + c.name + ".png", cv::IMREAD_COLOR);
    if (bgr.empty()) Die("cannot read the colour image of " + c.name);
    const cv::Mat& d = depth.value();
    const double fx = c.K(0, 0), fy = c.K(1, 1), cx = c.K(0, 2), cy = c.K(1, 2);
    const cv::Matx33d Rt = c.R.t();
    for (int v = 0; v < d.rows; ++v) {
      for (int u = 0; u < d.cols; ++u) {
        const float z = d.at<float>(v, u);
        if (!std::isfinite(z)) continue;
        const cv::Vec3d cam((u - cx) / fx * z, (v - cy) / fy * z, z);
        const cv::Vec3d w = Rt * (cam - c.T);
        Point p;
        p.x = static_cast<float>(w[0]);
        p.y = static_cast<float>(w[1]);
        p.z = static_cast<float>(w[2]);
        const cv::Vec3b px = bgr.at<cv::Vec3b>(v, u);
        p.r = px[2], p.g = px[1], p.b = px[0];
        p.camera = static_cast<uint16_t>(b.id);
        pts.push_back(p);
      }
    }
  }
  return pts;
}

}  // namespace

nlohmann::json RunStaticBackground(const std::string& scratch, bool quick) {
  ingest::GeneratorOptions g;
  g.frames = quick ? 3 : 8;
  g.distortion = false;
  g.supersample = quick ? 1 : 2;
  g.seed = 7;
  const std::string dir = scratch + "/static_background_recording";
  std::filesystem::remove_all(dir);
  auto rec = ingest::GenerateRecording(g, dir);
  if (!rec.ok()) Die(rec.status().ToString());
  nlohmann::json frames = nlohmann::json::array(), out;
  for (uint32_t attrs : {uint32_t{codec::kPosition}, uint32_t{codec::kPosition | codec::kColor}}) {
    codec::EncodeOptions o;
    o.qp = 11;
    o.qc = 8;  // lossless colour: only the bits differ
    o.attributes = attrs;
    const std::string what = attrs == codec::kPosition ? "position" : "position_color";
    std::vector<double> savings;
    codec::Reference ref;
    for (int f = 0; f < g.frames; ++f) {
      const std::vector<Point> pts = FramePoints(dir, rec->calibration, f);
      std::string intra, temporal;
      Status st = codec::Encode(pts, o, &intra);
      if (!st.ok()) Die(st.ToString());
      if (f > 0) {
        st = codec::Encode(pts, o, &temporal, nullptr, &ref);
        if (!st.ok()) Die(st.ToString());
        codec::DecodeOptions d;
        d.reference = &ref;
        std::vector<Point> a, b;
        if (!codec::Decode(temporal, &a, d).ok() || !codec::Decode(intra, &b).ok() || a.size() != b.size()) {
          Die("temporal and intra streams decode differently");
        }
        const double n = static_cast<double>(pts.size());
        const double s = 1.0 - static_cast<double>(temporal.size()) / static_cast<double>(intra.size());
        savings.push_back(s);
        frames.push_back({{"attributes", what}, {"frame", f}, {"points", pts.size()},
                          {"intra_bpp", 8.0 * intra.size() / n},
                          {"temporal_bpp", 8.0 * temporal.size() / n}, {"saving", s}});
      }
      // The next frame's reference: this frame as decoded, on this stream's grid.
      const std::string& coded = f > 0 ? temporal : intra;
      codec::DecodeOptions d;
      d.reference = f > 0 ? &ref : nullptr;
      std::vector<Point> dec;
      if (!codec::Decode(coded, &dec, d).ok()) Die("cannot decode frame " + std::to_string(f));
      codec::StreamInfo info;
      if (!codec::ReadInfo(coded, &info).ok()) Die("cannot read a stream's header");
      ref.points = std::move(dec);
      for (int a = 0; a < 3; ++a) ref.origin[a] = info.origin[a];
      ref.step = info.step;
      ref.qp = info.qp;
    }
    out[what + "_saving_median"] = Median(savings);
    std::fprintf(stderr, "static background, %s: temporal saves %.1f %% (median)\n", what.c_str(),
                 100 * Median(savings));
  }
  out["frames"] = frames;
  out["recording"] = {{"bricks", g.bricks}, {"frames", g.frames}, {"width", g.width},
                      {"height", g.height}, {"noise_sigma", g.noise_sigma}, {"qp", 11}};
  std::filesystem::remove_all(dir);
  return out;
}

}  // namespace hvdb::bench
