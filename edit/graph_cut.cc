#include "edit/graph_cut.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <map>

#include <boost/graph/adjacency_list.hpp>
#include <boost/graph/boykov_kolmogorov_max_flow.hpp>
#include <flann/flann.hpp>
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

// One frame's points in a FLANN kd-tree.
struct FrameIndex {
  std::vector<uint32_t> members;  // indices into the input
  std::vector<float> coords;
  std::unique_ptr<flann::Index<flann::L2_Simple<float>>> index;
};

// A colour model: a GMM (eq. 9.3) trained by OpenCV's EM. The log-density is evaluated here
// from the trained means, covariances and weights: EM::predict2 costs ~10 us per call, which
// dominated a million-point cut.
class ColorModel {
 public:
  Status Train(const std::vector<cv::Vec3d>& samples, int components) {
    if (samples.empty()) return Status::InvalidArgument("graph cut: a colour model has no samples");
    int k = std::clamp(std::min<int>(components, static_cast<int>(samples.size()) / 4), 1, 16);
    cv::Mat data(static_cast<int>(samples.size()), 3, CV_64F);
    for (int i = 0; i < data.rows; ++i) {
      for (int j = 0; j < 3; ++j) data.at<double>(i, j) = samples[static_cast<size_t>(i)][j];
    }
    auto em = cv::ml::EM::create();
    em->setClustersNumber(k);
    em->setCovarianceMatrixType(cv::ml::EM::COV_MAT_GENERIC);
    em->setTermCriteria(cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-4));
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
      params.beta_c <= 0 || params.beta_n <= 0 || params.gmm_components < 1) {
    return Status::InvalidArgument("graph cut: k, radii, betas and components must be positive");
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

  // Neighbourhoods (FLANN kd-trees per frame).
  auto t0 = Clock::now();
  std::map<uint32_t, FrameIndex> frames;
  for (size_t i = 0; i < n; ++i) frames[points[i].frame].members.push_back(static_cast<uint32_t>(i));
  for (auto& [f, fi] : frames) {
    fi.coords.resize(fi.members.size() * 3);
    for (size_t j = 0; j < fi.members.size(); ++j) {
      const Point& p = points[fi.members[j]];
      fi.coords[3 * j] = p.x;
      fi.coords[3 * j + 1] = p.y;
      fi.coords[3 * j + 2] = p.z;
    }
    flann::Matrix<float> m(fi.coords.data(), fi.members.size(), 3);
    fi.index = std::make_unique<flann::Index<flann::L2_Simple<float>>>(
        m, flann::KDTreeSingleIndexParams(10));
    fi.index->buildIndex();
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
  auto search = [&](const FrameIndex& target, const FrameIndex& source, int k, double radius,
                    bool inter) {
    flann::SearchParams sp(flann::FLANN_CHECKS_UNLIMITED);
    sp.cores = 0;  // all cores
    sp.max_neighbors = inter ? k : k + 1;  // intra: the point finds itself
    sp.sorted = true;
    flann::Matrix<float> queries(const_cast<float*>(source.coords.data()), source.members.size(), 3);
    std::vector<std::vector<size_t>> idx;
    std::vector<std::vector<float>> dist;
    target.index->radiusSearch(queries, idx, dist, static_cast<float>(radius * radius), sp);
    for (size_t q = 0; q < idx.size(); ++q) {
      uint32_t a = source.members[q];
      for (size_t hit : idx[q]) {
        uint32_t b = target.members[hit];
        if (a == b || !related(a, b)) continue;
        if (!inter && b < a) {
          arcs.push_back({b, a, false});
        } else {
          arcs.push_back({a, b, inter});
        }
      }
    }
  };
  for (auto it = frames.begin(); it != frames.end(); ++it) {
    search(it->second, it->second, params.k, params.intra_radius, false);
    auto next = frames.find(it->first + 1);
    if (next != frames.end()) search(next->second, it->second, std::max(1, params.k / 2),
                                     params.inter_radius, true);
  }
  // Mutual neighbours were found twice: keep each arc once.
  std::sort(arcs.begin(), arcs.end(), [](const Arc& x, const Arc& y) {
    return std::tie(x.a, x.b, x.inter) < std::tie(y.a, y.b, y.inter);
  });
  arcs.erase(std::unique(arcs.begin(), arcs.end(),
                         [](const Arc& x, const Arc& y) { return x.a == y.a && x.b == y.b; }),
             arcs.end());
  res.neighbours_ms = Ms(t0);

  // Likelihood energy (eq. 9.2). Theta is the negative log of the colour posterior rather than
  // of the raw GMM density (eq. 9.3), which can exceed 1 for peaked models and make the ratio
  // of eq. 9.2 meaningless; the order of preferences is the same.
  t0 = Clock::now();
  ColorModel mf, mb;
  HVDB_RETURN_IF_ERROR(mf.Train(fg, params.gmm_components));
  HVDB_RETURN_IF_ERROR(mb.Train(bg, params.gmm_components));
  std::vector<double> e1(n, 0), e0(n, 0);
  for (size_t i = 0; i < n; ++i) {
    if (seeds[i] != Seed::kUnknown) continue;
    cv::Vec3d c(attr[i].c[0], attr[i].c[1], attr[i].c[2]);
    double lf = mf.LogLikelihood(c), lb = mb.LogLikelihood(c);
    double post_f = 1.0 / (1.0 + std::exp(std::clamp(lb - lf, -700.0, 700.0)));
    double theta_f = -std::log(std::max(post_f, 1e-12));
    double theta_b = -std::log(std::max(1.0 - post_f, 1e-12));
    e1[i] = theta_f / (theta_f + theta_b);
    e0[i] = theta_b / (theta_f + theta_b);
  }
  res.gmm_ms = Ms(t0);

  // The graph: source = foreground (alpha = 1), sink = background.
  t0 = Clock::now();
  using Traits = boost::adjacency_list_traits<boost::vecS, boost::vecS, boost::directedS>;
  using Graph = boost::adjacency_list<
      boost::vecS, boost::vecS, boost::directedS,
      boost::property<boost::vertex_index_t, long,
                      boost::property<boost::vertex_color_t, boost::default_color_type,
                                      boost::property<boost::vertex_distance_t, long,
                                                      boost::property<boost::vertex_predecessor_t,
                                                                      Traits::edge_descriptor>>>>,
      boost::property<boost::edge_capacity_t, double,
                      boost::property<boost::edge_residual_capacity_t, double,
                                      boost::property<boost::edge_reverse_t,
                                                      Traits::edge_descriptor>>>>;
  Graph g(n + 2);
  const auto src = static_cast<Traits::vertex_descriptor>(n);
  const auto snk = static_cast<Traits::vertex_descriptor>(n + 1);
  auto cap = boost::get(boost::edge_capacity, g);
  auto rev = boost::get(boost::edge_reverse, g);
  auto add = [&](Traits::vertex_descriptor u, Traits::vertex_descriptor v, double cuv, double cvu) {
    auto e = boost::add_edge(u, v, g).first;
    auto r = boost::add_edge(v, u, g).first;
    cap[e] = cuv;
    cap[r] = cvu;
    rev[e] = r;
    rev[r] = e;
  };
  // Hard constraints: more than any cut through the node's arcs can cost.
  const double inf = 1e9;
  for (size_t i = 0; i < n; ++i) {
    double to_src = params.lambda_d * e0[i], to_snk = params.lambda_d * e1[i];
    if (seeds[i] == Seed::kForeground) {
      to_src = inf;
      to_snk = 0;
    } else if (seeds[i] == Seed::kBackground) {
      to_src = 0;
      to_snk = inf;
    }
    if (to_src > 0) add(src, i, to_src, 0);
    if (to_snk > 0) add(i, snk, to_snk, 0);
  }
  for (const Arc& a : arcs) {
    double dc = ColorDiff(attr[a.a], attr[a.b]);
    double s = std::exp(-dc * dc / (2 * params.beta_c * params.beta_c));
    if (attr[a.a].has_normal && attr[a.b].has_normal) {
      double dn = NormalDiff(attr[a.a], attr[a.b]);
      s += std::exp(-dn * dn / (2 * params.beta_n * params.beta_n));  // eq. 9.6
    }
    double w = (a.inter ? params.lambda_t : params.lambda_i) * s;
    add(a.a, a.b, w, w);
    if (a.inter) {
      ++res.inter_edges;
    } else {
      ++res.intra_edges;
    }
  }
  res.graph_ms = Ms(t0);

  t0 = Clock::now();
  res.energy = boost::boykov_kolmogorov_max_flow(g, src, snk);
  res.maxflow_ms = Ms(t0);
  // Nodes still connected to the source in the residual graph are black (foreground).
  auto color = boost::get(boost::vertex_color, g);
  for (size_t i = 0; i < n; ++i) {
    res.selected[i] = boost::get(color, i) == boost::black_color ? 1 : 0;
  }
  return res;
}

}  // namespace hvdb::edit
