// PhotoConsistencyMask (thesis 5.3, fig. 5.4, eq. 5.13).
//
// The scenes: a plane at world z = 2 seen by cameras near the origin. The views' images are
// painted analytically (each pixel's ray, through the lens distortion, intersected with the
// plane), independently of the splatting code under test.
#include "ingest/photo_consistency.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "ingest/points.h"
#include "render/splat.h"

namespace hvdb::ingest {
namespace {

constexpr double kPlaneZ = 2.0;

struct Rgb {
  uint8_t r, g, b;
};

uint8_t To8(double v) { return static_cast<uint8_t>(std::lround(std::clamp(v, 0.0, 1.0) * 255)); }

// Inverse of the YUV the implementation uses (BT.601, U and V in [-0.5, 0.5]).
Rgb FromYuv(double y, double u, double v) {
  return {To8(y + 1.402 * v), To8(y - 0.344136 * u - 0.714136 * v), To8(y + 1.772 * u)};
}

CameraModel LookAt(const std::string& name, cv::Vec3d centre, cv::Vec3d target, int w, int h,
                   double f, std::vector<double> dist = {}) {
  const cv::Vec3d fwd = cv::normalize(target - centre);
  const cv::Vec3d right = cv::normalize(fwd.cross(cv::Vec3d(0, -1, 0)));
  const cv::Vec3d down = fwd.cross(right);
  CameraModel c;
  c.name = name;
  c.K = {f, 0, (w - 1) / 2.0, 0, f, (h - 1) / 2.0, 0, 0, 1};
  c.R = {right[0], right[1], right[2], down[0], down[1], down[2], fwd[0], fwd[1], fwd[2]};
  c.T = -(c.R * centre);
  c.size = {w, h};
  c.dist = std::move(dist);
  return c;
}

using PlaneColour = std::function<Rgb(double x, double y)>;

// The camera's image of the plane z = kPlaneZ coloured by `colour`, through its distortion.
cv::Mat Paint(const CameraModel& cam, const PlaneColour& colour) {
  const int w = cam.size.width, h = cam.size.height;
  std::vector<cv::Point2d> px;
  px.reserve(static_cast<size_t>(w * h));
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) px.emplace_back(x, y);
  std::vector<cv::Point2d> norm;
  cv::undistortPoints(px, norm, cv::Mat(cam.K), cam.dist, cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 200, 1e-14));
  cv::Mat img(h, w, CV_8UC3);
  const cv::Vec3d o = cam.Centre();
  for (int i = 0; i < w * h; ++i) {
    const cv::Vec3d dir = cam.R.t() * cv::Vec3d(norm[static_cast<size_t>(i)].x,
                                                norm[static_cast<size_t>(i)].y, 1);
    const double t = (kPlaneZ - o[2]) / dir[2];
    const Rgb c = colour(o[0] + t * dir[0], o[1] + t * dir[1]);
    img.at<cv::Vec3b>(i / w, i % w) = cv::Vec3b(c.b, c.g, c.r);
  }
  return img;
}

Point MakePoint(double x, double y, double z, Rgb c, double sigma = 0.01, double sigma_n = 0.002) {
  Point p;
  p.x = static_cast<float>(x);
  p.y = static_cast<float>(y);
  p.z = static_cast<float>(z);
  p.cov = {static_cast<float>(sigma * sigma), 0, 0, static_cast<float>(sigma * sigma), 0,
           static_cast<float>(sigma_n * sigma_n)};
  p.flags = kFlagHasCovariance;
  p.r = c.r;
  p.g = c.g;
  p.b = c.b;
  return p;
}

// Plane samples on a 2 cm grid over x in [-1.6, 1.6], y in [-1.2, 1.2].
std::vector<Point> PlanePoints(const PlaneColour& colour) {
  std::vector<Point> pts;
  for (int j = 0; j <= 120; ++j) {
    for (int i = 0; i <= 160; ++i) {
      const double x = -1.6 + 0.02 * i, y = -1.2 + 0.02 * j;
      pts.push_back(MakePoint(x, y, kPlaneZ, colour(x, y)));
    }
  }
  return pts;
}

// A smooth colour ramp over the plane.
Rgb Ramp(double x, double y) {
  const double s = (x + 1.6) / 3.2, t = (y + 1.2) / 2.4;
  return {To8(0.25 + 0.4 * s), To8(0.45 + 0.25 * t), To8(0.7 - 0.3 * s)};
}

// Appends a 3x3 cluster (1 cm apart) around (x, y, z), returning the indices added.
std::vector<size_t> AddCluster(std::vector<Point>* pts, double x, double y, double z, Rgb c) {
  std::vector<size_t> idx;
  for (int j = -1; j <= 1; ++j) {
    for (int i = -1; i <= 1; ++i) {
      idx.push_back(pts->size());
      pts->push_back(MakePoint(x + 0.01 * i, y + 0.01 * j, z, c));
    }
  }
  return idx;
}

TEST(PhotoConsistency, RemovesExactlyTheVisibleOutliers) {
  const std::vector<CameraModel> cams = {
      LookAt("c0", {0, 0, 0}, {0, 0, 2}, 160, 120, 150),
      LookAt("c1", {-0.4, 0.1, 0}, {0, 0, 2}, 160, 120, 150),
      LookAt("c2", {0.9, 0, 0.2}, {0.2, 0, 2}, 160, 120, 150),
  };
  std::vector<Point> pts = PlanePoints(Ramp);
  const size_t plane = pts.size();
  // Wrong-coloured clusters floating 0.6 m in front of the plane, seen by every camera.
  std::vector<size_t> visible;
  const Rgb wrong[] = {{255, 0, 255}, {0, 255, 0}, {255, 255, 255}, {20, 20, 20}};
  const double where[][2] = {{-0.2, 0.1}, {0.15, -0.2}, {0.3, 0.25}, {-0.35, -0.15}};
  for (int k = 0; k < 4; ++k) {
    for (size_t i : AddCluster(&pts, where[k][0], where[k][1], 1.4, wrong[k])) visible.push_back(i);
  }
  // One seen only by c2 (0.5 m in front of it, outside the other two frusta).
  const std::vector<size_t> only_c2 = AddCluster(&pts, 0.719, 0.0, 0.666, {255, 0, 0});
  // Wrong-coloured clusters 0.3 m behind the plane: occluded in every view, never tested.
  std::vector<size_t> hidden;
  for (const auto& w : {std::array<double, 2>{0.0, 0.0}, {0.25, -0.1}, {-0.3, 0.2}}) {
    for (size_t i : AddCluster(&pts, w[0], w[1], kPlaneZ + 0.3, {255, 0, 255})) hidden.push_back(i);
  }
  std::vector<ColourView> views;
  for (const auto& c : cams) views.push_back({&c, Paint(c, Ramp)});

  PhotoConsistencyStats st;
  const std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  ASSERT_EQ(keep.size(), pts.size());
  for (size_t i = 0; i < plane; ++i) ASSERT_EQ(keep[i], 1) << "plane point " << i;
  for (size_t i : visible) EXPECT_EQ(keep[i], 0) << "outlier " << i;
  for (size_t i : only_c2) EXPECT_EQ(keep[i], 0) << "outlier " << i;
  for (size_t i : hidden) EXPECT_EQ(keep[i], 1) << "hidden point " << i;
  EXPECT_EQ(st.removed, visible.size() + only_c2.size());
  ASSERT_EQ(st.removed_per_view.size(), 3u);
  EXPECT_EQ(st.removed_per_view[0], visible.size());  // all seen first by c0
  EXPECT_EQ(st.removed_per_view[1], 0u);
  EXPECT_EQ(st.removed_per_view[2], only_c2.size());
  // Every hidden point was skipped in every view; the plane was tested in every view.
  EXPECT_GE(st.occluded_skips, 3 * hidden.size());
  EXPECT_GE(st.tested, plane);
  EXPECT_GT(st.ms, 0);

  // The same in one thread.
  PhotoConsistencyOptions one;
  one.threads = 1;
  PhotoConsistencyStats st1;
  EXPECT_EQ(PhotoConsistencyMask(pts, views, one, &st1), keep);
  EXPECT_EQ(st1.tested, st.tested);
  EXPECT_EQ(st1.occluded_skips, st.occluded_skips);
}

TEST(PhotoConsistency, ThresholdsPerYuvComponent) {
  const CameraModel cam = LookAt("c0", {0, 0, 0}, {0, 0, 2}, 160, 120, 150);
  const double y0 = 0.4;
  const Rgb grey = FromYuv(y0, 0, 0);
  auto uniform = [&](double, double) { return grey; };
  std::vector<Point> pts = PlanePoints(uniform);
  const size_t plane = pts.size();
  // Floating points 0.5 m in front of the plane, colour = the plane's shifted in YUV.
  struct Case {
    double dy, du, dv;
    bool kept;
  };
  const Case cases[] = {
      {+0.10, 0, 0, true},  {-0.10, 0, 0, true},  {+0.35, 0, 0, true},
      {+0.45, 0, 0, false}, {+0.50, 0, 0, false}, {0, +0.10, 0, true},
      {0, +0.20, 0, false}, {0, 0, -0.20, false}, {0, 0, +0.12, true},
  };
  std::vector<size_t> idx;
  for (int k = 0; k < 9; ++k) {
    idx.push_back(pts.size());
    const Case& c = cases[k];
    pts.push_back(MakePoint(-0.45 + 0.3 * (k % 4), -0.3 + 0.3 * (k / 4), 1.5,
                            FromYuv(y0 + c.dy, c.du, c.dv)));
  }
  const std::vector<ColourView> views = {{&cam, Paint(cam, uniform)}};
  PhotoConsistencyStats st;
  std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  for (size_t i = 0; i < plane; ++i) ASSERT_EQ(keep[i], 1);
  size_t removed = 0;
  for (int k = 0; k < 9; ++k) {
    EXPECT_EQ(keep[idx[static_cast<size_t>(k)]], cases[k].kept ? 1 : 0) << "case " << k;
    removed += cases[k].kept ? 0 : 1;
  }
  EXPECT_EQ(st.removed, removed);
  ASSERT_EQ(st.removed_per_view.size(), 1u);
  EXPECT_EQ(st.removed_per_view[0], removed);
  // Plane points behind the kept floating points are (partly or fully) occluded by them.
  EXPECT_GT(st.occluded_skips, 0u);
  EXPECT_GE(st.tested, 9u);
  EXPECT_LE(st.tested + st.occluded_skips, pts.size());

  // Tighter thresholds: a 10% Y shift is then inconsistent too; U/V tolerate 0.25.
  PhotoConsistencyOptions tight;
  tight.max_dy = 0.05;
  tight.max_du = tight.max_dv = 0.25;
  keep = PhotoConsistencyMask(pts, views, tight, &st);
  for (size_t i = 0; i < plane; ++i) ASSERT_EQ(keep[i], 1);
  const bool want[] = {false, false, false, false, false, true, true, true, true};
  for (int k = 0; k < 9; ++k) EXPECT_EQ(keep[idx[static_cast<size_t>(k)]], want[k] ? 1 : 0) << k;
}

TEST(PhotoConsistency, RemovedPointsNoLongerHideWhatIsBehind) {
  // O is inconsistent in both views. In view B, X lies right behind O; X agrees with A's image
  // (so A keeps it) but not with B's, whose plane has a U tint within the tolerance for the
  // plane itself. X must be tested in B, and removed, because O is gone: a second round.
  const CameraModel a = LookAt("a", {0, 0, 0}, {0, 0, 2}, 160, 120, 150);
  const CameraModel b = LookAt("b", {0.9, 0, 0.2}, {0.2, 0, 2}, 160, 120, 150);
  const Rgb plane_colour = FromYuv(0.5, 0, 0);
  auto in_a = [&](double, double) { return plane_colour; };
  auto in_b = [&](double, double) { return FromYuv(0.5, 0.1, 0); };
  std::vector<Point> pts = PlanePoints(in_a);
  const size_t plane = pts.size();
  const cv::Vec3d o(0.3, 0, 1.0);
  const cv::Vec3d ray = cv::normalize(o - b.Centre());
  const cv::Vec3d x = o + 0.3 * ray;
  pts.push_back(MakePoint(o[0], o[1], o[2], {255, 0, 255}));
  pts.push_back(MakePoint(x[0], x[1], x[2], FromYuv(0.5, -0.1, 0)));
  const std::vector<ColourView> views = {{&a, Paint(a, in_a)}, {&b, Paint(b, in_b)}};
  PhotoConsistencyStats st;
  const std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  for (size_t i = 0; i < plane; ++i) ASSERT_EQ(keep[i], 1);
  EXPECT_EQ(keep[plane], 0);      // O
  EXPECT_EQ(keep[plane + 1], 0);  // X
  ASSERT_EQ(st.removed_per_view.size(), 2u);
  EXPECT_EQ(st.removed_per_view[0], 1u);  // O, rejected by B too but counted for A
  EXPECT_EQ(st.removed_per_view[1], 1u);  // X
  EXPECT_GE(st.rounds, 2);
  // B alone finds both: X only once O is gone.
  const std::vector<ColourView> only_b = {views[1]};
  const std::vector<uint8_t> keep_b = PhotoConsistencyMask(pts, only_b, {}, &st);
  EXPECT_EQ(keep_b[plane], 0);
  EXPECT_EQ(keep_b[plane + 1], 0);
  EXPECT_GE(st.rounds, 2);

  // Control: with O consistent in both views (half way between A's and B's tint) it is kept
  // and shields X in B, so X survives.
  std::vector<Point> shielded = pts;
  shielded[plane] = MakePoint(o[0], o[1], o[2], FromYuv(0.5, 0.05, 0));
  const std::vector<uint8_t> keep2 = PhotoConsistencyMask(shielded, views, {}, &st);
  EXPECT_EQ(keep2[plane], 1);
  EXPECT_EQ(keep2[plane + 1], 1);
}

// Vertical stripes alternating in U by 0.2 (Y equal): a splat on a stripe edge deviates by at
// most half that, but one misplaced by more than its radius deviates by the full 0.2.
Rgb Stripes(double x, double) {
  const bool odd = static_cast<int>(std::floor((x + 10) / 0.2)) % 2 != 0;
  return FromYuv(0.5, odd ? 0.1 : -0.1, 0);
}

TEST(PhotoConsistency, ProjectsWithLensDistortion) {
  const std::vector<CameraModel> cams = {
      LookAt("barrel", {0, 0, 0}, {0, 0, 2}, 160, 120, 150, {-0.25, 0.05, 0, 0, 0}),
      LookAt("tangential", {-0.3, 0.1, 0}, {0, 0, 2}, 160, 120, 150, {0.1, 0, 0.004, -0.003}),
  };
  const std::vector<Point> pts = PlanePoints(Stripes);
  std::vector<ColourView> views;
  for (const auto& c : cams) views.push_back({&c, Paint(c, Stripes)});
  PhotoConsistencyStats st;
  std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  EXPECT_EQ(st.removed, 0u);
  EXPECT_EQ(std::count(keep.begin(), keep.end(), 0), 0);
  EXPECT_GT(st.tested, 10000u);  // about half the plane in each of the two views

  // The test can fail: the same distorted images with the distortion ignored remove many.
  std::vector<CameraModel> pinhole = cams;
  for (auto& c : pinhole) c.dist.clear();
  std::vector<ColourView> wrong;
  for (size_t i = 0; i < pinhole.size(); ++i) wrong.push_back({&pinhole[i], views[i].image});
  keep = PhotoConsistencyMask(pts, wrong, {}, &st);
  EXPECT_GT(st.removed, 500u) << st.removed << " of " << st.tested;
}

TEST(PhotoConsistency, PointsFromDepthPassTheirOwnViews) {
  // End to end: points from two cameras' depth maps of the ramp plane (images in the pinhole
  // frame), checked against the cameras' distorted images. Nothing may be removed.
  std::vector<CameraModel> cams = {
      LookAt("c0", {0, 0, 0}, {0, 0, 2}, 160, 120, 150, {-0.1, 0, 0, 0}),
      LookAt("c1", {0.5, 0, 0.1}, {0, 0, 2}, 160, 120, 150, {0.05, 0, 0, 0}),
  };
  std::vector<Point> pts;
  for (size_t v = 0; v < cams.size(); ++v) {
    CameraModel pinhole = cams[v];
    pinhole.dist.clear();
    DepthView dv;
    dv.camera = &cams[v];
    dv.colour = Paint(pinhole, Ramp);
    dv.depth = cv::Mat(120, 160, CV_32F);
    const cv::Vec3d o = pinhole.Centre();
    for (int y = 0; y < 120; ++y) {
      for (int x = 0; x < 160; ++x) {
        const cv::Vec3d dir = pinhole.R.t() * (pinhole.K.inv() * cv::Vec3d(x, y, 1));
        dv.depth.at<float>(y, x) = static_cast<float>((kPlaneZ - o[2]) / dir[2]);  // z_cam
      }
    }
    dv.camera_id = static_cast<uint16_t>(v);
    const std::vector<Point> part = PointsFromDepth(dv, {});
    ASSERT_EQ(part.size(), 160u * 120u);
    pts.insert(pts.end(), part.begin(), part.end());
  }
  std::vector<ColourView> views;
  for (const auto& c : cams) views.push_back({&c, Paint(c, Ramp)});
  PhotoConsistencyStats st;
  const std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  EXPECT_EQ(st.removed, 0u);
  EXPECT_EQ(std::count(keep.begin(), keep.end(), 1), static_cast<long>(pts.size()));
  EXPECT_GT(st.tested, pts.size());
}

TEST(PhotoConsistency, BadViewsAreSkipped) {
  const CameraModel cam = LookAt("c0", {0, 0, 0}, {0, 0, 2}, 160, 120, 150);
  std::vector<Point> pts = PlanePoints(Ramp);
  pts.push_back(MakePoint(0, 0, 1.5, {255, 0, 255}));
  const cv::Mat grey(120, 160, CV_8UC1, cv::Scalar(100));
  const std::vector<ColourView> views = {{nullptr, Paint(cam, Ramp)}, {&cam, grey}, {&cam, {}}};
  PhotoConsistencyStats st;
  const std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  EXPECT_EQ(std::count(keep.begin(), keep.end(), 1), static_cast<long>(pts.size()));
  EXPECT_EQ(st.tested, 0u);
  EXPECT_EQ(st.removed_per_view, std::vector<size_t>(3, 0));
  // An image at half the calibrated size: the intrinsics follow it.
  cv::Mat half;
  cv::resize(Paint(cam, Ramp), half, {80, 60}, 0, 0, cv::INTER_AREA);
  const std::vector<ColourView> small = {{&cam, half}};
  const std::vector<uint8_t> keep2 = PhotoConsistencyMask(pts, small, {}, &st);
  EXPECT_EQ(keep2.back(), 0);
  EXPECT_EQ(st.removed, 1u);
}

TEST(PhotoConsistency, Throughput) {
  // 640 x 480 depth map -> 307 200 points; photo-consistency in three 640 x 480 views.
  const std::vector<CameraModel> cams = {
      LookAt("c0", {0, 0, 0}, {0, 0, 2}, 640, 480, 600),
      LookAt("c1", {-0.3, 0, 0}, {0, 0, 2}, 640, 480, 600),
      LookAt("c2", {0.3, 0.1, 0}, {0, 0, 2}, 640, 480, 600),
  };
  DepthView dv;
  dv.camera = &cams[0];
  dv.colour = Paint(cams[0], Ramp);
  dv.depth = cv::Mat(480, 640, CV_32F, cv::Scalar(kPlaneZ));
  auto t0 = std::chrono::steady_clock::now();
  const std::vector<Point> pts = PointsFromDepth(dv, {});
  auto t1 = std::chrono::steady_clock::now();
  ASSERT_EQ(pts.size(), 640u * 480u);
  std::vector<ColourView> views;
  for (const auto& c : cams) views.push_back({&c, Paint(c, Ramp)});
  PhotoConsistencyStats st;
  const std::vector<uint8_t> keep = PhotoConsistencyMask(pts, views, {}, &st);
  const double points_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  std::printf("PointsFromDepth: %zu points in %.1f ms (%.1f M points/s)\n", pts.size(), points_ms,
              pts.size() / points_ms / 1e3);
  std::printf("PhotoConsistencyMask: %zu points x 3 views in %.1f ms (%.2f M points/s)\n",
              pts.size(), st.ms, pts.size() / st.ms / 1e3);
  EXPECT_EQ(st.removed, 0u);
  EXPECT_EQ(std::count(keep.begin(), keep.end(), 1), static_cast<long>(pts.size()));
}

// Fig. 5.4 as the header states it, by brute force: per view on its own, rounds of a full
// z-buffer of the points not removed (one pixel at a time over each splat's whole box) and a
// test of every one of them (std::exp, double sums), until a round removes nothing; a point is
// removed when any view rejects it. The reference the tiled, incremental, vectorised test is
// checked against.
std::vector<uint8_t> ReferenceMask(const std::vector<Point>& pts, const std::vector<ColourView>& views,
                                   const PhotoConsistencyOptions& o) {
  std::vector<uint8_t> keep(pts.size(), 1);
  for (const ColourView& cv : views) {
    render::RenderOptions ro;
    ro.cutoff_radius = static_cast<float>(o.cutoff_radius);
    ro.depth_threshold = static_cast<float>(o.depth_threshold);
    auto view = render::internal::PrepareView(cv.camera->ToRenderCamera(), ro);
    EXPECT_TRUE(view.ok());
    std::vector<render::internal::Splat> splats;
    std::vector<uint32_t> index;
    for (size_t i = 0; i < pts.size(); ++i) {
      // A point made by one of the views' cameras: its Gaussian conditioned on the position
      // along that camera's ray.
      Point p = pts[i];
      for (const ColourView& src : views) {
        if (src.camera_id < 0 || src.camera_id != p.camera) continue;
        const cv::Vec3d d = cv::Vec3d(p.x, p.y, p.z) - src.camera->Centre();
        const auto& c = p.cov;
        const cv::Matx33d V(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]);
        const cv::Vec3d vd = V * d;
        const cv::Matx33d W = V - (vd * vd.t()) * (1.0 / d.dot(vd));
        p.cov = {static_cast<float>(W(0, 0)), static_cast<float>(W(0, 1)), static_cast<float>(W(0, 2)),
                 static_cast<float>(W(1, 1)), static_cast<float>(W(1, 2)), static_cast<float>(W(2, 2))};
      }
      render::internal::Splat sp;
      if (!render::internal::ProjectSplat(p, *view, {}, &sp)) continue;
      splats.push_back(sp);
      index.push_back(static_cast<uint32_t>(i));
    }
    std::vector<uint8_t> alive(splats.size(), 1);
    for (int round = 0; round < PhotoConsistencyOptions::kMaxRounds; ++round) {
      std::vector<float> zbuf(size_t{view->width} * view->height, std::numeric_limits<float>::infinity());
      for (size_t k = 0; k < splats.size(); ++k) {
        if (!alive[k]) continue;
        const auto& sp = splats[k];
        for (int y = sp.y0; y <= sp.y1; ++y)
          for (int x = sp.x0; x <= sp.x1; ++x) {
            const float fdx = static_cast<float>(x) - sp.u, fdy = static_cast<float>(y) - sp.v;
            if (render::internal::KernelQ(sp, fdx, fdy) > view->cutoff2) continue;
            float& z = zbuf[size_t(y) * view->width + size_t(x)];
            z = std::min(z, render::internal::FragmentDepth(sp, fdx, fdy));
          }
      }
      std::vector<size_t> removed;
      for (size_t k = 0; k < splats.size(); ++k) {
        const auto& sp = splats[k];
        const bool on_image = sp.u >= -0.5f && sp.u <= view->width - 0.5f && sp.v >= -0.5f &&
                              sp.v <= view->height - 0.5f;
        const Point& p = pts[index[k]];
        if (!alive[k] || !on_image || (cv.camera_id >= 0 && p.camera == cv.camera_id)) continue;
        const double py = 0.299 * p.r / 255 + 0.587 * p.g / 255 + 0.114 * p.b / 255;
        const double pu = (p.b / 255.0 - py) / 1.772, pv = (p.r / 255.0 - py) / 1.402;
        double sa = 0, dy = 0, du = 0, dv = 0;
        for (int y = sp.y0; y <= sp.y1; ++y)
          for (int x = sp.x0; x <= sp.x1; ++x) {
            const float fdx = static_cast<float>(x) - sp.u, fdy = static_cast<float>(y) - sp.v;
            const float q = render::internal::KernelQ(sp, fdx, fdy);
            if (q > view->cutoff2) continue;
            const float z = render::internal::FragmentDepth(sp, fdx, fdy);
            if (z > zbuf[size_t(y) * view->width + size_t(x)] + view->depth_threshold) continue;
            const double a = std::exp(-0.5 * q);
            const cv::Vec3b c = cv.image.at<cv::Vec3b>(y, x);
            const double iy = 0.299 * c[2] / 255 + 0.587 * c[1] / 255 + 0.114 * c[0] / 255;
            sa += a;
            dy += a * (iy - py);
            du += a * ((c[0] / 255.0 - iy) / 1.772 - pu);
            dv += a * ((c[2] / 255.0 - iy) / 1.402 - pv);
          }
        if (sa > 0 && (std::abs(dy / sa) > o.max_dy || std::abs(du / sa) > o.max_du ||
                       std::abs(dv / sa) > o.max_dv))
          removed.push_back(k);
      }
      if (removed.empty()) break;
      for (size_t k : removed) alive[k] = 0, keep[index[k]] = 0;
    }
  }
  return keep;
}

// Differential: a plane seen by four cameras, with clusters of points in front of and behind
// it in random colours, sizes and depths (seeded), against the brute-force reference.
TEST(PhotoConsistency, MatchesTheBruteForceReference) {
  cv::RNG rng(29);
  std::vector<Point> pts = PlanePoints(Ramp);
  for (int k = 0; k < 400; ++k) {
    const Rgb c{static_cast<uint8_t>(rng.uniform(0, 256)), static_cast<uint8_t>(rng.uniform(0, 256)),
                static_cast<uint8_t>(rng.uniform(0, 256))};
    pts.push_back(MakePoint(rng.uniform(-1.4, 1.4), rng.uniform(-1.0, 1.0), rng.uniform(1.2, 2.3), c,
                            rng.uniform(0.003, 0.03), rng.uniform(0.001, 0.01)));
  }
  std::vector<CameraModel> cams = {
      LookAt("a", {0, 0, 0}, {0, 0, kPlaneZ}, 160, 120, 120),
      LookAt("b", {0.4, 0.1, 0}, {0, 0, kPlaneZ}, 150, 110, 110, {-0.05, 0.01, 0.001, -0.001, 0}),
      LookAt("c", {-0.5, -0.2, 0.1}, {0.1, 0, kPlaneZ}, 170, 130, 140),
      LookAt("d", {0.1, 0.4, -0.2}, {0, 0, kPlaneZ}, 128, 96, 90)};
  std::vector<ColourView> views;
  for (const CameraModel& c : cams) views.push_back({&c, Paint(c, Ramp)});
  PhotoConsistencyOptions o;
  const std::vector<uint8_t> want = ReferenceMask(pts, views, o);
  PhotoConsistencyStats st;
  const std::vector<uint8_t> got = PhotoConsistencyMask(pts, views, o, &st);
  EXPECT_GT(st.removed, 50u);
  EXPECT_LT(st.removed, 400u);
  size_t differ = 0;
  for (size_t i = 0; i < pts.size(); ++i) differ += want[i] != got[i];
  EXPECT_EQ(differ, 0u);
  // Neither the order of the views nor the number of threads changes the result.
  std::vector<ColourView> reversed(views.rbegin(), views.rend());
  PhotoConsistencyOptions one = o;
  one.threads = 1;
  EXPECT_EQ(PhotoConsistencyMask(pts, reversed, o), got);
  EXPECT_EQ(PhotoConsistencyMask(pts, views, one), got);
  PhotoConsistencyOptions three = o;
  three.threads = 3;
  EXPECT_EQ(PhotoConsistencyMask(pts, reversed, three), got);

  // With the points' cameras known, each point made by one of them is splatted with its pixel
  // footprint only. The random points are given elongated Gaussians along the ray from the
  // camera named as theirs (depth uncertainty), which then no longer streak in the others.
  std::vector<Point> rays = pts;
  for (size_t i = 0; i < rays.size(); ++i) {
    Point& p = rays[i];
    p.camera = static_cast<uint16_t>(i % 5);  // 4: a camera that is not a view
    if (p.camera == 4) continue;
    const cv::Vec3d d = cv::normalize(cv::Vec3d(p.x, p.y, p.z) - cams[p.camera].Centre());
    const double s2 = 0.05 * 0.05;
    p.cov[0] += static_cast<float>(s2 * d[0] * d[0]), p.cov[1] += static_cast<float>(s2 * d[0] * d[1]);
    p.cov[2] += static_cast<float>(s2 * d[0] * d[2]), p.cov[3] += static_cast<float>(s2 * d[1] * d[1]);
    p.cov[4] += static_cast<float>(s2 * d[1] * d[2]), p.cov[5] += static_cast<float>(s2 * d[2] * d[2]);
  }
  std::vector<ColourView> with_ids = views;
  for (size_t v = 0; v < with_ids.size(); ++v) with_ids[v].camera_id = static_cast<int>(v);
  const std::vector<uint8_t> want_ids = ReferenceMask(rays, with_ids, o);
  const std::vector<uint8_t> got_ids = PhotoConsistencyMask(rays, with_ids, o, &st);
  EXPECT_GT(st.removed, 50u);
  differ = 0;
  for (size_t i = 0; i < rays.size(); ++i) differ += want_ids[i] != got_ids[i];
  EXPECT_EQ(differ, 0u);
  // Without the ids the streaks are tested as they are: another result.
  EXPECT_NE(PhotoConsistencyMask(rays, views, o), got_ids);
}

}  // namespace
}  // namespace hvdb::ingest
