// The whole ingest pipeline on generated recordings (with ground truth), on depth and PLY
// recordings, through a real hvdb-server, after a SIGKILL, and with bad frames.
#include "ingest/pipeline.h"

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <map>
#include <thread>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "client/backend.h"
#include "formats/image_io.h"
#include "ingest/generator.h"
#include "protocol/render_convert.h"
#include "protocol/wire.h"
#include "render/metrics.h"
#include "render/renderer.h"
#include "storage/database.h"
#include "tests/ingest/strokes.h"
#include "tests/ingest/test_util.h"
#include "tests/server/server_process.h"

namespace hvdb::ingest {
namespace {

using testing::TempDir;
namespace fs = std::filesystem;

GeneratorOptions Rig(int frames, int width, int height) {
  GeneratorOptions g;
  g.bricks = 2;
  g.frames = frames;
  g.width = width;
  g.height = height;
  g.supersample = 2;
  g.seed = 11;
  return g;
}

// The generated stereo recording in `rec_dir` as a depth recording in `out_dir` (the generator's
// exact EXR depth maps, absolute path patterns) of its colour cameras, whose calibration goes
// to *cal; colour(camera) gives a camera's colour image pattern (and may write the files).
Recording DepthRecordingOf(const Recording& stereo, const std::string& rec_dir,
                           const std::string& out_dir, int frames, Calibration* cal,
                           const std::function<std::string(const std::string&)>& colour) {
  Recording r;
  r.dir = out_dir;
  fs::create_directories(r.dir);
  r.kind = RecordingKind::kDepth;
  r.frames = frames;
  r.fps = stereo.fps;
  for (const Brick& b : stereo.calibration.bricks) {
    cal->cameras.push_back(stereo.calibration.cameras[b.colour]);
    CameraFiles cf;
    cf.camera = cal->cameras.back().name;
    cf.colour = colour(cf.camera);
    cf.depth = rec_dir + "/groundtruth/{frame:06d}/{camera}.depth.exr";
    r.files.push_back(cf);
  }
  return r;
}

// Camera 0 of dataset "d" as the dataset declares it.
CameraInfo info_camera0(client::Backend& b) {
  auto info = b.Describe("d");
  return info.ok() && !info->cameras.empty() ? info->cameras[0] : CameraInfo{};
}

IngestOptions Options(const std::string& dataset) {
  IngestOptions o;
  o.dataset = dataset;
  o.stereo.num_disparities = 64;
  return o;
}

// Per dataset frame: the number of points.
std::map<uint32_t, uint64_t> FrameCounts(client::Backend& b, const std::string& dataset,
                                         uint32_t frames, double fps) {
  std::map<uint32_t, uint64_t> out;
  for (uint32_t f = 0; f < frames; ++f) {
    Window w;
    for (int a = 0; a < 3; ++a) {
      w.lo[a] = -1e9;
      w.hi[a] = 1e9;
    }
    w.lo[3] = w.hi[3] = f / fps;
    auto q = b.Query(dataset, w, QueryOptions{});
    EXPECT_TRUE(q.ok()) << q.status().ToString();
    if (!q.ok()) return out;
    Batch batch;
    uint64_t n = 0;
    while (true) {
      auto more = (*q)->Next(&batch);
      EXPECT_TRUE(more.ok());
      if (!more.ok() || !*more) break;
      n += batch.points.size();
    }
    out[f] = n;
  }
  return out;
}

// Depth error of every point against the generator's ground truth in its own camera: the point
// is projected into that (distorted) camera and compared with the exact depth there,
// bilinearly interpolated where the four neighbours lie on one surface. One entry per point;
// NaN where there is no reliable truth.
std::vector<double> DepthErrors(const std::string& rec_dir, const Calibration& cal,
                                const std::vector<Point>& points, int frame) {
  std::map<int, cv::Mat> gt;
  std::vector<double> err;
  char dir[16];
  std::snprintf(dir, sizeof dir, "%06d", frame);
  for (const Point& p : points) {
    const CameraModel& c = cal.cameras[p.camera];
    if (!gt.count(p.camera)) {
      auto z = ReadDepthExr(rec_dir + "/groundtruth/" + dir + "/" + c.name + ".depth.exr");
      EXPECT_TRUE(z.ok());
      gt[p.camera] = z.ok() ? *z : cv::Mat();
    }
    const cv::Mat& z = gt[p.camera];
    double zc = 0;
    const cv::Point2d px = c.Project(cv::Vec3d(p.x, p.y, p.z), &zc);
    const int u = static_cast<int>(std::floor(px.x)), v = static_cast<int>(std::floor(px.y));
    err.push_back(NAN);
    if (u < 0 || v < 0 || u + 1 >= z.cols || v + 1 >= z.rows) continue;
    const float a = z.at<float>(v, u), b = z.at<float>(v, u + 1), cc = z.at<float>(v + 1, u),
                d = z.at<float>(v + 1, u + 1);
    const float lo = std::min({a, b, cc, d}), hi = std::max({a, b, cc, d});
    if (!std::isfinite(hi) || hi - lo > 0.02f * lo) continue;  // an edge: no reliable truth
    const double fx = px.x - u, fy = px.y - v;
    const double truth = (a * (1 - fx) + b * fx) * (1 - fy) + (cc * (1 - fx) + d * fx) * fy;
    err.back() = std::abs(zc - truth);
  }
  return err;
}

double Quantile(std::vector<double> v, double q) {
  std::erase_if(v, [](double x) { return std::isnan(x); });
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * v.size()))];
}

// A Render request through `backend`: the PNG it answers, kept at `path` and read back (an
// empty image when it failed; *st says why).
render::Srgb8Image RenderPng(client::Backend& backend, const wire::Render& req, const std::string& path,
                             Status* st) {
  std::string png;
  Result<render::RenderRequest> r = wire::FromWire(req);  // as hvdb-server decodes it
  *st = !r.ok() ? r.status() : backend.Render(*r, [&](const render::RenderReply& reply) {
    png = reply.png;
    return Status::OK();
  });
  std::ofstream(path, std::ios::binary) << png;
  auto im = formats::ReadSrgb8(path);
  return st->ok() && im.ok() ? *im : render::Srgb8Image{};
}

TEST(Pipeline, GeneratedStereoRecordingGivesAccuratePoints) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(2, 240, 180), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  IngestOptions o = Options("gen");
  auto proc = FrameProcessor::Make(*rec, o);
  ASSERT_TRUE(proc.ok()) << proc.status().ToString();
  auto in = LoadFrame(*rec, 1);
  ASSERT_TRUE(in.ok());
  FrameReport rep;
  rep.dataset_frame = 1;
  auto pts = proc->Process(*in, &rep);
  ASSERT_TRUE(pts.ok()) << pts.status().ToString();
  EXPECT_GT(rep.valid_depth_pct, 60) << "valid disparities";
  EXPECT_GT(pts->size(), 2u * 240 * 180 * 4 / 10) << "points from two bricks";
  EXPECT_GT(rep.outliers_removed, 0u);
  for (const Point& p : *pts) {
    ASSERT_TRUE(p.flags & kFlagHasCovariance);
    ASSERT_TRUE(p.camera == rec->calibration.bricks[0].colour || p.camera == rec->calibration.bricks[1].colour);
  }
  // In disparity terms (|dz| fB / z^2, f and B of the brick's grey pair): the matcher's
  // subpixel accuracy survives depth, warping and point making.
  const double fB = rec->calibration.cameras[rec->calibration.bricks[0].left].K(0, 0) * 0.12;
  // Depth errors of points of frame 1 in disparity pixels, points without truth left out.
  auto disparity_errors = [&](const std::vector<Point>& points) {
    std::vector<double> e = DepthErrors(dir / "rec", rec->calibration, points, 1);
    for (size_t i = 0; i < e.size(); ++i) {
      const Point& p = points[i];
      double z = 0;
      rec->calibration.cameras[p.camera].Project(cv::Vec3d(p.x, p.y, p.z), &z);
      e[i] *= fB / (z * z);
    }
    std::erase_if(e, [](double x) { return std::isnan(x); });
    return e;
  };
  std::vector<double> err = disparity_errors(*pts);
  ASSERT_GT(err.size(), pts->size() / 2);
  const double med = Quantile(err, 0.5), p90 = Quantile(err, 0.9);
  std::printf("depth error vs ground truth, in disparity pixels: median %.3f, p90 %.3f over %zu points\n",
              med, p90, err.size());
  EXPECT_LT(med, 0.15);
  EXPECT_LT(p90, 0.8);

  // The generator's stripes change every frame (its recording.yml says spacetime: 1): frame 1,
  // the last, matched together with frame 0 by the spacetime matcher (thesis 3.4).
  EXPECT_EQ(proc->spacetime(), 1);
  auto f0 = LoadFrame(*rec, 0);
  ASSERT_TRUE(f0.ok());
  FrameReport rep_st;
  rep_st.dataset_frame = 1;
  auto st = proc->Process(*in, &rep_st, {&*f0, &*in}, 1);
  ASSERT_TRUE(st.ok()) << st.status().ToString();
  std::vector<double> est = disparity_errors(*st);
  ASSERT_GT(est.size(), st->size() / 2);
  const double med_st = Quantile(est, 0.5), p90_st = Quantile(est, 0.9);
  std::printf("spacetime (2 frames): median %.3f, p90 %.3f over %zu points\n", med_st, p90_st,
              est.size());
  EXPECT_LT(med_st, 0.15);
  EXPECT_LT(p90_st, 0.8);
  // A window whose centre is not the frame processed is refused.
  EXPECT_FALSE(proc->Process(*in, &rep_st, {&*f0, &*in}, 0).ok());

  // The ingested frame rendered (CPU EWA splatting) from each brick's own colour camera looks
  // like that camera's image: PSNR over the pixels the splats cover fully. Measured 18.0 and
  // 18.3 dB (seed 11, 240x180); the render issue's goal is 25 dB: not met yet (see the ingest
  // note: the generator's textures vary per pixel and the splats' pixel-sized Gaussians blur
  // them). The floor guards against regressions.
  auto cpu = render::MakeCpuRenderer();
  for (const Brick& b : rec->calibration.bricks) {
    const CameraModel& cam = rec->calibration.cameras[b.colour];
    render::RenderOptions ro;
    auto img = cpu->Render(*pts, cam.ToRenderCamera(), ro);
    ASSERT_TRUE(img.ok()) << img.status().ToString();
    auto photo = formats::ReadSrgb8(rec->Path(rec->files[static_cast<size_t>(&b - &rec->calibration.bricks[0])].colour, 1));
    ASSERT_TRUE(photo.ok()) << photo.status().ToString();
    std::vector<uint8_t> mask(img->pixels());
    size_t covered = 0;
    for (size_t i = 0; i < mask.size(); ++i) covered += mask[i] = img->coverage[i] >= 0.99f;
    const double psnr = render::Psnr(formats::ToSrgb8(*img), *photo, &mask);
    std::printf("%s: rendered ingest vs its photo: PSNR %.2f dB over %zu of %zu pixels\n",
                cam.name.c_str(), psnr, covered, mask.size());
    EXPECT_GT(covered, mask.size() / 2);
    EXPECT_GE(psnr, 16.5) << cam.name;
  }
}

// Thesis 6.5: parabola disparities smoothed by the billboard filter (6.2) against the subpixel
// LM, on a generated recording with exact depth: the depth error of the points and their
// flicker (the change of a camera's depth between frames where the true surface did not move).
TEST(Pipeline, TheBillboardFilterBeatsTheSubpixelLm) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(5, 192, 144), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  std::vector<FrameInput> frames;
  for (int f = 0; f < 5; ++f) {
    auto in = LoadFrame(*rec, f);
    ASSERT_TRUE(in.ok());
    frames.push_back(std::move(in).value());
  }
  IngestOptions lm = Options("gen");
  lm.spacetime = 0;
  IngestOptions bb = lm;
  bb.filter = IngestOptions::Filter::kBillboard;
  bb.stereo.subpixel = Subpixel::kParabola;
  struct Scores {
    double median = 0, p90 = 0, flicker = 0;
  };
  auto score = [&](const IngestOptions& o) {
    Scores sc;
    auto proc = FrameProcessor::Make(*rec, o);
    EXPECT_TRUE(proc.ok()) << proc.status().ToString();
    const int radius = proc->window_radius();
    EXPECT_EQ(radius, o.filter == IngestOptions::Filter::kBillboard ? 2 : 0);
    std::vector<double> err;
    std::map<int, cv::Mat> depth[2];  // frames 2 and 3: per camera, depth at each pixel
    for (int f = 2; f <= 3; ++f) {
      std::vector<const FrameInput*> window;
      for (int k = std::max(0, f - radius); k <= std::min(4, f + radius); ++k) window.push_back(&frames[k]);
      FrameReport rep;
      auto pts = proc->Process(frames[f], &rep, radius ? window : std::vector<const FrameInput*>{},
                               static_cast<size_t>(f - std::max(0, f - radius)));
      EXPECT_TRUE(pts.ok()) << pts.status().ToString();
      if (!pts.ok()) return sc;
      const std::vector<double> e = DepthErrors(dir / "rec", rec->calibration, *pts, f);
      err.insert(err.end(), e.begin(), e.end());
      for (const Point& p : *pts) {
        const CameraModel& c = rec->calibration.cameras[p.camera];
        double z = 0;
        const cv::Point2d px = c.Project(cv::Vec3d(p.x, p.y, p.z), &z);
        cv::Mat& d = depth[f - 2][p.camera];
        if (d.empty()) d = cv::Mat(c.size, CV_32F, cv::Scalar(0));
        const int u = static_cast<int>(std::lround(px.x)), v = static_cast<int>(std::lround(px.y));
        if (u >= 0 && v >= 0 && u < d.cols && v < d.rows) d.at<float>(v, u) = static_cast<float>(z);
      }
    }
    sc.median = Quantile(err, 0.5);
    sc.p90 = Quantile(err, 0.9);
    std::vector<double> change;
    for (const auto& [cam, d2] : depth[0]) {
      const std::string name = rec->calibration.cameras[cam].name;
      auto g2 = ReadDepthExr(dir / "rec" + "/groundtruth/000002/" + name + ".depth.exr");
      auto g3 = ReadDepthExr(dir / "rec" + "/groundtruth/000003/" + name + ".depth.exr");
      EXPECT_TRUE(g2.ok() && g3.ok() && depth[1].count(cam));
      if (!g2.ok() || !g3.ok() || !depth[1].count(cam)) continue;
      const cv::Mat& d3 = depth[1][cam];
      for (int v = 0; v < d2.rows; ++v)
        for (int u = 0; u < d2.cols; ++u) {
          const float a = d2.at<float>(v, u), b = d3.at<float>(v, u);
          if (a > 0 && b > 0 && g2->at<float>(v, u) == g3->at<float>(v, u)) change.push_back(std::abs(a - b));
        }
    }
    sc.flicker = Quantile(change, 0.5);
    EXPECT_GT(change.size(), 10000u);
    return sc;
  };
  const Scores a = score(lm), b = score(bb);
  std::printf("depth error median / p90 / flicker median (mm): LM %.2f / %.2f / %.2f, "
              "billboard %.2f / %.2f / %.2f\n", a.median * 1e3, a.p90 * 1e3, a.flicker * 1e3,
              b.median * 1e3, b.p90 * 1e3, b.flicker * 1e3);
  EXPECT_LT(b.median, a.median);
  EXPECT_LT(b.p90, a.p90);
  EXPECT_LT(b.flicker, 0.7 * a.flicker);
  // The filter is for stereo recordings; its options are checked.
  bb.billboard.radius = 0;
  EXPECT_FALSE(FrameProcessor::Make(*rec, bb).ok());
}

TEST(Pipeline, RunIngestsEveryFrameAndResumesWithoutDuplicates) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(3, 128, 96), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  auto backend = client::MakeEmbeddedBackend(dir / "data", 64 << 20);
  IngestOptions o = Options("v");
  o.stereo.num_disparities = 32;
  auto rep = RunIngest(*rec, *backend, o);
  ASSERT_TRUE(rep.ok()) << rep.status().ToString();
  EXPECT_EQ(rep->ingested, 3);
  EXPECT_EQ(rep->frames.size(), 3u);
  EXPECT_GT(rep->points, 0u);
  const auto counts = FrameCounts(*backend, "v", 3, rec->fps);
  for (const auto& fr : rep->frames) {
    EXPECT_EQ(fr.status, "ingested");
    EXPECT_EQ(counts.at(fr.dataset_frame), fr.points);
    EXPECT_GT(fr.stage_ms.at("stereo"), 0);
  }
  const nlohmann::json j = rep->ToJson();
  EXPECT_EQ(j["frames"].size(), 3u);
  // Run again: everything is present, nothing is added.
  auto again = RunIngest(*rec, *backend, o);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->ingested, 0);
  EXPECT_EQ(again->present, 3);
  EXPECT_EQ(FrameCounts(*backend, "v", 3, rec->fps), counts);
  auto info = backend->Describe("v");
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->cameras.size(), 2u);
  EXPECT_DOUBLE_EQ(info->fps, rec->fps);
}

// hvdb-ingest killed with SIGKILL after its first committed frame, then run again: the result
// is frame for frame what an uninterrupted ingest gives.
TEST(Pipeline, ResumeAfterKillMatchesAnUninterruptedRun) {
  TempDir dir;
  const int frames = 6;
  ASSERT_TRUE(GenerateRecording(Rig(frames, 128, 96), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  std::map<uint32_t, uint64_t> reference;
  {
    auto backend = client::MakeEmbeddedBackend(dir / "ref", 64 << 20);
    IngestOptions o = Options("v");
    o.stereo.num_disparities = 32;
    ASSERT_TRUE(RunIngest(*rec, *backend, o).ok());
    reference = FrameCounts(*backend, "v", frames, rec->fps);
  }
  const std::string args = " run " + (dir / "rec") + " --dataset v --data " + (dir / "data") +
                           " --num-disparities 32 --workers 1 --quiet";
  for (int attempt = 0; attempt < 2; ++attempt) {
    const pid_t pid = ::fork();
    if (pid == 0) {
      ::execl("/bin/sh", "sh", "-c", (std::string("exec ") + HVDB_INGEST_PATH + args + " >/dev/null 2>&1").c_str(),
              static_cast<char*>(nullptr));
      ::_exit(127);
    }
    // Wait for a committed frame (a tree file), then kill at once.
    const fs::path trees = fs::path(dir / "data") / "v" / "trees";
    const size_t want = static_cast<size_t>(attempt) + 1;
    bool seen = false;
    for (int i = 0; i < 6000 && !seen; ++i) {
      std::error_code ec;
      size_t n = 0;
      for (auto it = fs::directory_iterator(trees, ec); !ec && it != fs::directory_iterator(); ++it) ++n;
      seen = n >= want;
      if (!seen) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    ASSERT_TRUE(seen) << "no frame committed";
    ::kill(pid, SIGKILL);
    int st = 0;
    ::waitpid(pid, &st, 0);
  }
  auto r = testing::RunCommand(std::string(HVDB_INGEST_PATH) + args + " --report " + (dir / "report.json"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "report.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_GE(j["already_present"].get<int>(), 1) << r.output;
  EXPECT_EQ(j["already_present"].get<int>() + j["ingested"].get<int>(), frames);
  auto backend = client::MakeEmbeddedBackend(dir / "data", 64 << 20);
  EXPECT_EQ(FrameCounts(*backend, "v", frames, rec->fps), reference);
  auto check = backend->Check("v");
  ASSERT_TRUE(check.ok());
  EXPECT_TRUE(check->empty());
}

// The generator's exact depth maps as a depth recording (EXR), pointed at with absolute path
// patterns, ingested through a real hvdb-server.
TEST(Pipeline, DepthRecordingThroughTheServer) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(2, 160, 120), dir / "rec").ok());
  auto stereo = OpenRecording(dir / "rec");
  ASSERT_TRUE(stereo.ok());
  Calibration cal;
  Recording r = DepthRecordingOf(*stereo, dir / "rec", dir / "depth", 2, &cal,
                                 [&](const std::string&) { return (dir / "rec") + "/frames/{frame:06d}/{camera}.png"; });
  ASSERT_TRUE(SaveCalibration(cal, r.dir + "/calibration.yml").ok());
  ASSERT_TRUE(SaveRecording(r).ok());
  hvdb::testing::ServerProcess server(dir / "data");
  ASSERT_TRUE(server.running());
  const std::string addr = "127.0.0.1:" + std::to_string(server.port());
  auto out = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " run " + r.dir +
                                 " --dataset d --server " + addr + " --quiet");
  ASSERT_EQ(out.exit_code, 0) << out.output;
  EXPECT_NE(out.output.find("ingested 2 frames"), std::string::npos) << out.output;
  auto backend = client::MakeRemoteBackend({addr, ""});
  ASSERT_TRUE(backend.ok());
  const auto counts = FrameCounts(**backend, "d", 2, r.fps);
  EXPECT_GT(counts.at(0), 160u * 120u);
  EXPECT_GT(counts.at(1), 160u * 120u);
  // The points of frame 0 agree with the exact depth (their only error is the undistortion's
  // nearest-neighbour resampling).
  Window w;
  for (int a = 0; a < 3; ++a) {
    w.lo[a] = -1e9;
    w.hi[a] = 1e9;
  }
  auto q = (*backend)->Query("d", w, QueryOptions{});
  ASSERT_TRUE(q.ok());
  std::vector<Point> pts;
  Batch b;
  while (*(*q)->Next(&b)) pts.insert(pts.end(), b.points.begin(), b.points.end());
  std::vector<Point> f0;
  for (const Point& p : pts)
    if (p.frame == 0) f0.push_back(p);
  // Point::camera is the index in the depth recording's calibration, the same cameras.
  auto err = DepthErrors(dir / "rec", cal, f0, 0);
  std::erase_if(err, [](double x) { return std::isnan(x); });
  ASSERT_GT(err.size(), f0.size() / 2);
  EXPECT_LT(Quantile(err, 0.5), 0.003);

  // The photos went in with the points (PutPhoto over the wire): frame 0 seen from camera 0,
  // rendered by the server with and without texture, against camera 0's photo over the pixels
  // the splats cover. The points alone blur the generator's per-pixel texture (~18 dB); the
  // photos over the points' depth give it back (the thesis's 6.3; the goal: 25 dB).
  auto render = [&](bool texture) -> render::Srgb8Image {
    wire::Render req;
    req.set_dataset("d");
    req.mutable_view()->set_dataset_camera(0);
    wire::ToWire(Region{Window{{-1e9, -1e9, -1e9, 0}, {1e9, 1e9, 1e9, 0}}}, req.mutable_region());
    req.set_texture(texture);
    req.set_renderer(wire::RENDERER_CPU);
    Status st;
    render::Srgb8Image im = RenderPng(**backend, req, dir / (texture ? "textured.png" : "points.png"), &st);
    EXPECT_TRUE(st.ok()) << st.ToString();
    return im;
  };
  const render::Srgb8Image points_only = render(false), textured = render(true);
  auto photo = formats::ReadSrgb8(stereo->Path(stereo->files[0].colour, 0));
  ASSERT_TRUE(photo.ok());
  ASSERT_EQ(textured.width, photo->width);
  std::vector<uint8_t> mask(size_t{photo->width} * photo->height);
  for (size_t i = 0; i < mask.size(); ++i) mask[i] = textured.channels == 3 || textured.data[4 * i + 3] == 255;
  const double p_points = render::Psnr(points_only, *photo, &mask), p_tex = render::Psnr(textured, *photo, &mask);
  std::printf("camera 0, frame 0: points only %.2f dB, textured %.2f dB\n", p_points, p_tex);
  EXPECT_GE(p_tex, 25.0);
  EXPECT_GT(p_tex, p_points + 3);
  // A bad photo is refused, not stored: bytes that are no image, an image of another size.
  Photo junk;
  junk.camera = info_camera0(**backend);
  junk.image = "not an image";
  Status refused = (*backend)->PutPhoto("d", 0, junk);
  EXPECT_TRUE(refused.IsInvalidArgument()) << refused.ToString();
  {
    std::ifstream f(dir / "points.png", std::ios::binary);  // a real PNG, of camera 0's size
    junk.image.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
  junk.camera.width /= 2;
  refused = (*backend)->PutPhoto("d", 0, junk);
  EXPECT_TRUE(refused.IsInvalidArgument()) << refused.ToString();
  EXPECT_NE(refused.ToString().find("its camera"), std::string::npos) << refused.ToString();
  // A frame without photos: a clear error, not a silent fallback.
  auto other = (*backend)->CreateDataset([] {
    DatasetInfo i;
    i.name = "bare";
    return i;
  }());
  ASSERT_TRUE(other.ok());
  ASSERT_TRUE((*backend)->BulkLoad("bare", 0, std::vector<Point>(f0.begin(), f0.begin() + 100)).ok());
  wire::Render bare;
  bare.set_dataset("bare");
  auto* cam = bare.mutable_view()->mutable_camera();
  wire::ToWire(info_camera0(**backend), cam);
  wire::ToWire(Region{Window{{-1e9, -1e9, -1e9, 0}, {1e9, 1e9, 1e9, 0}}}, bare.mutable_region());
  bare.set_texture(true);
  Status st = (*backend)->Render(wire::FromWire(bare).value(),
                                 [](const render::RenderReply&) { return Status::OK(); });
  EXPECT_TRUE(st.IsNotFound()) << st.ToString();
  EXPECT_NE(st.ToString().find("no photos"), std::string::npos) << st.ToString();
}

// Object billboards (thesis 6.4): strokes painted on the moving box in the first frame's
// colour images (red on the box, blue elsewhere, from the generator's object ids) make each
// view's billboard the box alone, with a matte at its boundary: the points are the box's, in
// every frame, and cover most of it.
TEST(Pipeline, ObjectStrokesIngestTheMarkedObjectOnly) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(3, 240, 180), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  std::filesystem::create_directories(dir / "rec/strokes");
  std::map<int, int> box_pixels;  // per colour camera: the box's pixels in frame 1
  for (const Brick& b : rec->calibration.bricks) {
    const std::string name = rec->calibration.cameras[b.colour].name;
    const cv::Mat ids = cv::imread(dir / "rec" + "/groundtruth/000000/" + name + ".object.png", cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(ids.empty());
    ASSERT_GT(cv::countNonZero(ids == kObjectMoving), 100);
    const cv::Mat marks = testing::BrushStrokes(ids == kObjectMoving);
    // Painted as the recording's stroke images are: red on the object, blue on the rest.
    cv::Mat paint(ids.size(), CV_8UC3, cv::Scalar(128, 128, 128));
    paint.setTo(cv::Scalar(0, 0, 255), marks == kStrokeObject);
    paint.setTo(cv::Scalar(255, 0, 0), marks == kStrokeRest);
    ASSERT_TRUE(cv::imwrite(dir / "rec/strokes" + "/" + name + ".png", paint));
    const cv::Mat ids1 = cv::imread(dir / "rec" + "/groundtruth/000001/" + name + ".object.png", cv::IMREAD_UNCHANGED);
    box_pixels[b.colour] = cv::countNonZero(ids1 == kObjectMoving);
  }
  IngestOptions o = Options("obj");
  o.filter = IngestOptions::Filter::kBillboard;
  o.stereo.subpixel = Subpixel::kParabola;
  o.object_strokes = "strokes/{camera}.png";
  o.depth_out = dir / "out";  // also writes each view's matte
  auto proc = FrameProcessor::Make(*rec, o);
  ASSERT_TRUE(proc.ok()) << proc.status().ToString();
  std::vector<FrameInput> frames;
  for (int f = 0; f < 3; ++f) frames.push_back(*LoadFrame(*rec, f));
  for (int f = 0; f < 3; ++f) {
    std::vector<const FrameInput*> window;
    for (const FrameInput& in : frames) window.push_back(&in);
    FrameReport rep;
    std::map<uint16_t, PhotoBillboard> boards;
    auto pts = proc->Process(frames[f], &rep, window, static_cast<size_t>(f), &boards);
    ASSERT_TRUE(pts.ok()) << pts.status().ToString();
    const SyntheticScene scene(11, f, rec->fps);
    size_t on_box = 0;
    std::map<int, size_t> per_camera;
    std::vector<double> err;
    for (const Point& p : *pts) {
      const cv::Vec3d o3 = rec->calibration.cameras[p.camera].Centre(), P(p.x, p.y, p.z);
      auto hit = scene.Intersect(Ray{o3, P - o3});
      if (hit && hit->object == kObjectMoving) {
        ++on_box;
        err.push_back(cv::norm(hit->position - P));
      }
      ++per_camera[p.camera];
    }
    std::printf("frame %d: %zu points, %.1f %% on the box, median error %.1f mm\n", f, pts->size(),
                100.0 * on_box / pts->size(), 1e3 * Quantile(err, 0.5));
    EXPECT_LT(Quantile(err, 0.5), 0.015);  // 0.06 disparity pixels at 2.7 m
    EXPECT_GT(on_box, 0.9 * pts->size()) << "frame " << f;
    if (f == 1) {
      for (auto [cam, n] : box_pixels) {
        EXPECT_GT(per_camera[cam], 0.6 * n) << "camera " << cam;
      }
    }
    EXPECT_EQ(boards.size(), rec->calibration.bricks.size());
  }
  // The mattes written with the depth maps cover the box (in the undistorted image).
  for (auto [cam, n] : box_pixels) {
    const cv::Mat matte = cv::imread(dir / "out/000001" + "/" + rec->calibration.cameras[cam].name + ".alpha.png",
                                     cv::IMREAD_UNCHANGED);
    ASSERT_FALSE(matte.empty());
    const int object = cv::countNonZero(matte >= 128);
    EXPECT_GT(object, 0.8 * n) << "camera " << cam;
    EXPECT_LT(object, 1.2 * n) << "camera " << cam;
  }
  // Clear errors: strokes need the billboard filter; a camera without its stroke image.
  IngestOptions plain = o;
  plain.filter = IngestOptions::Filter::kNone;
  EXPECT_TRUE(FrameProcessor::Make(*rec, plain).status().IsInvalidArgument());
  IngestOptions missing = o;
  missing.object_strokes = "nowhere/{camera}.png";
  auto st = FrameProcessor::Make(*rec, missing).status();
  EXPECT_TRUE(st.IsNotFound()) << st.ToString();
}

// A stereo recording ingested through a real hvdb-server with the billboard filter: the
// billboards travel with the photos (PutPhoto.billboard) and the server draws them
// (Render.billboards, thesis 6.3) from a brick's colour camera like its photo.
TEST(Pipeline, BillboardsThroughTheServer) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(3, 160, 120), dir / "rec").ok());
  auto rec = OpenRecording(dir / "rec");
  ASSERT_TRUE(rec.ok());
  hvdb::testing::ServerProcess server(dir / "data");
  ASSERT_TRUE(server.running());
  const std::string addr = "127.0.0.1:" + std::to_string(server.port());
  auto out = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " run " + (dir / "rec") +
                                 " --dataset d --server " + addr +
                                 " --filter billboard --num-disparities 64 --quiet");
  ASSERT_EQ(out.exit_code, 0) << out.output;
  auto backend = client::MakeRemoteBackend({addr, ""});
  ASSERT_TRUE(backend.ok());
  const uint16_t colour0 = static_cast<uint16_t>(rec->calibration.bricks[0].colour);
  auto render = [&](uint32_t frame, bool billboards, bool texture, Status* st) -> render::Srgb8Image {
    wire::Render req;
    req.set_dataset("d");
    req.mutable_view()->set_dataset_camera(colour0);
    const double t = frame / rec->fps;
    wire::ToWire(Region{Window{{-1e9, -1e9, -1e9, t}, {1e9, 1e9, 1e9, t}}}, req.mutable_region());
    req.set_billboards(billboards);
    req.set_texture(texture);
    req.set_renderer(wire::RENDERER_CPU);
    return RenderPng(**backend, req, dir / ("r" + std::to_string(billboards) + std::to_string(texture) + ".png"), st);
  };
  Status st;
  const render::Srgb8Image boards = render(1, true, false, &st);
  ASSERT_TRUE(st.ok()) << st.ToString();
  const render::Srgb8Image points = render(1, false, false, &st);
  ASSERT_TRUE(st.ok()) << st.ToString();
  auto photo = formats::ReadSrgb8(rec->Path(rec->files[0].colour, 1));
  ASSERT_TRUE(photo.ok());
  ASSERT_EQ(boards.width, photo->width);
  // Over the pixels both draw (opaque in both images; black is nothing drawn).
  std::vector<uint8_t> mask(size_t{photo->width} * photo->height);
  size_t drawn = 0;
  for (size_t i = 0; i < mask.size(); ++i) {
    auto opaque = [&](const render::Srgb8Image& im) {
      const uint8_t* p = &im.data[im.channels * i];
      return p[0] + p[1] + p[2] > 0 && (im.channels == 3 || p[3] == 255);
    };
    drawn += mask[i] = opaque(boards) && opaque(points);
  }
  const double p_boards = render::Psnr(boards, *photo, &mask), p_points = render::Psnr(points, *photo, &mask);
  std::printf("camera %u, frame 1: points %.2f dB, billboards %.2f dB over %zu pixels\n", colour0,
              p_points, p_boards, drawn);
  EXPECT_GT(drawn, mask.size() / 2);
  EXPECT_GE(p_boards, 25.0);
  EXPECT_GT(p_boards, p_points + 3);
  // A billboard render of a frame that has none is NOT_FOUND, not a silent fallback: the
  // same points and photos re-stored without billboards in another dataset.
  Window w{{-1e9, -1e9, -1e9, 0}, {1e9, 1e9, 1e9, 0}};
  auto q = (*backend)->Query("d", w, QueryOptions{});
  ASSERT_TRUE(q.ok());
  std::vector<Point> f0;
  Batch b;
  while (*(*q)->Next(&b)) f0.insert(f0.end(), b.points.begin(), b.points.end());
  auto info = (*backend)->Describe("d");
  ASSERT_TRUE(info.ok());
  DatasetInfo bare = *info;
  bare.name = "bare";
  ASSERT_TRUE((*backend)->CreateDataset(bare).ok());
  ASSERT_TRUE((*backend)->BulkLoad("bare", 0, f0).ok());
  wire::Render req;
  req.set_dataset("bare");
  req.mutable_view()->set_dataset_camera(colour0);
  wire::ToWire(Region{w}, req.mutable_region());
  req.set_billboards(true);
  st = (*backend)->Render(wire::FromWire(req).value(),
                          [](const render::RenderReply&) { return Status::OK(); });
  EXPECT_TRUE(st.IsNotFound()) << st.ToString();
  EXPECT_NE(st.ToString().find("no billboards"), std::string::npos) << st.ToString();
  // A billboard whose maps do not decode is refused when stored.
  Photo junk;
  junk.camera = info->cameras[0];
  {
    std::ifstream f(dir / "r10.png", std::ios::binary);  // an image of the camera's size
    junk.image.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
  }
  junk.billboard.scale = 10;
  junk.billboard.plane = {0, 0, 5};
  junk.billboard.displacement = junk.image;  // 8-bit RGB, not 16-bit grey
  junk.billboard.alpha = junk.image;
  Status refused = (*backend)->PutPhoto("d", 0, junk);
  EXPECT_TRUE(refused.IsInvalidArgument()) << refused.ToString();
  EXPECT_NE(refused.ToString().find("displacement"), std::string::npos) << refused.ToString();
}

// Colour images in a format other than PNG or JPEG are stored as PNG with the frame (and
// decode to the recorded pixels), so that a textured render can read them.
TEST(Pipeline, PhotosInOtherFormatsAreStoredAsPng) {
  TempDir dir;
  ASSERT_TRUE(GenerateRecording(Rig(1, 96, 72), dir / "rec").ok());
  auto stereo = OpenRecording(dir / "rec");
  ASSERT_TRUE(stereo.ok());
  Calibration cal;
  cv::Mat bmp_pixels;
  Recording r = DepthRecordingOf(*stereo, dir / "rec", dir / "depth", 1, &cal, [&](const std::string& name) {
    cv::Mat im = cv::imread((dir / "rec") + "/frames/000000/" + name + ".png", cv::IMREAD_COLOR);
    EXPECT_FALSE(im.empty());
    EXPECT_TRUE(cv::imwrite((dir / "depth") + "/" + name + ".bmp", im));
    if (bmp_pixels.empty()) bmp_pixels = im;
    return (dir / "depth") + "/{camera}.bmp";
  });
  ASSERT_TRUE(SaveCalibration(cal, r.dir + "/calibration.yml").ok());
  ASSERT_TRUE(SaveRecording(r).ok());
  {
    auto backend = client::MakeEmbeddedBackend(dir / "data", 16 << 20);
    // Made in code without its calibration: a clear error, not a crash.
    EXPECT_TRUE(RunIngest(r, *backend, Options("d")).status().IsInvalidArgument());
    auto opened = OpenRecording(r.dir);
    ASSERT_TRUE(opened.ok()) << opened.status().ToString();
    auto rep = RunIngest(*opened, *backend, Options("d"));
    ASSERT_TRUE(rep.ok()) << rep.status().ToString();
    EXPECT_GT(rep->frames[0].stage_ms.count("photos"), 0u);
  }
  auto db = Database::Open(dir / "data");
  ASSERT_TRUE(db.ok());
  auto ds = (*db)->GetDataset("d");
  ASSERT_TRUE(ds.ok());
  auto photos = (*ds)->Photos(0);
  ASSERT_TRUE(photos.ok());
  ASSERT_EQ(photos->size(), stereo->calibration.bricks.size());
  const Photo& first = (*photos)[0];
  EXPECT_EQ(first.image.rfind("\x89PNG", 0), 0u);
  EXPECT_EQ(first.camera.width, 96u);
  const cv::Mat decoded = cv::imdecode(cv::Mat(1, static_cast<int>(first.image.size()), CV_8U,
                                               const_cast<char*>(first.image.data())),
                                       cv::IMREAD_COLOR);
  ASSERT_EQ(decoded.size(), bmp_pixels.size());
  EXPECT_EQ(cv::norm(decoded, bmp_pixels, cv::NORM_INF), 0);
}

TEST(Pipeline, PlyRecordingAndBadFrames) {
  TempDir dir;
  Recording r;
  r.dir = dir / "ply";
  fs::create_directories(r.dir + "/frames");
  r.kind = RecordingKind::kPly;
  r.frames = 3;
  r.fps = 25;
  r.ply_scale = 0.01;  // centimetres
  ASSERT_TRUE(SaveRecording(r).ok());
  for (int f = 0; f < 3; ++f) {
    char name[64];
    std::snprintf(name, sizeof name, "%s/frames/%06d.ply", r.dir.c_str(), f);
    std::ofstream out(name);
    out << "ply\nformat ascii 1.0\nelement vertex " << 10 + f
        << "\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
           "property uchar green\nproperty uchar blue\nend_header\n";
    for (int i = 0; i < 10 + f; ++i) out << i << " " << 2 * i << " 100 255 0 0\n";
  }
  // Frame 1 is broken: stop with its name, or skip it.
  std::ofstream(r.dir + "/frames/000001.ply") << "ply\nformat ascii 1.0\nelement vertex 5\nend_header\n";
  const std::string base = std::string(HVDB_INGEST_PATH) + " run " + r.dir + " --dataset p --quiet --data " + (dir / "data");
  auto stop = testing::RunCommand(base);
  EXPECT_NE(stop.exit_code, 0);
  EXPECT_NE(stop.output.find("000001.ply"), std::string::npos) << stop.output;
  EXPECT_NE(stop.output.find("--skip-bad-frames"), std::string::npos) << stop.output;
  auto skip = testing::RunCommand(base + " --skip-bad-frames --report " + (dir / "r.json"));
  EXPECT_EQ(skip.exit_code, 3) << skip.output;
  std::ifstream in(dir / "r.json");
  const auto j = nlohmann::json::parse(in);
  EXPECT_EQ(j["skipped"].get<int>(), 1);
  bool listed = false;
  for (const auto& f : j["frames"])
    if (f["frame"] == 1) listed = f["status"] == "skipped" && f["error"].get<std::string>().find("000001.ply") != std::string::npos;
  EXPECT_TRUE(listed) << j.dump();
  auto backend = client::MakeEmbeddedBackend(dir / "data", 16 << 20);
  const auto counts = FrameCounts(*backend, "p", 3, 25);
  EXPECT_EQ(counts.at(0), 10u);
  EXPECT_EQ(counts.at(1), 0u);
  EXPECT_EQ(counts.at(2), 12u);
  auto q = backend->Query("p", Window{{-1, -1, 0.5, 2 / 25.0}, {1, 1, 1.5, 2 / 25.0}}, QueryOptions{});
  ASSERT_TRUE(q.ok());
  Batch b;
  ASSERT_TRUE(*(*q)->Next(&b));
  EXPECT_NEAR(b.points[0].z, 1.0, 1e-6);  // 100 cm
}

TEST(Pipeline, UsageErrors) {
  TempDir dir;
  auto none = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " run " + dir.path() + " --dataset x --data " + (dir / "d"));
  EXPECT_EQ(none.exit_code, 2);
  EXPECT_NE(none.output.find("recording.yml"), std::string::npos) << none.output;
  auto both = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " run " + dir.path() + " --dataset x");
  EXPECT_NE(both.exit_code, 0);
  EXPECT_NE(both.output.find("--data"), std::string::npos);
  // The billboard filter on a depth recording needs the sensor's baseline; nothing is created.
  {
    Recording r;
    r.dir = dir / "depth";
    std::filesystem::create_directories(r.dir);
    r.kind = RecordingKind::kDepth;
    r.frames = 1;
    Calibration cal;
    cal.cameras.push_back(GeneratorCalibration(Rig(1, 32, 24)).cameras[0]);
    r.files.push_back(CameraFiles{cal.cameras[0].name, "c.png", "d.exr", "", "", ""});
    ASSERT_TRUE(SaveCalibration(cal, r.dir + "/calibration.yml").ok());
    ASSERT_TRUE(SaveRecording(r).ok());
  }
  auto bb = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " run " + (dir / "depth") +
                                " --dataset x --data " + (dir / "d") + " --filter billboard");
  EXPECT_EQ(bb.exit_code, 2) << bb.output;
  EXPECT_NE(bb.output.find("--billboard-baseline"), std::string::npos) << bb.output;
  EXPECT_FALSE(std::filesystem::exists(dir / "d/x"));
  for (const char* sub : {"run", "check", "calibrate", "stereo", "generate", "replay"}) {
    auto h = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " " + sub + " --help");
    EXPECT_EQ(h.exit_code, 0) << sub << ": " << h.output;
  }
}

}  // namespace
}  // namespace hvdb::ingest
