// Fitting Gaussians to photos (gaussian_fit.h): 3DGS's training loop on the CPU.
#include "ingest/gaussian_fit.h"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <nanoflann.hpp>
#include <numeric>
#include <random>
#include <string>
#include <thread>

#include "ingest/gaussian_loss.h"
#include "render/gaussian_grad.h"

namespace hvdb::ingest {

namespace {

using formats::GaussianCloud;

// A cloud's arrays as parameter groups: each with its values per splat and learning rate.
struct Group {
  std::vector<float> GaussianCloud::*array;
  float lr;
};

// Adam (Kingma and Ba 2015) as torch.optim.Adam with 3DGS's eps of 1e-15: first and second
// moments shaped as the cloud.
struct Adam {
  GaussianCloud m, v;
  int step = 0;
};

void Resize(GaussianCloud* c, const GaussianCloud& like) {
  c->sh_degree = like.sh_degree;
  c->Resize(like.size());
}

// Rebuilds every per-splat array of `c` from `from` (the new splats' source indices). Where
// `zero` is true, the new arrays start at 0 (Adam's moments of cloned or split splats).
void Gather(GaussianCloud* c, const std::vector<uint32_t>& from, bool zero,
            const std::vector<uint8_t>& fresh) {
  auto gather = [&](std::vector<float>& a, size_t width) {
    std::vector<float> out(from.size() * width);
    for (size_t k = 0; k < from.size(); ++k) {
      if (zero && fresh[k]) continue;
      std::copy_n(a.begin() + static_cast<ptrdiff_t>(from[k] * width), width,
                  out.begin() + static_cast<ptrdiff_t>(k * width));
    }
    a.swap(out);
  };
  gather(c->position, 3);
  gather(c->scale, 3);
  gather(c->rotation, 4);
  gather(c->opacity, 1);
  gather(c->sh_dc, 3);
  gather(c->sh_rest, c->sh_rest_per_splat());
}

// Raises a cloud's SH degree to `degree`, its new coefficients 0 (the layout is channel-major
// per splat, so every splat's coefficients move).
void RaiseDegree(GaussianCloud* c, int degree) {
  const int from = formats::ShRestPerChannel(c->sh_degree);
  const int to = formats::ShRestPerChannel(degree);
  std::vector<float> rest(c->size() * 3 * static_cast<size_t>(to), 0.0f);
  for (size_t i = 0; i < c->size(); ++i) {
    for (int ch = 0; ch < 3; ++ch) {
      for (int j = 0; j < from; ++j) {
        rest[(i * 3 + ch) * to + j] = c->sh_rest[(i * 3 + ch) * from + j];
      }
    }
  }
  c->sh_rest.swap(rest);
  c->sh_degree = degree;
}

// The radius of the cameras' centres about their mean, times 1.1 (3DGS's getNerfppNorm); 1
// for a single camera.
float SceneExtent(const std::vector<FitView>& views) {
  double mean[3] = {0, 0, 0};
  for (const FitView& v : views) {
    for (int k = 0; k < 3; ++k) mean[k] += v.camera.world_from_camera[4 * k + 3] / views.size();
  }
  double radius = 0;
  for (const FitView& v : views) {
    double d2 = 0;
    for (int k = 0; k < 3; ++k) {
      const double d = v.camera.world_from_camera[4 * k + 3] - mean[k];
      d2 += d * d;
    }
    radius = std::max(radius, std::sqrt(d2));
  }
  return radius > 0 ? static_cast<float>(radius * 1.1) : 1.0f;
}

// Which splats some view sees, centre on a set pixel of its mask (a warm start's changed
// pixels).
std::vector<uint8_t> SeenOnMasks(const GaussianCloud& cloud, const std::vector<FitView>& views) {
  std::vector<uint8_t> seen(cloud.size(), 0);
  for (const FitView& v : views) {
    for (size_t i = 0; i < cloud.size(); ++i) {
      if (seen[i]) continue;
      const float* p = &cloud.position[3 * i];
      const long at = PixelOf(v.camera, p[0], p[1], p[2]);
      seen[i] = at >= 0 && v.mask[static_cast<size_t>(at)] != 0;
    }
  }
  return seen;
}

// Zeroes the gradient (and the densification statistic) of splats not `active`: Adam then
// leaves them exactly as they are.
void Freeze(const std::vector<uint8_t>& active, GaussianCloud* grad, std::vector<float>* screen) {
  const size_t rest = grad->sh_rest_per_splat();
  for (size_t i = 0; i < active.size(); ++i) {
    if (active[i]) continue;
    std::fill_n(&grad->position[3 * i], 3, 0.0f);
    std::fill_n(&grad->scale[3 * i], 3, 0.0f);
    std::fill_n(&grad->rotation[4 * i], 4, 0.0f);
    grad->opacity[i] = 0.0f;
    std::fill_n(&grad->sh_dc[3 * i], 3, 0.0f);
    if (rest > 0) std::fill_n(&grad->sh_rest[rest * i], rest, 0.0f);
    (*screen)[i] = -1.0f;  // not counted for densification
  }
}

// Every step-th point, as nanoflann's dataset adaptor.
struct KeptPoints {
  std::span<const Point> pts;
  size_t step;
  size_t kdtree_get_point_count() const { return (pts.size() + step - 1) / step; }
  float kdtree_get_pt(uint32_t i, size_t d) const {
    const Point& p = pts[i * step];
    return d == 0 ? p.x : d == 1 ? p.y : p.z;
  }
  template <class B>
  bool kdtree_get_bbox(B&) const {
    return false;
  }
};

}  // namespace

long PixelOf(const render::Camera& camera, double x, double y, double z) {
  const auto& m = camera.world_from_camera;  // columns: the camera's axes and centre
  const double d[3] = {x - m[3], y - m[7], z - m[11]};
  double c[3] = {0, 0, 0};
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) c[r] += m[4 * k + r] * d[k];  // R^T d
  }
  if (!(c[2] > 0)) return -1;
  const double u = std::round(camera.fx * c[0] / c[2] + camera.cx);
  const double v = std::round(camera.fy * c[1] / c[2] + camera.cy);
  if (!(u >= 0 && v >= 0 && u < camera.width && v < camera.height)) return -1;
  return static_cast<long>(v) * camera.width + static_cast<long>(u);
}

std::vector<uint8_t> ChangedPixels(const std::vector<float>& before, const std::vector<float>& now,
                                   int width, int height, float threshold, int grow) {
  const size_t pixels = static_cast<size_t>(width) * height;
  std::vector<uint8_t> changed(pixels, 0), out(pixels, 0);
  for (size_t i = 0; i < pixels; ++i) {
    for (int ch = 0; ch < 3; ++ch) {
      if (std::fabs(before[3 * i + ch] - now[3 * i + ch]) > threshold) changed[i] = 1;
    }
  }
  // Grown by a square of radius `grow`, separably: a pixel is set when a window of 2 grow + 1
  // along the row, then along the column, holds a set pixel (prefix counts).
  std::vector<uint8_t> rows(pixels, 0);
  std::vector<int> count(static_cast<size_t>(std::max(width, height)) + 1);
  auto window = [&](auto at, int n, auto set) {
    count[0] = 0;
    for (int k = 0; k < n; ++k) count[k + 1] = count[k] + (at(k) ? 1 : 0);
    for (int k = 0; k < n; ++k) {
      if (count[std::min(n, k + grow + 1)] - count[std::max(0, k - grow)] > 0) set(k);
    }
  };
  for (int y = 0; y < height; ++y) {
    const size_t row = static_cast<size_t>(y) * width;
    window([&](int x) { return changed[row + x] != 0; }, width, [&](int x) { rows[row + x] = 1; });
  }
  for (int x = 0; x < width; ++x) {
    window([&](int y) { return rows[static_cast<size_t>(y) * width + x] != 0; }, height,
           [&](int y) { out[static_cast<size_t>(y) * width + x] = 1; });
  }
  return out;
}

FitOptions Scheduled(FitOptions o, int iterations) {
  o.iterations = iterations;
  o.densify_from = iterations / 15;
  o.densify_until = iterations * 2 / 3;
  o.densify_interval = std::max(1, iterations / 15);
  o.sh_degree_interval = std::max(1, iterations / 4);
  return o;
}

double Psnr(std::span<const float> render, std::span<const float> target,
            std::span<const uint8_t> valid) {
  double se = 0;
  size_t n = 0;
  for (size_t i = 0; i < render.size(); ++i) {
    if (!valid.empty() && !valid[i / 3]) continue;
    const double a = std::clamp(render[i], 0.0f, 1.0f), b = std::clamp(target[i], 0.0f, 1.0f);
    se += (a - b) * (a - b);
    ++n;
  }
  if (n == 0) return std::nan("");
  const double mse = se / static_cast<double>(n);
  return mse > 0 ? 10.0 * std::log10(1.0 / mse) : 200.0;
}

GaussianCloud CloudFromPoints(std::span<const Point> points, int sh_degree, size_t max_splats) {
  const size_t step =
      max_splats == 0 ? 1 : std::max<size_t>(1, (points.size() + max_splats - 1) / max_splats);
  GaussianCloud c;
  c.sh_degree = sh_degree;
  c.Resize((points.size() + step - 1) / step);
  // The kept points' mean squared distance to their 3 nearest kept neighbours (3DGS sizes its
  // starting splats by it): nanoflann's kd-tree.
  const KeptPoints kept{points, step};
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, KeptPoints>,
                                                   KeptPoints, 3, uint32_t>;
  Tree tree(3, kept, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  for (size_t i = 0; i < c.size(); ++i) {
    Point p = points[i * step];
    Eigen::Matrix3d cov;
    cov << p.cov[0], p.cov[1], p.cov[2], p.cov[1], p.cov[3], p.cov[4], p.cov[2], p.cov[4], p.cov[5];
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
    // Grown (shape and orientation kept) until its widest standard deviation reaches the
    // neighbours' distance, so that a sparser sample still covers the surface; never shrunk.
    uint32_t idx[4];
    float d2[4];
    nanoflann::KNNResultSet<float, uint32_t> found(4);
    found.init(idx, d2);
    const float q[3] = {p.x, p.y, p.z};
    tree.findNeighbors(found, q, nanoflann::SearchParams());
    double mean = 0;
    for (size_t k = 1; k < found.size(); ++k) mean += d2[k] / static_cast<double>(found.size() - 1);
    const double widest = eig.eigenvalues()[2];
    Eigen::Matrix3d R = eig.eigenvectors();
    double var[3];
    if (!(widest > 1e-14)) {  // a point without a covariance: round, the neighbours' size
      R.setIdentity();
      // (at least 1 mm: neighbours may share the point's position)
      for (double& v : var) v = std::max(found.size() > 1 ? mean : 1e-6, 1e-6);
    } else {
      const double grow = found.size() > 1 ? std::max(1.0, mean / widest) : 1.0;
      // Flat ones keep a hundredth of their width across (3DGS's splats may be thin, not 0).
      for (int k = 0; k < 3; ++k)
        var[k] = std::max(eig.eigenvalues()[k] * grow, 1e-4 * widest * grow);
    }
    if (R.determinant() < 0) R.col(2) = -R.col(2);
    const Eigen::Quaterniond qr(R);
    for (int k = 0; k < 3; ++k) c.scale[3 * i + k] = static_cast<float>(0.5 * std::log(var[k]));
    c.position[3 * i] = p.x, c.position[3 * i + 1] = p.y, c.position[3 * i + 2] = p.z;
    c.rotation[4 * i] = static_cast<float>(qr.w());
    c.rotation[4 * i + 1] = static_cast<float>(qr.x());
    c.rotation[4 * i + 2] = static_cast<float>(qr.y());
    c.rotation[4 * i + 3] = static_cast<float>(qr.z());
    c.opacity[i] = formats::Logit(0.1f);
    const uint8_t rgb[3] = {p.r, p.g, p.b};
    for (int ch = 0; ch < 3; ++ch) {
      c.sh_dc[3 * i + ch] = static_cast<float>((rgb[ch] / 255.0 - 0.5) / formats::kShC0);
    }
  }
  return c;
}

Status FitGaussians(const std::vector<FitView>& views, const FitOptions& o, GaussianCloud* cloud,
                    FitReport* report) {
  const auto start = std::chrono::steady_clock::now();
  if (views.empty()) return Status::InvalidArgument("fit: no training views");
  for (size_t k = 0; k < views.size(); ++k) {
    const auto& cam = views[k].camera;
    if (views[k].rgb.size() != 3ull * cam.width * cam.height) {
      return Status::InvalidArgument("fit: view " + std::to_string(k) + " holds " +
                                     std::to_string(views[k].rgb.size()) + " values, its " +
                                     std::to_string(cam.width) + "x" + std::to_string(cam.height) +
                                     " camera needs 3 a pixel");
    }
  }
  if (o.iterations < 0 || o.sh_degree < 0 || o.sh_degree > formats::kMaxShDegree ||
      o.sh_degree_interval < 1 || o.lambda_dssim < 0 || o.lambda_dssim > 1 ||
      o.densify_interval < 1 || o.threads < 0) {
    return Status::InvalidArgument(
        "fit: options out of range (iterations >= 0, sh_degree 0..3, intervals >= 1, "
        "lambda_dssim 0..1, threads >= 0)");
  }
  HVDB_RETURN_IF_ERROR(formats::ValidateGaussianCloud(*cloud, "the starting cloud"));
  if (cloud->size() == 0) return Status::InvalidArgument("fit: the starting cloud is empty");
  cloud->antialiased = false;
  const unsigned threads = o.threads > 0 ? static_cast<unsigned>(o.threads)
                                         : std::max(1u, std::thread::hardware_concurrency());
  const float extent = SceneExtent(views);
  FitReport rep;
  rep.splats_in = cloud->size();

  Adam adam;
  Resize(&adam.m, *cloud);
  Resize(&adam.v, *cloud);
  std::mt19937_64 rng(o.seed);
  // The views that can drive the fit: those with a pixel in their mask (or without a mask).
  std::vector<uint32_t> order;
  for (size_t k = 0; k < views.size(); ++k) {
    const auto& mask = views[k].mask;
    if (!views[k].valid.empty() && views[k].valid.size() != views[k].rgb.size() / 3) {
      return Status::InvalidArgument("fit: view " + std::to_string(k) +
                                     "'s valid pixels are not one byte a pixel");
    }
    if (!mask.empty() && mask.size() != views[k].rgb.size() / 3) {
      return Status::InvalidArgument("fit: view " + std::to_string(k) +
                                     "'s mask is not one byte a pixel");
    }
    if (mask.empty() != views.front().mask.empty()) {
      return Status::InvalidArgument("fit: masks are given for some views and not others");
    }
    if (mask.empty() || std::any_of(mask.begin(), mask.end(), [](uint8_t b) { return b != 0; })) {
      order.push_back(static_cast<uint32_t>(k));
    }
  }
  const int iterations = order.empty() ? 0 : o.iterations;
  // With masks: the splats that may change.
  std::vector<uint8_t> active;
  if (!views.front().mask.empty()) active = SeenOnMasks(*cloud, views);
  size_t next_view = order.size();
  std::vector<double> grad_accum(cloud->size(), 0.0);
  std::vector<uint32_t> grad_count(cloud->size(), 0);
  render::GaussianGradRasterizer raster;
  render::GaussianGradient grad;
  std::vector<float> image, dL, screen, masked;
  double epoch_loss = 0;
  int epoch_views = 0;

  for (int it = 1; it <= iterations; ++it) {
    if (o.cancelled && o.cancelled()) {
      return Status(StatusCode::kCancelled, "fit: cancelled at iteration " + std::to_string(it));
    }
    // The SH degree grows as 3DGS's oneupSHdegree.
    if (cloud->sh_degree < o.sh_degree && it % o.sh_degree_interval == 0) {
      const int d = cloud->sh_degree + 1;
      RaiseDegree(cloud, d);
      RaiseDegree(&adam.m, d);
      RaiseDegree(&adam.v, d);
    }
    if (next_view == order.size()) {
      std::shuffle(order.begin(), order.end(), rng);
      next_view = 0;
      if (epoch_views > 0) rep.loss = epoch_loss / epoch_views;
      epoch_loss = 0;
      epoch_views = 0;
    }
    const FitView& view = views[order[next_view++]];
    HVDB_RETURN_IF_ERROR(
        raster.Forward(*cloud, view.camera, o.background, static_cast<int>(threads), &image));
    // Outside the view's valid pixels the target is the render itself: no loss, and the
    // gradient there is cut below.
    const std::vector<float>* target = &view.rgb;
    if (!view.valid.empty()) {
      masked = view.rgb;
      for (size_t p = 0; p < view.valid.size(); ++p) {
        if (!view.valid[p]) std::copy_n(&image[3 * p], 3, &masked[3 * p]);
      }
      target = &masked;
    }
    const PhotoLoss loss =
        L1DssimLoss(image, *target, static_cast<int>(view.camera.width),
                    static_cast<int>(view.camera.height), o.lambda_dssim, threads, &dL);
    for (size_t p = 0; p < view.valid.size(); ++p) {
      if (!view.valid[p]) dL[3 * p] = dL[3 * p + 1] = dL[3 * p + 2] = 0.0f;
    }
    epoch_loss += loss.loss;
    ++epoch_views;
    raster.Backward(dL, &grad, &screen);
    if (!active.empty()) Freeze(active, &grad, &screen);
    if (o.densify && it < o.densify_until) {
      for (size_t i = 0; i < cloud->size(); ++i) {
        // Every view that draws the splat counts, as 3DGS's denominator (visible: radius > 0).
        if (screen[i] >= 0) grad_accum[i] += screen[i], ++grad_count[i];
      }
    }

    // Adam, with 3DGS's learning rates; the position's decays exponentially.
    ++adam.step;
    const float t = static_cast<float>(it - 1) / std::max(1, o.iterations - 1);
    const float lr_position =
        std::exp(std::log(o.lr_position) * (1 - t) + std::log(o.lr_position_final) * t) * extent;
    const Group groups[] = {
        {&GaussianCloud::position, lr_position},   {&GaussianCloud::scale, o.lr_scale},
        {&GaussianCloud::rotation, o.lr_rotation}, {&GaussianCloud::opacity, o.lr_opacity},
        {&GaussianCloud::sh_dc, o.lr_sh_dc},       {&GaussianCloud::sh_rest, o.lr_sh_rest}};
    const double b1 = 0.9, b2 = 0.999, eps = 1e-15;
    const double c1 = 1 - std::pow(b1, adam.step), c2 = 1 - std::pow(b2, adam.step);
    for (const Group& g : groups) {
      std::vector<float>& p = cloud->*g.array;
      std::vector<float>& m = adam.m.*g.array;
      std::vector<float>& v = adam.v.*g.array;
      const std::vector<float>& d = grad.*g.array;
      const double step = g.lr / c1;
      const double root_c2 = std::sqrt(c2);
      for (size_t k = 0; k < p.size(); ++k) {
        m[k] = static_cast<float>(b1 * m[k] + (1 - b1) * d[k]);
        v[k] = static_cast<float>(b2 * v[k] + (1 - b2) * d[k] * d[k]);
        p[k] -= static_cast<float>(step * m[k] / (std::sqrt(v[k]) / root_c2 + eps));
      }
    }

    // Densify and prune (3DGS's densify_and_prune).
    if (o.densify && it >= o.densify_from && it < o.densify_until && it % o.densify_interval == 0) {
      const size_t n = cloud->size();
      std::vector<uint32_t> from;
      std::vector<uint8_t> fresh;
      std::vector<std::array<float, 3>> offset;  // split: the new centre's offset
      std::normal_distribution<float> normal(0.0f, 1.0f);
      const float big = o.percent_dense * extent;
      size_t added = 0;  // splats the cloud grows by
      std::vector<uint8_t> next_active;
      for (size_t i = 0; i < n; ++i) {
        if (!active.empty() && !active[i]) {  // frozen: kept as it is
          from.push_back(static_cast<uint32_t>(i));
          fresh.push_back(0);
          offset.push_back({0, 0, 0});
          next_active.push_back(0);
          continue;
        }
        const bool drop = formats::Sigmoid(cloud->opacity[i]) < o.prune_opacity;
        const double mean_grad = grad_count[i] > 0 ? grad_accum[i] / grad_count[i] : 0.0;
        const bool grow = mean_grad >= o.densify_gradient && n + added + 1 < o.max_splats;
        const float smax = std::exp(
            std::max({cloud->scale[3 * i], cloud->scale[3 * i + 1], cloud->scale[3 * i + 2]}));
        if (drop) continue;        // (3DGS prunes after splitting: the children would go too)
        if (grow && smax > big) {  // split in two, each sampled from the splat
          for (int k = 0; k < 2; ++k) {
            from.push_back(static_cast<uint32_t>(i));
            fresh.push_back(1);
            offset.push_back({normal(rng), normal(rng), normal(rng)});
          }
          ++added;
          next_active.resize(from.size(), 1);
          continue;  // the original goes
        }
        from.push_back(static_cast<uint32_t>(i));
        fresh.push_back(0);
        offset.push_back({0, 0, 0});
        if (grow) {  // clone
          from.push_back(static_cast<uint32_t>(i));
          fresh.push_back(1);
          offset.push_back({0, 0, 0});
          ++added;
        }
        next_active.resize(from.size(), 1);
      }
      if (from.empty()) {
        return Status::InvalidArgument("fit: every splat fell below the pruning opacity " +
                                       std::to_string(o.prune_opacity));
      }
      std::vector<uint8_t> split(from.size(), 0);
      for (size_t k = 0; k < from.size(); ++k) {
        split[k] = fresh[k] && (offset[k][0] != 0 || offset[k][1] != 0 || offset[k][2] != 0);
      }
      Gather(cloud, from, false, fresh);
      Gather(&adam.m, from, true, fresh);
      Gather(&adam.v, from, true, fresh);
      for (size_t k = 0; k < from.size(); ++k) {
        if (!split[k]) continue;
        // The new centre: the splat's own Gaussian sampled (R S z), its scale / (0.8 * 2).
        float* s = &cloud->scale[3 * k];
        const float* q = &cloud->rotation[4 * k];
        const float qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        const float w = qn > 0 ? q[0] / qn : 1, x = qn > 0 ? q[1] / qn : 0;
        const float y = qn > 0 ? q[2] / qn : 0, z = qn > 0 ? q[3] / qn : 0;
        const float R[9] = {
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
            2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
        const float sz[3] = {std::exp(s[0]) * offset[k][0], std::exp(s[1]) * offset[k][1],
                             std::exp(s[2]) * offset[k][2]};
        for (int r = 0; r < 3; ++r) {
          cloud->position[3 * k + r] +=
              R[3 * r] * sz[0] + R[3 * r + 1] * sz[1] + R[3 * r + 2] * sz[2];
        }
        for (int c = 0; c < 3; ++c) s[c] -= std::log(1.6f);
      }
      grad_accum.assign(cloud->size(), 0.0);
      grad_count.assign(cloud->size(), 0);
      if (!active.empty()) active.swap(next_active);
    }
    if (o.progress) o.progress(it, iterations);
  }
  if (epoch_views > 0) rep.loss = epoch_loss / epoch_views;

  double psnr = 0;
  int psnr_views = 0;
  for (const FitView& view : views) {
    HVDB_RETURN_IF_ERROR(
        raster.Forward(*cloud, view.camera, o.background, static_cast<int>(threads), &image));
    const double p = Psnr(image, view.rgb, view.valid);
    if (std::isnan(p)) continue;  // no valid pixel
    psnr += p;
    ++psnr_views;
  }
  rep.psnr = psnr_views > 0 ? psnr / psnr_views : std::nan("");
  rep.iterations = iterations;
  rep.splats_out = cloud->size();
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (report != nullptr) *report = rep;
  return Status::OK();
}

}  // namespace hvdb::ingest
