#include "ingest/segmentation.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>

#include <opencv2/imgproc.hpp>

#include "edit/color_model.h"
#include "edit/maxflow.h"

namespace hvdb::ingest {

namespace {

// A one-dimensional Gaussian mixture (the depth models, eq. 6.22 in one dimension): means
// started at the samples' quantiles, then EM. Written here: edit's ColorModel is the same
// fit in three dimensions.
struct Gmm1 {
  std::vector<double> mean, inv_var, log_norm;  // log_norm: log(weight) - log(2 pi var) / 2

  Status Train(std::vector<double> x, int components) {
    if (x.empty()) return Status::InvalidArgument("segmentation: a depth model has no samples");
    std::sort(x.begin(), x.end());
    const size_t k = std::max<size_t>(1, std::min<size_t>(static_cast<size_t>(components), x.size() / 4));
    // No component narrower than depth's own uncertainty, taken as 2 % of the depth (a
    // stereo rig's at a few metres): a narrower one would claim the floor under an object
    // for the object by depth alone.
    const double kMinVar = std::pow(0.02 * x[x.size() / 2], 2);
    std::vector<double> m(k), var(k, 0), w(k, 1.0 / static_cast<double>(k));
    for (size_t j = 0; j < k; ++j) m[j] = x[std::min(x.size() - 1, (2 * j + 1) * x.size() / (2 * k))];
    double total = 0;
    for (double v : x) total += v;
    double spread = 0;
    for (double v : x) spread += (v - total / static_cast<double>(x.size())) * (v - total / static_cast<double>(x.size()));
    for (double& v : var) v = std::max(kMinVar, spread / static_cast<double>(x.size()) / static_cast<double>(k * k));
    std::vector<double> r(k);
    for (int it = 0; it < 30; ++it) {
      std::vector<double> sw(k, 0), sx(k, 0), sxx(k, 0);
      for (double v : x) {
        double best = -std::numeric_limits<double>::infinity();
        for (size_t j = 0; j < k; ++j) {
          r[j] = std::log(w[j]) - 0.5 * std::log(2 * std::numbers::pi * var[j]) -
                 0.5 * (v - m[j]) * (v - m[j]) / var[j];
          best = std::max(best, r[j]);
        }
        double sum = 0;
        for (size_t j = 0; j < k; ++j) sum += r[j] = std::exp(r[j] - best);
        for (size_t j = 0; j < k; ++j) {
          const double q = r[j] / sum;
          sw[j] += q, sx[j] += q * v, sxx[j] += q * v * v;
        }
      }
      for (size_t j = 0; j < k; ++j) {
        if (sw[j] < 1e-9) continue;  // an empty component keeps its place
        m[j] = sx[j] / sw[j];
        var[j] = std::max(kMinVar, sxx[j] / sw[j] - m[j] * m[j]);
        w[j] = sw[j] / static_cast<double>(x.size());
      }
    }
    mean = m;
    inv_var.resize(k);
    log_norm.resize(k);
    for (size_t j = 0; j < k; ++j) {
      inv_var[j] = 1 / var[j];
      log_norm[j] = std::log(std::max(w[j], 1e-12)) - 0.5 * std::log(2 * std::numbers::pi * var[j]);
    }
    return Status::OK();
  }
  double LogLikelihood(double v) const {
    double best = -std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < mean.size(); ++j)
      best = std::max(best, log_norm[j] - 0.5 * (v - mean[j]) * (v - mean[j]) * inv_var[j]);
    double sum = 0;
    for (size_t j = 0; j < mean.size(); ++j)
      sum += std::exp(log_norm[j] - 0.5 * (v - mean[j]) * (v - mean[j]) * inv_var[j] - best);
    return best + std::log(sum);
  }
};

edit::Rgb ToRgb(const cv::Vec3b& bgr) { return {bgr[2] / 255.0, bgr[1] / 255.0, bgr[0] / 255.0}; }
bool ValidZ(float z) { return z > 0 && std::isfinite(z); }

}  // namespace

struct SegmentationModel::Impl {
  edit::ColorModel object_colour, rest_colour;
  Gmm1 object_depth, rest_depth;
  bool depth = false;
  double lambda_z = 0;
};

Status SegmentationOptions::Validate() const {
  if (components < 1 || components > 32)
    return Status::InvalidArgument("segmentation: components must be 1..32");
  if (!(lambda_z >= 0 && lambda_z <= 1))
    return Status::InvalidArgument("segmentation: lambda_z must be in [0, 1]");
  for (double v : {lambda_d, lambda_i, lambda_t})
    if (!(v >= 0) || !std::isfinite(v))
      return Status::InvalidArgument("segmentation: the energy weights must be finite and >= 0");
  return Status::OK();
}

Result<SegmentationModel> SegmentationModel::Fit(const cv::Mat& colour, const cv::Mat& depth,
                                                 const cv::Mat& strokes,
                                                 const SegmentationOptions& o) {
  HVDB_RETURN_IF_ERROR(o.Validate());
  if (colour.type() != CV_8UC3 || strokes.type() != CV_8U || strokes.size() != colour.size())
    return Status::InvalidArgument("segmentation: colour must be CV_8UC3 and strokes CV_8U of its size");
  if (!depth.empty() && (depth.type() != CV_32F || depth.size() != colour.size()))
    return Status::InvalidArgument("segmentation: depth must be CV_32F of the colour's size");
  std::vector<edit::Rgb> oc, rc;
  std::vector<double> oz, rz;
  for (int y = 0; y < colour.rows; ++y)
    for (int x = 0; x < colour.cols; ++x) {
      const uint8_t s = strokes.at<uint8_t>(y, x);
      if (s != kStrokeObject && s != kStrokeRest) continue;
      const float z = depth.empty() ? 0.f : depth.at<float>(y, x);
      (s == kStrokeObject ? oc : rc).push_back(ToRgb(colour.at<cv::Vec3b>(y, x)));
      if (ValidZ(z)) (s == kStrokeObject ? oz : rz).push_back(z);
    }
  if (oc.empty() || rc.empty())
    return Status::InvalidArgument("segmentation: needs strokes on the object and on the rest");
  auto impl = std::make_shared<Impl>();
  HVDB_RETURN_IF_ERROR(impl->object_colour.Train(oc, o.components));
  HVDB_RETURN_IF_ERROR(impl->rest_colour.Train(rc, o.components));
  // The depth term only where both sides have depth under their strokes.
  impl->depth = o.lambda_z > 0 && !oz.empty() && !rz.empty();
  if (impl->depth) {
    HVDB_RETURN_IF_ERROR(impl->object_depth.Train(oz, o.components));
    HVDB_RETURN_IF_ERROR(impl->rest_depth.Train(rz, o.components));
  }
  impl->lambda_z = o.lambda_z;
  SegmentationModel m;
  m.impl_ = std::move(impl);
  return m;
}

void SegmentationModel::Costs(const cv::Vec3b& bgr, float z, double* object, double* rest) const {
  const Impl& m = *impl_;
  const edit::Rgb c = ToRgb(bgr);
  double tf = -m.object_colour.LogLikelihood(c), tb = -m.rest_colour.LogLikelihood(c);
  if (m.depth && ValidZ(z)) {
    tf = (1 - m.lambda_z) * tf - m.lambda_z * m.object_depth.LogLikelihood(z);
    tb = (1 - m.lambda_z) * tb - m.lambda_z * m.rest_depth.LogLikelihood(z);
  }
  // -log of the posteriors exp(-tf) / (exp(-tf) + exp(-tb)) and the same for tb, bounded.
  const double lo = std::min(tf, tb);
  const double lse = -lo + std::log(std::exp(lo - tf) + std::exp(lo - tb));
  *object = std::min(30.0, tf + lse);
  *rest = std::min(30.0, tb + lse);
}

Result<std::vector<cv::Mat>> SegmentFrames(const SegmentationModel& model,
                                           const std::vector<cv::Mat>& colours,
                                           const std::vector<cv::Mat>& depths,
                                           const std::vector<cv::Mat>& strokes,
                                           const SegmentationOptions& o) {
  HVDB_RETURN_IF_ERROR(o.Validate());
  if (colours.empty()) return Status::InvalidArgument("segmentation: no frames");
  if ((!depths.empty() && depths.size() != colours.size()) ||
      (!strokes.empty() && strokes.size() != colours.size()))
    return Status::InvalidArgument("segmentation: depths and strokes must be one per frame, or none");
  const cv::Size size = colours[0].size();
  for (size_t f = 0; f < colours.size(); ++f) {
    if (colours[f].type() != CV_8UC3 || colours[f].size() != size)
      return Status::InvalidArgument("segmentation: every frame must be CV_8UC3 of one size");
    if (!depths.empty() && !depths[f].empty() && (depths[f].type() != CV_32F || depths[f].size() != size))
      return Status::InvalidArgument("segmentation: a depth map is not CV_32F of the frames' size");
    if (!strokes.empty() && !strokes[f].empty() && (strokes[f].type() != CV_8U || strokes[f].size() != size))
      return Status::InvalidArgument("segmentation: a stroke image is not CV_8U of the frames' size");
  }
  const uint32_t W = static_cast<uint32_t>(size.width), H = static_cast<uint32_t>(size.height);
  const uint32_t F = static_cast<uint32_t>(colours.size());
  const size_t plane = size_t{W} * H, n = plane * F;
  // Arcs (up to 6 per node) are indexed by 32 bits.
  if (6 * n >= (size_t{1} << 32)) return Status::InvalidArgument("segmentation: too many pixels for one cut");
  auto colour_at = [&](size_t v) {
    const size_t f = v / plane, p = v % plane;
    return ToRgb(colours[f].at<cv::Vec3b>(static_cast<int>(p / W), static_cast<int>(p % W)));
  };
  auto d2 = [](const edit::Rgb& a, const edit::Rgb& b) {
    return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]);
  };
  // Neighbours of node v: left, right, up, down within its frame; itself a frame before, after.
  auto neighbours = [&](size_t v, uint32_t out[6]) {
    const size_t p = v % plane, f = v / plane;
    const uint32_t x = static_cast<uint32_t>(p % W), y = static_cast<uint32_t>(p / W);
    int k = 0;
    if (x > 0) out[k++] = static_cast<uint32_t>(v - 1);
    if (x + 1 < W) out[k++] = static_cast<uint32_t>(v + 1);
    if (y > 0) out[k++] = static_cast<uint32_t>(v - W);
    if (y + 1 < H) out[k++] = static_cast<uint32_t>(v + W);
    if (f > 0) out[k++] = static_cast<uint32_t>(v - plane);
    if (f + 1 < F) out[k++] = static_cast<uint32_t>(v + plane);
    return k;
  };
  double sum = 0;
  size_t links = 0;
  for (size_t v = 0; v < n; ++v) {
    const size_t p = v % plane;
    if (p % W + 1 < W) sum += d2(colour_at(v), colour_at(v + 1)), ++links;
    if (p / W + 1 < H) sum += d2(colour_at(v), colour_at(v + W)), ++links;
  }
  const double beta = sum > 0 ? static_cast<double>(links) / (2 * sum) : 0;
  std::vector<uint32_t> start(n + 1, 0), head, twin;
  std::vector<float> cap;
  head.reserve(n * 6);
  cap.reserve(n * 6);
  uint32_t nb[6];
  for (size_t v = 0; v < n; ++v) {
    const int k = neighbours(v, nb);
    const edit::Rgb cv_ = colour_at(v);
    for (int j = 0; j < k; ++j) {
      const bool temporal = nb[j] / plane != v / plane;
      const double s = std::exp(-beta * d2(cv_, colour_at(nb[j])));
      head.push_back(nb[j]);
      cap.push_back(static_cast<float>((temporal ? o.lambda_t : o.lambda_i) * s));
    }
    start[v + 1] = static_cast<uint32_t>(head.size());
  }
  twin.resize(head.size());
  for (size_t v = 0; v < n; ++v)
    for (uint32_t a = start[v]; a < start[v + 1]; ++a) {
      const uint32_t u = head[a];
      for (uint32_t b = start[u]; b < start[u + 1]; ++b)
        if (head[b] == v) twin[a] = b;
    }
  edit::MaxFlow flow(std::move(start), std::move(head), std::move(twin), std::move(cap));
  constexpr float kHard = 1e9f;  // a stroke: its label cannot be cut away
  for (size_t v = 0; v < n; ++v) {
    const size_t f = v / plane, p = v % plane;
    const int y = static_cast<int>(p / W), x = static_cast<int>(p % W);
    const uint8_t s = strokes.empty() || strokes[f].empty() ? 0 : strokes[f].at<uint8_t>(y, x);
    if (s == kStrokeObject) {
      flow.SetTerminals(static_cast<uint32_t>(v), kHard, 0);
    } else if (s == kStrokeRest) {
      flow.SetTerminals(static_cast<uint32_t>(v), 0, kHard);
    } else {
      const float z = depths.empty() || depths[f].empty() ? 0.f : depths[f].at<float>(y, x);
      double object, rest;
      model.Costs(colours[f].at<cv::Vec3b>(y, x), z, &object, &rest);
      // Source = object: cutting a node from the source labels it rest, and costs its
      // rest energy; from the sink, its object energy.
      flow.SetTerminals(static_cast<uint32_t>(v), static_cast<float>(o.lambda_d * rest),
                        static_cast<float>(o.lambda_d * object));
    }
  }
  flow.Solve();
  std::vector<cv::Mat> labels(F);
  for (uint32_t f = 0; f < F; ++f) {
    labels[f] = cv::Mat(size, CV_8U);
    for (uint32_t y = 0; y < H; ++y)
      for (uint32_t x = 0; x < W; ++x)
        labels[f].at<uint8_t>(static_cast<int>(y), static_cast<int>(x)) =
            flow.SourceSide(static_cast<uint32_t>(f * plane + size_t{y} * W + x)) ? 1 : 0;
  }
  return labels;
}

Status MattingOptions::Validate() const {
  if (band < 1 || band > 64) return Status::InvalidArgument("matting: band must be 1..64 pixels");
  if (neighbours < 4 || neighbours > 1024) return Status::InvalidArgument("matting: neighbours must be 4..1024");
  if (radius < 2 || radius > 128) return Status::InvalidArgument("matting: radius must be 2..128 pixels");
  if (iterations < 1 || iterations > 100) return Status::InvalidArgument("matting: iterations must be 1..100");
  if (!(sigma_c > 0) || !std::isfinite(sigma_c)) return Status::InvalidArgument("matting: sigma_c must be > 0");
  return Status::OK();
}

Result<cv::Mat> BayesianMatte(const cv::Mat& colour, const cv::Mat& labels, const MattingOptions& o,
                              cv::Mat* foreground) {
  HVDB_RETURN_IF_ERROR(o.Validate());
  if (colour.type() != CV_8UC3 || labels.type() != CV_8U || labels.size() != colour.size())
    return Status::InvalidArgument("matting: colour must be CV_8UC3 and labels CV_8U of its size");
  const int W = colour.cols, H = colour.rows;
  // The graymap (6.4.2): object and rest eroded by the band; the rest unknown.
  cv::Mat object = labels != 0, rest = labels == 0, sure_object, sure_rest;
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_ELLIPSE, {2 * o.band + 1, 2 * o.band + 1});
  cv::erode(object, sure_object, kernel);
  cv::erode(rest, sure_rest, kernel);
  cv::Mat alpha(colour.size(), CV_32F);
  std::vector<cv::Vec3d> fg(size_t(W) * H), bg(size_t(W) * H);
  std::vector<uint8_t> known(size_t(W) * H, 0);
  std::vector<int> unknown;
  for (int y = 0; y < H; ++y)
    for (int x = 0; x < W; ++x) {
      const size_t i = size_t(y) * W + x;
      const cv::Vec3b c = colour.at<cv::Vec3b>(y, x);
      const cv::Vec3d cd(c[0] / 255.0, c[1] / 255.0, c[2] / 255.0);
      if (sure_object.at<uint8_t>(y, x)) {
        alpha.at<float>(y, x) = 1, fg[i] = cd, known[i] = 1;
      } else if (sure_rest.at<uint8_t>(y, x)) {
        alpha.at<float>(y, x) = 0, bg[i] = cd, known[i] = 1;
      } else {
        alpha.at<float>(y, x) = labels.at<uint8_t>(y, x) ? 1.f : 0.f;
        unknown.push_back(static_cast<int>(i));
      }
    }
  // Onion peel: the unknown pixels nearest the known regions first.
  cv::Mat dist;
  cv::distanceTransform((sure_object == 0) & (sure_rest == 0), dist, cv::DIST_L2, 3);
  std::stable_sort(unknown.begin(), unknown.end(), [&](int a, int b) {
    return dist.at<float>(a / W, a % W) < dist.at<float>(b / W, b % W);
  });
  const double s2 = o.sigma_c * o.sigma_c, g = o.radius / 2.0;
  struct Sample {
    double d2;
    size_t i;
  };
  std::vector<Sample> cand;
  for (int i : unknown) {
    const int y = i / W, x = i % W;
    const cv::Vec3b c8 = colour.at<cv::Vec3b>(y, x);
    const cv::Vec3d C(c8[0] / 255.0, c8[1] / 255.0, c8[2] / 255.0);
    // A weighted Gaussian of each side's colours from the nearest known or solved pixels.
    auto gather = [&](bool object_side, cv::Vec3d* mean, cv::Matx33d* cov) {
      cand.clear();
      for (int yy = std::max(0, y - o.radius); yy <= std::min(H - 1, y + o.radius); ++yy)
        for (int xx = std::max(0, x - o.radius); xx <= std::min(W - 1, x + o.radius); ++xx) {
          const size_t j = size_t(yy) * W + xx;
          if (!known[j]) continue;
          const float a = alpha.at<float>(yy, xx);
          if (object_side ? !(a > 0) : !(a < 1)) continue;
          cand.push_back({double((yy - y) * (yy - y) + (xx - x) * (xx - x)), j});
        }
      if (cand.empty()) return false;
      const size_t k = std::min(cand.size(), static_cast<size_t>(o.neighbours));
      std::partial_sort(cand.begin(), cand.begin() + static_cast<long>(k), cand.end(),
                        [](const Sample& a, const Sample& b) { return a.d2 < b.d2 || (a.d2 == b.d2 && a.i < b.i); });
      double wsum = 0;
      cv::Vec3d m(0, 0, 0);
      std::vector<double> w(k);
      for (size_t t = 0; t < k; ++t) {
        const size_t j = cand[t].i;
        const double a = alpha.at<float>(static_cast<int>(j / W), static_cast<int>(j % W));
        const double side = object_side ? a * a : (1 - a) * (1 - a);
        w[t] = side * std::exp(-cand[t].d2 / (2 * g * g));
        m += w[t] * (object_side ? fg[j] : bg[j]);
        wsum += w[t];
      }
      if (!(wsum > 0)) return false;
      m /= wsum;
      cv::Matx33d S = cv::Matx33d::eye() * 1e-4;  // keeps a flat colour's Gaussian invertible
      for (size_t t = 0; t < k; ++t) {
        const cv::Vec3d d = (object_side ? fg[cand[t].i] : bg[cand[t].i]) - m;
        S += (w[t] / wsum) * (d * d.t());
      }
      *mean = m;
      *cov = S;
      return true;
    };
    cv::Vec3d mf, mb;
    cv::Matx33d cf, cb;
    if (!gather(true, &mf, &cf) || !gather(false, &mb, &cb)) continue;  // keeps the label
    const cv::Matx33d icf = cf.inv(), icb = cb.inv();
    double a = 0.5;
    cv::Vec3d Fc = mf, Bc = mb;
    for (int it = 0; it < o.iterations; ++it) {
      // (F, B) given alpha: the 6x6 system of Chuang et al. (eq. 9 there).
      cv::Matx66d A = cv::Matx66d::zeros();
      cv::Vec6d b;
      const cv::Vec3d bf = icf * mf + C * (a / s2), bb = icb * mb + C * ((1 - a) / s2);
      for (int r = 0; r < 3; ++r) {
        for (int q = 0; q < 3; ++q) {
          A(r, q) = icf(r, q) + (r == q ? a * a / s2 : 0);
          A(r + 3, q + 3) = icb(r, q) + (r == q ? (1 - a) * (1 - a) / s2 : 0);
          A(r, q + 3) = A(r + 3, q) = r == q ? a * (1 - a) / s2 : 0;
        }
        b[r] = bf[r];
        b[r + 3] = bb[r];
      }
      cv::Mat fb;
      if (!cv::solve(cv::Mat(A), cv::Mat(b), fb, cv::DECOMP_CHOLESKY)) break;
      for (int r = 0; r < 3; ++r) {
        Fc[r] = std::clamp(fb.at<double>(r), 0.0, 1.0);
        Bc[r] = std::clamp(fb.at<double>(r + 3), 0.0, 1.0);
      }
      // alpha given (F, B): the projection of C onto the line from B to F.
      const cv::Vec3d d = Fc - Bc;
      const double dd = d.dot(d);
      if (!(dd > 1e-9)) break;
      a = std::clamp((C - Bc).dot(d) / dd, 0.0, 1.0);
    }
    alpha.at<float>(y, x) = static_cast<float>(a);
    fg[static_cast<size_t>(i)] = Fc;
    bg[static_cast<size_t>(i)] = Bc;
    known[static_cast<size_t>(i)] = 1;
  }
  if (foreground != nullptr) {
    *foreground = colour.clone();
    for (int i : unknown) {
      const cv::Vec3d& f = fg[static_cast<size_t>(i)];
      if (!known[static_cast<size_t>(i)]) continue;
      foreground->at<cv::Vec3b>(i / W, i % W) =
          cv::Vec3b(cv::saturate_cast<uint8_t>(f[0] * 255), cv::saturate_cast<uint8_t>(f[1] * 255),
                    cv::saturate_cast<uint8_t>(f[2] * 255));
    }
  }
  return alpha;
}

}  // namespace hvdb::ingest
