#include "bench/view_generated.h"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "client/backend.h"
#include "protocol/render_convert.h"
#include "ingest/generator.h"
#include "ingest/pipeline.h"
#include "render/metrics.h"

namespace hvdb::bench {
render::Srgb8Image FromMat(const cv::Mat& bgr) {
  render::Srgb8Image im;
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

cv::Mat ToMat(const render::Srgb8Image& im) {
  cv::Mat bgr(static_cast<int>(im.height), static_cast<int>(im.width), CV_8UC3);
  for (int y = 0; y < bgr.rows; ++y) {
    for (int x = 0; x < bgr.cols; ++x) {
      const uint8_t* p = &im.data[(size_t(y) * im.width + size_t(x)) * im.channels];
      bgr.at<cv::Vec3b>(y, x) = im.channels >= 3 ? cv::Vec3b(p[2], p[1], p[0]) : cv::Vec3b(p[0], p[0], p[0]);
    }
  }
  return bgr;
}

int RunGeneratedViews(const GeneratedViewOptions& opt, nlohmann::json& figures) {
  namespace fs = std::filesystem;
  auto fail = [](const std::string& what, const Status& st) {
    std::fprintf(stderr, "view-bench: %s: %s\n", what.c_str(), st.ToString().c_str());
    return 1;
  };
  ingest::GeneratorOptions g;
  g.bricks = 4;
  g.frames = opt.quick ? 3 : 5;
  g.width = opt.quick ? 160 : 320;
  g.height = opt.quick ? 120 : 240;
  g.seed = 7;
  const std::string dir = opt.scratch + "/generated";
  fs::remove_all(dir);
  if (auto r = ingest::GenerateRecording(g, dir); !r.ok()) return fail("generate", r.status());
  auto full = ingest::OpenRecording(dir);
  if (!full.ok()) return fail("open the generated recording", full.status());
  auto backend = client::MakeEmbeddedBackend(opt.scratch + "/generated-data", size_t{128} << 20);
  const int frame = g.frames / 2;
  const std::vector<int> held = opt.quick ? std::vector<int>{1} : std::vector<int>{1, 2};
  if (!opt.images.empty()) fs::create_directories(opt.images);
  for (int h : held) {
    // The recording without brick h: its cameras stay in the calibration (ids unchanged).
    ingest::Recording rec = *full;
    rec.calibration.bricks.erase(rec.calibration.bricks.begin() + h);
    rec.files.erase(rec.files.begin() + h);
    const ingest::CameraModel& target = full->calibration.cameras[static_cast<size_t>(full->calibration.bricks[static_cast<size_t>(h)].colour)];
    const cv::Mat photo_bgr = cv::imread(full->Path(full->files[static_cast<size_t>(h)].colour, frame));
    char fdir[16];
    std::snprintf(fdir, sizeof fdir, "%06d", frame);
    auto truth = ingest::ReadDepthExr(dir + "/groundtruth/" + fdir + "/" + target.name + ".depth.exr");
    if (photo_bgr.empty() || !truth.ok()) return fail("held-out photo", Status::NotFound(target.name));
    std::vector<uint8_t> mask(size_t(truth->rows) * size_t(truth->cols));
    for (int y = 0; y < truth->rows; ++y)
      for (int x = 0; x < truth->cols; ++x)
        mask[size_t(y) * size_t(truth->cols) + size_t(x)] = std::isfinite(truth->at<float>(y, x));
    const render::Srgb8Image photo = FromMat(photo_bgr);
    nlohmann::json params = {{"held_out", target.name}, {"bricks_ingested", 3}, {"frame", frame},
                             {"width", g.width}, {"height", g.height}, {"seed", g.seed}};
    // Every render of both ingests first; then PSNR over the pixels all of them draw (and h
    // sees the scene there): the same pixels for every method.
    struct Shot {
      std::string name;
      render::Srgb8Image image;
      double ingest_s;
    };
    std::vector<Shot> shots;
    for (bool billboard : {false, true}) {
      ingest::IngestOptions io;
      io.dataset = std::string(billboard ? "bb-" : "lm-") + target.name;
      if (billboard) {
        io.filter = ingest::IngestOptions::Filter::kBillboard;
        io.stereo.subpixel = ingest::Subpixel::kParabola;
      }
      const auto t0 = std::chrono::steady_clock::now();
      auto report = ingest::RunIngest(rec, *backend, io);
      if (!report.ok()) return fail("ingest", report.status());
      const double ingest_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      auto render = [&](bool texture, bool boards) -> render::Srgb8Image {
        wire::Render req;
        req.set_dataset(io.dataset);
        wire::ToWire(ingest::ToCameraInfo(target, 0), req.mutable_view()->mutable_camera());
        const double t = frame / rec.fps;
        wire::ToWire(Region{Window{{-1e9, -1e9, -1e9, t}, {1e9, 1e9, 1e9, t}}}, req.mutable_region());
        req.set_view_dependent(!texture && !boards);
        req.set_texture(texture);
        req.set_billboards(boards);
        req.set_renderer(wire::RENDERER_CPU);
        std::string png;
        Status st = backend->Render(wire::FromWire(req).value(),
                                    [&](const render::RenderReply& r) {
          png = r.png;
          return Status::OK();
        });
        if (!st.ok()) {
          fail("render", st);
          std::exit(1);
        }
        const cv::Mat bgr = cv::imdecode(cv::Mat(1, static_cast<int>(png.size()), CV_8U, png.data()), cv::IMREAD_COLOR);
        return FromMat(bgr);
      };
      const std::string pre = billboard ? "billboard_ingest." : "lm_ingest.";
      shots.push_back({pre + "points", render(false, false), ingest_s});
      shots.push_back({pre + "textured", render(true, false), ingest_s});
      if (billboard) shots.push_back({pre + "billboards", render(false, true), ingest_s});
    }
    size_t drawn = 0;
    for (size_t i = 0; i < mask.size(); ++i) {
      for (const Shot& s : shots) {
        const uint8_t* px = &s.image.data[3 * i];
        if (px[0] + px[1] + px[2] == 0) mask[i] = 0;  // black: nothing drawn there
      }
      drawn += mask[i];
    }
    params["pixels_compared"] = drawn;
    std::printf("generated, %s held out (frame %d, %zu pixels all draw):", target.name.c_str(), frame, drawn);
    for (const Shot& s : shots) {
      const double psnr = render::Psnr(s.image, photo, &mask);
      nlohmann::json p = params;
      p["ingest_s"] = s.ingest_s;
      figures.push_back({{"name", "generated_view." + s.name + ".psnr"}, {"unit", "dB"}, {"median", psnr}, {"params", p}});
      std::printf(" %s %.2f dB;", s.name.c_str(), psnr);
    }
    std::printf("\n");
    std::fflush(stdout);
    cv::Mat row;
    if (!opt.images.empty()) {
      // billboards | textured points of the same ingest | photo
      std::vector<cv::Mat> cols;
      for (const char* want : {"billboard_ingest.billboards", "billboard_ingest.textured"})
        for (const Shot& s : shots)
          if (s.name == want) cols.push_back(ToMat(s.image));
      cols.push_back(photo_bgr);
      cv::hconcat(cols, row);
    }
    if (!opt.images.empty() && !row.empty())
      cv::imwrite(opt.images + "/generated-" + target.name + ".png", row);
  }
  return 0;
}

}  // namespace hvdb::bench
