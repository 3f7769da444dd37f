#include "edit/graph_cut.h"

#include "edit/maxflow.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <map>

#include <atomic>
#include <thread>

#include <nanoflann.hpp>
#include <opencv2/core.hpp>
#include <opencv2/ml.hpp>

namespace hvdb::edit {

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a) {
  return std::chrono::duration<double, std::milli>(Clock::now() - a).count();
}

struct Attr {
  float c[3];  // colour in [0, 1]
  float n[3];  // unit normal (0 if none)
  bool has_normal;
};

double ColorDiff(const Attr& a, const Attr& b) {
  double d = 0;
  for (int i = 0; i < 3; ++i) d += (a.c[i] - b.c[i]) * (a.c[i] - b.c[i]);
  return std::sqrt(d / 3.0);  // in [0, 1]
}

double NormalDiff(const Attr& a, const Attr& b) {
  if (!a.has_normal || !b.has_normal) return 0;
  double d = 0;
  for (int i = 0; i < 3; ++i) d += (a.n[i] - b.n[i]) * (a.n[i] - b.n[i]);
  return std::sqrt(d) / 2.0;  // in [0, 1]
}

// One frame's points in a kd-tree (nanoflann: header-only, and its k-nearest search fills
// caller-owned arrays, where FLANN's radius search allocated two vectors per query: that was
// a third of a million-point cut).
struct Cloud {
  std::vector<float> coords;  // x y z per point
  size_t kdtree_get_point_count() const { return coords.size() / 3; }
  float kdtree_get_pt(uint32_t i, size_t d) const { return coords[3 * i + d]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const { return false; }
};
using KdIndex = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Cloud>,
                                                    Cloud, 3, uint32_t>;
struct FrameIndex {
  std::vector<uint32_t> members;  // indices into the input
  Cloud cloud;
  std::unique_ptr<KdIndex> index;
};

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();

// fn(lo, hi) over [0, n) in one contiguous chunk per core (independent iterations only).
template <typename Fn>
void ParallelFor(size_t n, Fn&& fn) {
  const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  if (threads == 1 || n < 4096) return fn(size_t{0}, n);
  std::vector<std::thread> pool;
  const size_t chunk = (n + threads - 1) / threads;
  for (size_t t = 1; t < threads; ++t) {
    size_t lo = t * chunk, hi = std::min(n, lo + chunk);
    if (lo < hi) pool.emplace_back([&fn, lo, hi] { fn(lo, hi); });
  }
  fn(size_t{0}, std::min(n, chunk));
  for (auto& th : pool) th.join();
}

// For every point of `source`, the input indices of its up to k nearest points of `target`
// within `radius` (itself excluded), nearest first, in out[k * j ...] for source member j
// (kNone where there are fewer). On all cores: the queries are independent.
void Nearest(const FrameIndex& target, const FrameIndex& source, int k, double radius,
             std::vector<uint32_t>* out) {
  const size_t m = source.members.size();
  const size_t kk = static_cast<size_t>(k);
  out->assign(m * kk, kNone);
  const float r2 = static_cast<float>(radius * radius);
  // Within a frame each point finds itself too: one more.
  const size_t want = &target == &source ? kk + 1 : kk;
  auto work = [&](size_t lo, size_t hi) {
    std::vector<uint32_t> idx(want);
    std::vector<float> d2(want);
    for (size_t j = lo; j < hi; ++j) {
      const float* q = &source.cloud.coords[3 * j];
      nanoflann::KNNResultSet<float, uint32_t> rs(want);
      rs.init(idx.data(), d2.data());
      // The worst distance starts at the radius, not infinity: the search prunes by it from
      // the first node (half the time of a plain k-nearest search on these surfaces).
      d2[want - 1] = r2;
      target.index->findNeighbors(rs, q, nanoflann::SearchParams());
      const size_t found = rs.size();
      size_t w = 0;
      for (size_t h = 0; h < found && w < kk; ++h) {
        uint32_t b = target.members[idx[h]];
        if (b == source.members[j]) continue;
        (*out)[j * kk + w++] = b;
      }
    }
  };
  ParallelFor(m, work);
}

// A colour model: a GMM (eq. 9.3) trained by OpenCV's EM. The log-density is evaluated here
// from the trained means, covariances and weights: EM::predict2 costs ~10 us per call, which
// dominated a million-point cut.
class ColorModel {
 public:
  Status Train(const std::vector<cv::Vec3d>& samples, int components) {
    if (samples.empty()) return Status::InvalidArgument("graph cut: a colour model has no samples");
    int k = std::clamp(std::min<int>(components, static_cast<int>(samples.size()) / 4), 1, 16);
    // At most kMaxSamples, evenly strided, and at most 30 EM iterations: OpenCV's EM took
    // 0.6 s for 3 500 stroked colours (100 iterations); a thousand fit 5 Gaussians in 3D as well
    // (the real scene's precision and recall did not move) in a tenth of the time.
    constexpr size_t kMaxSamples = 1000;
    const size_t stride = (samples.size() + kMaxSamples - 1) / kMaxSamples;
    cv::Mat data(static_cast<int>((samples.size() + stride - 1) / stride), 3, CV_64F);
    for (int i = 0; i < data.rows; ++i) {
      for (int j = 0; j < 3; ++j) {
        data.at<double>(i, j) = samples[static_cast<size_t>(i) * stride][j];
      }
    }
    // EM starts from k-means++ centres drawn from OpenCV's thread-local generator: seeded here,
    // so that the same strokes always give the same models and the same cut.
    cv::theRNG() = cv::RNG(0x9e3779b97f4a7c15ULL);
    auto em = cv::ml::EM::create();
    em->setClustersNumber(k);
    em->setCovarianceMatrixType(cv::ml::EM::COV_MAT_GENERIC);
    em->setTermCriteria(cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 30, 1e-3));
    if (!em->trainEM(data)) return Status::Internal("graph cut: GMM training failed");
    cv::Mat means = em->getMeans(), weights = em->getWeights();
    std::vector<cv::Mat> covs;
    em->getCovs(covs);
    comps_.clear();
    for (int j = 0; j < means.rows; ++j) {
      Component c;
      cv::Mat cov;
      covs[static_cast<size_t>(j)].convertTo(cov, CV_64F);
      cov += cv::Mat::eye(3, 3, CV_64F) * 1e-6;  // keep single-colour strokes invertible
      cv::Mat inv = cov.inv(cv::DECOMP_CHOLESKY);
      double det = cv::determinant(cov);
      for (int a = 0; a < 3; ++a) {
        c.mean[a] = means.at<double>(j, a);
        for (int b = 0; b < 3; ++b) c.inv[a][b] = inv.at<double>(a, b);
      }
      c.log_norm = std::log(std::max(weights.at<double>(0, j), 1e-300)) -
                   0.5 * (3 * std::log(2 * M_PI) + std::log(std::max(det, 1e-300)));
      comps_.push_back(c);
    }
    return Status::OK();
  }
  double LogLikelihood(const cv::Vec3d& x) const {
    double best = -1e300, terms[16];
    size_t n = 0;
    for (const Component& c : comps_) {
      double d[3] = {x[0] - c.mean[0], x[1] - c.mean[1], x[2] - c.mean[2]};
      double q = 0;
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) q += d[a] * c.inv[a][b] * d[b];
      }
      terms[n] = c.log_norm - 0.5 * q;
      best = std::max(best, terms[n++]);
    }
    double sum = 0;
    for (size_t i = 0; i < n; ++i) sum += std::exp(terms[i] - best);
    return best + std::log(sum);
  }

 private:
  struct Component {
    double mean[3];
    double inv[3][3];
    double log_norm;
  };
  std::vector<Component> comps_;
};

}  // namespace

// ---------------------------------------------------------------------------------------------
// The graph: built once per region of interest, cut again for every new set of strokes.

struct GraphCut::State {
  GraphCutParams params;
  std::vector<Attr> attr;
  std::unique_ptr<MaxFlow> flow;
  std::vector<float> hard;  // per node: a capacity no cut through its links can reach
  bool solved = false;
  GraphCutResult base;      // the build's figures (neighbours, graph, arcs, betas)
};

GraphCut::GraphCut(std::unique_ptr<State> s) : s_(std::move(s)) {}
GraphCut::~GraphCut() = default;
size_t GraphCut::size() const { return s_->attr.size(); }

Result<std::unique_ptr<GraphCut>> GraphCut::Build(const std::vector<Point>& points,
                                                 const GraphCutParams& params) {
  const size_t n = points.size();
  if (params.k < 1 || params.intra_radius <= 0 || params.inter_radius <= 0 ||
      params.beta_c < 0 || params.beta_n < 0 || params.gmm_components < 1) {
    return Status::InvalidArgument("graph cut: k, radii and components must be positive, "
                                   "betas >= 0");
  }
  if (n >= 0xfffffff0u) return Status::LimitExceeded("graph cut: too many points");
  auto st = std::make_unique<State>();
  st->params = params;
  GraphCutResult& res = st->base;
  std::vector<Attr>& attr = st->attr;
  attr.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const Point& p = points[i];
    attr[i].c[0] = p.r / 255.f;
    attr[i].c[1] = p.g / 255.f;
    attr[i].c[2] = p.b / 255.f;
    attr[i].has_normal = params.use_normals && (p.flags & kFlagHasNormal);
    auto nn = DecodeNormal(p.normal_oct);
    for (int j = 0; j < 3; ++j) attr[i].n[j] = attr[i].has_normal ? nn[static_cast<size_t>(j)] : 0.f;
  }

  // Neighbourhoods (a kd-tree per frame).
  auto t0 = Clock::now();
  std::map<uint32_t, FrameIndex> frames;
  for (size_t i = 0; i < n; ++i) frames[points[i].frame].members.push_back(static_cast<uint32_t>(i));
  {
    // The frames' trees are independent: built on all cores.
    std::vector<FrameIndex*> todo;
    for (auto& [f, fi] : frames) todo.push_back(&fi);
    std::atomic<size_t> next{0};
    auto build = [&] {
      for (size_t t; (t = next++) < todo.size();) {
        FrameIndex& fi = *todo[t];
        fi.cloud.coords.resize(fi.members.size() * 3);
        for (size_t j = 0; j < fi.members.size(); ++j) {
          const Point& p = points[fi.members[j]];
          fi.cloud.coords[3 * j] = p.x;
          fi.cloud.coords[3 * j + 1] = p.y;
          fi.cloud.coords[3 * j + 2] = p.z;
        }
        fi.index = std::make_unique<KdIndex>(3, fi.cloud,
                                             nanoflann::KDTreeSingleIndexAdaptorParams(10));
      }
    };
    std::vector<std::thread> pool;
    const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
    for (size_t t = 1; t < std::min(threads, todo.size()); ++t) pool.emplace_back(build);
    build();
    for (auto& th : pool) th.join();
  }
  struct Arc {
    uint32_t a, b;
    bool inter;
  };
  std::vector<Arc> arcs;
  auto related = [&](uint32_t a, uint32_t b) {
    return ColorDiff(attr[a], attr[b]) <= params.max_color_diff &&
           NormalDiff(attr[a], attr[b]) <= params.max_normal_diff;
  };
  // Intra-frame: each point's k nearest, by input index, so that a pair both find is one arc.
  const size_t k = static_cast<size_t>(params.k);
  std::vector<uint32_t> intra(n * k, kNone);
  for (auto& [f, fi] : frames) {
    std::vector<uint32_t> near;
    Nearest(fi, fi, params.k, params.intra_radius, &near);
    for (size_t j = 0; j < fi.members.size(); ++j) {
      std::copy_n(&near[j * k], k, &intra[fi.members[j] * k]);
    }
  }
  auto lists = [&](uint32_t b, uint32_t a) {
    const uint32_t* l = &intra[b * k];
    return std::find(l, l + k, a) != l + k;
  };
  for (uint32_t a = 0; a < n; ++a) {
    for (size_t h = 0; h < k; ++h) {
      uint32_t b = intra[a * k + h];
      if (b == kNone) break;
      // Mutual neighbours: the arc is made from the smaller index's side only.
      if (b < a && lists(b, a)) continue;
      if (related(a, b)) arcs.push_back({std::min(a, b), std::max(a, b), false});
    }
  }
  std::vector<uint32_t>().swap(intra);
  // Inter-frame: to the k/2 nearest in the next frame.
  const int kt = std::max(1, params.k / 2);
  for (auto it = frames.begin(); it != frames.end(); ++it) {
    auto next = frames.find(it->first + 1);
    if (next == frames.end()) continue;
    std::vector<uint32_t> near;
    Nearest(next->second, it->second, kt, params.inter_radius, &near);
    for (size_t j = 0; j < it->second.members.size(); ++j) {
      uint32_t a = it->second.members[j];
      for (size_t h = 0; h < static_cast<size_t>(kt); ++h) {
        uint32_t b = near[j * static_cast<size_t>(kt) + h];
        if (b == kNone) break;
        if (related(a, b)) arcs.push_back({a, b, true});
      }
    }
  }
  frames.clear();
  res.neighbours_ms = Ms(t0);

  // Link costs (eqs. 9.5, 9.6), on all cores. beta 0: from the data, as GrabCut does (Rother
  // et al. 2004): the root mean square of the differences over the arcs, so that a typical
  // difference costs the same in a low- and in a high-contrast capture.
  t0 = Clock::now();
  double beta_c = params.beta_c, beta_n = params.beta_n;
  if (beta_c == 0 || beta_n == 0) {
    double sc = 0, sn = 0;
    size_t nn = 0;
    for (const Arc& a : arcs) {
      double dc = ColorDiff(attr[a.a], attr[a.b]);
      sc += dc * dc;
      if (attr[a.a].has_normal && attr[a.b].has_normal) {
        double dn = NormalDiff(attr[a.a], attr[a.b]);
        sn += dn * dn;
        ++nn;
      }
    }
    if (beta_c == 0) beta_c = std::max(1e-3, std::sqrt(sc / std::max<size_t>(arcs.size(), 1)));
    if (beta_n == 0) beta_n = std::max(1e-3, std::sqrt(sn / std::max<size_t>(nn, 1)));
  }
  res.beta_c = beta_c;
  res.beta_n = beta_n;
  std::vector<float> weight(arcs.size());
  ParallelFor(arcs.size(), [&](size_t lo, size_t hi) {
    for (size_t x = lo; x < hi; ++x) {
      const Arc& a = arcs[x];
      double dc = ColorDiff(attr[a.a], attr[a.b]);
      double s = std::exp(-dc * dc / (2 * beta_c * beta_c));
      if (attr[a.a].has_normal && attr[a.b].has_normal) {
        double dn = NormalDiff(attr[a.a], attr[a.b]);
        // Both cues must agree for a strong link (eq. 9.6 adds them; a product keeps a link
        // between alike colours across a crease weak, where the sum left it half strong and
        // the cut went around the strokes instead: recall 0.05 on an alike-coloured sphere).
        s = 2 * s * std::exp(-dn * dn / (2 * beta_n * beta_n));
      }
      weight[x] = static_cast<float>((a.inter ? params.lambda_t : params.lambda_i) * s);
    }
  });
  // The graph in arrays, arcs laid out by node (each node's degree is known, so each arc's
  // reverse is known as it is placed). Terminal links are not arcs: MaxFlow keeps one signed
  // residual per node.
  std::vector<uint32_t> start(n + 1, 0);
  for (const Arc& a : arcs) ++start[a.a + 1], ++start[a.b + 1];
  for (size_t v = 0; v < n; ++v) start[v + 1] += start[v];
  const size_t ne = start[n];
  std::vector<uint32_t> fill(start.begin(), start.end() - 1), head(ne), twin(ne);
  std::vector<float> cap(ne);
  st->hard.assign(n, 1.f);
  for (size_t x = 0; x < arcs.size(); ++x) {
    const Arc& a = arcs[x];
    const uint32_t p = fill[a.a]++, q = fill[a.b]++;
    head[p] = a.b;
    head[q] = a.a;
    cap[p] = cap[q] = weight[x];
    twin[p] = q;
    twin[q] = p;
    st->hard[a.a] += weight[x];
    st->hard[a.b] += weight[x];
    if (a.inter) {
      ++res.inter_edges;
    } else {
      ++res.intra_edges;
    }
  }
  std::vector<Arc>().swap(arcs);
  st->flow = std::make_unique<MaxFlow>(std::move(start), std::move(head), std::move(twin),
                                       std::move(cap));
  res.graph_ms = Ms(t0);
  return std::unique_ptr<GraphCut>(new GraphCut(std::move(st)));
}

Result<GraphCutResult> GraphCut::Cut(const std::vector<Seed>& seeds) {
  State& st = *s_;
  const size_t n = st.attr.size();
  if (seeds.size() != n) return Status::InvalidArgument("graph cut: one seed per point expected");
  std::vector<cv::Vec3d> fg, bg;
  for (size_t i = 0; i < n; ++i) {
    cv::Vec3d c(st.attr[i].c[0], st.attr[i].c[1], st.attr[i].c[2]);
    if (seeds[i] == Seed::kForeground) fg.push_back(c);
    if (seeds[i] == Seed::kBackground) bg.push_back(c);
  }
  if (fg.empty() || bg.empty()) {
    return Status::InvalidArgument("graph cut: needs at least one foreground and one background "
                                   "stroke inside the region of interest");
  }
  // The models must not depend on the order the points came in (a re-cut's node order is the
  // first query's): the stroked colours sorted, then subsampled and fitted.
  auto by_colour = [](const cv::Vec3d& a, const cv::Vec3d& b) {
    return std::lexicographical_compare(a.val, a.val + 3, b.val, b.val + 3);
  };
  std::sort(fg.begin(), fg.end(), by_colour);
  std::sort(bg.begin(), bg.end(), by_colour);
  GraphCutResult res = st.base;
  if (st.solved) res.neighbours_ms = res.graph_ms = 0;  // reused
  res.warm = st.solved;
  res.selected.assign(n, 0);

  // Likelihood energy (eq. 9.2). Theta is the negative log of the colour posterior rather than
  // of the raw GMM density (eq. 9.3), which can exceed 1 for peaked models and make the ratio
  // of eq. 9.2 meaningless; the order of preferences is the same. The models are trained on
  // every stroke given, so a re-cut minimises the same energy a first cut with all strokes does.
  auto t0 = Clock::now();
  ColorModel mf, mb;
  HVDB_RETURN_IF_ERROR(mf.Train(fg, st.params.gmm_components));
  HVDB_RETURN_IF_ERROR(mb.Train(bg, st.params.gmm_components));
  std::vector<float> to_src(n), to_snk(n);
  const double ld = st.params.lambda_d;
  ParallelFor(n, [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      // The seeds' hard constraints: more than any cut through a node's links can cost.
      if (seeds[i] == Seed::kForeground) {
        to_src[i] = st.hard[i] + static_cast<float>(2 * ld);
        to_snk[i] = 0;
        continue;
      }
      if (seeds[i] == Seed::kBackground) {
        to_src[i] = 0;
        to_snk[i] = st.hard[i] + static_cast<float>(2 * ld);
        continue;
      }
      cv::Vec3d c(st.attr[i].c[0], st.attr[i].c[1], st.attr[i].c[2]);
      double lf = mf.LogLikelihood(c), lb = mb.LogLikelihood(c);
      double post_f = 1.0 / (1.0 + std::exp(std::clamp(lb - lf, -700.0, 700.0)));
      double theta_f = -std::log(std::max(post_f, 1e-12));
      double theta_b = -std::log(std::max(1.0 - post_f, 1e-12));
      // Source = foreground (alpha = 1): cutting the source link labels a point background.
      to_src[i] = static_cast<float>(ld * theta_b / (theta_f + theta_b));
      to_snk[i] = static_cast<float>(ld * theta_f / (theta_f + theta_b));
    }
  });
  for (size_t i = 0; i < n; ++i) st.flow->SetTerminals(static_cast<uint32_t>(i), to_src[i], to_snk[i]);
  res.gmm_ms = Ms(t0);

  t0 = Clock::now();
  const uint64_t aug0 = st.flow->augmentations();
  st.flow->Solve();
  st.solved = true;
  res.augmentations = st.flow->augmentations() - aug0;
  res.maxflow_ms = Ms(t0);
  // The cut's energy (eq. 9.1), from the labels: terminal links of the side each point is not
  // on, and links between points on different sides.
  double energy = 0;
  for (size_t i = 0; i < n; ++i) {
    res.selected[i] = st.flow->SourceSide(static_cast<uint32_t>(i)) ? 1 : 0;
    energy += res.selected[i] ? to_snk[i] : to_src[i];
  }
  energy += st.flow->CutLinks([&](uint32_t v) { return res.selected[v] != 0; });
  res.energy = energy;
  return res;
}

Result<GraphCutResult> RunGraphCut(const std::vector<Point>& points, const std::vector<Seed>& seeds,
                                   const GraphCutParams& params) {
  if (seeds.size() != points.size()) {
    return Status::InvalidArgument("graph cut: one seed per point expected");
  }
  size_t fg = 0, bg = 0;
  for (Seed s : seeds) fg += s == Seed::kForeground, bg += s == Seed::kBackground;
  if (fg == 0 || bg == 0) {
    return Status::InvalidArgument("graph cut: needs at least one foreground and one background "
                                   "stroke inside the region of interest");
  }
  HVDB_ASSIGN_OR_RETURN(auto g, GraphCut::Build(points, params));
  return g->Cut(seeds);
}

}  // namespace hvdb::edit
