#include "ingest/points.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>

#include <opencv2/imgproc.hpp>

namespace hvdb::ingest {

namespace {

bool ValidDepth(float z) { return std::isfinite(z) && z > 0; }

// The depth of the neighbour at (x + dx, y + dy) when a difference may be taken to it: inside
// the image, valid, and not across a depth discontinuity.
bool UsableNeighbour(const cv::Mat& depth, int x, int y, int dx, int dy, float z, double jump,
                     float* zn) {
  const int nx = x + dx, ny = y + dy;
  if (nx < 0 || ny < 0 || nx >= depth.cols || ny >= depth.rows) return false;
  const float v = depth.at<float>(ny, nx);
  if (!ValidDepth(v) || std::abs(static_cast<double>(v) - z) > jump * z) return false;
  *zn = v;
  return true;
}

struct Band {
  std::vector<Point> points;
  PointStats stats;
};

}  // namespace

std::vector<Point> PointsFromDepth(const DepthView& view, const PointOptions& options,
                                   PointStats* stats) {
  if (stats) *stats = PointStats{};
  const cv::Mat& depth = view.depth;
  if (view.camera == nullptr || depth.empty() || depth.type() != CV_32FC1 ||
      view.colour.type() != CV_8UC3 || view.colour.size() != depth.size() ||
      (!view.sigma_z.empty() &&
       (view.sigma_z.type() != CV_32FC1 || view.sigma_z.size() != depth.size())) ||
      options.stride < 1) {
    return {};
  }
  const CameraModel& cam = *view.camera;
  // M = R^-1 P^-1 maps homogeneous pixels to world directions; its columns m1, m2, m3 make every
  // per-pixel product a few multiply-adds: M (x, y, 1)^T = x m1 + y m2 + m3.
  const cv::Matx33d M = cam.R.t() * cam.K.inv();
  const cv::Vec3d m1(M(0, 0), M(1, 0), M(2, 0)), m2(M(0, 1), M(1, 1), M(2, 1)),
      m3(M(0, 2), M(1, 2), M(2, 2));
  const cv::Vec3d O = cam.Centre();
  // 5.2: pixel size plus calibration error. A sample taken every stride-th pixel stands for a
  // stride x stride block: its footprint is that wide, or the samples leave gaps between them.
  const double sigma_xy = options.stride + options.sigma_c;
  const double jump = options.max_relative_jump;
  const int stride = options.stride;
  const int rows = (depth.rows + stride - 1) / stride;  // sampled rows
  const int cols = (depth.cols + stride - 1) / stride;

  auto ray = [&](double x, double y) { return x * m1 + y * m2 + m3; };

  auto do_rows = [&](int r0, int r1, Band* band) {
    band->points.reserve(static_cast<size_t>(r1 - r0) * static_cast<size_t>(cols));
    for (int r = r0; r < r1; ++r) {
      const int y = r * stride;
      const float* zrow = depth.ptr<float>(y);
      const cv::Vec3b* crow = view.colour.ptr<cv::Vec3b>(y);
      const float* srow = view.sigma_z.empty() ? nullptr : view.sigma_z.ptr<float>(y);
      for (int x = 0; x < depth.cols; x += stride) {
        ++band->stats.pixels;
        const float zf = zrow[x];
        if (!ValidDepth(zf)) continue;
        const double z = zf;
        double sigma_z;
        if (srow) {
          sigma_z = srow[x];
          if (!std::isfinite(sigma_z) || sigma_z < 0) continue;  // e.g. invalid disparity
        } else {
          sigma_z = options.default_relative_sigma_z * z * z;
        }
        ++band->stats.valid;
        const cv::Vec3d d = ray(x, y);
        const cv::Vec3d X = z * d + O;  // eq. 5.12
        // Columns of R^-1 P^-1 Sigma_R (eqs. 5.10-5.11): the pixel footprint at depth z and the
        // depth uncertainty along the ray; V = sum T T^T.
        const cv::Vec3d tx = (sigma_xy * z) * m1, ty = (sigma_xy * z) * m2, tz = sigma_z * d;
        Point p;
        p.x = static_cast<float>(X[0]);
        p.y = static_cast<float>(X[1]);
        p.z = static_cast<float>(X[2]);
        p.frame = options.frame;
        auto cov = [&](int i, int j) {
          return static_cast<float>(tx[i] * tx[j] + ty[i] * ty[j] + tz[i] * tz[j]);
        };
        p.cov = {cov(0, 0), cov(0, 1), cov(0, 2), cov(1, 1), cov(1, 2), cov(2, 2)};
        p.r = crow[x][2];
        p.g = crow[x][1];
        p.b = crow[x][0];
        p.flags = kFlagHasCovariance;
        p.camera = view.camera_id;
        if (options.normals) {
          // Eqs. 5.5-5.6 with z_x, z_y as forward differences (the thesis' (x+1, y, 1) term makes
          // T1 exactly X(x+1, y) - X(x, y)); where the forward neighbour is missing or across a
          // discontinuity, the mirrored backward difference X(x, y) - X(x-1, y) =
          // R^-1 P^-1 (z e1 + z_x (x-1, y, 1)) with z_x = z - z(x-1). Both are exact on planes.
          float zn;
          bool have_x = true, have_y = true;
          cv::Vec3d t1, t2;
          if (UsableNeighbour(depth, x, y, 1, 0, zf, jump, &zn)) {
            t1 = z * m1 + (zn - z) * ray(x + 1, y);
          } else if (UsableNeighbour(depth, x, y, -1, 0, zf, jump, &zn)) {
            t1 = z * m1 + (z - zn) * ray(x - 1, y);
          } else {
            have_x = false;
          }
          if (UsableNeighbour(depth, x, y, 0, 1, zf, jump, &zn)) {
            t2 = z * m2 + (zn - z) * ray(x, y + 1);
          } else if (UsableNeighbour(depth, x, y, 0, -1, zf, jump, &zn)) {
            t2 = z * m2 + (z - zn) * ray(x, y - 1);
          } else {
            have_y = false;
          }
          if (have_x && have_y) {
            cv::Vec3d n = t1.cross(t2);
            const double len = cv::norm(n);
            if (len > 0 && std::isfinite(len)) {
              // Toward the camera: X - O = z d with z > 0, so n . d must be negative.
              if (n.dot(d) > 0) n = -n;
              n /= len;
              p.normal_oct = EncodeNormal(static_cast<float>(n[0]), static_cast<float>(n[1]),
                                          static_cast<float>(n[2]));
              p.flags |= kFlagHasNormal;
              ++band->stats.with_normal;
            }
          }
        }
        band->points.push_back(p);
      }
    }
    band->stats.points = band->points.size();
  };

  // Bands of rows on all cores; concatenated in order so the output stays row-major.
  constexpr int kBandRows = 32;
  const int nbands = (rows + kBandRows - 1) / kBandRows;
  std::vector<Band> bands(static_cast<size_t>(nbands));
  const unsigned hw = std::max(1u, std::thread::hardware_concurrency());
  const unsigned nthreads = std::min<unsigned>(hw, static_cast<unsigned>(nbands));
  std::atomic<int> next{0};
  auto work = [&] {
    for (int b = next++; b < nbands; b = next++) {
      do_rows(b * kBandRows, std::min(rows, (b + 1) * kBandRows), &bands[static_cast<size_t>(b)]);
    }
  };
  if (nthreads <= 1) {
    work();
  } else {
    std::vector<std::thread> pool;
    for (unsigned t = 1; t < nthreads; ++t) pool.emplace_back(work);
    work();
    for (auto& t : pool) t.join();
  }
  size_t total = 0;
  for (const Band& b : bands) total += b.points.size();
  std::vector<Point> out;
  out.reserve(total);
  PointStats sum;
  for (const Band& b : bands) {
    out.insert(out.end(), b.points.begin(), b.points.end());
    sum.pixels += b.stats.pixels;
    sum.valid += b.stats.valid;
    sum.points += b.stats.points;
    sum.with_normal += b.stats.with_normal;
  }
  if (stats) *stats = sum;
  return out;
}

cv::Mat DepthSigmaFromDisparity(const cv::Mat& disparity, const cv::Mat& disparity_dx,
                                double baseline, double fx, double sigma_c) {
  if (disparity.empty() || disparity.type() != CV_32FC1 || disparity_dx.type() != CV_32FC1 ||
      disparity_dx.size() != disparity.size()) {
    return {};
  }
  cv::Mat out(disparity.size(), CV_32FC1);
  const double scale = std::abs(baseline) * fx;
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    const float* dx = disparity_dx.ptr<float>(y);
    float* o = out.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      const double dv = d[x];
      if (!std::isfinite(dv) || dv <= 0) {
        o[x] = std::numeric_limits<float>::infinity();
        continue;
      }
      const double g = std::isfinite(dx[x]) ? std::abs(static_cast<double>(dx[x])) : 0.0;
      o[x] = static_cast<float>(scale / (dv * dv) * (g + sigma_c));  // eq. 5.8
    }
  }
  return out;
}

}  // namespace hvdb::ingest

namespace hvdb::ingest {

cv::Mat RemoveDepthEdges(const cv::Mat& depth, double max_relative_jump, int radius) {
  if (depth.empty() || depth.type() != CV_32FC1 || radius < 1) return depth.clone();
  cv::Mat out = depth.clone();
  const int w = depth.cols, h = depth.rows;
  // A pixel within `radius` of a jump is dropped: on both sides of a silhouette the sensor (or
  // the matcher) mixes foreground and background, and such samples float between the two.
  // First mark the jumps between 4-neighbours, then dilate the marks by `radius - 1`.
  cv::Mat edge(h, w, CV_8U, cv::Scalar(0));
  for (int y = 0; y < h; ++y) {
    const float* row = depth.ptr<float>(y);
    const float* below = y + 1 < h ? depth.ptr<float>(y + 1) : nullptr;
    for (int x = 0; x < w; ++x) {
      const float z = row[x];
      if (!ValidDepth(z)) continue;
      auto jump = [&](float zn) {
        return !ValidDepth(zn) ? false : std::abs(zn - z) > max_relative_jump * std::min(z, zn);
      };
      if (x + 1 < w && jump(row[x + 1])) edge.at<uint8_t>(y, x) = edge.at<uint8_t>(y, x + 1) = 1;
      if (below && jump(below[x])) edge.at<uint8_t>(y, x) = edge.at<uint8_t>(y + 1, x) = 1;
    }
  }
  if (radius > 1) {
    cv::dilate(edge, edge, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius - 1, 2 * radius - 1)));
  }
  out.setTo(0.0f, edge);
  return out;
}

}  // namespace hvdb::ingest
