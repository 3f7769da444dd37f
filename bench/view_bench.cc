// view-bench: novel views of real multi-view data, one camera left out (issue 16).
//
// For each held-out camera h of the SJTU stage frame (8 cameras of 1920x1080 with COLMAP depth):
// the other seven are ingested by the ingest pipeline (FrameProcessor: what hvdb-ingest stores),
// the points are rendered from camera h by the CPU renderer, and the image is compared with
// h's photo: PSNR over the pixels where h's own depth map is valid (the scene, not the void
// behind it). Next to it in the same run, the naive baseline: the nearest other camera's photo
// forward-warped into h by its own depth map (z-buffered, one-pixel cracks filled from their
// neighbours). Writes JSON and, per camera, the three images side by side.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <unistd.h>
#include <vector>

#include "bench/real_recordings.h"
#include "ingest/pipeline.h"
#include "ingest/recording.h"
#include "render/metrics.h"
#include "render/projective_texture.h"
#include "render/renderer.h"

namespace {

using hvdb::ingest::DepthFrameView;
namespace fs = std::filesystem;

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// BGR cv::Mat -> RGB Srgb8Image.
hvdb::render::Srgb8Image FromMat(const cv::Mat& bgr) {
  hvdb::render::Srgb8Image im;
  im.width = static_cast<uint32_t>(bgr.cols);
  im.height = static_cast<uint32_t>(bgr.rows);
  im.channels = 3;
  im.data.resize(size_t{im.width} * im.height * 3);
  for (int y = 0; y < bgr.rows; ++y) {
    for (int x = 0; x < bgr.cols; ++x) {
      const cv::Vec3b p = bgr.at<cv::Vec3b>(y, x);
      uint8_t* o = &im.data[(size_t(y) * im.width + size_t(x)) * 3];
      o[0] = p[2], o[1] = p[1], o[2] = p[0];
    }
  }
  return im;
}

cv::Mat ToMat(const hvdb::render::Srgb8Image& im) {
  cv::Mat bgr(static_cast<int>(im.height), static_cast<int>(im.width), CV_8UC3);
  for (int y = 0; y < bgr.rows; ++y) {
    for (int x = 0; x < bgr.cols; ++x) {
      const uint8_t* p = &im.data[(size_t(y) * im.width + size_t(x)) * im.channels];
      bgr.at<cv::Vec3b>(y, x) = im.channels >= 3 ? cv::Vec3b(p[2], p[1], p[0]) : cv::Vec3b(p[0], p[0], p[0]);
    }
  }
  return bgr;
}

// The naive baseline: `src`'s photo forward-warped into `dst` by src's depth (metres, 0 = none),
// nearest pixel with a z-buffer, then every empty pixel with at least 3 filled neighbours of
// its 8 takes their mean (the cracks a forward warp leaves between pixels that spread apart).
cv::Mat Warp(const DepthFrameView& src, const hvdb::ingest::CameraModel& dst) {
  const int w = dst.size.width, h = dst.size.height;
  cv::Mat out(h, w, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::Mat zbuf(h, w, CV_32F, cv::Scalar(std::numeric_limits<float>::infinity()));
  const cv::Matx33d Kinv = src.model.K.inv();
  const cv::Matx33d Rt = src.model.R.t();
  const cv::Vec3d centre = src.model.Centre();
  for (int y = 0; y < src.depth.rows; ++y) {
    for (int x = 0; x < src.depth.cols; ++x) {
      const float z = src.depth.at<float>(y, x);
      if (!(z > 0)) continue;
      const cv::Vec3d world = Rt * (Kinv * cv::Vec3d(x, y, 1) * z) + centre;
      double zc = 0;
      const cv::Point2d p = dst.Project(world, &zc);
      const int u = static_cast<int>(std::lround(p.x)), v = static_cast<int>(std::lround(p.y));
      if (zc <= 0 || u < 0 || v < 0 || u >= w || v >= h) continue;
      if (zc < zbuf.at<float>(v, u)) {
        zbuf.at<float>(v, u) = static_cast<float>(zc);
        out.at<cv::Vec3b>(v, u) = src.colour.at<cv::Vec3b>(y, x);
      }
    }
  }
  cv::Mat filled = out.clone();
  for (int y = 1; y + 1 < h; ++y) {
    for (int x = 1; x + 1 < w; ++x) {
      if (std::isfinite(zbuf.at<float>(y, x))) continue;
      int n = 0, sum[3] = {0, 0, 0};
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          if (!std::isfinite(zbuf.at<float>(y + dy, x + dx))) continue;
          const cv::Vec3b c = out.at<cv::Vec3b>(y + dy, x + dx);
          for (int k = 0; k < 3; ++k) sum[k] += c[k];
          ++n;
        }
      }
      if (n >= 3) filled.at<cv::Vec3b>(y, x) = cv::Vec3b(uchar(sum[0] / n), uchar(sum[1] / n), uchar(sum[2] / n));
    }
  }
  return filled;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"view-bench: novel views of the SJTU stage, one camera left out, against the "
               "naive warp of the nearest camera"};
  std::string out = "view.json", images = "", shared = HVDB_SHARED_DATA, scratch;
  std::vector<int> held = {1, 2, 4, 5, 7, 8};
  int stride = 2;
  bool quick = false, png = false, no_geometric = false, no_photo = false;
  int edge_radius = 2;
  app.add_option("--out", out, "JSON output file")->capture_default_str();
  app.add_option("--images", images, "folder for the images (ours | warp | photo per camera)");
  app.add_option("--cameras", held, "held-out camera ids (interior cameras by default)")
      ->capture_default_str();
  app.add_option("--stride", stride, "ingest every stride-th depth pixel")->check(CLI::Range(1, 8))
      ->capture_default_str();
  app.add_option("--shared-data", shared, "the shared data folder")->capture_default_str();
  app.add_option("--scratch", scratch, "folder for the recording files (default: a temporary one)");
  app.add_flag("--png", png, "images as PNG instead of JPEG");
  app.add_flag("--no-geometric", no_geometric, "ingest without the cross-view geometric consistency test");
  app.add_flag("--no-photo", no_photo, "ingest without photo-consistency");
  app.add_option("--edge-radius", edge_radius, "ingest's mixed-pixel removal radius (0: off)")->capture_default_str();
  app.add_flag("--quick", quick, "camera 4 only, stride 4 (CI smoke run)");
  CLI11_PARSE(app, argc, argv);
  if (quick) held = {4}, stride = 4;
  const bool own_scratch = scratch.empty();
  if (own_scratch) scratch = (fs::temp_directory_path() / ("view-bench-" + std::to_string(getpid()))).string();
  if (auto st = hvdb::bench::WriteSjtuRecording(shared, scratch + "/rec-sjtu"); !st.ok()) {
    std::fprintf(stderr, "view-bench: %s\n", st.ToString().c_str());
    return 1;
  }
  auto rec = hvdb::ingest::OpenRecording(scratch + "/rec-sjtu");
  if (!rec.ok()) {
    std::fprintf(stderr, "view-bench: %s\n", rec.status().ToString().c_str());
    return 1;
  }
  auto frame = hvdb::ingest::LoadFrame(*rec, 0);
  if (!frame.ok()) {
    std::fprintf(stderr, "view-bench: %s\n", frame.status().ToString().c_str());
    return 1;
  }
  if (!images.empty()) fs::create_directories(images);
  auto renderer = hvdb::render::MakeCpuRenderer();
  nlohmann::json figures = nlohmann::json::array();
  std::vector<double> gains;
  for (int id : held) {
    const std::string name = "cam" + std::to_string(id);
    auto it = std::find_if(frame->depth.begin(), frame->depth.end(), [&](const DepthFrameView& v) {
      return rec->calibration.cameras[static_cast<size_t>(v.camera)].name == name;
    });
    if (it == frame->depth.end()) {
      std::fprintf(stderr, "view-bench: no camera %s in the shared data\n", name.c_str());
      return 1;
    }
    const DepthFrameView& target = *it;
    hvdb::ingest::FrameInput others = *frame;
    others.depth.erase(others.depth.begin() + (it - frame->depth.begin()));
    // Ingest the other seven as hvdb-ingest does.
    hvdb::ingest::IngestOptions io;
    io.dataset = "view-bench";
    io.stride = stride;
    io.geometric_consistency = !no_geometric;
    io.photo_consistency = !no_photo;
    io.edge_radius = edge_radius;
    auto proc = hvdb::ingest::FrameProcessor::Make(*rec, io);
    if (!proc.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", proc.status().ToString().c_str());
      return 1;
    }
    auto t0 = std::chrono::steady_clock::now();
    hvdb::ingest::FrameReport report;
    auto points = proc->Process(others, &report);
    if (!points.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", points.status().ToString().c_str());
      return 1;
    }
    const double ingest_s = Seconds(t0);
    if (getenv("ONLY")) {
      std::vector<hvdb::Point> kept;
      for (const auto& p : *points) if (p.camera == atoi(getenv("ONLY"))) kept.push_back(p);
      *points = kept;
    }
    // Render h's view, view-dependent blending over the seven source cameras.
    hvdb::render::RenderOptions ro;
    ro.view_dependent = true;
    for (const DepthFrameView& v : others.depth) {
      ro.source_cameras.push_back({static_cast<uint16_t>(v.camera), v.model.ToRenderCamera().world_from_camera});
    }
    t0 = std::chrono::steady_clock::now();
    auto img = renderer->Render(*points, target.model.ToRenderCamera(), ro);
    if (!img.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", img.status().ToString().c_str());
      return 1;
    }
    const double render_s = Seconds(t0);
    hvdb::render::Srgb8Image ours = hvdb::render::ToSrgb8(*img);
    if (ours.channels == 4) {  // drop alpha (the background is black and opaque)
      hvdb::render::Srgb8Image rgb{ours.width, ours.height, 3, {}};
      rgb.data.reserve(size_t{ours.width} * ours.height * 3);
      for (size_t p = 0; p < ours.data.size(); p += 4) rgb.data.insert(rgb.data.end(), &ours.data[p], &ours.data[p + 3]);
      ours = std::move(rgb);
    }
    // Colour from the seven photos over the points' depth (thesis 6.3): what each source sees
    // is its own render's depth.
    t0 = std::chrono::steady_clock::now();
    std::vector<std::vector<uint8_t>> rgbs;
    std::vector<hvdb::render::Image> seen;
    std::vector<hvdb::render::TextureView> tviews;
    for (const DepthFrameView& v : others.depth) {
      const hvdb::render::Camera sc = v.model.ToRenderCamera();
      auto si = renderer->Render(*points, sc, hvdb::render::RenderOptions{});
      if (!si.ok()) {
        std::fprintf(stderr, "view-bench: %s\n", si.status().ToString().c_str());
        return 1;
      }
      seen.push_back(std::move(*si));
      rgbs.push_back(FromMat(v.colour).data);
    }
    for (size_t i = 0; i < others.depth.size(); ++i) {
      tviews.push_back({others.depth[i].model.ToRenderCamera(), rgbs[i], seen[i].depth});
    }
    hvdb::render::Image textured = *img;
    hvdb::render::TextureStats tstats;
    if (auto st = hvdb::render::ProjectiveTexture(target.model.ToRenderCamera(), tviews,
                                                  hvdb::render::TextureOptions{}, &textured, &tstats);
        !st.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", st.ToString().c_str());
      return 1;
    }
    const double texture_s = Seconds(t0);
    hvdb::render::Srgb8Image tex = hvdb::render::ToSrgb8(textured);
    if (tex.channels == 4) {
      hvdb::render::Srgb8Image rgb{tex.width, tex.height, 3, {}};
      for (size_t p = 0; p < tex.data.size(); p += 4) rgb.data.insert(rgb.data.end(), &tex.data[p], &tex.data[p + 3]);
      tex = std::move(rgb);
    }
    // The naive warp of the nearest other camera.
    const DepthFrameView* nearest = nullptr;
    for (const DepthFrameView& v : others.depth) {
      if (!nearest || cv::norm(v.model.Centre() - target.model.Centre()) <
                          cv::norm(nearest->model.Centre() - target.model.Centre())) {
        nearest = &v;
      }
    }
    const cv::Mat warp = Warp(*nearest, target.model);
    // PSNR where h's depth is valid.
    std::vector<uint8_t> mask(size_t(target.depth.rows) * size_t(target.depth.cols));
    for (int y = 0; y < target.depth.rows; ++y) {
      for (int x = 0; x < target.depth.cols; ++x) mask[size_t(y) * size_t(target.depth.cols) + size_t(x)] = target.depth.at<float>(y, x) > 0;
    }
    const hvdb::render::Srgb8Image photo = FromMat(target.colour), warped = FromMat(warp);
    const double psnr_points = hvdb::render::Psnr(ours, photo, &mask);
    const double psnr_ours = hvdb::render::Psnr(tex, photo, &mask);
    const double psnr_warp = hvdb::render::Psnr(warped, photo, &mask);
    const double ssim_ours = hvdb::render::Ssim(tex, photo, &mask);
    const double ssim_warp = hvdb::render::Ssim(warped, photo, &mask);
    gains.push_back(psnr_ours - psnr_warp);
    std::printf("%s: %zu points from 7 cameras (ingest %.1f s, render %.2f s, texture %.2f s): PSNR "
                "points only %.2f dB, textured %.2f dB, warp of %s %.2f dB (%+.2f dB); SSIM %.3f vs %.3f\n",
                name.c_str(), points->size(), ingest_s, render_s, texture_s, psnr_points, psnr_ours,
                rec->calibration.cameras[static_cast<size_t>(nearest->camera)].name.c_str(),
                psnr_warp, psnr_ours - psnr_warp, ssim_ours, ssim_warp);
    std::fflush(stdout);
    nlohmann::json params = {{"held_out", name}, {"stride", stride}, {"points", points->size()},
                             {"warped_from", rec->calibration.cameras[static_cast<size_t>(nearest->camera)].name}};
    figures.push_back({{"name", "view_psnr_ours"}, {"unit", "dB"}, {"median", psnr_ours}, {"params", params}});
    figures.push_back({{"name", "view_psnr_points_only"}, {"unit", "dB"}, {"median", psnr_points}, {"params", params}});
    figures.push_back({{"name", "view_psnr_warp"}, {"unit", "dB"}, {"median", psnr_warp}, {"params", params}});
    figures.push_back({{"name", "view_ssim_ours"}, {"unit", "ratio"}, {"median", ssim_ours}, {"params", params}});
    figures.push_back({{"name", "view_ssim_warp"}, {"unit", "ratio"}, {"median", ssim_warp}, {"params", params}});
    figures.push_back({{"name", "view_ingest"}, {"unit", "s"}, {"median", ingest_s}, {"params", params}});
    figures.push_back({{"name", "view_render"}, {"unit", "s"}, {"median", render_s}, {"params", params}});
    if (!images.empty()) {
      // ours | warp | photo, at half size.
      cv::Mat row;
      cv::hconcat(std::vector<cv::Mat>{ToMat(tex), warp, target.colour}, row);
      cv::resize(row, row, cv::Size(row.cols / 2, row.rows / 2), 0, 0, cv::INTER_AREA);
      if (png) {
        cv::imwrite(images + "/" + name + ".png", row);
      } else {
        cv::imwrite(images + "/" + name + ".jpg", row, {cv::IMWRITE_JPEG_QUALITY, 88});
      }
    }
  }
  std::vector<double> sorted = gains;
  std::sort(sorted.begin(), sorted.end());
  const double median_gain = sorted.empty() ? 0 : sorted[sorted.size() / 2];
  figures.push_back({{"name", "view_psnr_gain_over_warp"}, {"unit", "dB"}, {"median", median_gain},
                     {"values", gains}, {"params", {{"cameras", held.size()}, {"stride", stride}}}});
  std::printf("median PSNR gain over the warp: %+.2f dB over %zu cameras\n", median_gain, gains.size());
  std::ofstream(out) << nlohmann::json{{"benchmark", "view"}, {"figures", figures}}.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  std::error_code ec;
  if (own_scratch) fs::remove_all(scratch, ec);
  return 0;
}
