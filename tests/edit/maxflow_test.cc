// edit/maxflow.h against Boost's Edmonds-Karp max-flow on random graphs (the differential
// oracle), cold and warm: after changing terminal capacities, a warm Solve must find a cut as
// cheap as a fresh solve of the changed graph. Seeded, deterministic.
#include "edit/maxflow.h"

#include <gtest/gtest.h>

#include <boost/graph/adjacency_list.hpp>
#include <boost/graph/edmonds_karp_max_flow.hpp>
#include <random>

namespace hvdb::edit {
namespace {

struct Graph {
  size_t n = 0;
  std::vector<std::array<uint32_t, 2>> links;
  std::vector<float> weight;
  std::vector<float> src, snk;
};

// A grid of w x h nodes (4-neighbours) plus a few random long links, integer-valued
// capacities so that float sums are exact.
Graph RandomGraph(std::mt19937& rng, int w, int h) {
  Graph g;
  g.n = static_cast<size_t>(w * h);
  std::uniform_int_distribution<int> cap(0, 20), term(0, 12), node(0, w * h - 1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const uint32_t v = static_cast<uint32_t>(y * w + x);
      if (x + 1 < w) g.links.push_back({v, v + 1});
      if (y + 1 < h) g.links.push_back({v, v + static_cast<uint32_t>(w)});
    }
  }
  for (int i = 0; i < w * h / 10; ++i) {
    uint32_t a = static_cast<uint32_t>(node(rng)), b = static_cast<uint32_t>(node(rng));
    if (a != b) g.links.push_back({a, b});
  }
  for (size_t i = 0; i < g.links.size(); ++i) g.weight.push_back(static_cast<float>(cap(rng)));
  for (size_t v = 0; v < g.n; ++v) {
    g.src.push_back(static_cast<float>(term(rng)));
    g.snk.push_back(static_cast<float>(term(rng)));
  }
  return g;
}

std::unique_ptr<MaxFlow> Make(const Graph& g) {
  std::vector<uint32_t> start(g.n + 1, 0);
  for (const auto& l : g.links) ++start[l[0] + 1], ++start[l[1] + 1];
  for (size_t v = 0; v < g.n; ++v) start[v + 1] += start[v];
  std::vector<uint32_t> fill(start.begin(), start.end() - 1), head(start[g.n]), twin(start[g.n]);
  std::vector<float> cap(start[g.n]);
  for (size_t i = 0; i < g.links.size(); ++i) {
    const uint32_t p = fill[g.links[i][0]]++, q = fill[g.links[i][1]]++;
    head[p] = g.links[i][1];
    head[q] = g.links[i][0];
    twin[p] = q;
    twin[q] = p;
    cap[p] = cap[q] = g.weight[i];
  }
  return std::make_unique<MaxFlow>(std::move(start), std::move(head), std::move(twin),
                                   std::move(cap));
}

// The cost of the cut `side` (true: source side).
double CutCost(const Graph& g, const std::vector<bool>& side) {
  double c = 0;
  for (size_t v = 0; v < g.n; ++v) c += side[v] ? g.snk[v] : g.src[v];
  for (size_t i = 0; i < g.links.size(); ++i) {
    if (side[g.links[i][0]] != side[g.links[i][1]]) c += g.weight[i];
  }
  return c;
}

// Boost's Edmonds-Karp on the same graph with explicit terminals: the max-flow value.
double Oracle(const Graph& g) {
  using Traits = boost::adjacency_list_traits<boost::vecS, boost::vecS, boost::directedS>;
  using G = boost::adjacency_list<
      boost::vecS, boost::vecS, boost::directedS, boost::no_property,
      boost::property<boost::edge_capacity_t, double,
                      boost::property<boost::edge_residual_capacity_t, double,
                                      boost::property<boost::edge_reverse_t, Traits::edge_descriptor>>>>;
  G bg(g.n + 2);
  auto capm = boost::get(boost::edge_capacity, bg);
  auto revm = boost::get(boost::edge_reverse, bg);
  auto add = [&](size_t a, size_t b, double c, double back) {
    auto e = boost::add_edge(a, b, bg).first, r = boost::add_edge(b, a, bg).first;
    capm[e] = c;
    capm[r] = back;
    revm[e] = r;
    revm[r] = e;
  };
  const size_t s = g.n, t = g.n + 1;
  for (size_t v = 0; v < g.n; ++v) {
    add(s, v, g.src[v], 0);
    add(v, t, g.snk[v], 0);
  }
  for (size_t i = 0; i < g.links.size(); ++i) {
    add(g.links[i][0], g.links[i][1], g.weight[i], g.weight[i]);
  }
  return boost::edmonds_karp_max_flow(bg, s, t);
}

std::vector<bool> Sides(const MaxFlow& f, size_t n) {
  std::vector<bool> side(n);
  for (size_t v = 0; v < n; ++v) side[v] = f.SourceSide(static_cast<uint32_t>(v));
  return side;
}

TEST(MaxFlowTest, ColdCutIsMinimumOnRandomGraphs) {
  std::mt19937 rng(20261125);
  for (int round = 0; round < 100; ++round) {
    Graph g = RandomGraph(rng, 12 + round % 7, 9 + round % 5);
    auto f = Make(g);
    for (size_t v = 0; v < g.n; ++v) f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
    f->Solve();
    EXPECT_EQ(f->CheckTrees(), "");
    EXPECT_DOUBLE_EQ(CutCost(g, Sides(*f, g.n)), Oracle(g)) << "round " << round;
  }
}

TEST(MaxFlowTest, WarmCutAfterTerminalChangesIsMinimum) {
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> term(0, 12), coin(0, 3);
  for (int round = 0; round < 100; ++round) {
    Graph g = RandomGraph(rng, 14, 10);
    auto f = Make(g);
    for (size_t v = 0; v < g.n; ++v) f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
    f->Solve();
    // Several rounds of changes, as strokes and retrained colour models bring: some nodes
    // change a little, some become hard constraints, some flip their preference.
    for (int step = 0; step < 3; ++step) {
      for (size_t v = 0; v < g.n; ++v) {
        switch (coin(rng)) {
          case 0: break;
          case 1: g.src[v] = static_cast<float>(term(rng)); break;
          case 2: g.snk[v] = static_cast<float>(term(rng)); break;
          default:
            if (v % 7 == 0) g.src[v] = 1000, g.snk[v] = 0;
        }
        f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
      }
      f->Solve();
      EXPECT_EQ(f->CheckTrees(), "");
      EXPECT_DOUBLE_EQ(CutCost(g, Sides(*f, g.n)), Oracle(g)) << "round " << round << " step " << step;
    }
  }
}

// Blocks solved on all cores first, then coarser blocks, then the whole graph (what the graph
// cut does on a large region): the same minimum, cold and after terminal changes.
TEST(MaxFlowTest, BlocksThenWholeGraphIsMinimum) {
  std::mt19937 rng(1125);
  std::uniform_int_distribution<int> term(0, 12);
  for (int round = 0; round < 40; ++round) {
    Graph g = RandomGraph(rng, 30 + round % 5, 20 + round % 3);
    const uint32_t n = static_cast<uint32_t>(g.n);
    auto f = Make(g);
    f->set_levels({{0, n / 6, n / 3, n / 2, 2 * n / 3, 5 * n / 6}, {0, n / 2}});
    for (size_t v = 0; v < g.n; ++v) f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
    f->Solve();
    EXPECT_EQ(f->CheckTrees(), "");
    EXPECT_DOUBLE_EQ(CutCost(g, Sides(*f, g.n)), Oracle(g)) << "round " << round;
    for (size_t v = 0; v < g.n; v += 3) {
      g.src[v] = static_cast<float>(term(rng));
      f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
    }
    f->Solve();
    EXPECT_EQ(f->CheckTrees(), "");
    EXPECT_DOUBLE_EQ(CutCost(g, Sides(*f, g.n)), Oracle(g)) << "round " << round << ", warm";
  }
}

// Coarser levels continue from the finer levels' search trees (ReuseTrees) with one clock
// across blocks that ran in parallel: still the minimum, with consistent trees, over many
// re-cuts that change every terminal (as a retrained colour model does), on uneven blocks.
TEST(MaxFlowTest, CoarserLevelsKeepTheFinerTreesOverManyReCuts) {
  std::mt19937 rng(20261203);
  std::uniform_int_distribution<int> term(0, 12);
  for (int round = 0; round < 16; ++round) {
    Graph g = RandomGraph(rng, 40 + round % 7, 24 + round % 4);
    const uint32_t n = static_cast<uint32_t>(g.n);
    auto f = Make(g);
    // Nested levels, or (odd rounds) a last level whose edge at n / 2 cuts a block of the
    // level before: that one starts its trees afresh.
    if (round % 2 == 0) {
      f->set_levels({{0, 3, n / 5, n / 4, n / 2, n / 2 + 1, 3 * n / 4}, {0, n / 4, n / 2}, {0, n / 2}});
    } else {
      f->set_levels({{0, 3, n / 5, n / 4, n / 2, n / 2 + 1, 3 * n / 4}, {0, n / 4, 3 * n / 4}, {0, n / 2}});
    }
    for (int step = 0; step < 4; ++step) {
      for (size_t v = 0; v < g.n; ++v) {
        if (step > 0 && (v + step) % 2 == 0) {
          g.src[v] = static_cast<float>(term(rng));
          g.snk[v] = static_cast<float>(term(rng));
        }
        f->SetTerminals(static_cast<uint32_t>(v), g.src[v], g.snk[v]);
      }
      f->Solve();
      ASSERT_EQ(f->CheckTrees(), "") << "round " << round << " step " << step;
      EXPECT_DOUBLE_EQ(CutCost(g, Sides(*f, g.n)), Oracle(g)) << "round " << round << " step " << step;
    }
  }
}

}  // namespace
}  // namespace hvdb::edit
