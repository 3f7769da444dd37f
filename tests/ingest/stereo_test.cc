// The stereo matcher (ingest/stereo.h) on synthetic pairs with exactly known subpixel
// disparities and on a real Middlebury 2014 pair (its PFM ground truth read by formats/pfm.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>
#include <string>
#include <vector>

#include "formats/pfm.h"
#include "ingest/stereo.h"
#include "tests/run_command.h"

namespace hvdb::ingest {
namespace {

// Binary stripes of random widths in [1, 4] px (the thesis's structured-light pattern, 3.4),
// as a piecewise-constant function of u whose integral is exact: pixels are area samples, so
// the images are what a camera sees of a continuous scene, at any subpixel shift.
class Stripes {
 public:
  explicit Stripes(uint32_t seed, double from = -400, double to = 1200) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> width(1.0, 4.0);
    double u = from, cum = 0;
    int v = 0;
    while (u < to) {
      edge_.push_back(u);
      val_.push_back(v);
      cum_.push_back(cum);
      const double w = width(rng);
      cum += v * w;
      u += w;
      v = 1 - v;
    }
    edge_.push_back(u);
    val_.push_back(v);
    cum_.push_back(cum);
  }
  // Mean over [a, b].
  double Mean(double a, double b) const { return (F(b) - F(a)) / (b - a); }

 private:
  double F(double u) const {
    size_t i = std::upper_bound(edge_.begin(), edge_.end(), u) - edge_.begin();
    i = i == 0 ? 0 : i - 1;
    return cum_[i] + val_[i] * (u - edge_[i]);
  }
  std::vector<double> edge_, val_, cum_;
};

// Scene texture along a row: two stripe patterns, the second slanted so that rows differ.
struct Texture {
  Stripes a{1}, b{2};
  double Mean(double u0, double u1, double y) const {
    return 40 + 120 * a.Mean(u0, u1) + 80 * b.Mean(u0 + 0.37 * y, u1 + 0.37 * y);
  }
};

// Disparity d(x, y) = c + gx * x + gy * y in left coordinates (a plane). The right pixel xr
// sees left x = (xr + c + gy * y) / (1 - gx).
struct Plane {
  double c, gx, gy;
  double At(double x, double y) const { return c + gx * x + gy * y; }
};

void MakePair(const Texture& tex, const Plane& p, int w, int h, cv::Mat* left, cv::Mat* right) {
  *left = cv::Mat(h, w, CV_8U);
  *right = cv::Mat(h, w, CV_8U);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      left->at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(tex.Mean(x - 0.5, x + 0.5, y));
      const double s = 1 - p.gx, off = p.c + p.gy * y;
      right->at<uint8_t>(y, x) =
          cv::saturate_cast<uint8_t>(tex.Mean((x - 0.5 + off) / s, (x + 0.5 + off) / s, y));
    }
  }
}

struct Stats {
  double median_err = 0, valid = 0;
};

// Over the interior (a `border`-px margin; the left `left_margin` columns have no match).
Stats Evaluate(const DisparityMap& m, const Plane& p, int border, int left_margin) {
  std::vector<double> err;
  int n = 0;
  for (int y = border; y < m.d.rows - border; ++y) {
    for (int x = left_margin; x < m.d.cols - border; ++x) {
      ++n;
      const float d = m.d.at<float>(y, x);
      if (std::isinf(d)) continue;
      err.push_back(std::abs(d - p.At(x, y)));
    }
  }
  Stats s;
  s.valid = static_cast<double>(err.size()) / n;
  if (!err.empty()) {
    std::nth_element(err.begin(), err.begin() + err.size() / 2, err.end());
    s.median_err = err[err.size() / 2];
  }
  return s;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

StereoParams SynthParams() {
  StereoParams p;
  p.min_disparity = 0;
  p.num_disparities = 32;
  p.window = 9;
  return p;
}

TEST(Stereo, ConstantSubpixelShift) {
  Texture tex;
  const Plane plane{10.37, 0, 0};
  cv::Mat l, r;
  MakePair(tex, plane, 200, 120, &l, &r);
  auto res = MatchStereo(l, r, SynthParams());
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  const Stats s = Evaluate(*res, plane, 8, 24);
  std::printf("constant 10.37: median |error| %.4f px, valid %.2f%%\n", s.median_err, 100 * s.valid);
  EXPECT_LE(s.median_err, 0.1);
  EXPECT_GE(s.valid, 0.95);
  // Without S5 the result is the integer WTA: off by the fractional 0.37.
  StereoParams coarse = SynthParams();
  coarse.subpixel = Subpixel::kNone;
  auto c = MatchStereo(l, r, coarse);
  ASSERT_TRUE(c.ok());
  const Stats sc = Evaluate(*c, plane, 8, 24);
  EXPECT_NEAR(sc.median_err, 0.37, 0.01);
  EXPECT_EQ(cv::countNonZero(c->dx), 0);
  EXPECT_TRUE(res->dt.empty());
  EXPECT_GT(res->timing.total_ms, 0);
}

TEST(Stereo, SlantedPlaneRecoversDisparityAndGradients) {
  Texture tex;
  const Plane plane{6.2, 0.05, 0.03};  // 6.2 .. 19 px across the image
  cv::Mat l, r;
  MakePair(tex, plane, 240, 140, &l, &r);
  auto res = MatchStereo(l, r, SynthParams());
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  const Stats s = Evaluate(*res, plane, 8, 24);
  EXPECT_LE(s.median_err, 0.1);
  EXPECT_GE(s.valid, 0.95);
  std::vector<double> dx, dy;
  for (int y = 8; y < l.rows - 8; ++y) {
    for (int x = 24; x < l.cols - 8; ++x) {
      if (std::isinf(res->d.at<float>(y, x))) continue;
      dx.push_back(res->dx.at<float>(y, x));
      dy.push_back(res->dy.at<float>(y, x));
    }
  }
  ASSERT_FALSE(dx.empty());
  std::printf("slanted: median |error| %.4f px, valid %.2f%%, median dx %.4f dy %.4f\n",
              s.median_err, 100 * s.valid, Median(dx), Median(dy));
  EXPECT_NEAR(Median(dx), 0.05, 0.01);
  EXPECT_NEAR(Median(dy), 0.03, 0.01);
}

TEST(Stereo, BgrInputMatchesGrey) {
  Texture tex;
  cv::Mat l, r, lb, rb;
  MakePair(tex, {7.5, 0, 0}, 120, 60, &l, &r);
  cv::cvtColor(l, lb, cv::COLOR_GRAY2BGR);
  cv::cvtColor(r, rb, cv::COLOR_GRAY2BGR);
  auto a = MatchStereo(l, r, SynthParams());
  auto b = MatchStereo(lb, rb, SynthParams());
  ASSERT_TRUE(a.ok() && b.ok());
  cv::Mat diff = a->d != b->d;  // inf == inf compares equal
  EXPECT_EQ(cv::countNonZero(diff), 0);
}

// A fronto-parallel foreground band (d = 20) over a background (d = 8): left pixels
// x in [88, 100) see background that the band hides in the right view.
TEST(Stereo, CrossCheckDetectsOcclusion) {
  const int w = 220, h = 80, fg0 = 100, fg1 = 140, dbg = 8, dfg = 20;
  Texture bg;
  Stripes fg(7);
  auto fgval = [&](double x, double y) {
    return 30 + 190 * fg.Mean(x - 0.5, x + 0.5) * (0.8 + 0.2 * std::sin(0.3 * y));
  };
  cv::Mat l(h, w, CV_8U), r(h, w, CV_8U);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      l.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(
          x >= fg0 && x < fg1 ? fgval(x, y) : bg.Mean(x - 0.5, x + 0.5, y));
      const int xl_fg = x + dfg, xl_bg = x + dbg;
      r.at<uint8_t>(y, x) = cv::saturate_cast<uint8_t>(
          xl_fg >= fg0 && xl_fg < fg1 ? fgval(xl_fg, y) : bg.Mean(xl_bg - 0.5, xl_bg + 0.5, y));
    }
  }
  auto res = MatchStereo(l, r, SynthParams());
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  int occ = 0, occ_invalid = 0, fgn = 0, fg_ok = 0, bgn = 0, bg_ok = 0;
  for (int y = 8; y < h - 8; ++y) {
    for (int x = 30; x < w - 8; ++x) {
      const float d = res->d.at<float>(y, x);
      if (x >= fg0 - (dfg - dbg) && x < fg0) {
        ++occ;
        occ_invalid += std::isinf(d);
      } else if (x >= fg0 + 4 && x < fg1 - 4) {
        ++fgn;
        fg_ok += std::abs(d - dfg) < 0.5;
      } else if (x < fg0 - 20 || x >= fg1 + 8) {
        ++bgn;
        bg_ok += std::abs(d - dbg) < 0.5;
      }
    }
  }
  std::printf("occlusion: %.1f%% of the occluded band invalid, fg %.1f%% bg %.1f%% correct\n",
              100.0 * occ_invalid / occ, 100.0 * fg_ok / fgn, 100.0 * bg_ok / bgn);
  EXPECT_GE(static_cast<double>(occ_invalid) / occ, 0.75);
  EXPECT_GE(static_cast<double>(fg_ok) / fgn, 0.95);
  EXPECT_GE(static_cast<double>(bg_ok) / bgn, 0.95);
  // Without the check the occluded band gets (wrong) disparities.
  StereoParams nocheck = SynthParams();
  nocheck.cross_check = false;
  auto res2 = MatchStereo(l, r, nocheck);
  ASSERT_TRUE(res2.ok());
  int occ_inf2 = 0;
  for (int y = 8; y < h - 8; ++y) {
    for (int x = fg0 - (dfg - dbg); x < fg0; ++x) occ_inf2 += std::isinf(res2->d.at<float>(y, x));
  }
  EXPECT_LT(occ_inf2, occ / 4);
}

// A plane moving towards the cameras: d(t) = 10.2 + 0.3 (t - 1) over three frames.
TEST(Stereo, SpacetimeRecoversTemporalGradient) {
  Texture tex;
  std::vector<cv::Mat> ls, rs;
  for (int t = 0; t < 3; ++t) {
    cv::Mat l, r;
    MakePair(tex, {10.2 + 0.3 * (t - 1), 0, 0}, 160, 80, &l, &r);
    ls.push_back(l);
    rs.push_back(r);
  }
  auto res = MatchSpacetime(ls, rs, 1, SynthParams());
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  ASSERT_EQ(res->dt.type(), CV_32F);
  const Stats s = Evaluate(*res, {10.2, 0, 0}, 8, 24);
  EXPECT_LE(s.median_err, 0.1);
  EXPECT_GE(s.valid, 0.95);
  std::vector<double> dt;
  for (int y = 8; y < 72; ++y) {
    for (int x = 24; x < 152; ++x) {
      if (!std::isinf(res->d.at<float>(y, x))) dt.push_back(res->dt.at<float>(y, x));
    }
  }
  std::printf("spacetime: median |error| %.4f px, valid %.2f%%, median dt %.4f\n", s.median_err,
              100 * s.valid, Median(dt));
  EXPECT_NEAR(Median(dt), 0.3, 0.05);
  // Errors of the spacetime entry point.
  EXPECT_TRUE(MatchSpacetime(ls, rs, 3, SynthParams()).status().IsInvalidArgument());
  EXPECT_TRUE(MatchSpacetime(ls, {rs[0]}, 0, SynthParams()).status().IsInvalidArgument());
  EXPECT_TRUE(MatchSpacetime({}, {}, 0, SynthParams()).status().IsInvalidArgument());
}

TEST(Stereo, ParameterAndInputValidation) {
  cv::Mat img(50, 80, CV_8U, cv::Scalar(10));
  auto expect_invalid = [&](const StereoParams& p, const std::string& needle) {
    auto r = MatchStereo(img, img, p);
    ASSERT_FALSE(r.ok()) << needle;
    EXPECT_TRUE(r.status().IsInvalidArgument());
    EXPECT_NE(r.status().message().find(needle), std::string::npos) << r.status().message();
  };
  StereoParams p;
  p.num_disparities = 16;
  EXPECT_TRUE(MatchStereo(img, img, p).ok());
  StereoParams q = p;
  q.num_disparities = 0;
  expect_invalid(q, "num_disparities");
  q = p, q.num_disparities = 81;
  expect_invalid(q, "larger than the image width");
  q = p, q.min_disparity = 70;
  expect_invalid(q, "does not fit the image width");
  q = p, q.window = 8;
  expect_invalid(q, "window must be odd");
  q = p, q.window = 0;
  expect_invalid(q, "window must be odd");
  q = p, q.window = 51;
  expect_invalid(q, "larger than the image");
  q = p, q.cross_check_tolerance = -1;
  expect_invalid(q, "cross_check_tolerance");
  q = p, q.discontinuity_threshold = 0;
  expect_invalid(q, "discontinuity_threshold");
  q = p, q.threads = -2;
  expect_invalid(q, "threads");
  EXPECT_TRUE(p.Validate({80, 50}).ok());
  EXPECT_TRUE(p.Validate({0, 0}).IsInvalidArgument());

  auto r1 = MatchStereo(cv::Mat(), img, p);
  ASSERT_FALSE(r1.ok());
  EXPECT_NE(r1.status().message().find("left image is empty"), std::string::npos);
  auto r2 = MatchStereo(img, cv::Mat(50, 81, CV_8U, cv::Scalar(0)), p);
  ASSERT_FALSE(r2.ok());
  EXPECT_NE(r2.status().message().find("sizes differ"), std::string::npos);
  auto r3 = MatchStereo(img, cv::Mat(50, 80, CV_16U, cv::Scalar(0)), p);
  ASSERT_FALSE(r3.ok());
  EXPECT_NE(r3.status().message().find("right image must be 8-bit"), std::string::npos);
}

// ---- Real data: Middlebury 2014, quarter size ----

const std::string kScene = std::string(HVDB_SHARED_DATA) + "/middlebury-2014-quarter/trainingQ/Teddy/";

TEST(Stereo, MiddleburyTeddyBadPixelRate) {
  cv::Mat l = cv::imread(kScene + "im0.png", cv::IMREAD_COLOR);
  cv::Mat r = cv::imread(kScene + "im1.png", cv::IMREAD_COLOR);
  ASSERT_FALSE(l.empty());
  ASSERT_FALSE(r.empty());
  auto gt = formats::ReadPfm(kScene + "disp0GT.pfm");
  ASSERT_TRUE(gt.ok());
  cv::Mat mask = cv::imread(kScene + "mask0nocc.png", cv::IMREAD_GRAYSCALE);
  StereoParams p;
  p.num_disparities = 64;  // calib.txt ndisp
  auto res = MatchStereo(l, r, p);
  ASSERT_TRUE(res.ok()) << res.status().ToString();
  int n = 0, bad = 0, invalid = 0;
  for (int y = 0; y < l.rows; ++y) {
    for (int x = 0; x < l.cols; ++x) {
      if (mask.at<uint8_t>(y, x) != 255) continue;
      ++n;
      const float d = res->d.at<float>(y, x);
      invalid += std::isinf(d);
      bad += std::isinf(d) || std::abs(d - gt->at<float>(y, x)) > 2.0f;  // invalid counts as bad
    }
  }
  const double bad2 = static_cast<double>(bad) / n, density = 1.0 - static_cast<double>(invalid) / n;
  const StereoTiming& t = res->timing;
  std::printf("Teddy: bad2 %.2f%% (invalid counted as bad), density %.2f%%; ms: cost %.0f "
              "aggregate %.0f min %.0f wta %.0f check %.0f subpixel %.0f total %.0f\n",
              100 * bad2, 100 * density, t.cost_ms, t.aggregate_ms, t.min_filter_ms, t.wta_ms,
              t.cross_check_ms, t.subpixel_ms, t.total_ms);
  // Measured (deterministic, any thread count): bad2 9.8 %, density 96.0 %. OpenCV's
  // StereoSGBM (3-way, block 5) scores 15.9 % / 89.3 % on the same pair (stereo-bench). The
  // floor leaves ~2 points for compiler/library differences while still failing on any
  // regression that would put us behind SGBM here.
  EXPECT_LT(bad2, 0.12);
  EXPECT_GT(density, 0.93);
}

}  // namespace
}  // namespace hvdb::ingest

namespace hvdb::ingest {
namespace {

// `hvdb-ingest stereo` (the launcher, with its own PNG reader) writes exactly what the matcher
// gives in process with the parabola (the default for a pair without --structured-light), and
// runs LM with --structured-light; the other subcommands reach hvdb-ingest-all.
TEST(StereoCommand, WritesTheMatchersDisparitiesAndHandsTheRestOn) {
  const std::string dir = std::string(HVDB_SHARED_DATA) + "/middlebury-2014-quarter/trainingQ/Teddy/";
  const std::string out = ::testing::TempDir() + "/hvdb-stereo-cmd.pfm";
  auto run = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " stereo " + dir + "im0.png " + dir +
                                 "im1.png --out " + out + " --num-disparities 64");
  ASSERT_EQ(run.code, 0) << run.out;
  EXPECT_NE(run.out.find("subpixel: parabola (auto: natural texture)"), std::string::npos) << run.out;
  auto got = formats::ReadPfm(out);
  ASSERT_TRUE(got.ok()) << got.status().ToString();
  StereoParams p;
  p.num_disparities = 64;
  p.subpixel = Subpixel::kParabola;
  auto want = MatchStereo(cv::imread(dir + "im0.png"), cv::imread(dir + "im1.png"), p);
  ASSERT_TRUE(want.ok());
  ASSERT_EQ(got->size(), want->d.size());
  cv::Mat diff = (*got != want->d) & (*got == *got);  // NaN-free maps: +inf equals +inf
  EXPECT_EQ(cv::countNonZero(diff), 0);
  auto lm = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " stereo " + dir + "im0.png " + dir +
                                "im1.png --out " + out + " --num-disparities 64 --structured-light");
  EXPECT_EQ(lm.code, 0) << lm.out;
  EXPECT_NE(lm.out.find("subpixel: lm (auto: structured light)"), std::string::npos) << lm.out;
  auto bad = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " stereo " + dir + "nothing.png " + dir +
                                 "im1.png --out " + out);
  EXPECT_EQ(bad.code, 1);
  EXPECT_NE(bad.out.find("nothing.png: no such file"), std::string::npos) << bad.out;
  auto help = testing::RunCommand(std::string(HVDB_INGEST_PATH) + " --help");
  EXPECT_EQ(help.code, 0);
  EXPECT_NE(help.out.find("run"), std::string::npos) << help.out;
  EXPECT_NE(help.out.find("Usage: hvdb-ingest"), std::string::npos) << help.out;
}

}  // namespace
}  // namespace hvdb::ingest
