// ingest-bench: accuracy and throughput of the ingest pipeline (ingest/), as JSON in the figure
// format of the other benchmarks (bench/README.md).
//
//  1. Generated structured-light recordings (ingest/generator.h, exact ground truth from the
//     analytic scene): per brick, the matcher's disparity error after subpixel refinement and
//     the valid fraction over non-occluded pixels (pixels whose surface point the right camera
//     also sees), bad-pixel rates; and the 3D error of the merged, cleaned points (distance
//     along the viewing ray to the true surface): RMSE, median, p90.
//  1b. The billboard filter (thesis 6.2, --filter billboard) against the subpixel LM on a
//     generated recording of 6 frames: 3D error of the points and flicker (the change of each
//     colour camera's depth between consecutive frames where the true surface did not move),
//     with integer and parabola disparities as its input, single-frame and spacetime stereo.
//  2. Real sequences of ../shared/data, described by recording.yml files written into the
//     scratch directory with absolute path patterns (nothing is copied) and ingested by the
//     hvdb-ingest binary into a scratch data directory: points per frame, frames/s, points/s,
//     peak memory (of that process). For the RGB-D sequences with poses, how well consecutive
//     frames agree in world space: the points of frame i+1 projected into the camera of frame i
//     and compared with frame i's own depth map.
// The Middlebury stereo pairs are stereo-bench's (bench/stereo_bench.cc).
#include <sys/resource.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <chrono>
#include <nlohmann/json.hpp>
#include <sstream>
#include <vector>

#include "client/backend.h"
#include "bench/real_recordings.h"
#include "ingest/generator.h"
#include "ingest/pipeline.h"
#include "ingest/rectify.h"

namespace fs = std::filesystem;
using namespace hvdb;
using namespace hvdb::ingest;

namespace {

const std::string kData = HVDB_SHARED_DATA;

nlohmann::json Figure(const std::string& name, const std::string& unit, std::vector<double> v,
                      nlohmann::json params) {
  std::sort(v.begin(), v.end());
  if (v.empty()) v.push_back(NAN);
  return {{"name", name},          {"unit", unit},          {"median", v[v.size() / 2]},
          {"min", v.front()},      {"max", v.back()},       {"repetitions", v.size()},
          {"params", std::move(params)}};
}

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())))];
}

[[noreturn]] void Die(const std::string& what, const Status& st) {
  std::fprintf(stderr, "ingest-bench: %s: %s\n", what.c_str(), st.ToString().c_str());
  std::exit(1);
}

template <typename T>
T Check(Result<T> r, const std::string& what) {
  if (!r.ok()) Die(what, r.status());
  return std::move(r).value();
}

// ---- 1. generated recordings ---------------------------------------------------------------

void RunGenerated(const std::string& scratch, bool quick, nlohmann::json& figures) {
  GeneratorOptions g;
  g.bricks = quick ? 2 : 3;
  g.frames = quick ? 1 : 4;
  g.width = quick ? 160 : 320;
  g.height = quick ? 120 : 240;
  const std::string dir = scratch + "/generated";
  fs::remove_all(dir);
  Check(GenerateRecording(g, dir), "generate");
  const Recording rec = Check(OpenRecording(dir), "open generated recording");
  IngestOptions opt;
  opt.dataset = "gen";
  const nlohmann::json params = {{"bricks", g.bricks}, {"width", g.width}, {"height", g.height},
                                 {"frames", g.frames}, {"seed", g.seed},
                                 {"window", opt.stereo.window},
                                 {"num_disparities", opt.stereo.num_disparities}};
  std::vector<double> abs_err_all, valid_pct, bad1, bad05, stereo_ms, rmse, med3d, p90_3d;
  // The same with the spacetime matcher over the frame and its neighbours (thesis 3.4: the
  // stripe patterns change every frame), next to single-frame stereo on the same pairs.
  std::vector<double> st_err_all, st_valid, st_bad1, st_ms, st_med3d, st_rmse;
  const FrameProcessor proc = Check(FrameProcessor::Make(rec, opt), "frame processor");
  std::vector<FrameInput> all;
  for (int f = 0; f < rec.frames; ++f) all.push_back(Check(LoadFrame(rec, f), "load frame"));
  struct Score {
    std::vector<double> err;
    size_t nonocc = 0, valid = 0, b1 = 0, b05 = 0;
  };
  for (int f = 0; f < rec.frames; ++f) {
    const SyntheticScene scene(g.seed, f, g.fps);
    const FrameInput& in = all[static_cast<size_t>(f)];
    const int lo = std::max(0, f - 1), hi = std::min(rec.frames - 1, f + 1);
    for (size_t j = 0; j < in.stereo.size(); ++j) {
      const StereoView& v = in.stereo[j];
      const Brick& b = rec.calibration.bricks[static_cast<size_t>(v.brick)];
      const Rectification r = Check(PrepareRectification(rec.calibration.cameras[b.left],
                                                         rec.calibration.cameras[b.right]),
                                    "rectify");
      cv::Mat l, rr;
      Rectify(r, v.left, v.right, &l, &rr);
      const DisparityMap dm = Check(MatchStereo(l, rr, opt.stereo), "match");
      stereo_ms.push_back(dm.timing.total_ms);
      std::vector<cv::Mat> ls, rs;
      for (int k = lo; k <= hi; ++k) {
        const StereoView& wv = all[static_cast<size_t>(k)].stereo[j];
        cv::Mat lk, rk;
        Rectify(r, wv.left, wv.right, &lk, &rk);
        ls.push_back(lk);
        rs.push_back(rk);
      }
      const DisparityMap ds =
          ls.size() > 1 ? Check(MatchSpacetime(ls, rs, static_cast<size_t>(f - lo), opt.stereo),
                                "spacetime match")
                        : dm;
      st_ms.push_back(ds.timing.total_ms);
      const cv::Vec3d Or = rec.calibration.cameras[b.right].Centre();
      const double fx = r.left.K(0, 0);
      auto score = [&](const DisparityMap& m) {
        Score sc;
        for (int y = 0; y < l.rows; ++y) {
          for (int x = 0; x < l.cols; ++x) {
            const Ray ray = CameraRay(r.left, {static_cast<double>(x), static_cast<double>(y)});
            auto hit = scene.Intersect(ray);
            if (!hit) continue;
            const cv::Vec3d pc = r.left.R * hit->position + r.left.T;
            const double d_gt = r.baseline * fx / pc[2];
            if (d_gt < opt.stereo.min_disparity + 1 ||
                d_gt > opt.stereo.min_disparity + opt.stereo.num_disparities - 2 || x - d_gt < 1)
              continue;
            const Ray to_right{Or, hit->position - Or};
            if (scene.Occluded(to_right, 1e-6, 1 - 1e-4)) continue;  // occluded in the right view
            ++sc.nonocc;
            const float d = m.d.at<float>(y, x);
            if (!std::isfinite(d)) continue;
            ++sc.valid;
            const double e = std::abs(d - d_gt);
            sc.err.push_back(e);
            sc.b1 += e > 1;
            sc.b05 += e > 0.5;
          }
        }
        return sc;
      };
      const Score one = score(dm), st = score(ds);
      abs_err_all.insert(abs_err_all.end(), one.err.begin(), one.err.end());
      valid_pct.push_back(100.0 * one.valid / std::max<size_t>(1, one.nonocc));
      bad1.push_back(100.0 * one.b1 / std::max<size_t>(1, one.valid));
      bad05.push_back(100.0 * one.b05 / std::max<size_t>(1, one.valid));
      st_err_all.insert(st_err_all.end(), st.err.begin(), st.err.end());
      st_valid.push_back(100.0 * st.valid / std::max<size_t>(1, st.nonocc));
      st_bad1.push_back(100.0 * st.b1 / std::max<size_t>(1, st.valid));
      std::printf("generated frame %d brick %d: median |d - d_gt| %.3f px (spacetime, %zu frames: "
                  "%.3f px), valid %.1f%% (%.1f%%) of %zu non-occluded, bad>1px %.2f%% (%.2f%%), "
                  "%.0f ms (%.0f ms)\n",
                  f, v.brick, Quantile(one.err, 0.5), ls.size(), Quantile(st.err, 0.5),
                  valid_pct.back(), st_valid.back(), one.nonocc, bad1.back(), st_bad1.back(),
                  dm.timing.total_ms, ds.timing.total_ms);
    }
    // 3D error of the merged, cleaned points, single-frame and spacetime.
    auto error3d = [&](const std::vector<Point>& pts) {
      std::vector<double> e3;
      for (const Point& p : pts) {
        const CameraModel& c = rec.calibration.cameras[p.camera];
        const cv::Vec3d o = c.Centre(), P(p.x, p.y, p.z);
        auto hit = scene.Intersect(Ray{o, P - o});
        if (!hit) {
          e3.push_back(1.0);  // a point in front of nothing: counted as a 1 m error
          continue;
        }
        e3.push_back(cv::norm(hit->position - P));
      }
      return e3;
    };
    FrameReport rep;
    const std::vector<Point> pts = Check(proc.Process(in, &rep), "process frame");
    std::vector<double> e3 = error3d(pts);
    double s = 0;
    for (double e : e3) s += e * e;
    rmse.push_back(std::sqrt(s / std::max<size_t>(1, e3.size())));
    med3d.push_back(Quantile(e3, 0.5));
    p90_3d.push_back(Quantile(e3, 0.9));
    std::vector<const FrameInput*> window;
    for (int k = lo; k <= hi; ++k) window.push_back(&all[static_cast<size_t>(k)]);
    FrameReport rep_st;
    const std::vector<Point> pts_st =
        Check(proc.Process(in, &rep_st, window, static_cast<size_t>(f - lo)), "process spacetime");
    std::vector<double> e3s = error3d(pts_st);
    double ss = 0;
    for (double e : e3s) ss += e * e;
    st_rmse.push_back(std::sqrt(ss / std::max<size_t>(1, e3s.size())));
    st_med3d.push_back(Quantile(e3s, 0.5));
    std::printf("generated frame %d: %zu points, %llu outliers removed, 3D error RMSE %.2f mm, "
                "median %.2f mm, p90 %.2f mm; spacetime: %zu points, median %.2f mm\n",
                f, pts.size(), static_cast<unsigned long long>(rep.outliers_removed),
                rmse.back() * 1e3, med3d.back() * 1e3, p90_3d.back() * 1e3, pts_st.size(),
                st_med3d.back() * 1e3);
  }
  figures.push_back(Figure("generated.disparity.median_abs_error", "px",
                           {Quantile(abs_err_all, 0.5)}, params));
  figures.back()["target"] = {{"op", "<="}, {"value", 0.1}, {"source", "issue 5"}};
  figures.push_back(Figure("generated.disparity.valid_nonoccluded", "%", valid_pct, params));
  figures.back()["target"] = {{"op", ">="}, {"value", 95}, {"source", "issue 5"}};
  figures.push_back(Figure("generated.disparity.bad_1px", "%", bad1, params));
  figures.push_back(Figure("generated.disparity.bad_0.5px", "%", bad05, params));
  figures.push_back(Figure("generated.stereo_time", "ms", stereo_ms, params));
  auto mm = [](std::vector<double> v) {
    for (double& x : v) x *= 1e3;
    return v;
  };
  figures.push_back(Figure("generated.points.rmse_3d", "mm", mm(rmse), params));
  figures.push_back(Figure("generated.points.median_3d", "mm", mm(med3d), params));
  figures.push_back(Figure("generated.points.p90_3d", "mm", mm(p90_3d), params));
  nlohmann::json sp = params;
  sp["spacetime"] = "the frame and one on either side (two at the ends), thesis 3.4";
  figures.push_back(Figure("generated.spacetime.disparity.median_abs_error", "px",
                           {Quantile(st_err_all, 0.5)}, sp));
  figures.push_back(Figure("generated.spacetime.disparity.valid_nonoccluded", "%", st_valid, sp));
  figures.push_back(Figure("generated.spacetime.disparity.bad_1px", "%", st_bad1, sp));
  figures.push_back(Figure("generated.spacetime.stereo_time", "ms", st_ms, sp));
  figures.push_back(Figure("generated.spacetime.points.median_3d", "mm", mm(st_med3d), sp));
  figures.push_back(Figure("generated.spacetime.points.rmse_3d", "mm", mm(st_rmse), sp));
  std::printf("generated: median |d - d_gt| %.3f px single-frame, %.3f px spacetime\n",
              Quantile(abs_err_all, 0.5), Quantile(st_err_all, 0.5));
}

// ---- 1b. billboard filter against subpixel refinement ------------------------------------

// Thesis 6.5: disparities (integer, as the thesis, or the parabola's) smoothed by the bilateral
// filter of 6.2 (--filter billboard) against the subpixel LM of 3.5, on a generated recording
// with exact geometry. Per frame: the 3D error of the points (along the viewing ray, as above);
// over frames the flicker: the median and p90 change of each colour camera's depth between
// consecutive frames at pixels whose true surface did not move (static floor, wall and
// spheres), from the points of each frame.
void RunBillboard(const std::string& scratch, bool quick, nlohmann::json& figures) {
  GeneratorOptions g;
  g.bricks = quick ? 2 : 3;
  g.frames = quick ? 3 : 6;
  g.width = quick ? 160 : 320;
  g.height = quick ? 120 : 240;
  g.seed = 7;
  const std::string dir = scratch + "/generated-billboard";
  fs::remove_all(dir);
  Check(GenerateRecording(g, dir), "generate");
  const Recording rec = Check(OpenRecording(dir), "open generated recording");
  std::vector<FrameInput> all;
  for (int f = 0; f < rec.frames; ++f) all.push_back(Check(LoadFrame(rec, f), "load frame"));
  struct Config {
    std::string name;
    IngestOptions opt;
  };
  std::vector<Config> configs;
  IngestOptions base;
  base.dataset = "gen";
  base.spacetime = 0;  // single-frame stereo everywhere: the filter is what is compared
  configs.push_back({"lm", base});
  IngestOptions bb = base;
  bb.filter = IngestOptions::Filter::kBillboard;
  bb.stereo.subpixel = Subpixel::kNone;
  configs.push_back({"billboard", bb});
  IngestOptions bp = bb;
  bp.stereo.subpixel = Subpixel::kParabola;
  configs.push_back({"billboard_parabola", bp});
  IngestOptions none = base;
  none.stereo.subpixel = Subpixel::kNone;
  configs.push_back({"integer", none});
  IngestOptions para = base;
  para.stereo.subpixel = Subpixel::kParabola;
  configs.push_back({"parabola", para});
  // With the spacetime matcher the recording asks for (its stripes change every frame).
  IngestOptions st = base;
  st.spacetime = -1;
  configs.push_back({"spacetime_lm", st});
  IngestOptions stb = bp;
  stb.spacetime = -1;
  configs.push_back({"spacetime_billboard_parabola", stb});
  const nlohmann::json params = {{"bricks", g.bricks}, {"width", g.width}, {"height", g.height},
                                 {"frames", g.frames}, {"seed", g.seed},
                                 {"billboard_radius", bb.billboard.radius},
                                 {"billboard_frames", bb.billboard.temporal_radius},
                                 {"billboard_delta_d", bb.billboard.delta_d}};
  for (const Config& c : configs) {
    const FrameProcessor proc = Check(FrameProcessor::Make(rec, c.opt), "frame processor");
    const int radius = proc.window_radius();
    std::vector<double> rmse, med, p90, ms, flicker;
    // Per frame, per colour camera: depth at each pixel from the points (0: none).
    std::vector<std::map<int, cv::Mat>> depth(static_cast<size_t>(rec.frames));
    for (int f = 0; f < rec.frames; ++f) {
      const SyntheticScene scene(g.seed, f, g.fps);
      std::vector<const FrameInput*> window;
      const int lo = std::max(0, f - radius), hi = std::min(rec.frames - 1, f + radius);
      for (int k = lo; k <= hi; ++k) window.push_back(&all[static_cast<size_t>(k)]);
      FrameReport rep;
      const auto t0 = std::chrono::steady_clock::now();
      const std::vector<Point> pts = Check(
          proc.Process(all[static_cast<size_t>(f)], &rep, window.size() > 1 ? window : std::vector<const FrameInput*>{},
                       static_cast<size_t>(f - lo)),
          "process frame");
      ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
      std::vector<double> e3;
      for (const Point& p : pts) {
        const CameraModel& cam = rec.calibration.cameras[p.camera];
        const cv::Vec3d o = cam.Centre(), P(p.x, p.y, p.z);
        auto hit = scene.Intersect(Ray{o, P - o});
        e3.push_back(hit ? cv::norm(hit->position - P) : 1.0);
        const CameraModel pin = Pinhole(cam);
        double z = 0;
        const cv::Point2d px = pin.Project(P, &z);
        const int u = static_cast<int>(std::lround(px.x)), v = static_cast<int>(std::lround(px.y));
        cv::Mat& d = depth[static_cast<size_t>(f)][p.camera];
        if (d.empty()) d = cv::Mat(pin.size, CV_32F, cv::Scalar(0));
        if (u >= 0 && v >= 0 && u < d.cols && v < d.rows) d.at<float>(v, u) = static_cast<float>(z);
      }
      double s2 = 0;
      for (double e : e3) s2 += e * e;
      rmse.push_back(1e3 * std::sqrt(s2 / std::max<size_t>(1, e3.size())));
      med.push_back(1e3 * Quantile(e3, 0.5));
      p90.push_back(1e3 * Quantile(e3, 0.9));
    }
    std::vector<double> change;  // |z_f - z_f+1| at static pixels, metres
    for (int f = 0; f + 1 < rec.frames; ++f) {
      const SyntheticScene s0(g.seed, f, g.fps), s1(g.seed, f + 1, g.fps);
      for (const auto& [cam_id, d0] : depth[static_cast<size_t>(f)]) {
        auto it = depth[static_cast<size_t>(f) + 1].find(cam_id);
        if (it == depth[static_cast<size_t>(f) + 1].end()) continue;
        const CameraModel pin = Pinhole(rec.calibration.cameras[static_cast<size_t>(cam_id)]);
        for (int v = 0; v < d0.rows; ++v)
          for (int u = 0; u < d0.cols; ++u) {
            const float a = d0.at<float>(v, u), b = it->second.at<float>(v, u);
            if (!(a > 0 && b > 0)) continue;
            const Ray ray = CameraRay(pin, {double(u), double(v)});
            auto h0 = s0.Intersect(ray), h1 = s1.Intersect(ray);
            if (!h0 || !h1 || h0->object == kObjectMoving || h1->object == kObjectMoving ||
                std::abs(h0->t - h1->t) > 1e-9)
              continue;  // the surface moved: a change there is not flicker
            change.push_back(std::abs(double(a) - double(b)));
          }
      }
    }
    flicker = {1e3 * Quantile(change, 0.5)};
    const double flicker_p90 = 1e3 * Quantile(change, 0.9);
    nlohmann::json pc = params;
    pc["config"] = c.name;
    pc["subpixel"] = c.opt.stereo.subpixel == Subpixel::kNone ? "none"
                     : c.opt.stereo.subpixel == Subpixel::kParabola ? "parabola" : "lm";
    pc["filter"] = c.opt.filter == IngestOptions::Filter::kBillboard ? "billboard" : "none";
    const std::string pre = "billboard_vs_lm." + c.name + ".";
    figures.push_back(Figure(pre + "points.rmse_3d", "mm", rmse, pc));
    figures.push_back(Figure(pre + "points.median_3d", "mm", med, pc));
    figures.push_back(Figure(pre + "points.p90_3d", "mm", p90, pc));
    figures.push_back(Figure(pre + "flicker.median", "mm", flicker, pc));
    figures.push_back(Figure(pre + "flicker.p90", "mm", {flicker_p90}, pc));
    figures.push_back(Figure(pre + "frame_time", "ms", ms, pc));
    std::printf("billboard vs lm: %-18s 3D error median %.2f mm, p90 %.2f mm, RMSE %.1f mm; "
                "flicker median %.2f mm, p90 %.2f mm; %.0f ms/frame\n",
                c.name.c_str(), Quantile(med, 0.5), Quantile(p90, 0.5), Quantile(rmse, 0.5),
                flicker[0], flicker_p90, Quantile(ms, 0.5));
  }
}

// ---- 2. real sequences -----------------------------------------------------------------------

struct RealSet {
  std::string name;
  std::string dir;  // recording directory written here
  bool poses = false;
};

using hvdb::bench::CameraYaml;
using hvdb::bench::kEye;
using hvdb::bench::kZero;
using hvdb::bench::WriteYaml;

std::vector<RealSet> DescribeRealSets(const std::string& scratch, bool quick) {
  std::vector<RealSet> sets;
  const int rgbd_frames = quick ? 3 : 24;
  {  // 7-Scenes redkitchen: 640x480 Kinect v1, depth in mm (0 and 65535 invalid), poses.
    RealSet s{"7scenes", scratch + "/rec-7scenes", true};
    fs::create_directories(s.dir);
    const std::string src = kData + "/sevenscenes-redkitchen-rgbd/rgbd-frames/";
    WriteYaml(s.dir + "/calibration.yml",
              "cameras:\n" + CameraYaml("kinect", 640, 480, 585, 585, 320, 240, kEye, kZero));
    WriteYaml(s.dir + "/recording.yml",
              "format: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\nframes: " +
                  std::to_string(rgbd_frames) +
                  "\nfps: 30\nfirst_frame: 150\nframe_step: 1\ndepth_encoding: \"png16\"\n"
                  "depth_scale: 0.001\ndepth_invalid: [ 0, 65535 ]\ncameras:\n   - { name: kinect, colour: \"" +
                  src + "frame-{frame:06d}.color.png\", depth: \"" + src +
                  "frame-{frame:06d}.depth.png\", pose: \"" + src + "frame-{frame:06d}.pose.txt\" }\n");
    sets.push_back(s);
  }
  {  // Shelf bin: 640x480, depth registered to colour, every second frame from 15.
    RealSet s{"shelf", scratch + "/rec-shelf", true};
    fs::create_directories(s.dir);
    const std::string src = kData + "/apc-shelf-rgbd-sequence/sample/";
    WriteYaml(s.dir + "/calibration.yml",
              "cameras:\n" + CameraYaml("realsense", 640, 480, 615.1951904296875, 615.19525146484375,
                                        298.44268798828125, 247.51919555664062, kEye, kZero));
    WriteYaml(s.dir + "/recording.yml",
              "format: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\nframes: " +
                  std::to_string(rgbd_frames) +
                  "\nfps: 15\nfirst_frame: 15\nframe_step: 2\ndepth_encoding: \"png16\"\n"
                  "depth_scale: 0.001\ndepth_invalid: [ 0 ]\ncameras:\n   - { name: realsense, colour: \"" +
                  src + "frame-{frame:06d}.color.png\", depth: \"" + src +
                  "frame-{frame:06d}.depth.png\", pose: \"" + src + "frame-{frame:06d}.pose.txt\" }\n");
    sets.push_back(s);
  }
  {  // SJTU 10-camera stage, one frame; cameras 3 and 6 are held out of the shared copy.
    RealSet s{"sjtu", scratch + "/rec-sjtu", false};
    if (auto st = hvdb::bench::WriteSjtuRecording(kData, s.dir); !st.ok()) {
      std::fprintf(stderr, "ingest-bench: %s\n", st.ToString().c_str());
    }
    sets.push_back(s);
  }
  {  // Panoptic point-cloud video: 16 binary PLY frames in centimetres.
    RealSet s{"panoptic", scratch + "/rec-panoptic", false};
    fs::create_directories(s.dir);
    WriteYaml(s.dir + "/recording.yml",
              "format: \"hvdb-recording\"\nversion: 1\nkind: \"ply\"\nframes: " +
                  std::to_string(quick ? 3 : 16) + "\nfps: 29.97\nfirst_frame: 380\nply: \"" + kData +
                  "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/ptcloud_hd{frame:08d}.ply\"\n"
                  "ply_scale: 0.01\n");
    sets.push_back(s);
  }
  return sets;
}

// Consecutive frames of a posed RGB-D recording: frame i+1's points in frame i's camera.
void FrameAgreement(const RealSet& s, const std::string& data, nlohmann::json& figures) {
  const Recording rec = Check(OpenRecording(s.dir), "open " + s.name);
  auto backend = client::MakeEmbeddedBackend(data, 256u << 20);
  std::vector<double> rel_all;
  std::vector<double> within2;
  for (int i = 0; i + 1 < rec.frames; ++i) {
    const FrameInput fi = Check(LoadFrame(rec, i), "load");
    const DepthFrameView& v = fi.depth[0];
    Window w;
    for (int a = 0; a < 3; ++a) {
      w.lo[a] = -1e9;
      w.hi[a] = 1e9;
    }
    w.lo[3] = w.hi[3] = (i + 1) / rec.fps;
    auto q = Check(backend->Query(s.name, w, QueryOptions{}), "query");
    Batch b;
    size_t n = 0, ok2 = 0;
    while (Check(q->Next(&b), "next")) {
      for (const Point& p : b.points) {
        double z = 0;
        const cv::Point2d px = v.model.Project(cv::Vec3d(p.x, p.y, p.z), &z);
        const int u = static_cast<int>(std::lround(px.x)), vv = static_cast<int>(std::lround(px.y));
        if (z <= 0 || u < 0 || vv < 0 || u >= v.depth.cols || vv >= v.depth.rows) continue;
        const float zi = v.depth.at<float>(vv, u);
        if (!(zi > 0)) continue;
        const double rel = std::abs(z - zi) / zi;
        rel_all.push_back(rel * 100);
        ++n;
        ok2 += rel <= 0.02;
      }
    }
    within2.push_back(100.0 * ok2 / std::max<size_t>(1, n));
  }
  figures.push_back(Figure("real." + s.name + ".consecutive.median_rel_depth", "%",
                           {Quantile(rel_all, 0.5)}, {{"pairs", rec.frames - 1}}));
  figures.push_back(Figure("real." + s.name + ".consecutive.within_2pct", "%", within2,
                           {{"pairs", rec.frames - 1}}));
  std::printf("%s: consecutive frames agree: median relative depth difference %.2f%%, %.1f%% "
              "of points within 2%%\n",
              s.name.c_str(), Quantile(rel_all, 0.5), Quantile(within2, 0.5));
}

// Consecutive frames of a posed RGB-D recording, output against output: frame i's points
// z-buffered into frame i's camera, frame i+1's points compared with that depth (what a viewer
// of the video sees flicker).
void PointAgreement(const RealSet& s, const std::string& dataset, const std::string& data,
                    nlohmann::json& figures) {
  const Recording rec = Check(OpenRecording(s.dir), "open " + s.name);
  auto backend = client::MakeEmbeddedBackend(data, 256u << 20);
  auto frame_points = [&](int f) {
    Window w;
    for (int a = 0; a < 3; ++a) {
      w.lo[a] = -1e9;
      w.hi[a] = 1e9;
    }
    w.lo[3] = w.hi[3] = f / rec.fps;
    auto q = Check(backend->Query(dataset, w, QueryOptions{}), "query");
    std::vector<Point> pts;
    Batch b;
    while (Check(q->Next(&b), "next")) pts.insert(pts.end(), b.points.begin(), b.points.end());
    return pts;
  };
  std::vector<double> rel_all;
  for (int i = 0; i + 1 < rec.frames; ++i) {
    const FrameInput fi = Check(LoadFrame(rec, i), "load");
    const CameraModel& cam = fi.depth[0].model;
    cv::Mat z0(cam.size, CV_32F, cv::Scalar(0));
    for (const Point& p : frame_points(i)) {
      double z = 0;
      const cv::Point2d px = cam.Project(cv::Vec3d(p.x, p.y, p.z), &z);
      const int u = static_cast<int>(std::lround(px.x)), v = static_cast<int>(std::lround(px.y));
      if (z <= 0 || u < 0 || v < 0 || u >= z0.cols || v >= z0.rows) continue;
      float& d = z0.at<float>(v, u);
      if (d == 0 || z < d) d = static_cast<float>(z);
    }
    for (const Point& p : frame_points(i + 1)) {
      double z = 0;
      const cv::Point2d px = cam.Project(cv::Vec3d(p.x, p.y, p.z), &z);
      const int u = static_cast<int>(std::lround(px.x)), v = static_cast<int>(std::lround(px.y));
      if (z <= 0 || u < 0 || v < 0 || u >= z0.cols || v >= z0.rows) continue;
      const float d = z0.at<float>(v, u);
      if (d > 0) rel_all.push_back(100 * std::abs(z - d) / d);
    }
  }
  std::vector<double> within;
  size_t ok = 0;
  for (double r : rel_all) ok += r <= 1;
  figures.push_back(Figure("real." + dataset + ".consecutive_points.median_rel_depth", "%",
                           {Quantile(rel_all, 0.5)}, {{"pairs", rec.frames - 1}}));
  figures.push_back(Figure("real." + dataset + ".consecutive_points.p90_rel_depth", "%",
                           {Quantile(rel_all, 0.9)}, {{"pairs", rec.frames - 1}}));
  figures.push_back(Figure("real." + dataset + ".consecutive_points.within_1pct", "%",
                           {100.0 * ok / std::max<size_t>(1, rel_all.size())}, {{"pairs", rec.frames - 1}}));
  std::printf("%s: consecutive frames' points agree: median relative depth difference %.3f%%, p90 "
              "%.3f%%, %.1f%% within 1%%\n",
              dataset.c_str(), Quantile(rel_all, 0.5), Quantile(rel_all, 0.9),
              100.0 * ok / std::max<size_t>(1, rel_all.size()));
}

void RunReal(const std::string& scratch, bool quick, nlohmann::json& figures) {
  std::vector<std::pair<RealSet, std::string>> runs;  // set, extra hvdb-ingest arguments
  for (const RealSet& s : DescribeRealSets(scratch, quick)) {
    runs.push_back({s, s.name == "sjtu" ? (quick ? " --stride 4" : " --stride 2") : ""});
    if (s.name == "7scenes") {
      // The billboard filter on a real depth camera (Kinect v1: 7.5 cm baseline), frames
      // reprojected by their poses: the same sequence, output against output.
      RealSet b = s;
      b.name = "7scenes_billboard";
      runs.push_back({b, " --filter billboard --billboard-baseline 0.075"});
    }
  }
  for (const auto& [s, extra] : runs) {
    const std::string data = scratch + "/data-" + s.name, report = scratch + "/" + s.name + ".json";
    fs::remove_all(data);
    const std::string cmd = std::string(HVDB_INGEST_BIN) + " run " + s.dir + " --dataset " + s.name +
                            " --data " + data + " --quiet --report " + report + extra;
    std::printf("%s\n", cmd.c_str());
    std::fflush(stdout);
    if (std::system(cmd.c_str()) != 0) {
      std::fprintf(stderr, "ingest-bench: %s failed\n", cmd.c_str());
      std::exit(1);
    }
    std::ifstream in(report);
    const auto j = nlohmann::json::parse(in);
    std::vector<double> ppf, valid, removed;
    for (const auto& f : j["frames"]) {
      ppf.push_back(f["points"].get<double>());
      valid.push_back(f["valid_depth_pct"].get<double>());
      removed.push_back(f["outliers_removed"].get<double>());
    }
    const nlohmann::json p = {{"frames", j["ingested"]}, {"recording", s.dir}, {"args", extra},
                              {"stride", s.name == "sjtu" ? (quick ? 4 : 2) : 1}};
    figures.push_back(Figure("real." + s.name + ".points_per_frame", "points", ppf, p));
    figures.push_back(Figure("real." + s.name + ".frames_per_s", "frames/s", {j["frames_per_s"].get<double>()}, p));
    figures.push_back(Figure("real." + s.name + ".points_per_s", "points/s", {j["points_per_s"].get<double>()}, p));
    figures.push_back(Figure("real." + s.name + ".peak_rss", "MiB", {j["peak_rss_mb"].get<double>()}, p));
    if (s.name != "panoptic") {
      figures.push_back(Figure("real." + s.name + ".valid_depth", "%", valid, p));
      figures.push_back(Figure("real." + s.name + ".outliers_removed", "points", removed, p));
    }
    if (s.poses) FrameAgreement(s, data, figures);
    if (s.name.rfind("7scenes", 0) == 0) PointAgreement(s, s.name, data, figures);
    fs::remove_all(data);
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"ingest-bench: accuracy and throughput of hvdb-ingest on generated recordings "
               "(exact ground truth) and on the real sequences in ../shared/data"};
  std::string out = "ingest.json", scratch;
  bool quick = false, keep = false;
  app.add_option("--out", out, "JSON file to write")->capture_default_str();
  app.add_option("--scratch", scratch, "scratch directory (default: $TMPDIR/ingest-bench-PID)");
  app.add_flag("--quick", quick, "small sizes for a CI smoke run");
  app.add_flag("--keep-scratch", keep, "leave the scratch directory");
  std::string write_recordings;
  app.add_option("--write-recordings", write_recordings,
                 "only write the recording.yml/calibration.yml of the real sequences (rec-7scenes, "
                 "rec-shelf, rec-sjtu, rec-panoptic, rec-panoptic-photos) into this folder, for timing whole "
                 "hvdb-ingest commands (bench/ingest_targets.py), and exit");
  std::vector<std::string> parts = {"generated", "billboard", "real"};
  app.add_option("--parts", parts, "which parts to run")
      ->capture_default_str()->check(CLI::IsMember({"generated", "billboard", "real"}));
  CLI11_PARSE(app, argc, argv);
  if (!write_recordings.empty()) {
    for (const RealSet& s : DescribeRealSets(write_recordings, quick)) std::printf("%s\n", s.dir.c_str());
    // The Panoptic clouds with their colour cameras (photos and --gaussians).
    const std::string photos = write_recordings + "/rec-panoptic-photos";
    if (auto st = hvdb::bench::WritePanopticRecording(kData, photos, quick ? 3 : 16); !st.ok()) {
      std::fprintf(stderr, "ingest-bench: %s\n", st.ToString().c_str());
      return 1;
    }
    std::printf("%s\n", photos.c_str());
    return 0;
  }
  if (scratch.empty()) {
    const char* t = std::getenv("TMPDIR");
    scratch = std::string(t && *t ? t : "/tmp") + "/ingest-bench-" + std::to_string(::getpid());
  }
  fs::create_directories(scratch);
  nlohmann::json figures = nlohmann::json::array();
  auto has = [&](const std::string& p) { return std::find(parts.begin(), parts.end(), p) != parts.end(); };
  if (has("generated")) RunGenerated(scratch, quick, figures);
  if (has("billboard")) RunBillboard(scratch, quick, figures);
  if (has("real")) RunReal(scratch, quick, figures);
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  nlohmann::json doc = {{"benchmark", "ingest"}, {"quick", quick},
                        {"peak_rss_mib", ru.ru_maxrss / 1024.0}, {"figures", figures}};
  std::ofstream(out) << doc.dump(2) << "\n";
  if (!keep) fs::remove_all(scratch);
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
