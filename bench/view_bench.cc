// view-bench: novel views of real multi-view data, one camera left out (issue 16).
//
// For each held-out camera h of the SJTU stage frame (8 cameras of 1920x1080 with COLMAP depth):
// the other seven are ingested by the ingest pipeline (FrameProcessor: what hvdb-ingest stores),
// the points are rendered from camera h by the CPU renderer, and the image is compared with
// h's photo: PSNR over the pixels where h's own depth map is valid (the scene, not the void
// behind it). Next to it in the same run, the naive baseline: the nearest other camera's photo
// forward-warped into h by its own depth map (z-buffered, one-pixel cracks filled from their
// neighbours). Writes JSON and, per camera, the three images side by side. The points and the
// seven photos go into a dataset and are rendered through the Render request (embedded: the
// RenderJob hvdb-server runs), plain (view-dependent splats) and as a request with no mode
// given: the default, which draws the frame textured from its photos (reply.mode_used says so).
// With --gaussians, also what `hvdb-ingest run --gaussians` makes of the seven cameras: Gaussians
// fitted to their photos from the points (ingest/gaussian_frames.h), stored in a Gaussian-splat
// dataset and rendered by the default request (gaussian mode), against the held-out photo.
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
#include "bench/view_generated.h"
#include "client/backend.h"
#include "ingest/gaussian_frames.h"
#include "formats/gaussian_points.h"
#include "ingest/pipeline.h"
#include "ingest/recording.h"
#include "protocol/render_convert.h"
#include "render/metrics.h"
#include "render/renderer.h"

namespace {

using hvdb::bench::FromMat;
using hvdb::bench::ToMat;
using hvdb::ingest::DepthFrameView;
namespace fs = std::filesystem;

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
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
  bool gaussians = false;
  hvdb::ingest::GaussianFrameOptions fit;
  app.add_flag("--gaussians", gaussians, "also fit Gaussians to the seven photos (hvdb-ingest run "
                                         "--gaussians) and render them");
  int fit_iterations = fit.fit.iterations;
  app.add_option("--fit-iterations", fit_iterations, "--gaussians: optimisation steps (the "
                                                     "schedule scales with them)")
      ->capture_default_str();
  app.add_option("--fit-resolution", fit.resolution_scale, "--gaussians: photos fitted at 1/N size")
      ->capture_default_str();
  app.add_option("--fit-sh-degree", fit.fit.sh_degree, "--gaussians: SH degree")->capture_default_str();
  app.add_option("--fit-start-splats", fit.max_start_splats, "--gaussians: most splats to start from")
      ->capture_default_str();
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
  std::vector<std::string> parts = {"sjtu", "generated"};
  app.add_option("--parts", parts, "sjtu: the SJTU stage against the warp; generated: a generated "
                                   "recording, points against billboards")
      ->capture_default_str()->check(CLI::IsMember({"sjtu", "generated"}));
  CLI11_PARSE(app, argc, argv);
  const bool sjtu = std::find(parts.begin(), parts.end(), "sjtu") != parts.end();
  const bool generated = std::find(parts.begin(), parts.end(), "generated") != parts.end();
  if (quick) held = {4}, stride = 4;
  fit.fit = hvdb::ingest::Scheduled(fit.fit, fit_iterations);
  const bool own_scratch = scratch.empty();
  if (own_scratch) scratch = (fs::temp_directory_path() / ("view-bench-" + std::to_string(getpid()))).string();
  nlohmann::json figures = nlohmann::json::array();
  if (generated) {
    if (hvdb::bench::RunGeneratedViews({scratch, images, quick}, figures) != 0) return 1;
  }
  if (!sjtu) {
    std::ofstream(out) << nlohmann::json{{"benchmark", "view"}, {"figures", figures}}.dump(2) << "\n";
    std::printf("wrote %s\n", out.c_str());
    std::error_code ec;
    if (own_scratch) fs::remove_all(scratch, ec);
    return 0;
  }
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
  // Datasets of the held-out runs (removed at the end with the scratch folder).
  auto backend = hvdb::client::MakeEmbeddedBackend(scratch + "/data", size_t{256} << 20);
  std::vector<double> gains, fit_gains;
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
    const size_t point_count = points->size();
    // Into a dataset as hvdb-ingest stores it: the points, and the seven photos with their
    // cameras; then rendered as `hvdb render` asks for it (embedded: the same RenderJob as
    // hvdb-server), with view-dependent blending, and textured.
    const std::string dataset = "held-out-" + name;
    hvdb::DatasetInfo info;
    info.name = dataset;
    std::vector<hvdb::Photo> photos;
    for (const DepthFrameView& v : others.depth) {
      std::ifstream f(v.colour_path, std::ios::binary);
      hvdb::Photo photo;
      photo.image.assign(std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>());
      photo.camera = hvdb::ingest::ToCameraInfo(v.model, static_cast<uint16_t>(v.camera));
      info.cameras.push_back(photo.camera);
      photos.push_back(std::move(photo));
    }
    if (auto c = backend->CreateDataset(info); !c.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", c.status().ToString().c_str());
      return 1;
    }
    for (const hvdb::Photo& photo : photos) {
      if (auto st = backend->PutPhoto(dataset, 0, photo); !st.ok()) {
        std::fprintf(stderr, "view-bench: %s\n", st.ToString().c_str());
        return 1;
      }
    }
    const std::vector<hvdb::Point> kept_points = gaussians ? *points : std::vector<hvdb::Point>{};
    if (auto st = backend->BulkLoad(dataset, 0, std::move(points).value()); !st.ok()) {
      std::fprintf(stderr, "view-bench: %s\n", st.status().ToString().c_str());
      return 1;
    }
    double render_s = 0, texture_s = 0;
    std::string default_mode, default_choice;
    std::string render_dataset = dataset;
    // texture = false: the points, view-dependent (mode given); true: the request's default
    // (no mode, texture or billboards given), which the job resolves: textured here, where
    // the frame has photos.
    auto render = [&](bool texture) -> hvdb::render::Srgb8Image {
      hvdb::wire::Render req;
      req.set_dataset(render_dataset);
      hvdb::wire::ToWire(hvdb::ingest::ToCameraInfo(target.model, static_cast<uint16_t>(target.camera)),
                         req.mutable_view()->mutable_camera());
      hvdb::wire::ToWire(hvdb::Region{hvdb::Window{{-1e9, -1e9, -1e9, 0}, {1e9, 1e9, 1e9, 0}}},
                         req.mutable_region());
      if (!texture) {
        req.set_view_dependent(true);
        req.set_mode(hvdb::wire::RENDER_VISIBILITY);
      }
      req.set_renderer(hvdb::wire::RENDERER_CPU);
      std::string encoded;
      const auto t = std::chrono::steady_clock::now();
      hvdb::Status st = backend->Render(hvdb::wire::FromWire(req).value(),
                                        [&](const hvdb::render::RenderReply& reply) {
        encoded = reply.png;
        if (texture) {
          default_mode = reply.mode_used;
          default_choice = reply.mode_choice;
        }
        return hvdb::Status::OK();
      });
      (texture ? texture_s : render_s) = Seconds(t);
      if (!st.ok()) {
        std::fprintf(stderr, "view-bench: render: %s\n", st.ToString().c_str());
        std::exit(1);
      }
      cv::Mat bgr = cv::imdecode(cv::Mat(1, static_cast<int>(encoded.size()), CV_8U, encoded.data()), cv::IMREAD_COLOR);
      return FromMat(bgr);
    };
    const hvdb::render::Srgb8Image ours = render(false), tex = render(true);
    const std::string textured_mode = default_mode, textured_choice = default_choice;
    // The seven photos' Gaussians, as hvdb-ingest run --gaussians makes and stores them.
    hvdb::render::Srgb8Image fitted;
    double fit_s = 0, fitted_render_s = 0;
    hvdb::ingest::FitReport fit_report;
    if (gaussians) {
      auto t_fit = std::chrono::steady_clock::now();
      auto views = hvdb::ingest::FrameFitViews(*rec, others, fit.resolution_scale);
      if (!views.ok()) {
        std::fprintf(stderr, "view-bench: %s\n", views.status().ToString().c_str());
        return 1;
      }
      hvdb::ingest::GaussianFrameOptions fo = fit;
      fo.fit.progress = [](int done, int total) {
        if (done % 50 == 0 || done == total) std::fprintf(stderr, "\r  fitting %d/%d ", done, total);
      };
      hvdb::ingest::GaussianVideoFitter fitter(fo);
      auto cloud = fitter.Fit(0, std::move(views).value(), kept_points, &fit_report);
      if (!cloud.ok()) {
        std::fprintf(stderr, "view-bench: fit: %s\n", cloud.status().ToString().c_str());
        return 1;
      }
      fit_s = Seconds(t_fit);
      std::fprintf(stderr, "\n");
      hvdb::DatasetInfo ginfo = info;
      ginfo.name = dataset + "-gaussians";
      ginfo.gaussians = true;
      if (auto c = backend->CreateDataset(ginfo); !c.ok()) {
        std::fprintf(stderr, "view-bench: %s\n", c.status().ToString().c_str());
        return 1;
      }
      std::vector<hvdb::Point> splats;
      hvdb::GaussianColumns columns;
      hvdb::formats::CloudToPoints(*cloud, 0, &splats, &columns);
      if (auto st = backend->BulkLoad(ginfo.name, 0, std::move(splats), &columns); !st.ok()) {
        std::fprintf(stderr, "view-bench: %s\n", st.status().ToString().c_str());
        return 1;
      }
      render_dataset = ginfo.name;
      const double tex_s = texture_s;
      fitted = render(true);  // the default of a Gaussian-splat dataset: gaussian mode
      fitted_render_s = texture_s;
      texture_s = tex_s;
      render_dataset = dataset;
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
    if (gaussians) {
      const double psnr_fit = hvdb::render::Psnr(fitted, photo, &mask);
      const double ssim_fit = hvdb::render::Ssim(fitted, photo, &mask);
      std::printf("%s: fitted Gaussians (%s, %d iterations at 1/%d size, %zu -> %zu splats, "
                  "training views %.2f dB) in %.1f s: PSNR %.2f dB (%+.2f dB over textured), "
                  "SSIM %.3f; render %.2f s\n",
                  name.c_str(), default_mode.c_str(), fit_report.iterations, fit.resolution_scale,
                  fit_report.splats_in, fit_report.splats_out, fit_report.psnr, fit_s, psnr_fit,
                  psnr_fit - psnr_ours, ssim_fit, fitted_render_s);
      nlohmann::json fp = {{"held_out", name}, {"stride", stride}, {"iterations", fit_report.iterations},
                           {"resolution_scale", fit.resolution_scale}, {"sh_degree", fit.fit.sh_degree},
                           {"splats_start", fit_report.splats_in}, {"splats", fit_report.splats_out},
                           {"mode_used", default_mode}, {"training_psnr", fit_report.psnr}};
      figures.push_back({{"name", "view_psnr_fitted"}, {"unit", "dB"}, {"median", psnr_fit}, {"params", fp}});
      figures.push_back({{"name", "view_ssim_fitted"}, {"unit", "ratio"}, {"median", ssim_fit}, {"params", fp}});
      figures.push_back({{"name", "view_psnr_fitted_over_textured"}, {"unit", "dB"},
                         {"median", psnr_fit - psnr_ours}, {"params", fp}});
      figures.push_back({{"name", "view_fit"}, {"unit", "s"}, {"median", fit_s}, {"params", fp}});
      fit_gains.push_back(psnr_fit - psnr_ours);
      default_mode = textured_mode;
      default_choice = textured_choice;
    }
    gains.push_back(psnr_ours - psnr_warp);
    std::printf("%s: %zu points from 7 cameras (ingest %.1f s, render %.2f s, default %.2f s): PSNR "
                "points only %.2f dB, default (%s: %s) %.2f dB, warp of %s %.2f dB (%+.2f dB); SSIM %.3f vs %.3f\n",
                name.c_str(), point_count, ingest_s, render_s, texture_s, psnr_points,
                default_mode.c_str(), default_choice.c_str(), psnr_ours,
                rec->calibration.cameras[static_cast<size_t>(nearest->camera)].name.c_str(),
                psnr_warp, psnr_ours - psnr_warp, ssim_ours, ssim_warp);
    std::fflush(stdout);
    nlohmann::json params = {{"held_out", name}, {"stride", stride}, {"points", point_count},
                             {"default_mode", default_mode},
                             {"warped_from", rec->calibration.cameras[static_cast<size_t>(nearest->camera)].name}};
    figures.push_back({{"name", "view_psnr_ours"}, {"unit", "dB"}, {"median", psnr_ours}, {"params", params}});
    figures.push_back({{"name", "view_psnr_points_only"}, {"unit", "dB"}, {"median", psnr_points}, {"params", params}});
    figures.push_back({{"name", "view_psnr_warp"}, {"unit", "dB"}, {"median", psnr_warp}, {"params", params}});
    figures.push_back({{"name", "view_ssim_ours"}, {"unit", "ratio"}, {"median", ssim_ours}, {"params", params}});
    figures.push_back({{"name", "view_ssim_warp"}, {"unit", "ratio"}, {"median", ssim_warp}, {"params", params}});
    figures.push_back({{"name", "view_ingest"}, {"unit", "s"}, {"median", ingest_s}, {"params", params}});
    figures.push_back({{"name", "view_render"}, {"unit", "s"}, {"median", render_s}, {"params", params}});
    figures.push_back({{"name", "view_render_default"}, {"unit", "s"}, {"median", texture_s}, {"params", params}});
    if (!images.empty()) {
      // ours (| fitted) | warp | photo, at half size.
      cv::Mat row;
      std::vector<cv::Mat> tiles = {ToMat(tex), warp, target.colour};
      if (gaussians) tiles.insert(tiles.begin() + 1, ToMat(fitted));
      cv::hconcat(tiles, row);
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
  if (!fit_gains.empty()) {
    std::vector<double> f = fit_gains;
    std::sort(f.begin(), f.end());
    const size_t m = f.size() / 2;
    // Of an even count: the mean of the middle two.
    const double median = f.size() % 2 ? f[m] : (f[m - 1] + f[m]) / 2;
    figures.push_back({{"name", "view_psnr_fitted_gain_over_textured"}, {"unit", "dB"},
                       {"median", median}, {"values", fit_gains}});
    std::printf("median PSNR gain of the fitted Gaussians over the textured render: %+.2f dB\n",
                median);
  }
  std::ofstream(out) << nlohmann::json{{"benchmark", "view"}, {"figures", figures}}.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  std::error_code ec;
  if (own_scratch) fs::remove_all(scratch, ec);
  return 0;
}
