// Tests of ingest/generator.cc: the synthetic structured-light recordings and their ground truth.
#include "ingest/generator.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfOutputFile.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::ingest {
namespace {

namespace fs = std::filesystem;

std::string TempDir(const std::string& name) {
  const fs::path p = fs::temp_directory_path() /
                     ("hvdb_generator_test_" + std::to_string(::getpid()) + "_" + name);
  fs::remove_all(p);
  return p.string();
}

std::string Frame(int f) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "%06d", f);
  return buf;
}

// "b<k>" (appended: GCC 12 warns falsely on "literal" + std::string temporaries).
std::string Prefix(int k) {
  std::string s = "b";
  s += std::to_string(k);
  return s;
}

std::string ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The default recording, generated once for the suite.
class GeneratorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new std::string(TempDir("default"));
    const auto start = std::chrono::steady_clock::now();
    Result<GeneratedRecording> rec = GenerateRecording(GeneratorOptions{}, *dir_);
    seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    ASSERT_TRUE(rec.ok()) << rec.status().ToString();
    std::printf("default recording (3 bricks x 3 cameras x 4 frames, 320x240, ss 3): %.2f s\n",
                seconds_);
    rec_ = new GeneratedRecording(std::move(rec).value());
  }
  void SetUp() override { ASSERT_NE(rec_, nullptr) << "generating the default recording failed"; }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
    dir_ = nullptr;
    delete rec_;
    rec_ = nullptr;
  }

  static cv::Mat Image(int frame, const std::string& camera) {
    return cv::imread(*dir_ + "/frames/" + Frame(frame) + "/" + camera + ".png", cv::IMREAD_UNCHANGED);
  }
  static cv::Mat Objects(int frame, const std::string& camera) {
    return cv::imread(*dir_ + "/groundtruth/" + Frame(frame) + "/" + camera + ".object.png",
                      cv::IMREAD_UNCHANGED);
  }
  static cv::Mat Depth(int frame, const std::string& camera) {
    Result<cv::Mat> d = ReadDepthExr(*dir_ + "/groundtruth/" + Frame(frame) + "/" + camera + ".depth.exr");
    EXPECT_TRUE(d.ok()) << d.status().ToString();
    return d.ok() ? d.value() : cv::Mat();
  }
  static const CameraModel& Camera(const std::string& name) {
    return rec_->calibration.cameras[static_cast<size_t>(rec_->calibration.Find(name))];
  }

  static std::string* dir_;
  static GeneratedRecording* rec_;
  static double seconds_;
};
std::string* GeneratorTest::dir_ = nullptr;
GeneratedRecording* GeneratorTest::rec_ = nullptr;
double GeneratorTest::seconds_ = 0;

TEST_F(GeneratorTest, LayoutAndCalibrationRoundTrip) {
  const GeneratorOptions o;
  EXPECT_EQ(rec_->frames, o.frames);
  EXPECT_EQ(rec_->fps, o.fps);
  ASSERT_EQ(rec_->calibration.cameras.size(), 9u);
  ASSERT_EQ(rec_->calibration.bricks.size(), 3u);
  for (int k = 0; k < 3; ++k) {
    const Brick& b = rec_->calibration.bricks[static_cast<size_t>(k)];
    EXPECT_EQ(b.id, k);
    const std::string p = Prefix(k);
    EXPECT_EQ(rec_->calibration.cameras[static_cast<size_t>(b.left)].name, p + "_left");
    EXPECT_EQ(rec_->calibration.cameras[static_cast<size_t>(b.right)].name, p + "_right");
    EXPECT_EQ(rec_->calibration.cameras[static_cast<size_t>(b.colour)].name, p + "_colour");
    // The grey pair is about `baseline` apart.
    const double base = cv::norm(rec_->calibration.cameras[static_cast<size_t>(b.left)].Centre() -
                                 rec_->calibration.cameras[static_cast<size_t>(b.right)].Centre());
    EXPECT_NEAR(base, o.baseline, 1e-9);
  }

  // recording.yml
  cv::FileStorage fs(*dir_ + "/recording.yml", cv::FileStorage::READ);
  ASSERT_TRUE(fs.isOpened());
  EXPECT_EQ(static_cast<std::string>(fs["format"]), "hvdb-recording");
  EXPECT_EQ(static_cast<int>(fs["version"]), 1);
  EXPECT_EQ(static_cast<std::string>(fs["kind"]), "stereo");
  EXPECT_EQ(static_cast<int>(fs["frames"]), 4);
  EXPECT_EQ(static_cast<double>(fs["fps"]), 10.0);
  EXPECT_EQ(static_cast<int>(fs["first_frame"]), 0);
  EXPECT_EQ(static_cast<std::string>(fs["generator"]["seed"]), "1");
  EXPECT_EQ(static_cast<int>(fs["generator"]["bricks"]), 3);
  EXPECT_EQ(static_cast<int>(fs["generator"]["width"]), 320);
  EXPECT_EQ(static_cast<int>(fs["generator"]["height"]), 240);

  // calibration.yml round trip
  Result<Calibration> loaded = LoadCalibration(*dir_ + "/calibration.yml");
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  ASSERT_TRUE(loaded->Validate().ok());
  ASSERT_EQ(loaded->cameras.size(), rec_->calibration.cameras.size());
  ASSERT_EQ(loaded->bricks.size(), rec_->calibration.bricks.size());
  for (size_t i = 0; i < loaded->cameras.size(); ++i) {
    const CameraModel &a = loaded->cameras[i], &b = rec_->calibration.cameras[i];
    EXPECT_EQ(a.name, b.name);
    EXPECT_EQ(a.size, b.size);
    EXPECT_LT(cv::norm(a.K - b.K), 1e-9);
    EXPECT_LT(cv::norm(a.R - b.R), 1e-12);
    EXPECT_LT(cv::norm(a.T - b.T), 1e-12);
    ASSERT_EQ(a.dist.size(), 5u);
    for (size_t k = 0; k < 5; ++k) EXPECT_NEAR(a.dist[k], b.dist[k], 1e-15);
    EXPECT_NE(a.dist[0], 0.0);  // distorted by default
    EXPECT_DOUBLE_EQ(a.reprojection_error, kGeneratorReprojectionError);
  }
  for (size_t i = 0; i < loaded->bricks.size(); ++i) {
    EXPECT_EQ(loaded->bricks[i].left, rec_->calibration.bricks[i].left);
    EXPECT_EQ(loaded->bricks[i].right, rec_->calibration.bricks[i].right);
    EXPECT_EQ(loaded->bricks[i].colour, rec_->calibration.bricks[i].colour);
  }
  EXPECT_FALSE(fs::exists(*dir_ + "/frames/" + Frame(4)));
}

TEST_F(GeneratorTest, ImagesHaveTheRightSizesAndTypes) {
  for (int f = 0; f < 4; ++f) {
    for (const CameraModel& c : rec_->calibration.cameras) {
      SCOPED_TRACE(c.name + " frame " + std::to_string(f));
      const bool colour = c.name.ends_with("_colour");
      const cv::Mat img = Image(f, c.name);
      ASSERT_FALSE(img.empty());
      EXPECT_EQ(img.type(), colour ? CV_8UC3 : CV_8UC1);
      EXPECT_EQ(img.size(), cv::Size(320, 240));
      const cv::Mat depth = Depth(f, c.name);
      EXPECT_EQ(depth.type(), CV_32FC1);
      EXPECT_EQ(depth.size(), cv::Size(320, 240));
      const cv::Mat obj = Objects(f, c.name);
      EXPECT_EQ(obj.type(), CV_8UC1);
      EXPECT_EQ(obj.size(), cv::Size(320, 240));
      // Not a blank image: plenty of contrast.
      cv::Scalar mean, stddev;
      cv::meanStdDev(img, mean, stddev);
      EXPECT_GT(stddev[0], 15.0);
      EXPECT_GT(mean[0], 30.0);
    }
  }
}

TEST_F(GeneratorTest, GroundTruthDepthAgreesWithTheScene) {
  int finite = 0, background = 0, checked = 0;
  for (int f : {0, 3}) {
    const SyntheticScene scene(1, f, 10);
    cv::Vec3d lo, hi;
    scene.Bounds(&lo, &hi);
    for (const CameraModel& c : rec_->calibration.cameras) {
      SCOPED_TRACE(c.name);
      const cv::Mat depth = Depth(f, c.name), obj = Objects(f, c.name);
      for (int v = 0; v < c.size.height; v += 5) {
        for (int u = 0; u < c.size.width; u += 5) {
          ++checked;
          const cv::Point2d px(u, v);
          const Ray ray = CameraRay(c, px);
          const std::optional<SceneHit> hit = scene.Intersect(ray);
          const float d = depth.at<float>(v, u);
          if (!hit) {
            EXPECT_TRUE(std::isinf(d) && d > 0) << u << "," << v << ": " << d;
            EXPECT_EQ(obj.at<uint8_t>(v, u), kObjectNone);
            ++background;
            continue;
          }
          ++finite;
          // The hit projects back onto the pixel centre, at the stored depth.
          double z = 0;
          const cv::Point2d back = c.Project(hit->position, &z);
          ASSERT_LT(cv::norm(back - px), 1e-6) << u << "," << v;
          ASSERT_NEAR(d, z, 1e-5 * z) << u << "," << v;
          EXPECT_EQ(obj.at<uint8_t>(v, u), hit->object);
          for (int k = 0; k < 3; ++k) {
            EXPECT_GE(hit->position[k], lo[k] - 1e-9);
            EXPECT_LE(hit->position[k], hi[k] + 1e-9);
          }
        }
      }
    }
  }
  // Mostly scene, some void past the floor and wall edges.
  EXPECT_GT(finite, checked * 8 / 10);
  EXPECT_GT(background, 0);
}

TEST_F(GeneratorTest, DistortionIsInTheImages) {
  // A pinhole back-projection would misplace the image corners by several pixels.
  const SyntheticScene scene(1, 0, 10);
  int corners = 0;
  for (const CameraModel& c : rec_->calibration.cameras) {
    CameraModel pinhole = c;
    pinhole.dist.clear();
    for (const cv::Point2d px : {cv::Point2d(5, 5), cv::Point2d(314, 5), cv::Point2d(5, 234), cv::Point2d(314, 234)}) {
      const std::optional<SceneHit> hit = scene.Intersect(CameraRay(c, px));
      if (!hit) continue;
      ++corners;
      EXPECT_GT(cv::norm(pinhole.Project(hit->position) - px), 2.0) << c.name;
    }
  }
  EXPECT_GT(corners, 20);
}

double GradientRatio(const cv::Mat& grey) {  // horizontal / vertical gradient energy
  cv::Mat g;
  grey.convertTo(g, CV_32F);
  double ex = 0, ey = 0;
  for (int v = 0; v + 1 < g.rows; ++v)
    for (int u = 0; u + 1 < g.cols; ++u) {
      const double dx = g.at<float>(v, u + 1) - g.at<float>(v, u);
      const double dy = g.at<float>(v + 1, u) - g.at<float>(v, u);
      ex += dx * dx;
      ey += dy * dy;
    }
  return ex / ey;
}

TEST_F(GeneratorTest, StripesInGreyImagesNotInColourImages) {
  for (int k = 0; k < 3; ++k) {
    const std::string p = Prefix(k);
    for (const char* side : {"_left", "_right"}) {
      const double r = GradientRatio(Image(0, p + side));
      EXPECT_GT(r, 2.5) << p + side;
    }
    cv::Mat grey;
    cv::cvtColor(Image(0, p + "_colour"), grey, cv::COLOR_BGR2GRAY);
    const double r = GradientRatio(grey);
    EXPECT_LT(r, 1.6) << p + "_colour";
    EXPECT_GT(r, 0.3) << p + "_colour";  // not a blank image
  }
}

TEST_F(GeneratorTest, PatternChangesEveryFrameButTexturesDoNot) {
  // On the static back wall: the grey images change with the projected pattern, the colour
  // images only by the sensor noise.
  for (const char* cam : {"b1_left", "b1_colour"}) {
    const cv::Mat o0 = Objects(0, cam), o1 = Objects(1, cam);
    const cv::Mat i0 = Image(0, cam), i1 = Image(1, cam);
    const cv::Mat d0 = Depth(0, cam), d1 = Depth(1, cam);
    double diff = 0;
    int n = 0;
    for (int v = 1; v + 1 < o0.rows; ++v)
      for (int u = 1; u + 1 < o0.cols; ++u) {
        bool wall = true;  // the 3x3 neighbourhood, so antialiased edges do not count
        for (int dv = -1; dv <= 1; ++dv)
          for (int du = -1; du <= 1; ++du)
            wall = wall && o0.at<uint8_t>(v + dv, u + du) == kObjectWall &&
                   o1.at<uint8_t>(v + dv, u + du) == kObjectWall;
        if (!wall) continue;
        EXPECT_EQ(d0.at<float>(v, u), d1.at<float>(v, u));  // static geometry
        const cv::Mat a = i0(cv::Rect(u, v, 1, 1)), b = i1(cv::Rect(u, v, 1, 1));
        diff += cv::norm(a, b, cv::NORM_L1) / a.channels();
        ++n;
      }
    ASSERT_GT(n, 5000) << cam;
    if (std::string(cam).ends_with("_colour")) {
      EXPECT_LT(diff / n, 2.0) << cam;
    } else {
      EXPECT_GT(diff / n, 15.0) << cam;
    }
  }
}

TEST_F(GeneratorTest, MovingObjectMoves) {
  const SyntheticScene s0(1, 0, 10), s3(1, 3, 10);
  const cv::Vec3d shift = s3.MovingCentre() - s0.MovingCentre();
  EXPECT_NEAR(std::abs(shift[0]), 0.4 * 0.3, 1e-9);  // 0.4 m/s for 0.3 s
  EXPECT_EQ(shift[1], 0.0);
  EXPECT_EQ(shift[2], 0.0);
  // Linear: equal steps between consecutive frames.
  const SyntheticScene s1(1, 1, 10);
  EXPECT_NEAR((s1.MovingCentre() - s0.MovingCentre())[0], shift[0] / 3, 1e-12);
  for (const char* cam : {"b0_left", "b1_colour", "b2_right"}) {
    double cx[2] = {0, 0};
    int n[2] = {0, 0};
    int fi = 0;
    for (int f : {0, 3}) {
      const cv::Mat obj = Objects(f, cam);
      for (int v = 0; v < obj.rows; ++v)
        for (int u = 0; u < obj.cols; ++u)
          if (obj.at<uint8_t>(v, u) == kObjectMoving) {
            cx[fi] += u;
            ++n[fi];
          }
      ++fi;
    }
    ASSERT_GT(n[0], 200) << cam;
    ASSERT_GT(n[1], 200) << cam;
    // About 0.12 m at ~2.7 m with f ~ 340 px: well over 5 px of image motion.
    EXPECT_GT(std::abs(cx[1] / n[1] - cx[0] / n[0]), 5.0) << cam;
  }
}

// Photo-consistency of the stripes: a left pixel's surface point, projected into the right
// camera, has the same grey value there. Proves that geometry, calibration and lighting agree.
TEST_F(GeneratorTest, StereoPairsArePhotoConsistent) {
  for (int k = 0; k < 3; ++k) {
    const std::string p = Prefix(k);
    const CameraModel& L = Camera(p + "_left");
    const CameraModel& R = Camera(p + "_right");
    const cv::Mat il = Image(0, p + "_left"), ir = Image(0, p + "_right");
    const cv::Mat dl = Depth(0, p + "_left"), dr = Depth(0, p + "_right");
    cv::Mat irf;
    ir.convertTo(irf, CV_32F);
    std::vector<double> err, err_shifted;
    double max_vertical = 0;
    for (int v = 2; v < il.rows - 2; v += 2) {
      for (int u = 2; u < il.cols - 2; u += 2) {
        const float z = dl.at<float>(v, u);
        if (!std::isfinite(z)) continue;
        bool smooth = true;  // away from depth edges (occlusions, antialiased boundaries)
        for (int dv = -2; dv <= 2; ++dv)
          for (int du = -2; du <= 2; ++du)
            smooth = smooth && std::abs(dl.at<float>(v + dv, u + du) - z) < 0.01f * z;
        if (!smooth) continue;
        const Ray ray = CameraRay(L, {static_cast<double>(u), static_cast<double>(v)});
        const cv::Vec3d dir_cam = L.R * ray.dir;
        const cv::Vec3d X = ray.origin + ray.dir * (z / dir_cam[2]);
        double zr = 0;
        const cv::Point2d q = R.Project(X, &zr);
        if (q.x < 3 || q.y < 3 || q.x > ir.cols - 4 || q.y > ir.rows - 4) continue;
        const int qu = static_cast<int>(std::lround(q.x)), qv = static_cast<int>(std::lround(q.y));
        if (std::abs(dr.at<float>(qv, qu) - zr) > 0.01 * zr) continue;  // occluded in the right view
        max_vertical = std::max(max_vertical, std::abs(q.y - v));
        cv::Mat patch;
        cv::getRectSubPix(irf, {1, 1}, cv::Point2f(static_cast<float>(q.x), static_cast<float>(q.y)), patch);
        err.push_back(std::abs(patch.at<float>(0, 0) - il.at<uint8_t>(v, u)));
        cv::getRectSubPix(irf, {1, 1}, cv::Point2f(static_cast<float>(q.x + 3), static_cast<float>(q.y)), patch);
        err_shifted.push_back(std::abs(patch.at<float>(0, 0) - il.at<uint8_t>(v, u)));
      }
    }
    ASSERT_GT(err.size(), 5000u) << p;
    auto median = [](std::vector<double> e) {
      std::nth_element(e.begin(), e.begin() + static_cast<long>(e.size() / 2), e.end());
      return e[e.size() / 2];
    };
    auto mean = [](const std::vector<double>& e) {
      double s = 0;
      for (double x : e) s += x;
      return s / static_cast<double>(e.size());
    };
    std::printf("%s: photo-consistency median %.2f mean %.2f; 3 px off: median %.2f mean %.2f; "
                "max vertical disparity %.2f px\n",
                p.c_str(), median(err), mean(err), median(err_shifted), mean(err_shifted), max_vertical);
    EXPECT_LT(median(err), 4.0) << p;
    EXPECT_LT(mean(err), 8.0) << p;
    // The check can fail: three pixels off, the stripes disagree.
    EXPECT_GT(mean(err_shifted), 2.5 * mean(err)) << p;
    // The pair is not rectified: corresponding points differ in row.
    EXPECT_GT(max_vertical, 0.5) << p;
  }
}

TEST(GeneratorDeterminism, SameSeedSameBytesOtherSeedOtherImages) {
  GeneratorOptions o;
  o.bricks = 2;
  o.frames = 2;
  o.width = 96;
  o.height = 72;
  o.supersample = 2;  // even: the pixel-centre ground truth takes its own ray
  const std::string a = TempDir("det_a"), b = TempDir("det_b"), c = TempDir("det_c");
  std::vector<std::pair<int, int>> calls;
  ASSERT_TRUE(GenerateRecording(o, a, [&](int done, int total) { calls.emplace_back(done, total); }).ok());
  EXPECT_EQ(calls, (std::vector<std::pair<int, int>>{{1, 2}, {2, 2}}));
  ASSERT_TRUE(GenerateRecording(o, b).ok());
  o.seed = 2;
  ASSERT_TRUE(GenerateRecording(o, c).ok());
  int files = 0, differing = 0;
  for (const auto& e : fs::recursive_directory_iterator(a)) {
    if (!e.is_regular_file()) continue;
    const fs::path rel = fs::relative(e.path(), a);
    ++files;
    EXPECT_EQ(ReadBytes(e.path().string()), ReadBytes((fs::path(b) / rel).string())) << rel;
    if (rel.string().starts_with("frames") &&
        ReadBytes(e.path().string()) != ReadBytes((fs::path(c) / rel).string()))
      ++differing;
  }
  // recording.yml + calibration.yml + 2 frames x 6 cameras x (image, depth, objects)
  EXPECT_EQ(files, 2 + 2 * 6 * 3);
  EXPECT_EQ(differing, 2 * 6);  // another seed: other patterns, noise and rig
  for (const auto& d : {a, b, c}) fs::remove_all(d);
}

TEST(GeneratorOptionsTest, ValidationNamesTheOption) {
  EXPECT_TRUE(GeneratorOptions{}.Validate().ok());
  struct Case {
    void (*set)(GeneratorOptions&);
    const char* name;
  };
  const Case cases[] = {
      {[](GeneratorOptions& o) { o.bricks = 0; }, "bricks"},
      {[](GeneratorOptions& o) { o.bricks = 17; }, "bricks"},
      {[](GeneratorOptions& o) { o.width = 8; }, "width"},
      {[](GeneratorOptions& o) { o.height = 5000; }, "height"},
      {[](GeneratorOptions& o) { o.frames = 0; }, "frames"},
      {[](GeneratorOptions& o) { o.fps = 0; }, "fps"},
      {[](GeneratorOptions& o) { o.fps = std::nan(""); }, "fps"},
      {[](GeneratorOptions& o) { o.supersample = 0; }, "supersample"},
      {[](GeneratorOptions& o) { o.supersample = 9; }, "supersample"},
      {[](GeneratorOptions& o) { o.noise_sigma = -1; }, "noise_sigma"},
      {[](GeneratorOptions& o) { o.noise_sigma = std::numeric_limits<double>::infinity(); }, "noise_sigma"},
      {[](GeneratorOptions& o) { o.baseline = 0; }, "baseline"},
      {[](GeneratorOptions& o) { o.baseline = 2; }, "baseline"},
  };
  for (const Case& c : cases) {
    GeneratorOptions o;
    c.set(o);
    const Status st = o.Validate();
    EXPECT_TRUE(st.IsInvalidArgument()) << c.name;
    EXPECT_NE(st.message().find(c.name), std::string::npos) << st.message();
    // Nothing is written for invalid options.
    const std::string dir = TempDir("invalid");
    EXPECT_TRUE(GenerateRecording(o, dir).status().IsInvalidArgument());
    EXPECT_FALSE(fs::exists(dir));
  }
}

TEST(GeneratorOptionsTest, WithoutDistortion) {
  GeneratorOptions o;
  o.bricks = 1;
  o.frames = 1;
  o.width = 64;
  o.height = 48;
  o.distortion = false;
  o.supersample = 1;
  o.noise_sigma = 0;
  const std::string dir = TempDir("pinhole");
  Result<GeneratedRecording> rec = GenerateRecording(o, dir);
  ASSERT_TRUE(rec.ok()) << rec.status().ToString();
  Result<Calibration> cal = LoadCalibration(dir + "/calibration.yml");
  ASSERT_TRUE(cal.ok()) << cal.status().ToString();
  const SyntheticScene scene(o.seed, 0, o.fps);
  for (const CameraModel& c : cal->cameras) {
    for (double d : c.dist) EXPECT_EQ(d, 0.0);
    // A pinhole ray through the corner pixel lands where the ground truth says.
    const cv::Matx33d Kinv = c.K.inv();
    const cv::Vec3d n = Kinv * cv::Vec3d(2, 3, 1);
    const std::optional<SceneHit> hit = scene.Intersect({c.Centre(), c.R.t() * n});
    const cv::Mat depth = ReadDepthExr(dir + "/groundtruth/000000/" + c.name + ".depth.exr").value();
    ASSERT_TRUE(hit.has_value()) << c.name;
    EXPECT_NEAR(depth.at<float>(3, 2), (c.R * hit->position + c.T)[2], 1e-5) << c.name;
  }
  fs::remove_all(dir);
}

TEST(GeneratorOptionsTest, RefusesNonEmptyOutput) {
  GeneratorOptions o;
  o.bricks = 1;
  o.frames = 1;
  o.width = o.height = 32;
  const std::string dir = TempDir("nonempty");
  fs::create_directories(dir);
  std::ofstream(dir + "/keep.txt") << "mine";
  Result<GeneratedRecording> r = GenerateRecording(o, dir);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kAlreadyExists);
  EXPECT_NE(r.status().message().find(dir), std::string::npos);
  EXPECT_EQ(ReadBytes(dir + "/keep.txt"), "mine");
  EXPECT_FALSE(fs::exists(dir + "/recording.yml"));
  // A file in the way.
  EXPECT_FALSE(GenerateRecording(o, dir + "/keep.txt").ok());
  // An empty directory is fine.
  fs::remove(dir + "/keep.txt");
  EXPECT_TRUE(GenerateRecording(o, dir).ok());
  EXPECT_TRUE(fs::exists(dir + "/frames/000000/b0_colour.png"));
  fs::remove_all(dir);
}

TEST(SceneTest, HitsAndMisses) {
  const SyntheticScene scene(7, 0, 10);
  // Straight down from above the floor's centre hits something on the way down with an
  // upward normal (the floor, or the top of an object).
  const std::optional<SceneHit> down = scene.Intersect({{-1.1, 3, 0.9}, {0, -1, 0}});
  ASSERT_TRUE(down.has_value());
  EXPECT_EQ(down->object, kObjectFloor);
  EXPECT_NEAR(down->position[1], kFloorY, 1e-12);
  EXPECT_NEAR(down->t, 3 - kFloorY, 1e-12);
  EXPECT_EQ(down->normal, cv::Vec3d(0, 1, 0));
  // Straight at the wall from the front, well above the objects.
  const std::optional<SceneHit> wall = scene.Intersect({{0, 0.8, 3}, {0, 0, -2}});
  ASSERT_TRUE(wall.has_value());
  EXPECT_EQ(wall->object, kObjectWall);
  EXPECT_NEAR(wall->t, (3 - kWallZ) / 2, 1e-12);  // in units of |dir|
  // Away from the scene: nothing.
  EXPECT_FALSE(scene.Intersect({{0, 0, 3}, {0, 0, 1}}).has_value());
  EXPECT_FALSE(scene.Intersect({{0, 0, 3}, {0, 1, 0}}).has_value());
  // At the moving box's centre from the front: its front face, normal towards the viewer.
  const cv::Vec3d c = scene.MovingCentre();
  const std::optional<SceneHit> box = scene.Intersect({c + cv::Vec3d(0, 0, 2), {0, 0, -1}});
  ASSERT_TRUE(box.has_value());
  EXPECT_EQ(box->object, kObjectMoving);
  EXPECT_NEAR(box->position[2], c[2] + 0.14, 1e-12);
  EXPECT_EQ(box->normal, cv::Vec3d(0, 0, 1));
  // Shadow queries: the box blocks the segment through it, not one that stops short.
  EXPECT_TRUE(scene.Occluded({c + cv::Vec3d(0, 0, 2), {0, 0, -1}}, 0, 3));
  EXPECT_FALSE(scene.Occluded({c + cv::Vec3d(0, 0, 2), {0, 0, -1}}, 0, 1.5));
  // Textured: colours vary across the floor and wall.
  std::vector<cv::Vec3b> colours;
  for (double x = -1; x <= 1; x += 0.13) colours.push_back(scene.Intersect({{x, 0.8, 3}, {0, 0, -1}})->colour_bgr);
  std::sort(colours.begin(), colours.end(), [](const cv::Vec3b& a, const cv::Vec3b& b) {
    return std::lexicographical_compare(a.val, a.val + 3, b.val, b.val + 3);
  });
  EXPECT_GT(std::unique(colours.begin(), colours.end()) - colours.begin(), 10);
}

TEST(CameraRayTest, InvertsProjectionWithDistortion) {
  GeneratorOptions o;
  const Calibration cal = GeneratorCalibration(o);
  for (const CameraModel& c : cal.cameras) {
    for (double v : {0.0, 17.3, 119.5, 239.0})
      for (double u : {0.0, 31.7, 160.0, 319.0}) {
        const Ray r = CameraRay(c, {u, v});
        EXPECT_NEAR(cv::norm(r.dir), 1.0, 1e-12);
        EXPECT_LT(cv::norm(r.origin - c.Centre()), 1e-12);
        EXPECT_LT(cv::norm(c.Project(r.origin + r.dir * 2.5) - cv::Point2d(u, v)), 1e-8);
      }
  }
}

// ---- EXR depth files

TEST(DepthExrTest, RoundTripKeepsEveryValue) {
  const std::string dir = TempDir("exr");
  fs::create_directories(dir);
  cv::Mat d(37, 53, CV_32F);
  cv::randu(d, 0.5f, 9.0f);
  d.at<float>(0, 0) = std::numeric_limits<float>::infinity();
  d.at<float>(36, 52) = std::numeric_limits<float>::infinity();
  d.at<float>(5, 7) = 1e-30f;
  ASSERT_TRUE(WriteDepthExr(dir + "/d.exr", d).ok());
  Result<cv::Mat> back = ReadDepthExr(dir + "/d.exr");
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  ASSERT_EQ(back->type(), CV_32FC1);
  ASSERT_EQ(back->size(), d.size());
  EXPECT_EQ(std::memcmp(back->data, d.data, d.total() * sizeof(float)), 0);
  EXPECT_TRUE(std::isinf(back->at<float>(0, 0)));
  // A region of interest (non-continuous rows) writes only that region.
  const cv::Mat roi = d(cv::Rect(3, 4, 20, 10));
  ASSERT_TRUE(WriteDepthExr(dir + "/roi.exr", roi).ok());
  Result<cv::Mat> roi_back = ReadDepthExr(dir + "/roi.exr");
  ASSERT_TRUE(roi_back.ok());
  EXPECT_EQ(cv::norm(roi_back.value(), roi, cv::NORM_INF), 0.0);
  // Wrong input types.
  EXPECT_TRUE(WriteDepthExr(dir + "/x.exr", cv::Mat(4, 4, CV_8U)).IsInvalidArgument());
  EXPECT_TRUE(WriteDepthExr(dir + "/x.exr", cv::Mat()).IsInvalidArgument());
  EXPECT_FALSE(WriteDepthExr(dir + "/no/such/dir/x.exr", d).ok());
  fs::remove_all(dir);
}

TEST(DepthExrTest, ErrorsNameTheFile) {
  const std::string dir = TempDir("exr_bad");
  fs::create_directories(dir);
  // Missing.
  Result<cv::Mat> missing = ReadDepthExr(dir + "/none.exr");
  ASSERT_FALSE(missing.ok());
  EXPECT_TRUE(missing.status().IsNotFound());
  EXPECT_NE(missing.status().message().find("none.exr"), std::string::npos);
  // Not an EXR.
  std::ofstream(dir + "/junk.exr") << "this is not an OpenEXR file at all";
  Result<cv::Mat> junk = ReadDepthExr(dir + "/junk.exr");
  ASSERT_FALSE(junk.ok());
  EXPECT_TRUE(junk.status().IsCorruption());
  EXPECT_NE(junk.status().message().find("junk.exr"), std::string::npos);
  // Truncated.
  cv::Mat d(64, 64, CV_32F, cv::Scalar(2.0f));
  cv::randu(d, 0.0f, 5.0f);  // incompressible enough that the pixels are most of the file
  ASSERT_TRUE(WriteDepthExr(dir + "/full.exr", d).ok());
  const std::string bytes = ReadBytes(dir + "/full.exr");
  std::ofstream(dir + "/cut.exr", std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  Result<cv::Mat> cut = ReadDepthExr(dir + "/cut.exr");
  ASSERT_FALSE(cut.ok());
  EXPECT_TRUE(cut.status().IsCorruption()) << cut.status().ToString();
  EXPECT_NE(cut.status().message().find("cut.exr"), std::string::npos);
  // A valid EXR without a "Z" channel.
  {
    Imf::Header header(4, 4);
    header.channels().insert("R", Imf::Channel(Imf::FLOAT));
    Imf::OutputFile file((dir + "/rgb.exr").c_str(), header);
    std::vector<float> px(16, 1.0f);
    Imf::FrameBuffer fb;
    fb.insert("R", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(px.data()), sizeof(float), 4 * sizeof(float)));
    file.setFrameBuffer(fb);
    file.writePixels(4);
  }
  Result<cv::Mat> no_z = ReadDepthExr(dir + "/rgb.exr");
  ASSERT_FALSE(no_z.ok());
  EXPECT_TRUE(no_z.status().IsCorruption());
  EXPECT_NE(no_z.status().message().find("rgb.exr"), std::string::npos);
  EXPECT_NE(no_z.status().message().find("\"Z\""), std::string::npos);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace hvdb::ingest
