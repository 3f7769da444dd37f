#include "ingest/billboard.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <thread>

#include <opencv2/imgcodecs.hpp>

#include "ingest/points.h"

namespace hvdb::ingest {
namespace {

// A displacement that is not there, inside the filter: finite (0 * it stays 0) and far from
// every real displacement, so the range kernel never counts it.
constexpr float kNone = 1e30f;

int Threads(int wanted) {
  const int hw = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return wanted > 0 ? wanted : hw;
}

// Runs fn(i) for i in [0, n) on `threads` threads, taking indices in turn.
template <typename Fn>
void ParallelFor(size_t n, int threads, const Fn& fn) {
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t i; (i = next.fetch_add(1)) < n;) fn(i);
  };
  const int t = std::clamp<int>(threads, 1, static_cast<int>(std::max<size_t>(1, n)));
  std::vector<std::thread> pool;
  for (int k = 1; k < t; ++k) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
}

// The cubic B-spline (support |t| < 2).
double BSpline(double t) {
  t = std::abs(t);
  if (t < 1) return (4 - 6 * t * t + 3 * t * t * t) / 6;
  if (t < 2) return (2 - t) * (2 - t) * (2 - t) / 6;
  return 0;
}

// Taps B(k / h) for k in [-r, r], with h = (r + 1) / 2 so that every tap is non-zero.
std::vector<float> Taps(int r) {
  std::vector<float> taps(static_cast<size_t>(2 * r + 1));
  const double h = (r + 1) / 2.0;
  for (int k = -r; k <= r; ++k) taps[static_cast<size_t>(k + r)] = static_cast<float>(BSpline(k / h));
  return taps;
}

bool ValidDepth(float z) { return z > 0 && std::isfinite(z); }

}  // namespace

Result<cv::Vec3d> FitBillboardPlane(const cv::Mat& depth, const cv::Mat& alpha,
                                    const cv::Matx33d& K, double scale) {
  if (depth.empty() || depth.type() != CV_32F)
    return Status::InvalidArgument("billboard plane: depth must be CV_32F");
  if (!alpha.empty() && (alpha.type() != CV_32F || alpha.size() != depth.size()))
    return Status::InvalidArgument("billboard plane: alpha must be CV_32F of the depth's size");
  if (!(scale > 0)) return Status::InvalidArgument("billboard plane: scale must be > 0");
  struct Sample {
    double x, y, z, w, ray;  // ray: |K^-1 (x, y, 1)|, the world length of a unit of depth
  };
  std::vector<Sample> s;
  const cv::Matx33d Ki = K.inv();
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float z = depth.at<float>(y, x);
      const double w = alpha.empty() ? 1.0 : alpha.at<float>(y, x);
      if (!ValidDepth(z) || !(w > 0)) continue;
      const cv::Vec3d r = Ki * cv::Vec3d(x, y, 1);
      s.push_back({double(x), double(y), double(z), w, cv::norm(r)});
    }
  }
  if (s.size() < 3) return Status::InvalidArgument("billboard plane: fewer than 3 depth samples");
  // Eq. 6.4: the least-squares plane in disparity space, the start. Normal equations in
  // coordinates centred on the samples' mean (well conditioned at any image size).
  double mx = 0, my = 0, sw = 0;
  for (const Sample& q : s) mx += q.w * q.x, my += q.w * q.y, sw += q.w;
  mx /= sw, my /= sw;
  auto solve3 = [](const cv::Matx33d& A, const cv::Vec3d& b, cv::Vec3d* out) {
    cv::Mat x;
    if (!cv::solve(cv::Mat(A), cv::Mat(b), x, cv::DECOMP_SVD)) return false;
    *out = cv::Vec3d(x.at<double>(0), x.at<double>(1), x.at<double>(2));
    const double tol = 1e-12 * std::max(1.0, cv::norm(A, cv::NORM_INF));
    cv::Mat w;
    cv::SVD::compute(cv::Mat(A), w);
    return w.at<double>(2) > tol;
  };
  cv::Matx33d A = cv::Matx33d::zeros();
  cv::Vec3d b(0, 0, 0);
  for (const Sample& q : s) {
    const cv::Vec3d g(q.x - mx, q.y - my, 1);
    A += q.w * (g * g.t());
    b += q.w * (scale / q.z) * g;
  }
  cv::Vec3d c;  // plane in centred coordinates: c0 (x - mx) + c1 (y - my) + c2
  if (!solve3(A, b, &c)) return Status::InvalidArgument("billboard plane: the samples lie on a line");
  auto positive = [&](const cv::Vec3d& p) {
    for (const Sample& q : s)
      if (!(p[0] * (q.x - mx) + p[1] * (q.y - my) + p[2] > 0)) return false;
    return true;
  };
  if (!positive(c)) c = cv::Vec3d(0, 0, b[2] / A(2, 2));  // a fronto-parallel start
  // Eq. 6.5 by Levenberg-Marquardt: residual e = |ray| (s / Pi - z), the distance along the
  // viewing ray between the plane and the sample, in metres.
  auto cost = [&](const cv::Vec3d& p) {
    double e2 = 0;
    for (const Sample& q : s) {
      const double pi = p[0] * (q.x - mx) + p[1] * (q.y - my) + p[2];
      const double e = q.ray * (scale / pi - q.z);
      e2 += q.w * e * e;
    }
    return e2;
  };
  double lambda = 1e-3, e_now = cost(c);
  for (int it = 0; it < 20; ++it) {
    cv::Matx33d JtJ = cv::Matx33d::zeros();
    cv::Vec3d Jte(0, 0, 0);
    for (const Sample& q : s) {
      const cv::Vec3d g(q.x - mx, q.y - my, 1);
      const double pi = c.dot(g);
      const double e = q.ray * (scale / pi - q.z);
      const cv::Vec3d J = -q.ray * scale / (pi * pi) * g;
      JtJ += q.w * (J * J.t());
      Jte += q.w * e * J;
    }
    bool improved = false;
    for (int tries = 0; tries < 10 && !improved; ++tries) {
      cv::Matx33d M = JtJ;
      for (int k = 0; k < 3; ++k) M(k, k) *= 1 + lambda;
      cv::Vec3d step;
      if (!solve3(M, -Jte, &step)) break;
      const cv::Vec3d next = c + step;
      const double e_next = positive(next) ? cost(next) : std::numeric_limits<double>::infinity();
      if (e_next < e_now) {
        const double rel = cv::norm(step) / std::max(1e-300, cv::norm(c));
        c = next;
        e_now = e_next;
        lambda = std::max(1e-9, lambda / 10);
        improved = true;
        if (rel < 1e-6) it = 20;
      } else {
        lambda *= 10;
      }
    }
    if (!improved) break;
  }
  // Back to pixel coordinates: Pi = c0 x + c1 y + (c2 - c0 mx - c1 my).
  return cv::Vec3d(c[0], c[1], c[2] - c[0] * mx - c[1] * my);
}

Result<Billboard> MakeBillboard(const CameraModel& camera, const cv::Mat& depth,
                                const cv::Mat& alpha, const cv::Mat& colour, double scale) {
  if (depth.type() != CV_32F || depth.size() != camera.size)
    return Status::InvalidArgument("billboard: depth must be CV_32F of the camera's size");
  if (!colour.empty() && (colour.type() != CV_8UC3 || colour.size() != depth.size()))
    return Status::InvalidArgument("billboard: colour must be CV_8UC3 of the depth's size");
  Billboard bb;
  bb.camera = camera;
  bb.scale = scale;
  bb.colour = colour;
  if (alpha.empty()) {
    bb.alpha = cv::Mat(depth.size(), CV_32F);
    for (int y = 0; y < depth.rows; ++y)
      for (int x = 0; x < depth.cols; ++x)
        bb.alpha.at<float>(y, x) = ValidDepth(depth.at<float>(y, x)) ? 1.f : 0.f;
  } else {
    bb.alpha = alpha.clone();
  }
  HVDB_ASSIGN_OR_RETURN(bb.plane, FitBillboardPlane(depth, bb.alpha, camera.K, scale));
  bb.displacement = cv::Mat(depth.size(), CV_32F);
  for (int y = 0; y < depth.rows; ++y) {
    for (int x = 0; x < depth.cols; ++x) {
      const float z = depth.at<float>(y, x);
      bb.displacement.at<float>(y, x) =
          ValidDepth(z) ? static_cast<float>(scale / z - bb.Plane(x, y))
                        : std::numeric_limits<float>::quiet_NaN();
    }
  }
  return bb;
}

cv::Mat BillboardDisparity(const Billboard& bb, const cv::Mat& displacement, float min_alpha) {
  const cv::Mat& D = displacement.empty() ? bb.displacement : displacement;
  cv::Mat d(D.size(), CV_32F);
  for (int y = 0; y < D.rows; ++y) {
    for (int x = 0; x < D.cols; ++x) {
      const float dv = static_cast<float>(D.at<float>(y, x) + bb.Plane(x, y));
      const bool ok = std::isfinite(dv) && dv > 0 && bb.alpha.at<float>(y, x) >= min_alpha;
      d.at<float>(y, x) = ok ? dv : std::numeric_limits<float>::infinity();
    }
  }
  return d;
}

cv::Mat BillboardDepth(const Billboard& bb, const cv::Mat& displacement, float min_alpha) {
  cv::Mat d = BillboardDisparity(bb, displacement, min_alpha);
  cv::Mat z(d.size(), CV_32F);
  for (int y = 0; y < d.rows; ++y)
    for (int x = 0; x < d.cols; ++x) {
      const float dv = d.at<float>(y, x);
      z.at<float>(y, x) = std::isfinite(dv) ? static_cast<float>(bb.scale / dv) : 0.f;
    }
  return z;
}

cv::Mat BillboardDepthSigma(const Billboard& bb, const cv::Mat& displacement, double sigma_c) {
  const cv::Mat d = BillboardDisparity(bb, displacement);
  // Central differences along x; one-sided at a hole's edge, 0 where no neighbour has one.
  cv::Mat dx(d.size(), CV_32F, cv::Scalar(0));
  for (int y = 0; y < d.rows; ++y) {
    const float* r = d.ptr<float>(y);
    float* o = dx.ptr<float>(y);
    for (int x = 0; x < d.cols; ++x) {
      const bool l = x > 0 && std::isfinite(r[x - 1]), c = std::isfinite(r[x]),
                 g = x + 1 < d.cols && std::isfinite(r[x + 1]);
      if (!c) continue;
      o[x] = l && g ? (r[x + 1] - r[x - 1]) / 2 : l ? r[x] - r[x - 1] : g ? r[x + 1] - r[x] : 0.f;
    }
  }
  const double fx = bb.camera.K(0, 0);
  return DepthSigmaFromDisparity(d, dx, bb.scale / fx, fx, sigma_c);
}

Result<PhotoBillboard> EncodeBillboard(const Billboard& bb, const cv::Mat& displacement_in) {
  const cv::Mat& displacement = displacement_in.empty() ? bb.displacement : displacement_in;
  if (displacement.type() != CV_32F || bb.alpha.type() != CV_32F || bb.alpha.size() != displacement.size())
    return Status::InvalidArgument("billboard: displacement and alpha must be CV_32F of one size");
  cv::Mat d16(displacement.size(), CV_16U), a8(displacement.size(), CV_8U);
  for (int y = 0; y < d16.rows; ++y)
    for (int x = 0; x < d16.cols; ++x) {
      const float d = displacement.at<float>(y, x), a = bb.alpha.at<float>(y, x);
      // The format holds [-128, 128) pixels to 1/256; a displacement beyond (a sample far off
      // the plane: an outlier) is stored as no sample rather than clamped to a wrong depth.
      const double code = (static_cast<double>(d) + 128.0) * 256.0;
      d16.at<uint16_t>(y, x) = std::isfinite(d) && a > 0 && code >= 0.5 && code < 65535.5
                                   ? static_cast<uint16_t>(std::lround(code))
                                   : 0;
      a8.at<uint8_t>(y, x) = static_cast<uint8_t>(std::lround(std::clamp(a, 0.f, 1.f) * 255));
    }
  PhotoBillboard out;
  out.scale = bb.scale;
  out.plane = {bb.plane[0], bb.plane[1], bb.plane[2]};
  std::vector<uint8_t> enc;
  if (!cv::imencode(".png", d16, enc)) return Status::Internal("billboard: cannot encode its displacement map");
  out.displacement.assign(enc.begin(), enc.end());
  if (!cv::imencode(".png", a8, enc)) return Status::Internal("billboard: cannot encode its alpha map");
  out.alpha.assign(enc.begin(), enc.end());
  return out;
}

Status BillboardFilterOptions::Validate() const {
  if (radius < 1 || radius > 64)
    return Status::InvalidArgument("billboard filter: radius " + std::to_string(radius) +
                                   " is outside 1..64 pixels");
  if (temporal_radius < 0 || temporal_radius > 16)
    return Status::InvalidArgument("billboard filter: temporal radius " +
                                   std::to_string(temporal_radius) + " is outside 0..16 frames");
  if (!(delta_d > 0) || !std::isfinite(delta_d))
    return Status::InvalidArgument("billboard filter: delta_d must be > 0 disparity pixels");
  if (iterations < 1 || iterations > 10)
    return Status::InvalidArgument("billboard filter: iterations must be 1..10");
  return Status::OK();
}

namespace {

// One layer of samples on the filtered view's pixel grid: the view itself at some frame, or
// another view reprojected. d: displacement relative to the filtered view's plane (kNone
// where there is none), a: alpha (0 where there is none), w: the layer's weight.
struct Layer {
  cv::Mat d, a;
  float w = 1;
};

Layer GridLayer(const Billboard& b, const Billboard& target, float w) {
  Layer l{cv::Mat(b.displacement.size(), CV_32F), cv::Mat(b.displacement.size(), CV_32F), w};
  const bool rebase = &b != &target;
  for (int y = 0; y < l.d.rows; ++y) {
    const float* d = b.displacement.ptr<float>(y);
    const float* a = b.alpha.ptr<float>(y);
    float* ld = l.d.ptr<float>(y);
    float* la = l.a.ptr<float>(y);
    for (int x = 0; x < l.d.cols; ++x) {
      const bool ok = std::isfinite(d[x]) && a[x] > 0;
      // Frames around are re-based on this frame's plane (d - Pi_centre): a billboard of a
      // whole view is refitted every frame, and a moving plane would shift what is static.
      ld[x] = !ok ? kNone
                  : rebase ? static_cast<float>(d[x] + b.Plane(x, y) - target.Plane(x, y)) : d[x];
      la[x] = ok ? a[x] : 0.f;
    }
  }
  return l;
}

// Another view's samples (displacements `du` of billboard bu) reprojected into `bv` by their
// depth, each to its nearest pixel (fig. 6.5's projection; the B-spline is then applied on the
// grid, off by at most half a pixel of a kernel 11 pixels wide). Where several land on one
// pixel the front-most wins, with those within delta_d of it (the rest are hidden there).
Layer WarpedLayer(const Billboard& bu, const cv::Mat& du, const Billboard& bv, float delta_d) {
  const int W = bv.camera.size.width, H = bv.camera.size.height;
  struct Sample {
    int pixel;
    float d, a;
  };
  std::vector<Sample> samples;
  const cv::Matx33d Ki = bu.camera.K.inv(), Rt = bu.camera.R.t();
  const cv::Vec3d Ou = bu.camera.Centre();
  const cv::Matx33d Av = bv.camera.K * bv.camera.R;
  const cv::Vec3d av = bv.camera.K * bv.camera.T;
  cv::Mat front(H, W, CV_32F, cv::Scalar(-std::numeric_limits<float>::infinity()));
  for (int y = 0; y < du.rows; ++y) {
    const float* D = du.ptr<float>(y);
    const float* A = bu.alpha.ptr<float>(y);
    for (int x = 0; x < du.cols; ++x) {
      if (!std::isfinite(D[x]) || !(A[x] > 0)) continue;
      const double disp = D[x] + bu.Plane(x, y);
      if (!(disp > 0)) continue;
      const cv::Vec3d X = Ou + Rt * (Ki * cv::Vec3d(x, y, 1) * (bu.scale / disp));
      const cv::Vec3d p = Av * X + av;
      if (!(p[2] > 0)) continue;
      const double xv = p[0] / p[2], yv = p[1] / p[2];
      const int ix = static_cast<int>(std::lround(xv)), iy = static_cast<int>(std::lround(yv));
      if (ix < 0 || iy < 0 || ix >= W || iy >= H) continue;
      const float d = static_cast<float>(bv.scale / p[2] - bv.Plane(xv, yv));
      samples.push_back({iy * W + ix, d, A[x]});
      float& f = front.at<float>(iy, ix);
      f = std::max(f, d);
    }
  }
  cv::Mat sd(H, W, CV_32F, cv::Scalar(0)), sa(H, W, CV_32F, cv::Scalar(0));
  for (const Sample& q : samples) {
    if (q.d < reinterpret_cast<const float*>(front.data)[q.pixel] - delta_d) continue;
    reinterpret_cast<float*>(sd.data)[q.pixel] += q.a * q.d;
    reinterpret_cast<float*>(sa.data)[q.pixel] += q.a;
  }
  Layer l{cv::Mat(H, W, CV_32F), sa, 1.f};
  for (int k = 0; k < W * H; ++k) {
    const float a = reinterpret_cast<const float*>(sa.data)[k];
    reinterpret_cast<float*>(l.d.data)[k] = a > 0 ? reinterpret_cast<const float*>(sd.data)[k] / a : kNone;
  }
  return l;
}

}  // namespace

Result<std::vector<cv::Mat>> FilterBillboards(
    const std::vector<std::vector<const Billboard*>>& window, size_t centre,
    const BillboardFilterOptions& o) {
  HVDB_RETURN_IF_ERROR(o.Validate());
  if (centre >= window.size()) return Status::InvalidArgument("billboard filter: no centre frame");
  const std::vector<const Billboard*>& views = window[centre];
  for (const auto& frame : window) {
    if (frame.size() != views.size())
      return Status::InvalidArgument("billboard filter: every frame needs the same views");
    for (size_t v = 0; v < frame.size(); ++v) {
      const Billboard* b = frame[v];
      if (b == nullptr || b->displacement.empty()) continue;
      if (b->displacement.type() != CV_32F || b->alpha.type() != CV_32F ||
          b->alpha.size() != b->displacement.size() || b->displacement.size() != b->camera.size ||
          !(b->scale > 0))
        return Status::InvalidArgument("billboard filter: a malformed billboard");
      if (views[v] != nullptr && !views[v]->displacement.empty() &&
          b->displacement.size() != views[v]->displacement.size())
        return Status::InvalidArgument("billboard filter: a view changes size over time");
    }
  }
  const int r = o.radius, threads = Threads(o.threads);
  const std::vector<float> bs = Taps(r);
  const std::vector<float> bt = Taps(o.temporal_radius);
  const float dd = static_cast<float>(o.delta_d);
  const int t_lo = std::max(0, static_cast<int>(centre) - o.temporal_radius);
  const int t_hi = std::min(static_cast<int>(window.size()) - 1,
                            static_cast<int>(centre) + o.temporal_radius);

  std::vector<cv::Mat> current(views.size()), out(views.size());
  for (size_t v = 0; v < views.size(); ++v)
    if (views[v] != nullptr && !views[v]->displacement.empty()) current[v] = views[v]->displacement;

  for (int pass = 0; pass < o.iterations; ++pass) {
    for (size_t v = 0; v < views.size(); ++v) {
      if (current[v].empty()) continue;
      const Billboard& bv = *views[v];
      const int W = current[v].cols, H = current[v].rows;
      // The layers: this view over the frames around (6.2.1), the other views of this frame
      // reprojected (6.2.2, from the last pass's displacements).
      std::vector<Layer> layers;
      for (int t = t_lo; t <= t_hi; ++t) {
        const Billboard* b = window[static_cast<size_t>(t)][v];
        if (b == nullptr || b->displacement.empty()) continue;
        const float w = bt[static_cast<size_t>(t - static_cast<int>(centre) + o.temporal_radius)];
        if (t == static_cast<int>(centre)) {
          Billboard self = bv;
          self.displacement = current[v];
          layers.push_back(GridLayer(self, self, w));
        } else if (b->camera.K == bv.camera.K && b->camera.R == bv.camera.R && b->camera.T == bv.camera.T) {
          layers.push_back(GridLayer(*b, bv, w));
        } else {
          // The camera moved (a hand-held depth camera): that frame's samples are reprojected
          // as another view's are.
          Layer l = WarpedLayer(*b, b->displacement, bv, dd);
          l.w = w;
          layers.push_back(std::move(l));
        }
      }
      if (o.inter_view)
        for (size_t u = 0; u < views.size(); ++u)
          if (u != v && !current[u].empty()) layers.push_back(WarpedLayer(*views[u], current[u], bv, dd));
      // The centre values the range kernel compares with (kNone where there are none).
      const cv::Mat ci = GridLayer(Billboard{bv.camera, bv.scale, bv.plane, current[v], bv.alpha, {}},
                                   bv, 1).d;
      // Eq. 6.12 with the B-spline applied separably, as eq. 6.10 allows on the grid: along x
      // with the range kernel against the centre pixel of the row, then along y with it
      // against the centre pixel of the column (so a sample counts when it is within delta_d
      // of a pixel of the target's column that is within delta_d of the target: k_R(j, i)
      // becomes k_R(j, m) k_R(m, i)). (2r+1) * 2 taps per layer instead of (2r+1)^2.
      cv::Mat num(H, W, CV_32F, cv::Scalar(0)), den(H, W, CV_32F, cv::Scalar(0));
      cv::Mat n1(H + 2 * r, W, CV_32F), q1(H + 2 * r, W, CV_32F);
      for (const Layer& l : layers) {
        n1.setTo(0);
        q1.setTo(0);
        ParallelFor(static_cast<size_t>(H), threads, [&](size_t yi) {
          const int y = static_cast<int>(yi);
          const float* c = ci.ptr<float>(y);
          const float* D = l.d.ptr<float>(y);
          const float* A = l.a.ptr<float>(y);
          float* pn = n1.ptr<float>(y + r);
          float* pq = q1.ptr<float>(y + r);
          for (int dx = -r; dx <= r; ++dx) {
            const float w = bs[static_cast<size_t>(dx + r)];
            const int x0 = std::max(0, -dx), x1 = std::min(W, W - dx);
            for (int x = x0; x < x1; ++x) {
              const float m = std::abs(D[x + dx] - c[x]) <= dd ? w * A[x + dx] : 0.f;
              pn[x] += m * D[x + dx];
              pq[x] += m;
            }
          }
        });
        ParallelFor(static_cast<size_t>(H), threads, [&](size_t yi) {
          const int y = static_cast<int>(yi);
          const float* c = ci.ptr<float>(y);
          float* pn = num.ptr<float>(y);
          float* pq = den.ptr<float>(y);
          for (int dy = -r; dy <= r; ++dy) {
            if (y + dy < 0 || y + dy >= H) continue;
            const float w = l.w * bs[static_cast<size_t>(dy + r)];
            const float* cm = ci.ptr<float>(y + dy);
            const float* N = n1.ptr<float>(y + r + dy);
            const float* Q = q1.ptr<float>(y + r + dy);
            for (int x = 0; x < W; ++x) {
              const float m = std::abs(cm[x] - c[x]) <= dd ? w : 0.f;
              pn[x] += m * N[x];
              pq[x] += m * Q[x];
            }
          }
        });
      }
      out[v] = cv::Mat(H, W, CV_32F);
      for (int y = 0; y < H; ++y) {
        const float* d0 = current[v].ptr<float>(y);
        for (int x = 0; x < W; ++x) {
          const float q = den.at<float>(y, x);
          out[v].at<float>(y, x) = std::isfinite(d0[x]) && q > 0 ? num.at<float>(y, x) / q : d0[x];
        }
      }
    }
    current = out;
  }
  // Views with no displacement map come back as NaN maps of their size (or empty).
  for (size_t v = 0; v < views.size(); ++v) {
    if (!out[v].empty() || views[v] == nullptr) continue;
    out[v] = cv::Mat(views[v]->camera.size, CV_32F,
                     cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  }
  return out;
}

}  // namespace hvdb::ingest
