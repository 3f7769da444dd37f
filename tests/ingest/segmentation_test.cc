// Object segmentation (thesis 6.4.1) on a generated recording, against its ground-truth object
// ids: brush strokes in the first frame only, the moving box segmented in every frame; with
// depth at least as well as with colour alone. Bayesian matting (6.4.2) against a synthetic
// composite with a known soft edge.
#include "ingest/segmentation.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ingest/generator.h"
#include "tests/ingest/strokes.h"
#include "tests/ingest/test_util.h"

namespace hvdb::ingest {
namespace {

using testing::TempDir;

struct Frame {
  cv::Mat colour, depth, truth;  // truth: CV_8U, 1 on the moving box
};

std::vector<Frame> MovingBoxFrames(const std::string& dir, int frames) {
  GeneratorOptions g;
  g.bricks = 1;
  g.frames = frames;
  g.width = 160;
  g.height = 120;
  g.supersample = 2;
  g.seed = 11;
  EXPECT_TRUE(GenerateRecording(g, dir).ok());
  std::vector<Frame> out;
  for (int f = 0; f < frames; ++f) {
    char n[16];
    std::snprintf(n, sizeof n, "%06d", f);
    Frame fr;
    fr.colour = cv::imread(dir + "/frames/" + n + "/b0_colour.png", cv::IMREAD_COLOR);
    auto z = ReadDepthExr(dir + "/groundtruth/" + n + "/b0_colour.depth.exr");
    EXPECT_TRUE(z.ok());
    fr.depth = z.ok() ? *z : cv::Mat();
    const cv::Mat ids = cv::imread(dir + "/groundtruth/" + n + "/b0_colour.object.png", cv::IMREAD_UNCHANGED);
    fr.truth = (ids == kObjectMoving) / 255;
    out.push_back(fr);
  }
  return out;
}

double Iou(const cv::Mat& a, const cv::Mat& b) {
  return static_cast<double>(cv::countNonZero(a & b)) / std::max(1, cv::countNonZero(a | b));
}

TEST(SegmentationTest, StrokesInOneFrameCutTheMovingBoxInEveryFrame) {
  TempDir dir;
  const std::vector<Frame> frames = MovingBoxFrames(dir / "rec", 4);
  std::vector<cv::Mat> colours, depths, strokes;
  for (const Frame& f : frames) {
    colours.push_back(f.colour);
    depths.push_back(f.depth);
    strokes.push_back(cv::Mat());
  }
  strokes[0] = testing::BrushStrokes(frames[0].truth);
  ASSERT_GT(cv::countNonZero(strokes[0] == kStrokeObject), 10);
  auto iou = [&](double lambda_z) {
    SegmentationOptions o;
    o.lambda_z = lambda_z;
    auto model = SegmentationModel::Fit(colours[0], depths[0], strokes[0], o);
    EXPECT_TRUE(model.ok()) << model.status().ToString();
    auto labels = SegmentFrames(*model, colours, depths, strokes, o);
    EXPECT_TRUE(labels.ok()) << labels.status().ToString();
    std::vector<double> out;
    for (size_t f = 0; f < frames.size(); ++f) out.push_back(Iou((*labels)[f], frames[f].truth));
    return out;
  };
  const std::vector<double> with_depth = iou(0.5), colour_only = iou(0);
  double mean_d = 0, mean_c = 0;
  for (size_t f = 0; f < frames.size(); ++f) {
    std::printf("frame %zu: IoU %.3f with depth, %.3f colour only\n", f, with_depth[f], colour_only[f]);
    EXPECT_GT(with_depth[f], 0.85) << "frame " << f;
    mean_d += with_depth[f] / frames.size();
    mean_c += colour_only[f] / frames.size();
  }
  EXPECT_GE(mean_d, mean_c - 0.005);
}

TEST(SegmentationTest, BayesianMattingRecoversASoftEdge) {
  // A disc of one colour distribution over another, its edge a 6-pixel ramp of alpha.
  const int n = 120;
  cv::RNG rng(3);
  cv::Mat colour(n, n, CV_8UC3), truth(n, n, CV_32F);
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      const double r = std::hypot(x - 60.0, y - 60.0);
      const double a = std::clamp((38.0 - r) / 6.0 + 0.5, 0.0, 1.0);
      truth.at<float>(y, x) = static_cast<float>(a);
      const cv::Vec3d F(0.2 + rng.gaussian(0.03), 0.35 + rng.gaussian(0.03), 0.85 + rng.gaussian(0.03));
      const cv::Vec3d B(0.75 + rng.gaussian(0.03), 0.6 + rng.gaussian(0.03), 0.15 + rng.gaussian(0.03));
      const cv::Vec3d c = a * F + (1 - a) * B;
      colour.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uint8_t>(c[0] * 255),
                                             cv::saturate_cast<uint8_t>(c[1] * 255),
                                             cv::saturate_cast<uint8_t>(c[2] * 255));
    }
  const cv::Mat labels = (truth >= 0.5) / 255;
  MattingOptions o;
  o.band = 5;
  cv::Mat fg;
  auto alpha = BayesianMatte(colour, labels, o, &fg);
  ASSERT_TRUE(alpha.ok()) << alpha.status().ToString();
  ASSERT_EQ(fg.size(), colour.size());
  double e_matte = 0, e_binary = 0;
  int band = 0;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) {
      const float t = truth.at<float>(y, x);
      if (!(t > 0 && t < 1)) continue;
      e_matte += std::abs(alpha->at<float>(y, x) - t);
      e_binary += std::abs(labels.at<uint8_t>(y, x) - t);
      ++band;
    }
  std::printf("soft edge: mean |alpha error| %.3f matte, %.3f binary over %d pixels\n",
              e_matte / band, e_binary / band, band);
  EXPECT_LT(e_matte, 0.5 * e_binary);
  // Far from the edge alpha is the label's.
  EXPECT_EQ(alpha->at<float>(60, 60), 1.f);
  EXPECT_EQ(alpha->at<float>(2, 2), 0.f);
}

TEST(SegmentationTest, BadInputIsAClearError) {
  const cv::Mat colour(20, 20, CV_8UC3, cv::Scalar(10, 20, 30));
  cv::Mat strokes(20, 20, CV_8U, cv::Scalar(0));
  SegmentationOptions o;
  EXPECT_FALSE(SegmentationModel::Fit(colour, {}, strokes, o).ok());  // no strokes
  strokes.at<uint8_t>(3, 3) = kStrokeObject;
  EXPECT_FALSE(SegmentationModel::Fit(colour, {}, strokes, o).ok());  // no rest strokes
  strokes.at<uint8_t>(15, 15) = kStrokeRest;
  EXPECT_TRUE(SegmentationModel::Fit(colour, {}, strokes, o).ok());
  EXPECT_FALSE(SegmentationModel::Fit(colour, cv::Mat(5, 5, CV_32F), strokes, o).ok());
  o.lambda_z = 2;
  EXPECT_FALSE(SegmentationModel::Fit(colour, {}, strokes, o).ok());
  auto model = SegmentationModel::Fit(colour, {}, strokes, SegmentationOptions{});
  ASSERT_TRUE(model.ok());
  EXPECT_FALSE(SegmentFrames(*model, {}, {}, {}, SegmentationOptions{}).ok());
  EXPECT_FALSE(SegmentFrames(*model, {colour, cv::Mat(10, 10, CV_8UC3)}, {}, {}, SegmentationOptions{}).ok());
  MattingOptions m;
  m.band = 0;
  EXPECT_FALSE(BayesianMatte(colour, strokes, m).ok());
  EXPECT_FALSE(BayesianMatte(colour, cv::Mat(5, 5, CV_8U), MattingOptions{}).ok());
}

}  // namespace
}  // namespace hvdb::ingest
