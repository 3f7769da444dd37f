#include "edit/graph_cut.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <map>

#include <atomic>
#include <iterator>
#include <thread>

#include <boost/graph/boykov_kolmogorov_max_flow.hpp>
#include <boost/graph/compressed_sparse_row_graph.hpp>
#include <boost/property_map/property_map.hpp>
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

// The (source, target) pairs of edges laid out by source (CSR offsets `start`), generated as
// the graph's constructor reads them instead of stored.
class SortedEdges {
 public:
  using iterator_category = std::input_iterator_tag;
  using value_type = std::pair<uint32_t, uint32_t>;
  using difference_type = std::ptrdiff_t;
  using pointer = const value_type*;
  using reference = value_type;
  SortedEdges(const uint32_t* start, const uint32_t* target, size_t nv, uint32_t p)
      : start_(start), target_(target), nv_(nv), p_(p) {
    Settle();
  }
  value_type operator*() const { return cur_; }
  pointer operator->() const { return &cur_; }
  SortedEdges& operator++() {
    ++p_;
    Settle();
    return *this;
  }
  SortedEdges operator++(int) {
    SortedEdges old = *this;
    ++*this;
    return old;
  }
  bool operator==(const SortedEdges& o) const { return p_ == o.p_; }
  bool operator!=(const SortedEdges& o) const { return p_ != o.p_; }

 private:
  void Settle() {  // the source of edge p: skip vertices without out-edges
    while (v_ < nv_ && start_[v_ + 1] <= p_) ++v_;
    if (v_ < nv_) cur_ = {v_, target_[p_]};
  }
  const uint32_t* start_;
  const uint32_t* target_;
  size_t nv_;
  uint32_t p_;
  uint32_t v_ = 0;
  value_type cur_{0, 0};
};

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

Result<GraphCutResult> RunGraphCut(const std::vector<Point>& points, const std::vector<Seed>& seeds,
                                   const GraphCutParams& params) {
  const size_t n = points.size();
  if (seeds.size() != n) return Status::InvalidArgument("graph cut: one seed per point expected");
  if (params.k < 1 || params.intra_radius <= 0 || params.inter_radius <= 0 ||
      params.beta_c < 0 || params.beta_n < 0 || params.gmm_components < 1) {
    return Status::InvalidArgument("graph cut: k, radii and components must be positive, "
                                   "betas >= 0");
  }
  GraphCutResult res;
  res.selected.assign(n, 0);
  std::vector<Attr> attr(n);
  std::vector<cv::Vec3d> fg, bg;
  for (size_t i = 0; i < n; ++i) {
    const Point& p = points[i];
    attr[i].c[0] = p.r / 255.f;
    attr[i].c[1] = p.g / 255.f;
    attr[i].c[2] = p.b / 255.f;
    attr[i].has_normal = params.use_normals && (p.flags & kFlagHasNormal);
    auto nn = DecodeNormal(p.normal_oct);
    for (int j = 0; j < 3; ++j) attr[i].n[j] = attr[i].has_normal ? nn[static_cast<size_t>(j)] : 0.f;
    cv::Vec3d c(attr[i].c[0], attr[i].c[1], attr[i].c[2]);
    if (seeds[i] == Seed::kForeground) fg.push_back(c);
    if (seeds[i] == Seed::kBackground) bg.push_back(c);
  }
  if (fg.empty() || bg.empty()) {
    return Status::InvalidArgument("graph cut: needs at least one foreground and one background "
                                   "stroke inside the region of interest");
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
  res.neighbours_ms = Ms(t0);

  // Likelihood energy (eq. 9.2). Theta is the negative log of the colour posterior rather than
  // of the raw GMM density (eq. 9.3), which can exceed 1 for peaked models and make the ratio
  // of eq. 9.2 meaningless; the order of preferences is the same.
  t0 = Clock::now();
  ColorModel mf, mb;
  HVDB_RETURN_IF_ERROR(mf.Train(fg, params.gmm_components));
  HVDB_RETURN_IF_ERROR(mb.Train(bg, params.gmm_components));
  std::vector<double> e1(n, 0), e0(n, 0);
  ParallelFor(n, [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      if (seeds[i] != Seed::kUnknown) continue;
      cv::Vec3d c(attr[i].c[0], attr[i].c[1], attr[i].c[2]);
      double lf = mf.LogLikelihood(c), lb = mb.LogLikelihood(c);
      double post_f = 1.0 / (1.0 + std::exp(std::clamp(lb - lf, -700.0, 700.0)));
      double theta_f = -std::log(std::max(post_f, 1e-12));
      double theta_b = -std::log(std::max(1.0 - post_f, 1e-12));
      e1[i] = theta_f / (theta_f + theta_b);
      e0[i] = theta_b / (theta_f + theta_b);
    }
  });
  res.gmm_ms = Ms(t0);

  // The graph: source = foreground (alpha = 1), sink = background. A compressed sparse row
  // graph built in one pass from an edge list: Boost's adjacency_list took a node and a vector
  // per vertex and an allocation per edge (2 s to build and free for a million points).
  t0 = Clock::now();
  // Capacities in single precision: they lie in [0, 2] (and 1e9 for seeds); 12 bytes an edge
  // keeps a million-point graph's ~20 M edges in cache-friendlier memory.
  struct EdgeProp {
    float cap = 0, res = 0;
  };
  using Csr = boost::compressed_sparse_row_graph<boost::directedS, boost::no_property, EdgeProp,
                                                 boost::no_property, uint32_t, uint32_t>;
  using Edge = boost::graph_traits<Csr>::edge_descriptor;
  const uint32_t src = static_cast<uint32_t>(n), snk = static_cast<uint32_t>(n + 1);
  const size_t nv = n + 2;
  // Terminal capacities (eq. 9.2) and the seeds' hard constraints: more than any cut through
  // a node's arcs can cost.
  const double inf = 1e9;
  std::vector<float> to_src(n), to_snk(n);
  for (size_t i = 0; i < n; ++i) {
    double s = params.lambda_d * e0[i], t = params.lambda_d * e1[i];
    if (seeds[i] == Seed::kForeground) {
      s = inf;
      t = 0;
    } else if (seeds[i] == Seed::kBackground) {
      s = 0;
      t = inf;
    }
    to_src[i] = static_cast<float>(s);
    to_snk[i] = static_cast<float>(t);
  }
  // The edges sorted by source, laid out directly (each node's degree is known), so that each
  // edge's reverse is known as it is placed and the graph is built without a sort.
  std::vector<uint32_t> start(nv + 1, 0);
  for (size_t i = 0; i < n; ++i) {
    if (to_src[i] > 0) ++start[src + 1], ++start[i + 1];
    if (to_snk[i] > 0) ++start[snk + 1], ++start[i + 1];
  }
  for (const Arc& a : arcs) ++start[a.a + 1], ++start[a.b + 1];
  for (size_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  const size_t ne = start[nv];
  std::vector<uint32_t> fill(start.begin(), start.end() - 1), target(ne), twin(ne);
  std::vector<EdgeProp> props(ne);
  auto place = [&](uint32_t u, uint32_t v, double cuv, double cvu) {
    const uint32_t p = fill[u]++, q = fill[v]++;
    target[p] = v;
    target[q] = u;
    props[p].cap = static_cast<float>(cuv);
    props[q].cap = static_cast<float>(cvu);
    twin[p] = q;
    twin[q] = p;
  };
  for (size_t i = 0; i < n; ++i) {
    const auto u = static_cast<uint32_t>(i);
    if (to_src[i] > 0) place(src, u, to_src[i], 0);
    if (to_snk[i] > 0) place(u, snk, to_snk[i], 0);
  }
  // Link costs (eqs. 9.5, 9.6), on all cores. beta 0: from the data, as GrabCut does (Rother
  // et al. 2004): the root mean square of the differences over the arcs, so that a typical
  // difference costs the same in a low- and in a high-contrast capture.
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
  for (size_t x = 0; x < arcs.size(); ++x) {
    const Arc& a = arcs[x];
    place(a.a, a.b, weight[x], weight[x]);
    if (a.inter) {
      ++res.inter_edges;
    } else {
      ++res.intra_edges;
    }
  }
  std::vector<Arc>().swap(arcs);
  // Sorted input keeps its order: edge p of the list is edge index p of the graph.
  Csr g(boost::edges_are_sorted, SortedEdges(start.data(), target.data(), nv, 0),
        SortedEdges(start.data(), target.data(), nv, static_cast<uint32_t>(ne)), props.begin(), nv,
        ne);
  std::vector<EdgeProp>().swap(props);
  const auto eindex = boost::get(boost::edge_index, g);
  std::vector<Edge> rev(ne);
  for (size_t p = 0; p < ne; ++p) rev[p] = Edge(target[p], twin[p]);
  res.graph_ms = Ms(t0);

  t0 = Clock::now();
  std::vector<Edge> pred(nv);
  std::vector<boost::default_color_type> color(nv);
  std::vector<long> dist(nv);
  const auto vindex = boost::get(boost::vertex_index, g);
  res.energy = boost::boykov_kolmogorov_max_flow(
      g, boost::get(&EdgeProp::cap, g), boost::get(&EdgeProp::res, g),
      boost::make_iterator_property_map(rev.begin(), eindex),
      boost::make_iterator_property_map(pred.begin(), vindex),
      boost::make_iterator_property_map(color.begin(), vindex),
      boost::make_iterator_property_map(dist.begin(), vindex), vindex, src, snk);
  res.maxflow_ms = Ms(t0);
  // Nodes still connected to the source in the residual graph are black (foreground).
  for (size_t i = 0; i < n; ++i) {
    res.selected[i] = color[i] == boost::black_color ? 1 : 0;
  }
  return res;
}

}  // namespace hvdb::edit
