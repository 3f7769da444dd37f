#include "edit/graph_cut.h"

#include "edit/color_model.h"
#include "edit/maxflow.h"
#include "edit/neighbours.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <numbers>
#include <map>

#include <atomic>
#include <thread>


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

constexpr uint32_t kNone = std::numeric_limits<uint32_t>::max();
constexpr uint32_t kMaxFlowPiece = 1u << 14;

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

// fn(c, lo, hi) for the chunks [c * chunk, min(n, (c + 1) * chunk)), shared out among the cores
// as they finish; what each chunk writes is the same whatever the number of cores.
template <typename Fn>
void ParallelChunks(size_t n, size_t chunk, Fn&& fn) {
  const size_t chunks = (n + chunk - 1) / chunk;
  const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t c; (c = next++) < chunks;) fn(c, c * chunk, std::min(n, (c + 1) * chunk));
  };
  std::vector<std::thread> pool;
  for (size_t t = 1; t < std::min(threads, chunks); ++t) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
}

// The distinct 24-bit colours of the points (sorted) and each node's index among them: a radix
// sort of (colour, node) pairs by the colour's three bytes, O(n).
void DistinctColours(const std::vector<Point>& points, const std::vector<uint32_t>& order,
                     std::vector<Rgb>* colours, std::vector<uint32_t>* colour_of) {
  const size_t n = order.size();
  std::vector<uint64_t> key(n), tmp(n);
  for (size_t v = 0; v < n; ++v) {
    const Point& p = points[order[v]];
    key[v] = (uint64_t{p.r} << 16 | uint64_t{p.g} << 8 | p.b) << 32 | v;
  }
  for (int shift = 32; shift < 56; shift += 8) {
    size_t count[257] = {};
    for (uint64_t x : key) ++count[((x >> shift) & 0xff) + 1];
    for (int d = 0; d < 256; ++d) count[d + 1] += count[d];
    for (uint64_t x : key) tmp[count[(x >> shift) & 0xff]++] = x;
    key.swap(tmp);
  }
  colours->clear();
  colour_of->resize(n);
  uint64_t last = ~uint64_t{0};
  for (uint64_t x : key) {
    const uint64_t c = x >> 32;
    if (c != last) {
      colours->push_back({((c >> 16) & 0xff) / 255.0, ((c >> 8) & 0xff) / 255.0, (c & 0xff) / 255.0});
      last = c;
    }
    (*colour_of)[x & 0xffffffffu] = static_cast<uint32_t>(colours->size() - 1);
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// The graph: built once per region of interest, cut again for every new set of strokes.

struct GraphCut::State {
  GraphCutParams params;
  std::vector<Attr> attr;
  std::vector<uint32_t> order;  // node -> input index
  // The distinct colours and each node's: models are evaluated once per colour (a capture has
  // a sixth as many colours as points).
  std::vector<Rgb> colours;
  std::vector<uint32_t> colour_of;
  // Per model (foreground, background): the stroked colours it was last trained on and its
  // log-likelihood per distinct colour, reused by a re-cut whose strokes of that kind did not
  // change.
  std::vector<Rgb> trained[2];
  std::vector<double> loglik[2];
  std::unique_ptr<MaxFlow> flow;
  std::vector<float> hard;  // per node: a capacity no cut through its links can reach
  bool solved = false;
  std::vector<std::vector<uint32_t>> levels;  // max-flow's blocks (finest first)
  GraphCutResult base;      // the build's figures (neighbours, graph, arcs, betas)
};

Status ValidateParams(const GraphCutParams& params) {
  if (params.k < 1 || params.k > 64 || !(params.intra_radius > 0) || !(params.inter_radius > 0) ||
      !std::isfinite(params.intra_radius) || !std::isfinite(params.inter_radius) ||
      params.beta_c < 0 || params.beta_n < 0 || params.gmm_components < 1) {
    return Status::InvalidArgument("graph cut: k must be 1..64, radii and components positive, "
                                   "betas >= 0");
  }
  return Status::OK();
}

GraphCut::GraphCut(std::unique_ptr<State> s) : s_(std::move(s)) {}
GraphCut::~GraphCut() = default;
size_t GraphCut::size() const { return s_->attr.size(); }

Result<std::unique_ptr<GraphCut>> GraphCut::Build(const std::vector<Point>& points,
                                                 const GraphCutParams& params) {
  const size_t n = points.size();
  HVDB_RETURN_IF_ERROR(ValidateParams(params));
  if (n >= 0xfffffff0u) return Status::LimitExceeded("graph cut: too many points");
  auto st = std::make_unique<State>();
  st->params = params;
  GraphCutResult& res = st->base;
  // Neighbourhoods: a grid per frame (edit/neighbours.h), all on one lattice so that a frame's
  // points can be looked up in the next frame's grid. Cells of the smaller radius (one ring of
  // cells around a point covers it), but no smaller than a quarter of the larger.
  auto t0 = Clock::now();
  std::map<uint32_t, std::vector<uint32_t>> members;  // frame -> input indices
  std::array<float, 3> origin = {0, 0, 0}, top = {0, 0, 0};
  for (size_t i = 0; i < n; ++i) {
    const Point& p = points[i];
    members[p.frame].push_back(static_cast<uint32_t>(i));
    if (i == 0) origin = top = {p.x, p.y, p.z};
    origin = {std::min(origin[0], p.x), std::min(origin[1], p.y), std::min(origin[2], p.z)};
    top = {std::max(top[0], p.x), std::max(top[1], p.y), std::max(top[2], p.z)};
  }
  // (and no more than 2^16 cells along an axis: edit/neighbours.h's coordinates are 17-bit)
  const double extent = std::max({top[0] - origin[0], top[1] - origin[1], top[2] - origin[2]});
  const float cell = static_cast<float>(
      std::max({std::min(params.intra_radius, params.inter_radius),
                std::max(params.intra_radius, params.inter_radius) / 4, extent / (1 << 16)}));
  std::vector<std::unique_ptr<PointGrid>> grids(members.size());
  std::vector<uint32_t> frame_of;  // grid index -> frame
  for (const auto& [f, m] : members) frame_of.push_back(f);
  {
    std::atomic<size_t> next{0};
    auto build = [&] {
      for (size_t g; (g = next++) < grids.size();) {
        const std::vector<uint32_t>& m = members[frame_of[g]];
        std::vector<float> xyz(m.size() * 3);
        for (size_t j = 0; j < m.size(); ++j) {
          const Point& p = points[m[j]];
          xyz[3 * j] = p.x, xyz[3 * j + 1] = p.y, xyz[3 * j + 2] = p.z;
        }
        grids[g] = std::make_unique<PointGrid>(xyz, origin, cell);
      }
    };
    std::vector<std::thread> pool;
    const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
    for (size_t t = 1; t < std::min(threads, grids.size()); ++t) pool.emplace_back(build);
    build();
    for (auto& th : pool) th.join();
  }
  // Nodes are numbered frame by frame in the grids' order (by place), whatever order the points
  // came in: neighbours get nearby numbers, so the graph's arrays are walked with few cache
  // misses, and MaxFlow's blocks of consecutive nodes are compact pieces of the scene.
  std::vector<uint32_t>& order = st->order;
  order.resize(n);
  std::vector<uint32_t> frame_start;  // first node of each grid's frame, then n
  for (size_t g = 0; g < grids.size(); ++g) {
    const uint32_t first = frame_start.empty() ? 0 : frame_start.back() + static_cast<uint32_t>(grids[g - 1]->size());
    frame_start.push_back(first);
    const std::vector<uint32_t>& m = members[frame_of[g]];
    for (size_t j = 0; j < grids[g]->size(); ++j) order[first + j] = m[grids[g]->input(j)];
  }
  frame_start.push_back(static_cast<uint32_t>(n));
  members.clear();
  std::vector<Attr>& attr = st->attr;
  attr.resize(n);
  for (size_t v = 0; v < n; ++v) {
    const Point& p = points[order[v]];
    attr[v].c[0] = p.r / 255.f;
    attr[v].c[1] = p.g / 255.f;
    attr[v].c[2] = p.b / 255.f;
    attr[v].has_normal = params.use_normals && (p.flags & kFlagHasNormal);
    auto nn = DecodeNormal(p.normal_oct);
    for (int j = 0; j < 3; ++j) attr[v].n[j] = attr[v].has_normal ? nn[static_cast<size_t>(j)] : 0.f;
  }
  DistinctColours(points, order, &st->colours, &st->colour_of);
  struct Arc {
    uint32_t a, b;
    bool inter;
  };
  const bool exclude = params.max_color_diff < 1 || params.max_normal_diff < 1;
  auto related = [&](uint32_t a, uint32_t b) {
    return !exclude || (ColorDiff(attr[a], attr[b]) <= params.max_color_diff &&
                        NormalDiff(attr[a], attr[b]) <= params.max_normal_diff);
  };
  // Intra-frame: each point's k nearest, by node, so that a pair both find is one arc;
  // inter-frame: its k/2 nearest in the next frame.
  const size_t k = static_cast<size_t>(params.k);
  const size_t kt = static_cast<size_t>(std::max(1, params.k / 2));
  std::vector<uint32_t> intra(n * k, kNone), inter(n * kt, kNone);
  for (size_t g = 0; g < grids.size(); ++g) {
    // Grid positions to node numbers: the frame's first node plus the position.
    auto copy = [&](const std::vector<uint32_t>& near, size_t per, uint32_t target_first,
                    std::vector<uint32_t>* to) {
      for (size_t j = 0; j < near.size(); ++j) {
        if (near[j] != PointGrid::kNone) (*to)[frame_start[g] * per + j] = target_first + near[j];
      }
    };
    std::vector<uint32_t> near;
    grids[g]->Nearest(*grids[g], params.k, static_cast<float>(params.intra_radius), &near);
    copy(near, k, frame_start[g], &intra);
      if (g + 1 == grids.size() || frame_of[g + 1] != frame_of[g] + 1) continue;
    grids[g + 1]->Nearest(*grids[g], static_cast<int>(kt), static_cast<float>(params.inter_radius), &near);
    copy(near, kt, frame_start[g + 1], &inter);
  }
  grids.clear();
  auto lists = [&](uint32_t b, uint32_t a) {
    const uint32_t* l = &intra[b * k];
    return std::find(l, l + k, a) != l + k;
  };
  // The arcs, on all cores in chunks of nodes joined in order (the same graph whatever the
  // number of cores).
  constexpr size_t kChunk = 1 << 14;
  std::vector<std::vector<Arc>> parts((n + kChunk - 1) / kChunk);
  ParallelChunks(n, kChunk, [&](size_t c, size_t lo, size_t hi) {
    std::vector<Arc>& out = parts[c];
    out.reserve((hi - lo) * (k / 2 + kt));
    for (uint32_t a = static_cast<uint32_t>(lo); a < hi; ++a) {
      for (size_t h = 0; h < k; ++h) {
        const uint32_t b = intra[a * k + h];
        if (b == kNone) break;
        // Mutual neighbours: the arc is made from the smaller number's side only.
        if (b < a && lists(b, a)) continue;
        if (related(a, b)) out.push_back({std::min(a, b), std::max(a, b), false});
      }
      for (size_t h = 0; h < kt; ++h) {
        const uint32_t b = inter[a * kt + h];
        if (b == kNone) break;
        if (related(a, b)) out.push_back({a, b, true});
      }
    }
  });
  std::vector<uint32_t>().swap(intra);
  std::vector<uint32_t>().swap(inter);
  std::vector<Arc> arcs;
  {
    size_t total = 0;
    for (const auto& part : parts) total += part.size();
    arcs.reserve(total);
    for (auto& part : parts) {
      arcs.insert(arcs.end(), part.begin(), part.end());
      std::vector<Arc>().swap(part);
    }
  }
  res.neighbours_ms = Ms(t0);

  // Link costs (eqs. 9.5, 9.6), on all cores. beta 0: from the data, as GrabCut does (Rother
  // et al. 2004): the root mean square of the differences over the arcs, so that a typical
  // difference costs the same in a low- and in a high-contrast capture.
  t0 = Clock::now();
  double beta_c = params.beta_c, beta_n = params.beta_n;
  if (beta_c == 0 || beta_n == 0) {
    // Sums per fixed chunk, added in chunk order: the same betas on any number of cores.
    constexpr size_t kSumChunk = 1 << 16;
    std::vector<std::array<double, 3>> sums((arcs.size() + kSumChunk - 1) / kSumChunk);
    ParallelChunks(arcs.size(), kSumChunk, [&](size_t c, size_t lo, size_t hi) {
      double sc = 0, sn = 0, nn = 0;
      for (size_t x = lo; x < hi; ++x) {
        const Arc& a = arcs[x];
        const double dc = ColorDiff(attr[a.a], attr[a.b]);
        sc += dc * dc;
        if (attr[a.a].has_normal && attr[a.b].has_normal) {
          const double dn = NormalDiff(attr[a.a], attr[a.b]);
          sn += dn * dn;
          ++nn;
        }
      }
      sums[c] = {sc, sn, nn};
    });
    double sc = 0, sn = 0, nn = 0;
    for (const auto& x : sums) sc += x[0], sn += x[1], nn += x[2];
    if (beta_c == 0) beta_c = std::max(1e-3, std::sqrt(sc / std::max<double>(arcs.size(), 1)));
    if (beta_n == 0) beta_n = std::max(1e-3, std::sqrt(sn / std::max(nn, 1.0)));
  }
  res.beta_c = beta_c;
  res.beta_n = beta_n;
  std::vector<float> weight(arcs.size());
  const double inv_c = 1 / (2 * beta_c * beta_c), inv_n = 1 / (2 * beta_n * beta_n);
  ParallelFor(arcs.size(), [&](size_t lo, size_t hi) {
    for (size_t x = lo; x < hi; ++x) {
      const Arc& a = arcs[x];
      const double dc = ColorDiff(attr[a.a], attr[a.b]);
      double s;
      if (attr[a.a].has_normal && attr[a.b].has_normal) {
        const double dn = NormalDiff(attr[a.a], attr[a.b]);
        // Both cues must agree for a strong link (eq. 9.6 adds them; a product keeps a link
        // between alike colours across a crease weak, where the sum left it half strong and
        // the cut went around the strokes instead: recall 0.05 on an alike-coloured sphere).
        // The product of the two exponentials as one (an exp per arc is a fifth of the graph's
        // time).
        s = 2 * std::exp(-dc * dc * inv_c - dn * dn * inv_n);
      } else {
        s = std::exp(-dc * dc * inv_c);
      }
      weight[x] = static_cast<float>((a.inter ? params.lambda_t : params.lambda_i) * s);
    }
  });
  // The graph in arrays, arcs laid out by node (each node's degree is known, so each arc's
  // reverse is known as it is placed). Terminal links are not arcs: MaxFlow keeps one signed
  // residual per node.
  // On all cores: each core counts and then places the arcs of its share of the list, at
  // offsets that put every node's arcs in list order, the layout one core would make.
  const size_t parts_n = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  const size_t share = (arcs.size() + parts_n - 1) / parts_n;
  std::vector<std::vector<uint32_t>> at(parts_n, std::vector<uint32_t>(n, 0));
  auto each_part = [&](auto&& fn) {
    std::vector<std::thread> pool;
    for (size_t c = 1; c < parts_n; ++c) pool.emplace_back(fn, c);
    fn(size_t{0});
    for (auto& th : pool) th.join();
  };
  auto range = [&](size_t c) {
    return std::pair{std::min(arcs.size(), c * share), std::min(arcs.size(), (c + 1) * share)};
  };
  each_part([&](size_t c) {
    auto [lo, hi] = range(c);
    for (size_t x = lo; x < hi; ++x) ++at[c][arcs[x].a], ++at[c][arcs[x].b];
  });
  std::vector<uint32_t> start(n + 1, 0);
  for (size_t v = 0; v < n; ++v) {
    uint32_t next = start[v];
    for (size_t c = 0; c < parts_n; ++c) {
      const uint32_t count = at[c][v];
      at[c][v] = next;  // from here on: where part c places node v's next arc
      next += count;
    }
    start[v + 1] = next;
  }
  const size_t ne = start[n];
  std::vector<MaxFlow::Arc> graph(ne);
  each_part([&](size_t c) {
    auto [lo, hi] = range(c);
    std::vector<uint32_t>& fill = at[c];
    for (size_t x = lo; x < hi; ++x) {
      const Arc& a = arcs[x];
      const uint32_t p = fill[a.a]++, q = fill[a.b]++;
      graph[p] = {a.b, q, weight[x], weight[x]};
      graph[q] = {a.a, p, weight[x], weight[x]};
    }
  });
  at.clear();
  for (const Arc& a : arcs) {
    if (a.inter) {
      ++res.inter_edges;
    } else {
      ++res.intra_edges;
    }
  }
  st->hard.assign(n, 1.f);
  ParallelFor(n, [&](size_t lo, size_t hi) {
    for (size_t v = lo; v < hi; ++v) {
      for (uint32_t e = start[v]; e < start[v + 1]; ++e) st->hard[v] += graph[e].rcap;
    }
  });
  std::vector<Arc>().swap(arcs);
  st->flow = std::make_unique<MaxFlow>(std::move(start), std::move(graph));
  // Max-flow's blocks (edit/maxflow.h): pieces of about 16 Ki nodes within each frame, then
  // the frames, then the whole region. Measured on issue 15's real scene (1.2 M points, five
  // frames, two cores): max-flow 0.75 s this way; 0.95 s with 64 Ki pieces and no frame level,
  // 1.3 s with 16 Ki pieces alone, 1.9 s without blocks; numbering all frames together by place
  // (so that temporal links stay inside blocks) was slower still (1.6 s): cuts inside a frame
  // need the most flow, and blocks spanning five frames cover a fifth of the area each.
  if (n > 2 * kMaxFlowPiece) {
    std::vector<std::vector<uint32_t>> levels(frame_start.size() > 2 ? 2 : 1);
    for (size_t f = 0; f + 1 < frame_start.size(); ++f) {
      const uint32_t len = frame_start[f + 1] - frame_start[f];
      const uint32_t pieces = std::max<uint32_t>(1, (len + kMaxFlowPiece / 2) / kMaxFlowPiece);
      for (uint32_t q = 0; q < pieces; ++q) {
        levels[0].push_back(frame_start[f] + static_cast<uint32_t>(uint64_t{len} * q / pieces));
      }
      if (levels.size() > 1) levels[1].push_back(frame_start[f]);
    }
    st->levels = std::move(levels);
  }
  res.graph_ms = Ms(t0);
  return std::unique_ptr<GraphCut>(new GraphCut(std::move(st)));
}

Result<GraphCutResult> GraphCut::Cut(const std::vector<Seed>& seeds) {
  State& st = *s_;
  const size_t n = st.attr.size();
  if (seeds.size() != n) return Status::InvalidArgument("graph cut: one seed per point expected");
  std::vector<Rgb> strokes[2];  // foreground, background
  for (size_t i = 0; i < n; ++i) {
    const Seed seed = seeds[st.order[i]];
    if (seed == Seed::kUnknown) continue;
    strokes[seed == Seed::kForeground ? 0 : 1].push_back(st.colours[st.colour_of[i]]);
  }
  if (strokes[0].empty() || strokes[1].empty()) {
    return Status::InvalidArgument("graph cut: needs at least one foreground and one background "
                                   "stroke inside the region of interest");
  }
  GraphCutResult res = st.base;
  if (st.solved) res.neighbours_ms = res.graph_ms = 0;  // reused
  res.warm = st.solved;
  res.selected.assign(n, 0);

  // Likelihood energy (eq. 9.2). Theta is the negative log of the colour posterior rather than
  // of the raw GMM density (eq. 9.3), which can exceed 1 for peaked models and make the ratio
  // of eq. 9.2 meaningless; the order of preferences is the same. The models are trained on
  // every stroke given, so a re-cut minimises the same energy a first cut with all strokes does;
  // a model whose strokes did not change is not trained or evaluated again.
  auto t0 = Clock::now();
  for (int m = 0; m < 2; ++m) {
    // The models must not depend on the order the points came in: the colours sorted.
    std::sort(strokes[m].begin(), strokes[m].end());
    if (!st.loglik[m].empty() && strokes[m] == st.trained[m]) continue;
    ColorModel model;
    HVDB_RETURN_IF_ERROR(model.Train(strokes[m], st.params.gmm_components));
    st.loglik[m].resize(st.colours.size());
    ParallelFor(st.colours.size(), [&](size_t lo, size_t hi) {
      for (size_t c = lo; c < hi; ++c) {
        st.loglik[m][c] = model.LogLikelihood(st.colours[c]);
      }
    });
    st.trained[m] = std::move(strokes[m]);
  }
  std::vector<float> to_src(n), to_snk(n);
  const double ld = st.params.lambda_d;
  ParallelFor(n, [&](size_t lo, size_t hi) {
    for (size_t i = lo; i < hi; ++i) {
      // The seeds' hard constraints: more than any cut through a node's links can cost.
      if (seeds[st.order[i]] == Seed::kForeground) {
        to_src[i] = st.hard[i] + static_cast<float>(2 * ld);
        to_snk[i] = 0;
        continue;
      }
      if (seeds[st.order[i]] == Seed::kBackground) {
        to_src[i] = 0;
        to_snk[i] = st.hard[i] + static_cast<float>(2 * ld);
        continue;
      }
      const uint32_t c = st.colour_of[i];
      const double lf = st.loglik[0][c], lb = st.loglik[1][c];
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
  // A re-cut starts from a flow that is maximal but for the changed terminals, mostly a little
  // everywhere, and goes through the same levels as a first cut: since the coarser levels keep
  // the finer ones' search trees (edit/maxflow.h), the level of whole frames pays for itself
  // (issue 15's real scene, 1.2 M points, a re-cut after a 5.8 k-point stroke: max-flow 1.08 s
  // this way, 2.1 s with the pieces alone; 0.18 s against 0.24 s when the strokes did not
  // change).
  if (!st.levels.empty()) st.flow->set_levels(st.levels);
  st.flow->Solve();
  st.solved = true;
  res.augmentations = st.flow->augmentations() - aug0;
  res.maxflow_ms = Ms(t0);
  // The cut's energy (eq. 9.1), from the labels: terminal links of the side each point is not
  // on, and links between points on different sides.
  double energy = 0;
  std::vector<uint8_t> side(n);
  for (size_t v = 0; v < n; ++v) {
    side[v] = st.flow->SourceSide(static_cast<uint32_t>(v)) ? 1 : 0;
    res.selected[st.order[v]] = side[v];
    energy += side[v] ? to_snk[v] : to_src[v];
  }
  energy += st.flow->CutLinks([&](uint32_t v) { return side[v] != 0; });
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
