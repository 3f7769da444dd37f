// `hvdb-ingest stereo`: the matcher of ingest/stereo.h on one rectified pair, written as a PFM
// disparity map of the left view.
#include <chrono>
#include <cmath>
#include <limits>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <thread>

#include "formats/image_codec.h"
#include "formats/pfm.h"
#include "ingest/commands.h"
#include "ingest/stereo.h"

namespace hvdb::ingest {

namespace {

struct StereoOptions {
  std::string left, right, out;
  StereoParams params;
  std::string subpixel = "auto";
  bool structured_light = false, no_multi_window = false, no_cross_check = false;
};

int RunStereo(const StereoOptions& o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  // libpng/libjpeg directly, not imgcodecs: this command's start is part of its time.
  auto load = [](const std::string& path, cv::Mat* img) -> bool {
    auto read = formats::ReadImageFile(path, formats::ImageMode::kColour);
    if (!read.ok()) {
      std::fprintf(stderr, "hvdb-ingest stereo: %s\n", read.status().message().c_str());
      return false;
    }
    *img = std::move(read).value();
    return true;
  };
  cv::Mat l, r;
  bool left_ok = false;
  std::thread left([&] { left_ok = load(o.left, &l); });  // the two decodes at once
  const bool right_ok = load(o.right, &r);
  left.join();
  if (!left_ok || !right_ok) return 1;
  const auto t1 = Clock::now();
  StereoParams p = o.params;
  if (o.subpixel == "auto") {
    // LM pays on projected stripes (0.05 px); on natural texture the parabola scores as well
    // (bench/README.md, stereo-bench) at a fiftieth of the time.
    p.subpixel = o.structured_light ? Subpixel::kLevenbergMarquardt : Subpixel::kParabola;
  } else {
    ParseSubpixel(o.subpixel, &p.subpixel);  // checked by CLI11
  }
  p.multi_window = !o.no_multi_window;
  p.cross_check = !o.no_cross_check;
  auto res = MatchStereo(l, r, p);
  if (!res.ok()) {
    std::fprintf(stderr, "hvdb-ingest stereo: %s\n", res.status().ToString().c_str());
    return 1;
  }
  const auto t2 = Clock::now();
  Status st = formats::WritePfm(o.out, res->d);
  const auto t3 = Clock::now();
  if (!st.ok()) {
    std::fprintf(stderr, "hvdb-ingest stereo: %s\n", st.ToString().c_str());
    return 1;
  }
  const StereoTiming& t = res->timing;
  const double valid = 100.0 * cv::countNonZero(res->d < std::numeric_limits<float>::infinity()) /
                       static_cast<double>(res->d.total());
  std::printf("%s: %dx%d, disparities [%d, %d), window %d\n", o.out.c_str(), l.cols, l.rows,
              p.min_disparity, p.min_disparity + p.num_disparities, p.window);
  static const char* kSubpixel[] = {"none", "parabola", "lm"};
  std::printf("subpixel: %s%s\n", kSubpixel[static_cast<int>(p.subpixel)],
              o.subpixel == "auto" ? (o.structured_light ? " (auto: structured light)" : " (auto: natural texture)") : "");
  std::printf("timing ms: prepare %.1f  cost %.1f  aggregate %.1f  min-filter %.1f  wta %.1f  "
              "cross-check %.1f  subpixel %.1f  matcher total %.1f\n",
              t.prepare_ms, t.cost_ms, t.aggregate_ms, t.min_filter_ms, t.wta_ms, t.cross_check_ms,
              t.subpixel_ms, t.total_ms);
  std::printf("command ms: read %.1f  match %.1f  write %.1f  (from main; the process started "
              "before it)\n", ms(t0, t1), ms(t1, t2), ms(t2, t3));
  std::printf("valid: %.2f %%\n", valid);
  return 0;
}

}  // namespace

void RegisterStereoCommand(CLI::App& app) {
  auto o = std::make_shared<StereoOptions>();
  CLI::App* sub = app.add_subcommand(
      "stereo",
      "Match a rectified stereo pair (thesis 3.3-3.5: Birchfield-Tomasi cost, box aggregation, "
      "multi-window minimum filter, winner-takes-all, left-right check, subpixel refinement: "
      "parabola, or Levenberg-Marquardt under structured light) and write the left view's disparity (x_left - x_right, pixels, "
      "float PFM, +inf = invalid).");
  sub->add_option("LEFT", o->left, "left image (rectified; PNG, JPEG, ...)")->required();
  sub->add_option("RIGHT", o->right, "right image (rectified, same size)")->required();
  sub->add_option("--out", o->out, "output disparity map (.pfm)")->required();
  sub->add_option("--min-disparity", o->params.min_disparity, "smallest disparity searched")
      ->capture_default_str();
  sub->add_option("--num-disparities", o->params.num_disparities,
                  "number of disparities searched (e.g. Middlebury calib.txt ndisp)")
      ->capture_default_str();
  sub->add_option("--window", o->params.window, "odd side of the matching window")
      ->capture_default_str();
  sub->add_option("--threads", o->params.threads, "worker threads (0 = all hardware threads)")
      ->capture_default_str();
  sub->add_option("--cross-check-tolerance", o->params.cross_check_tolerance,
                  "left-right disagreement (px) above which a pixel is invalid")
      ->capture_default_str();
  sub->add_option("--discontinuity-threshold", o->params.discontinuity_threshold,
                  "px: window pixels whose coarse disparity differs more are left out of S5")
      ->capture_default_str();
  sub->add_option("--subpixel", o->subpixel,
                  "none (integer disparities), parabola (through the costs around the winner), "
                  "lm (S5: Levenberg-Marquardt on disparity and its gradients) or auto: lm with "
                  "--structured-light, else parabola")
      ->capture_default_str()->check(CLI::IsMember({"none", "parabola", "lm", "auto"}));
  sub->add_flag("--structured-light", o->structured_light,
                "the pair sees projected stripes (thesis 4.1): --subpixel auto uses lm");
  sub->add_flag("--no-multi-window", o->no_multi_window, "skip the minimum filter (S3)");
  sub->add_flag("--no-cross-check", o->no_cross_check, "skip the left-right check");
  sub->callback([o]() {
    const int rc = RunStereo(*o);
    if (rc != 0) throw CLI::RuntimeError(rc);
  });
}

}  // namespace hvdb::ingest
