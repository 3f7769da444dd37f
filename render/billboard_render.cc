#include "render/billboard_render.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "formats/image_codec.h"
#include "render/camera_pose.h"
#include "render/splat.h"

namespace hvdb::render {

using internal::Angle;
using internal::Pose;
using internal::Vec3;

namespace {

// A map of a photo's billboard decoded from its PNG bytes; empty on failure.
cv::Mat DecodeMap(const std::string& bytes) {
  if (bytes.empty()) return {};
  auto m = formats::DecodeImage(bytes, "billboard map", formats::ImageMode::kAsStored);
  return m.ok() ? *m : cv::Mat();
}

}  // namespace

Result<BillboardSource> DecodeBillboard(const Photo& photo, std::span<const uint8_t> rgb,
                                        const std::string& what) {
  const PhotoBillboard& b = photo.billboard;
  const CameraInfo& c = photo.camera;
  if (!(b.scale > 0)) return Status::InvalidArgument(what + ": has no billboard");
  if (rgb.size() != size_t{c.width} * c.height * 3)
    return Status::InvalidArgument(what + ": the photo does not match its camera");
  const cv::Mat disp = DecodeMap(b.displacement), alpha = DecodeMap(b.alpha);
  const cv::Size size(static_cast<int>(c.width), static_cast<int>(c.height));
  if (disp.type() != CV_16UC1 || disp.size() != size)
    return Status::InvalidArgument(what + ": the billboard's displacement map is not a 16-bit grey "
                                   "PNG of the camera's size");
  if (alpha.type() != CV_8UC1 || alpha.size() != size)
    return Status::InvalidArgument(what + ": the billboard's alpha map is not an 8-bit grey PNG of "
                                   "the camera's size");
  BillboardSource s;
  s.camera.width = c.width;
  s.camera.height = c.height;
  s.camera.fx = c.fx, s.camera.fy = c.fy, s.camera.cx = c.cx, s.camera.cy = c.cy;
  s.camera.world_from_camera = c.world_from_camera;  // distortion: none
  const size_t n = size_t{c.width} * c.height;
  s.depth.assign(n, std::numeric_limits<float>::infinity());
  s.alpha.assign(n, 0.f);
  for (int y = 0; y < size.height; ++y) {
    const uint16_t* d = disp.ptr<uint16_t>(y);
    const uint8_t* a = alpha.ptr<uint8_t>(y);
    for (int x = 0; x < size.width; ++x) {
      const size_t i = size_t(y) * c.width + size_t(x);
      s.alpha[i] = a[x] / 255.f;
      if (d[x] == 0 || a[x] < 128) continue;
      const double dv = b.plane[0] * x + b.plane[1] * y + b.plane[2] + (d[x] / 256.0 - 128.0);
      if (dv > 0) s.depth[i] = static_cast<float>(b.scale / dv);
    }
  }
  // The photo undistorted into the billboard's pinhole camera (its colour map).
  const cv::Matx33d K(c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1);
  const std::vector<double> dist(c.distortion.begin(), c.distortion.end());
  const cv::Mat src(size, CV_8UC3, const_cast<uint8_t*>(rgb.data()));
  cv::Mat und;
  if (std::all_of(dist.begin(), dist.end(), [](double v) { return v == 0; })) {
    und = src;
  } else {
    cv::undistort(src, und, K, dist, K);
  }
  s.rgb.assign(und.data, und.data + n * 3);
  return s;
}

Status DrawBillboardDepth(const Camera& view, std::span<const BillboardSource> sources,
                          const BillboardDrawOptions& o, Image* image) {
  HVDB_RETURN_IF_ERROR(view.Validate());
  if (!(o.depth_tolerance >= 0)) return Status::InvalidArgument("billboards: depth_tolerance >= 0");
  for (const BillboardSource& s : sources) {
    const size_t n = size_t{s.camera.width} * s.camera.height;
    if (s.depth.size() != n || s.alpha.size() != n)
      return Status::InvalidArgument("billboards: a billboard's maps do not match its camera");
    HVDB_RETURN_IF_ERROR(s.camera.Validate());
  }
  const size_t n = size_t{view.width} * view.height;
  image->width = view.width;
  image->height = view.height;
  image->depth.assign(n, std::numeric_limits<float>::infinity());
  image->coverage.assign(n, 0.f);
  image->rgba.resize(4 * n);
  for (size_t i = 0; i < n; ++i)
    for (int c = 0; c < 4; ++c) image->rgba[4 * i + size_t(c)] = o.background[size_t(c)];

  const Pose target(view);
  std::vector<Pose> poses;
  for (const BillboardSource& s : sources) poses.emplace_back(s.camera);
  // Every fragment of every billboard, in tasks of row bands; fn(pixel, z, weight, alpha).
  constexpr uint32_t kBand = 32;
  struct Task {
    size_t source;
    uint32_t y0, y1;
  };
  std::vector<Task> tasks;
  for (size_t s = 0; s < sources.size(); ++s)
    for (uint32_t y = 0; y < sources[s].camera.height; y += kBand)
      tasks.push_back({s, y, std::min(sources[s].camera.height, y + kBand)});
  const auto& lin = internal::SrgbTable();
  // Each thread sums into buffers of its own, 28 bytes a pixel: as many threads as a budget of
  // 512 MiB allows (one at least), so a big view on many cores does not take gigabytes.
  const size_t thread_bytes = 28 * n;
  const unsigned wanted = o.threads ? o.threads : std::max(1u, std::thread::hardware_concurrency());
  const unsigned threads = static_cast<unsigned>(std::clamp<size_t>(
      std::min<size_t>({wanted, tasks.size(), (size_t{512} << 20) / std::max<size_t>(1, thread_bytes)}), 1, 64));
  auto fragments = [&](const Task& t, auto&& fn) {
    const BillboardSource& src = sources[t.source];
    const Pose& pose = poses[t.source];
    for (uint32_t y = t.y0; y < t.y1; ++y) {
      for (uint32_t x = 0; x < src.camera.width; ++x) {
        const size_t i = size_t(y) * src.camera.width + x;
        const float zs = src.depth[i], a = src.alpha[i];
        if (!std::isfinite(zs) || !(a > 0)) continue;
        const Vec3 X = pose.Unproject(x, y, zs);
        double u, v, zt;
        if (!target.Project(X, &u, &v, &zt)) continue;
        if (!(std::abs(u) < 1e6 && std::abs(v) < 1e6)) continue;  // far off the view (or grazing)
        // The sample's footprint: its pixel seen from the view, a little enlarged so that
        // neighbouring samples close up.
        const double h = std::clamp(0.6 * view.fx * zs / (src.camera.fx * zt), 0.5, 8.0);
        const long x0 = std::max(0L, static_cast<long>(std::ceil(u - h)));
        const long x1 = std::min(long(view.width) - 1, static_cast<long>(std::floor(u + h)));
        const long y0 = std::max(0L, static_cast<long>(std::ceil(v - h)));
        const long y1 = std::min(long(view.height) - 1, static_cast<long>(std::floor(v + h)));
        if (x0 > x1 || y0 > y1) continue;
        // The view's weight (unstructured lumigraph): smaller the wider the angle between
        // the billboard's camera and the view at this point.
        const Vec3 to_t{target.centre.x - X.x, target.centre.y - X.y, target.centre.z - X.z};
        const Vec3 to_s{pose.centre.x - X.x, pose.centre.y - X.y, pose.centre.z - X.z};
        const float w = static_cast<float>(a / (Angle(to_t, to_s) + 0.05));
        const uint8_t* c = src.rgb.empty() ? nullptr : &src.rgb[3 * i];
        for (long py = y0; py <= y1; ++py)
          for (long px = x0; px <= x1; ++px) fn(size_t(py) * view.width + size_t(px), float(zt), w, a, c);
      }
    }
  };
  auto run = [&](auto&& per_thread) {
    std::vector<std::thread> pool;
    for (unsigned k = 0; k < threads; ++k)
      pool.emplace_back([&, k] {
        for (size_t t = k; t < tasks.size(); t += threads) per_thread(k, tasks[t]);
      });
    for (auto& th : pool) th.join();
  };
  // Pass 1: the front-most fragment of each pixel.
  std::vector<std::vector<float>> zmin(threads);
  run([&](unsigned k, const Task& t) {
    if (zmin[k].empty()) zmin[k].assign(n, std::numeric_limits<float>::infinity());
    float* z = zmin[k].data();
    fragments(t, [&](size_t p, float zt, float, float, const uint8_t*) { z[p] = std::min(z[p], zt); });
  });
  std::vector<float> front(n, std::numeric_limits<float>::infinity());
  for (std::vector<float>& z : zmin) {
    for (size_t i = 0; i < z.size(); ++i) front[i] = std::min(front[i], z[i]);
    std::vector<float>().swap(z);  // freed before pass 2 allocates its sums
  }
  // Pass 2: eq. 6.13 over the fragments within the tolerance of it, and eq. 6.15.
  struct Sums {
    std::vector<float> wz, w, a, rgb;  // rgb: weighted linear colour of the fragments
  };
  std::vector<Sums> sums(threads);
  run([&](unsigned k, const Task& t) {
    Sums& s = sums[k];
    if (s.w.empty())
      s = {std::vector<float>(n, 0.f), std::vector<float>(n, 0.f), std::vector<float>(n, 0.f),
           std::vector<float>(3 * n, 0.f)};
    fragments(t, [&](size_t p, float zt, float w, float a, const uint8_t* c) {
      if (zt > front[p] * (1 + o.depth_tolerance)) return;
      s.wz[p] += w * zt;
      s.w[p] += w;
      s.a[p] = std::max(s.a[p], a);
      if (c != nullptr)
        for (int ch = 0; ch < 3; ++ch) s.rgb[3 * p + size_t(ch)] += w * lin[c[ch]];
    });
  });
  for (size_t i = 0; i < n; ++i) {
    float wz = 0, w = 0, a = 0, rgb[3] = {0, 0, 0};
    for (const Sums& s : sums) {
      if (s.w.empty()) continue;
      wz += s.wz[i], w += s.w[i], a = std::max(a, s.a[i]);
      for (int k = 0; k < 3; ++k) rgb[k] += s.rgb[3 * i + size_t(k)];
    }
    if (!(w > 0)) continue;
    image->depth[i] = wz / w;
    image->coverage[i] = a;
    // The billboards' own colours blended (the colour where projective texturing finds no
    // camera that sees the pixel's surface point).
    const internal::Resolved r = internal::Composite(rgb[0] / w, rgb[1] / w, rgb[2] / w, a, o.background);
    for (int k = 0; k < 4; ++k) image->rgba[4 * i + size_t(k)] = r.rgba[k];
  }
  return Status::OK();
}

}  // namespace hvdb::render
