#include "render/projective_texture.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

#include "render/camera_pose.h"
#include "render/splat.h"

namespace hvdb::render {

using internal::Angle;
using internal::Pose;
using internal::Vec3;

Status ProjectiveTexture(const Camera& camera, std::span<const TextureView> views,
                         const TextureOptions& o, Image* image, TextureStats* stats) {
  if (image == nullptr || image->width != camera.width || image->height != camera.height ||
      image->depth.size() != image->pixels() || image->rgba.size() != 4 * image->pixels() ||
      image->coverage.size() != image->pixels()) {
    return Status::InvalidArgument("projective texture: the image must be rendered from this camera");
  }
  if (o.max_views < 1 || !(o.visibility_tolerance > 0)) {
    return Status::InvalidArgument("projective texture: max_views >= 1 and visibility_tolerance > 0");
  }
  for (const TextureView& v : views) {
    const size_t n = size_t{v.camera.width} * v.camera.height;
    const size_t nd = v.depth_width == 0 ? n : size_t{v.depth_width} * v.depth_height;
    if (v.rgb.size() != 3 * n || v.depth.size() != nd || (v.depth_width == 0) != (v.depth_height == 0)) {
      return Status::InvalidArgument("projective texture: a view's photo or depth does not match its camera");
    }
    HVDB_RETURN_IF_ERROR(v.camera.Validate());
  }
  const Pose target(camera);
  std::vector<Pose> sources;
  for (const TextureView& v : views) sources.emplace_back(v.camera);
  const auto& lin = internal::SrgbTable();
  const unsigned threads = o.threads ? o.threads : std::max(1u, std::thread::hardware_concurrency());
  std::vector<uint64_t> with_depth(image->height, 0), textured(image->height, 0);
  internal::ParallelFor(image->height, threads, [&](size_t y) {
    struct Candidate {
      double angle;
      size_t view;
      double u, v;
    };
    std::vector<Candidate> seen;
    for (uint32_t x = 0; x < image->width; ++x) {
      const size_t px = y * image->width + x;
      const float z = image->depth[px];
      if (!std::isfinite(z)) continue;
      ++with_depth[y];
      const Vec3 X = target.Unproject(x, static_cast<double>(y), z);
      const Vec3 to_target{target.centre.x - X.x, target.centre.y - X.y, target.centre.z - X.z};
      seen.clear();
      for (size_t s = 0; s < sources.size(); ++s) {
        double u, v, zs;
        if (!sources[s].Project(X, &u, &v, &zs)) continue;
        const Camera& sc = views[s].camera;
        if (u < 0 || v < 0 || u > sc.width - 1.0 || v > sc.height - 1.0) continue;
        // Visible from s: s saw a surface at this point's depth (its nearest depth pixel).
        const TextureView& tv = views[s];
        const uint32_t dw = tv.depth_width ? tv.depth_width : sc.width;
        const uint32_t dh = tv.depth_height ? tv.depth_height : sc.height;
        const double du = (u + 0.5) * dw / sc.width - 0.5, dv = (v + 0.5) * dh / sc.height - 0.5;
        // Visible unless s saw something clearly nearer all around the point: the point's
        // depth must lie within the range of the 3x3 depth pixels around it (widened by the
        // tolerance). A splat covering a pixel lies in front of the surface at the pixel's
        // centre where the surface is seen at a grazing angle (its disc faces the camera that
        // took it), so no single pixel's depth can be trusted to the tolerance there; behind an
        // occluder all nine are nearer.
        const long cx = std::clamp<long>(std::lround(du), 0, long(dw) - 1);
        const long cy = std::clamp<long>(std::lround(dv), 0, long(dh) - 1);
        float lo = std::numeric_limits<float>::infinity(), hi = -lo;
        for (long yy = std::max(0L, cy - 1); yy <= std::min<long>(cy + 1, long(dh) - 1); ++yy) {
          for (long xx = std::max(0L, cx - 1); xx <= std::min<long>(cx + 1, long(dw) - 1); ++xx) {
            const float ds = tv.depth[static_cast<size_t>(yy) * dw + static_cast<size_t>(xx)];
            if (!std::isfinite(ds)) continue;
            lo = std::min(lo, ds);
            hi = std::max(hi, ds);
          }
        }
        const bool visible = lo <= hi && zs >= lo * (1 - o.visibility_tolerance) &&
                             zs <= hi * (1 + o.visibility_tolerance);
        if (!visible) continue;
        const Vec3 to_source{sources[s].centre.x - X.x, sources[s].centre.y - X.y, sources[s].centre.z - X.z};
        seen.push_back({Angle(to_target, to_source), s, u, v});
      }
      if (seen.empty()) continue;
      std::sort(seen.begin(), seen.end(), [](const Candidate& a, const Candidate& b) {
        return a.angle < b.angle || (a.angle == b.angle && a.view < b.view);
      });
      // Buehler's penalty relative to the first view left out (or, when all are used, to
      // half as much again as the largest angle used), and always a little above the angles
      // used: a view that sees the point straight along the virtual ray (angle 0) alone, or
      // views at equal angles, must not all get weight 0.
      const size_t k = std::min<size_t>(seen.size(), static_cast<size_t>(o.max_views));
      const double next = std::max(k < seen.size() ? seen[k].angle : seen[k - 1].angle * 1.5,
                                   seen[k - 1].angle + 1e-3);
      double rgb[3] = {0, 0, 0}, wsum = 0;
      for (size_t i = 0; i < k; ++i) {
        const double a = std::max(seen[i].angle, 1e-6);
        const double w = std::max(0.0, 1 - a / next) / a;
        if (!(w > 0)) continue;
        const TextureView& tv = views[seen[i].view];
        // Bilinear in linear light.
        const double fu = std::floor(seen[i].u), fv = std::floor(seen[i].v);
        const double au = seen[i].u - fu, av = seen[i].v - fv;
        const size_t x0 = static_cast<size_t>(fu), y0 = static_cast<size_t>(fv);
        const size_t x1 = std::min<size_t>(x0 + 1, tv.camera.width - 1), y1 = std::min<size_t>(y0 + 1, tv.camera.height - 1);
        const uint8_t* p00 = &tv.rgb[3 * (y0 * tv.camera.width + x0)];
        const uint8_t* p01 = &tv.rgb[3 * (y0 * tv.camera.width + x1)];
        const uint8_t* p10 = &tv.rgb[3 * (y1 * tv.camera.width + x0)];
        const uint8_t* p11 = &tv.rgb[3 * (y1 * tv.camera.width + x1)];
        for (int c = 0; c < 3; ++c) {
          const double top = lin[p00[c]] * (1 - au) + lin[p01[c]] * au;
          const double bottom = lin[p10[c]] * (1 - au) + lin[p11[c]] * au;
          rgb[c] += w * (top * (1 - av) + bottom * av);
        }
        wsum += w;
      }
      if (!(wsum > 0)) continue;
      ++textured[y];
      const float cov = image->coverage[px];
      const internal::Resolved r = internal::Composite(static_cast<float>(rgb[0] / wsum),
                                                       static_cast<float>(rgb[1] / wsum),
                                                       static_cast<float>(rgb[2] / wsum), cov,
                                                       o.background);
      for (int c = 0; c < 4; ++c) image->rgba[4 * px + static_cast<size_t>(c)] = r.rgba[c];
    }
  });
  if (stats) {
    *stats = {};
    for (size_t y = 0; y < image->height; ++y) stats->pixels += with_depth[y], stats->textured += textured[y];
  }
  return Status::OK();
}

}  // namespace hvdb::render
