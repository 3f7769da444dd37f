#include "ingest/geometric_consistency.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <thread>

namespace hvdb::ingest {

std::vector<uint8_t> GeometricConsistencyMask(std::span<const Point> points,
                                              std::span<const DepthMapView> views,
                                              const GeometricConsistencyOptions& o,
                                              GeometricConsistencyStats* stats) {
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<uint8_t> keep(points.size(), 1);
  // Per view: x_cam = A X + b with A = K R and b = K T, so that u = x/z, v = y/z, z = depth.
  struct Proj {
    cv::Matx33d A;
    cv::Vec3d b;
    const cv::Mat* depth;
    uint16_t id;
  };
  std::vector<Proj> proj;
  for (const DepthMapView& v : views) {
    if (v.camera == nullptr || v.depth.empty() || v.depth.type() != CV_32FC1) continue;
    proj.push_back({v.camera->K * v.camera->R, v.camera->K * v.camera->T, &v.depth, v.camera_id});
  }
  std::atomic<size_t> removed{0}, unjudged{0}, next{0};
  constexpr size_t kChunk = 1 << 15;
  auto work = [&] {
    size_t rem = 0, unj = 0;
    for (size_t lo; (lo = next.fetch_add(kChunk)) < points.size();) {
      const size_t hi = std::min(points.size(), lo + kChunk);
      for (size_t i = lo; i < hi; ++i) {
        const Point& p = points[i];
        const cv::Vec3d X(p.x, p.y, p.z);
        int support = 0, violations = 0;
        for (const Proj& v : proj) {
          if (v.id == p.camera) continue;  // its own view agrees by construction
          const cv::Vec3d x = v.A * X + v.b;
          if (!(x[2] > 0)) continue;
          const double u = x[0] / x[2], w = x[1] / x[2];
          const int col = static_cast<int>(std::lround(u)), row = static_cast<int>(std::lround(w));
          if (col < 0 || row < 0 || col >= v.depth->cols || row >= v.depth->rows) continue;
          const float zv = v.depth->at<float>(row, col);
          if (!(zv > 0) || !std::isfinite(zv)) continue;
          const double rel = (x[2] - zv) / zv;
          if (std::abs(rel) <= o.tolerance) {
            ++support;
          } else if (rel < 0) {
            ++violations;  // in front of what this view saw
          }
        }
        if (support == 0 && violations == 0) ++unj;
        keep[i] = support >= o.min_support && violations <= support;
        rem += !keep[i];
      }
    }
    removed += rem;
    unjudged += unj;
  };
  const size_t threads = o.threads > 0 ? static_cast<size_t>(o.threads)
                                       : std::max(1u, std::thread::hardware_concurrency());
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads && points.size() > kChunk; ++t) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
  if (stats) {
    stats->removed = removed;
    stats->unjudged = unjudged;
    stats->ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  return keep;
}

}  // namespace hvdb::ingest
