// stereo-bench: hvdb's stereo matcher (ingest/stereo.h, thesis 3.3-3.5) against OpenCV's
// semi-global matcher (cv::StereoSGBM) on the Middlebury 2014 quarter-size training scenes and
// the 2001-2006 scenes,
// both on the same pairs in the same run: bad-pixel rates on non-occluded pixels, density and
// time per pair. Writes JSON (bench/README.md schema: name, unit, median, min, max,
// repetitions, params).
#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <nlohmann/json.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "formats/pfm.h"
#include "ingest/stereo.h"

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

nlohmann::json Figure(const std::string& name, const std::string& unit, std::vector<double> v,
                      nlohmann::json params) {
  std::sort(v.begin(), v.end());
  return {{"name", name}, {"unit", unit}, {"median", v[v.size() / 2]}, {"min", v.front()},
          {"max", v.back()}, {"repetitions", v.size()}, {"params", std::move(params)}};
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

// calib.txt's ndisp (the files have irregular whitespace: "key= value ").
int ReadNdisp(const std::string& path) {
  std::ifstream f(path);
  std::string line;
  while (std::getline(f, line)) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) continue;
    std::string key = line.substr(0, eq);
    key.erase(std::remove_if(key.begin(), key.end(), ::isspace), key.end());
    if (key == "ndisp") return std::stoi(line.substr(eq + 1));
  }
  return -1;
}

struct Scores {
  double bad1 = 0, bad2 = 0, density = 0, bad2_valid = 0;  // fractions of non-occluded pixels
};

// Non-occluded pixels (mask 255) only; an invalid pixel (inf) counts as bad in bad1/bad2 and
// is reported separately as (1 - density); bad2_valid is bad2 among the valid pixels.
Scores Score(const cv::Mat& d, const cv::Mat& gt, const cv::Mat& mask) {
  long n = 0, b1 = 0, b2 = 0, valid = 0, b2v = 0;
  for (int y = 0; y < d.rows; ++y) {
    for (int x = 0; x < d.cols; ++x) {
      if (mask.at<uint8_t>(y, x) != 255) continue;
      ++n;
      const float v = d.at<float>(y, x);
      if (!std::isfinite(v)) {
        ++b1, ++b2;
        continue;
      }
      ++valid;
      const float e = std::abs(v - gt.at<float>(y, x));
      b1 += e > 1.0f;
      b2 += e > 2.0f;
      b2v += e > 2.0f;
    }
  }
  Scores s;
  s.bad1 = 100.0 * b1 / n;
  s.bad2 = 100.0 * b2 / n;
  s.density = 100.0 * valid / n;
  s.bad2_valid = valid ? 100.0 * b2v / valid : 0;
  return s;
}

// One evaluated pair: rectified left/right, ground-truth disparity of the left view (px, CV_32F)
// and the pixels evaluated (255: non-occluded, with ground truth).
struct Pair {
  std::string set, name;
  cv::Mat left, right, gt, mask;
  int ndisp = 0;
  std::string left_path, right_path;  // the image files (bench/ingest_targets.py runs the command on them)
};

// Middlebury 2014 (quarter size): im0/im1.png, disp0GT.pfm, mask0nocc.png, calib.txt's ndisp.
std::vector<Pair> Load2014(const std::string& data) {
  std::vector<Pair> out;
  std::error_code ec;
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(data, ec)) {
    if (e.is_directory() && fs::exists(e.path() / "disp0GT.pfm")) names.push_back(e.path().filename());
  }
  std::sort(names.begin(), names.end());
  for (const std::string& scene : names) {
    const std::string dir = data + "/" + scene + "/";
    Pair p{"2014", scene, cv::imread(dir + "im0.png", cv::IMREAD_COLOR),
           cv::imread(dir + "im1.png", cv::IMREAD_COLOR), {},
           cv::imread(dir + "mask0nocc.png", cv::IMREAD_GRAYSCALE), ReadNdisp(dir + "calib.txt"),
           dir + "im0.png", dir + "im1.png"};
    auto gt = hvdb::formats::ReadPfm(dir + "disp0GT.pfm");
    if (p.left.empty() || p.right.empty() || p.mask.empty() || !gt.ok() || p.ndisp <= 0) {
      std::fprintf(stderr, "stereo-bench: cannot read scene %s (%s)\n", dir.c_str(),
                   gt.ok() ? "images, mask or calib.txt ndisp" : gt.status().ToString().c_str());
      std::exit(1);
    }
    p.gt = *gt;
    out.push_back(std::move(p));
  }
  return out;
}

// Middlebury 2001-2006 (the shared folder's README): per year its file names and the grey
// scale k of the 8-bit ground truth (0: unknown). The evaluated pixels are Tsukuba's nonocc.png,
// elsewhere those whose left and right ground truth agree within 1 px (the occlusion test the
// Middlebury masks were made with), so both sets are scored on non-occluded pixels.
std::vector<Pair> Load2001to2006(const std::string& data) {
  struct Layout {
    const char *left, *right, *gt_left, *gt_right;
    float k;
  };
  const Layout layouts[] = {{"imL.png", "imR.png", "truedisp.pgm", nullptr, 16},  // Tsukuba
                            {"im2.ppm", "im6.ppm", "disp2.pgm", "disp6.pgm", 8},  // 2001
                            {"im2.jpg", "im6.ppm", "disp2.pgm", "disp6.pgm", 8},  // bull
                            {"imL.png", "imR.png", "disp2.png", "disp6.png", 4},  // 2003
                            {"view1.png", "view5.png", "disp1.png", "disp5.png", 3}};  // 2005/6
  std::vector<Pair> out;
  std::error_code ec;
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(data, ec)) {
    if (e.is_directory()) names.push_back(e.path().filename());
  }
  std::sort(names.begin(), names.end());
  for (const std::string& scene : names) {
    const std::string dir = data + "/" + scene + "/";
    const Layout* lay = nullptr;
    for (const Layout& l : layouts) {
      if (fs::exists(dir + l.left) && fs::exists(dir + l.gt_left)) lay = &l;
    }
    if (!lay) continue;
    Pair p;
    p.set = "2001-2006";
    p.name = scene;
    p.left_path = dir + lay->left;
    p.right_path = dir + lay->right;
    p.left = cv::imread(p.left_path, cv::IMREAD_COLOR);
    p.right = cv::imread(p.right_path, cv::IMREAD_COLOR);
    cv::Mat gl = cv::imread(dir + lay->gt_left, cv::IMREAD_GRAYSCALE), gr;
    if (lay->gt_right) gr = cv::imread(dir + lay->gt_right, cv::IMREAD_GRAYSCALE);
    if (p.left.empty() || p.right.empty() || gl.empty() || (lay->gt_right && gr.empty())) {
      std::fprintf(stderr, "stereo-bench: cannot read scene %s\n", dir.c_str());
      std::exit(1);
    }
    gl.convertTo(p.gt, CV_32F, 1.0 / lay->k);
    cv::Mat nonocc = lay->gt_right ? cv::Mat() : cv::imread(dir + "nonocc.png", cv::IMREAD_GRAYSCALE);
    p.mask = cv::Mat::zeros(gl.size(), CV_8U);
    float dmax = 0;
    for (int y = 0; y < gl.rows; ++y) {
      for (int x = 0; x < gl.cols; ++x) {
        if (gl.at<uint8_t>(y, x) == 0) continue;  // no ground truth
        const float d = p.gt.at<float>(y, x);
        dmax = std::max(dmax, d);
        bool visible;
        if (!nonocc.empty()) {
          visible = nonocc.at<uint8_t>(y, x) == 255;
        } else {
          const int xr = static_cast<int>(std::lround(x - d));
          visible = xr >= 0 && gr.at<uint8_t>(y, xr) != 0 &&
                    std::abs(gr.at<uint8_t>(y, xr) / lay->k - d) <= 1.0f;
        }
        if (visible) p.mask.at<uint8_t>(y, x) = 255;
      }
    }
    p.ndisp = static_cast<int>(std::ceil(dmax)) + 2;  // the scene's range, as calib.txt gives it
    out.push_back(std::move(p));
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"stereo-bench: hvdb's stereo matcher vs OpenCV StereoSGBM on Middlebury 2014 (Q)"};
  std::string out = "stereo.json";
  std::string data = std::string(HVDB_SHARED_DATA) + "/middlebury-2014-quarter/trainingQ";
  bool quick = false;
  int reps = 3, window = 9, threads = 0;
  app.add_option("--out", out, "JSON output file")->capture_default_str();
  app.add_option("--data", data, "folder of Middlebury scenes (im0/im1.png, calib.txt, "
                                 "disp0GT.pfm, mask0nocc.png)")->capture_default_str();
  app.add_flag("--quick", quick, "one scene, one repetition (CI smoke run)");
  app.add_option("--repetitions", reps, "timed runs per pair and matcher")->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_option("--window", window, "hvdb matching window")->capture_default_str();
  app.add_option("--threads", threads, "hvdb threads (0 = all); OpenCV uses its default pool")
      ->capture_default_str();
  std::string data_old = std::string(HVDB_SHARED_DATA) + "/middlebury-stereo-2001-2006";
  app.add_option("--data-2001-2006", data_old,
                 "folder of the Middlebury 2001-2006 scenes (\"\": leave them out)")
      ->capture_default_str();
  std::string subpixel = "parabola";
  app.add_option("--subpixel", subpixel,
                 "hvdb's subpixel step: none, parabola (S4's fit) or lm (S5, Levenberg-Marquardt)")
      ->capture_default_str()->check(CLI::IsMember({"none", "parabola", "lm"}));
  CLI11_PARSE(app, argc, argv);
  if (quick) reps = 1;

  std::vector<Pair> pairs = Load2014(data);
  if (pairs.empty()) {
    std::fprintf(stderr, "stereo-bench: no Middlebury scenes under %s\n", data.c_str());
    return 1;
  }
  if (quick) {
    auto teddy = std::find_if(pairs.begin(), pairs.end(), [](const Pair& p) { return p.name == "Teddy"; });
    pairs = {teddy != pairs.end() ? *teddy : pairs.front()};
  } else if (!data_old.empty()) {
    std::vector<Pair> old = Load2001to2006(data_old);
    if (old.empty()) {
      std::fprintf(stderr, "stereo-bench: no Middlebury 2001-2006 scenes under %s\n",
                   data_old.c_str());
      return 1;
    }
    pairs.insert(pairs.end(), old.begin(), old.end());
  }

  const auto started = Clock::now();
  nlohmann::json figures = nlohmann::json::array(), table = nlohmann::json::array();
  std::map<std::string, std::vector<double>> summary;  // per-matcher metric over scenes
  std::printf("%-9s %-12s %5s | %-30s | %-30s\n", "set", "scene", "ndisp", "hvdb bad1/bad2/dens/ms",
              "SGBM bad1/bad2/dens/ms");
  for (const Pair& pair : pairs) {
    const std::string& scene = pair.name;
    const cv::Mat &l = pair.left, &r = pair.right, &mask = pair.mask;
    const cv::Mat* gt = &pair.gt;
    const int ndisp = pair.ndisp;

    // hvdb: S1-S5 with the default parameters over the scene's disparity range.
    hvdb::ingest::StereoParams p;
    p.min_disparity = 0;
    p.num_disparities = ndisp;
    p.window = window;
    p.threads = threads;
    hvdb::ingest::ParseSubpixel(subpixel, &p.subpixel);
    std::vector<double> ours_ms, st_cost, st_agg, st_min, st_wta, st_check, st_sub;
    cv::Mat ours;
    for (int i = 0; i < reps; ++i) {
      auto t0 = Clock::now();
      auto res = hvdb::ingest::MatchStereo(l, r, p);
      ours_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
      if (!res.ok()) {
        std::fprintf(stderr, "stereo-bench: %s: %s\n", scene.c_str(), res.status().ToString().c_str());
        return 1;
      }
      const auto& t = res->timing;
      st_cost.push_back(t.cost_ms), st_agg.push_back(t.aggregate_ms), st_min.push_back(t.min_filter_ms);
      st_wta.push_back(t.wta_ms), st_check.push_back(t.cross_check_ms), st_sub.push_back(t.subpixel_ms);
      ours = res->d;
    }

    // OpenCV SGBM, 3-way, on the colour pair: blockSize 5, P1/P2 = 8/32 * cn * bs^2,
    // uniqueness 10, left-right check 1 px, speckle filter 100 px / 2 px as OpenCV's sample.
    const int bs = 5, cn = 3;
    const int ndisp16 = (ndisp + 15) / 16 * 16;  // SGBM needs a multiple of 16
    auto sgbm = cv::StereoSGBM::create(0, ndisp16, bs, 8 * cn * bs * bs, 32 * cn * bs * bs,
                                       /*disp12MaxDiff=*/1, /*preFilterCap=*/63,
                                       /*uniquenessRatio=*/10, /*speckleWindowSize=*/100,
                                       /*speckleRange=*/32, cv::StereoSGBM::MODE_SGBM_3WAY);
    std::vector<double> sgbm_ms;
    cv::Mat raw;
    for (int i = 0; i < reps; ++i) {
      auto t0 = Clock::now();
      sgbm->compute(l, r, raw);
      sgbm_ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    }
    cv::Mat theirs(raw.size(), CV_32F);
    for (int y = 0; y < raw.rows; ++y) {
      for (int x = 0; x < raw.cols; ++x) {
        const int16_t v = raw.at<int16_t>(y, x);  // 1/16 px; below minDisparity = invalid
        theirs.at<float>(y, x) = v < 0 ? std::numeric_limits<float>::infinity() : v / 16.0f;
      }
    }

    const Scores so = Score(ours, *gt, mask), ss = Score(theirs, *gt, mask);
    nlohmann::json params = {{"set", pair.set}, {"scene", scene}, {"width", l.cols},
                             {"height", l.rows}, {"ndisp", ndisp}};
    nlohmann::json ours_params = params, sgbm_params = params;
    ours_params["matcher"] = {{"window", window}, {"multi_window", p.multi_window},
                              {"cross_check", p.cross_check}, {"subpixel", subpixel},
                              {"threads", threads}, {"input", "grey"}};
    sgbm_params["matcher"] = {{"mode", "SGBM_3WAY"}, {"num_disparities", ndisp16},
                              {"block_size", bs}, {"P1", 8 * cn * bs * bs},
                              {"P2", 32 * cn * bs * bs}, {"uniqueness", 10},
                              {"disp12_max_diff", 1}, {"speckle_window", 100},
                              {"speckle_range", 32}, {"opencv_threads", cv::getNumThreads()},
                              {"input", "colour"}};
    const std::string pre = "stereo." + (pair.set == "2014" ? "" : pair.set + ".") + scene + ".";
    figures.push_back(Figure(pre + "hvdb.time", "ms", ours_ms, ours_params));
    figures.push_back(Figure(pre + "sgbm.time", "ms", sgbm_ms, sgbm_params));
    for (const auto& [stage, v] : std::vector<std::pair<std::string, std::vector<double>>>{
             {"cost", st_cost}, {"aggregate", st_agg}, {"min_filter", st_min}, {"wta", st_wta},
             {"cross_check", st_check}, {"subpixel", st_sub}}) {
      figures.push_back(Figure(pre + "hvdb.stage." + stage, "ms", v, ours_params));
    }
    for (const auto& [who, s, ps] : {std::tuple{"hvdb", so, ours_params},
                                     std::tuple{"sgbm", ss, sgbm_params}}) {
      figures.push_back(Figure(pre + who + ".bad1", "%", {s.bad1}, ps));
      figures.push_back(Figure(pre + who + ".bad2", "%", {s.bad2}, ps));
      figures.push_back(Figure(pre + who + ".density", "%", {s.density}, ps));
      figures.push_back(Figure(pre + who + ".bad2_valid", "%", {s.bad2_valid}, ps));
      for (const std::string& scope : {std::string(), pair.set + "."}) {
        summary[scope + who + ".bad1"].push_back(s.bad1);
        summary[scope + who + ".bad2"].push_back(s.bad2);
        summary[scope + who + ".density"].push_back(s.density);
        summary[scope + who + ".bad2_valid"].push_back(s.bad2_valid);
      }
    }
    const double om = Median(ours_ms), sm = Median(sgbm_ms);
    for (const std::string& scope : {std::string(), pair.set + "."}) {
      summary[scope + "hvdb.time"].push_back(om);
      summary[scope + "sgbm.time"].push_back(sm);
      summary[scope + "hvdb.time.x_sgbm"].push_back(om / sm);
    }
    figures.push_back({{"name", pre + "hvdb.time.x_sgbm"}, {"unit", "ratio"}, {"median", om / sm},
                       {"min", *std::min_element(ours_ms.begin(), ours_ms.end()) /
                                   *std::max_element(sgbm_ms.begin(), sgbm_ms.end())},
                       {"max", *std::max_element(ours_ms.begin(), ours_ms.end()) /
                                   *std::min_element(sgbm_ms.begin(), sgbm_ms.end())},
                       {"repetitions", reps},
                       {"params", {{"numerator", pre + "hvdb.time"}, {"denominator", pre + "sgbm.time"},
                                   {"numerator_median", om}, {"denominator_median", sm}}}});
    table.push_back({{"set", pair.set}, {"scene", scene}, {"left", pair.left_path}, {"right", pair.right_path},
                     {"width", l.cols}, {"height", l.rows}, {"ndisp", ndisp},
                     {"hvdb", {{"bad1", so.bad1}, {"bad2", so.bad2}, {"density", so.density},
                               {"bad2_valid", so.bad2_valid}, {"ms", om},
                               {"stages_ms", {{"cost", Median(st_cost)}, {"aggregate", Median(st_agg)},
                                              {"min_filter", Median(st_min)}, {"wta", Median(st_wta)},
                                              {"cross_check", Median(st_check)},
                                              {"subpixel", Median(st_sub)}}}}},
                     {"sgbm", {{"bad1", ss.bad1}, {"bad2", ss.bad2}, {"density", ss.density},
                               {"bad2_valid", ss.bad2_valid}, {"ms", sm}}}});
    std::printf("%-9s %-12s %5d | %5.1f %5.1f %5.1f %7.0f ms | %5.1f %5.1f %5.1f %7.0f ms\n",
                pair.set.c_str(), scene.c_str(), ndisp, so.bad1, so.bad2, so.density, om, ss.bad1, ss.bad2,
                ss.density, sm);
    std::fflush(stdout);
  }
  // Means over scenes (each scene weighs the same, as in the Middlebury tables' plain average).
  nlohmann::json means;
  for (const auto& [k, v] : summary) {
    double s = 0;
    for (double x : v) s += x;
    means[k] = s / v.size();
    figures.push_back(Figure("stereo.mean." + k,
                             k.ends_with("time") ? "ms" : k.ends_with("x_sgbm") ? "ratio" : "%",
                             {s / v.size()}, {{"scenes", v.size()}, {"over", "scenes, plain mean"}}));
  }
  std::printf("%-28s | %5.1f %5.1f %5.1f %7.0f ms | %5.1f %5.1f %5.1f %7.0f ms (time %.2fx SGBM's)\n", "mean",
              means["hvdb.bad1"].get<double>(), means["hvdb.bad2"].get<double>(),
              means["hvdb.density"].get<double>(), means["hvdb.time"].get<double>(),
              means["sgbm.bad1"].get<double>(), means["sgbm.bad2"].get<double>(),
              means["sgbm.density"].get<double>(), means["sgbm.time"].get<double>(),
              means["hvdb.time.x_sgbm"].get<double>());

  std::ostringstream cmd;
  for (int i = 0; i < argc; ++i) cmd << (i ? " " : "") << argv[i];
  nlohmann::json doc = {
      {"schema", "hvdb-bench/1"}, {"benchmark", "stereo"}, {"command", cmd.str()},
      {"quick", quick}, {"data", data}, {"repetitions", reps},
      {"duration_s", std::chrono::duration<double>(Clock::now() - started).count()},
      {"machine", {{"nproc", std::thread::hardware_concurrency()},
                   {"opencv", CV_VERSION}, {"opencv_threads", cv::getNumThreads()}}},
      {"metric_notes", "bad1/bad2: % of non-occluded pixels (2014: mask0nocc 255; 2001-2006: "
                       "Tsukuba's nonocc.png, else left and right ground truth agreeing within "
                       "1 px) with |d - GT| > 1/2 px, invalid pixels counted as bad; density: % "
                       "valid; bad2_valid: bad2 among valid; time.x_sgbm: mean of per-scene "
                       "ratios"},
      {"data_2001_2006", data_old},
      {"means", means}, {"scenes", table}, {"figures", figures}};
  std::ofstream(out) << doc.dump(2) << "\n";
  std::printf("wrote %s\n", out.c_str());
  return 0;
}
