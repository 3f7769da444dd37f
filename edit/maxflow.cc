#include "edit/maxflow.h"

#include <algorithm>
#include <atomic>
#include <limits>
#include <tuple>
#include <thread>

namespace hvdb::edit {

namespace {
std::vector<MaxFlow::Arc> Arcs(const std::vector<uint32_t>& head, const std::vector<uint32_t>& twin,
                               const std::vector<float>& cap) {
  std::vector<MaxFlow::Arc> arcs(head.size());
  for (size_t a = 0; a < head.size(); ++a) arcs[a] = {head[a], twin[a], cap[a], cap[twin[a]]};
  return arcs;
}
}  // namespace

MaxFlow::MaxFlow(std::vector<uint32_t> start, std::vector<uint32_t> head,
                 std::vector<uint32_t> twin, std::vector<float> cap)
    : MaxFlow(std::move(start), Arcs(head, twin, cap)) {}

MaxFlow::MaxFlow(std::vector<uint32_t> start, std::vector<Arc> arcs)
    : start_(std::move(start)), arc_(std::move(arcs)) {
  const size_t n = start_.size() - 1;
  node_.resize(n);
  to_src_.assign(n, 0);
  to_snk_.assign(n, 0);
}

void MaxFlow::SetTerminals(uint32_t v, float to_source, float to_sink) {
  // A flow already through v's terminal links stays: only the change of capacity moves v's
  // residual (and possibly turns it from the source's side to the sink's), which changes the
  // energy of every cut by the same constant (Kohli & Torr's reparametrisation).
  node_[v].tr += (to_source - to_src_[v]) - (to_sink - to_snk_[v]);
  to_src_[v] = to_source;
  to_snk_[v] = to_sink;
}

void MaxFlow::Activate(Search& s, uint32_t v) {
  // The queue of active nodes is a list threaded through the nodes (as in Kolmogorov's own
  // implementation): no allocation, and the node is in cache when it is queued.
  Node& nd = node_[v];
  if (nd.active) return;
  nd.active = 1;
  nd.next = kFree;
  if (s.tail == kFree) {
    s.head = v;
  } else {
    node_[s.tail].next = v;
  }
  s.tail = v;
}

void MaxFlow::PopActive(Search& s) {
  const uint32_t v = s.head;
  s.head = node_[v].next;
  if (s.head == kFree) s.tail = kFree;
  node_[v].active = 0;
}

void MaxFlow::Orphan(Search& s, uint32_t v, bool front) {
  node_[v].parent = kOrphan;
  if (front) {
    s.orphans.push_front(v);
  } else {
    s.orphans.push_back(v);
  }
}

void MaxFlow::StartTrees(Search& s) {
  // Paths of one link first, source -> v -> u -> sink, without any tree: in a graph cut most
  // of the flow goes between neighbours whose colour models disagree, and pushing it here
  // in one pass over the arcs spares the trees that many short augmentations (0.34 M instead
  // of 0.49 M on issue 15's real scene, max-flow 1.9 s instead of 3.1 s).
  for (uint32_t v = s.lo; v < s.hi; ++v) {
    for (uint32_t a = start_[v]; a < start_[v + 1] && node_[v].tr > 0; ++a) {
      const uint32_t u = arc_[a].head;
      if (!s.Has(u) || node_[u].tr >= 0 || arc_[a].rcap <= 0) continue;
      const float b = std::min({node_[v].tr, -node_[u].tr, arc_[a].rcap});
      node_[v].tr -= b;
      node_[u].tr += b;
      Push(a, b);
    }
  }
  // Time stamps start afresh (s.time: 1, see Solve): ones left by an earlier search (another
  // block's, or the last cut's) must not pass for this search's marks.
  for (uint32_t v = s.lo; v < s.hi; ++v) {
    Node& nd = node_[v];
    nd.active = 0;
    nd.ts = 0;
    if (nd.tr != 0) {
      nd.sink = nd.tr < 0;
      nd.parent = kTerminal;
      nd.ts = s.time;
      nd.dist = 1;
      Activate(s, v);
    } else {
      nd.parent = kFree;
    }
  }
}

void MaxFlow::ReuseTrees(Search& s, size_t threads) {
  // The trees the searches of the blocks below left are trees of this search too (blocks share
  // no node and no arc, and each ended with nothing left to grow inside it): only a tree node
  // with a residual arc into this search's range that leads out of its own tree (necessarily
  // across a block boundary) can still grow, so only those are active. Free nodes have no
  // terminal residual (a search's invariant), so nothing else is a root. The scan reads every
  // arc of the range: on all cores when the range is the whole graph (one search, nothing else
  // running), then the nodes found are queued in order.
  auto grows = [&](uint32_t v) {
    const Node& nd = node_[v];
    if (nd.parent == kFree) return false;
    for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
      const uint32_t u = arc_[a].head;
      if (!s.Has(u) || (nd.sink ? arc_[a].rrev : arc_[a].rcap) <= 0) continue;
      if (node_[u].parent == kFree || node_[u].sink != nd.sink) return true;
    }
    return false;
  };
  const uint32_t len = s.hi - s.lo;
  const size_t parts = len < (1u << 16) ? 1 : threads;
  std::vector<std::vector<uint32_t>> found(parts);
  auto scan = [&](size_t p) {
    const uint32_t lo = s.lo + static_cast<uint32_t>(uint64_t{len} * p / parts);
    const uint32_t hi = s.lo + static_cast<uint32_t>(uint64_t{len} * (p + 1) / parts);
    for (uint32_t v = lo; v < hi; ++v) {
      if (grows(v)) found[p].push_back(v);
    }
  };
  std::vector<std::thread> pool;
  for (size_t p = 1; p < parts; ++p) pool.emplace_back(scan, p);
  scan(0);
  for (auto& th : pool) th.join();
  for (const auto& f : found) {
    for (uint32_t v : f) Activate(s, v);
  }
}

void MaxFlow::Solve() {
  // The flow found so far is kept (a re-cut continues from it); the first level's search
  // trees are grown afresh, as terminals may have changed. Reusing the last cut's trees
  // (Kolmogorov's "reuse trees") was measured slower for a re-cut: retrained colour models
  // change every node's terminal links, so every node is revisited anyway, without the
  // one-link pre-pass that cancels most of the change (issue 15's real scene: 2.6 s and
  // 0.24 M augmentations against 0.53 s and 0.07 M).
  //
  // Blocks first (set_levels), on all cores: the graph cut numbers its nodes by place, so a block
  // of consecutive nodes is a compact piece of the scene, and most of the flow goes between
  // nearby nodes. Each block's max-flow with the arcs that leave it held at zero is a flow of
  // the whole graph (blocks share no node and no arc), so the coarser blocks and then the whole
  // graph continue from it and only route what must cross between blocks; a block's nodes and
  // arcs also stay in the cache while it is solved. A coarser level also keeps the finer one's
  // search trees and starts from the nodes on block boundaries (ReuseTrees): growing the trees
  // of the whole graph afresh was a serial pass over every arc, 190 ms of a re-cut on issue
  // 15's real scene (1.2 M points) when nothing was left to route.
  //
  // Kolmogorov's time stamps need one clock for trees that outlive a search: blocks of a level
  // run in parallel with clocks from the same start, and afterwards each block's stamps are
  // shifted past the blocks before it, as if the blocks had run one after another.
  const uint32_t n = static_cast<uint32_t>(node_.size());
  const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  std::vector<std::vector<uint32_t>> levels = levels_;
  levels.push_back({0});  // the whole graph
  for (size_t l = 0; l < levels.size(); ++l) {
    const std::vector<uint32_t>& level = levels[l];
    // Trees are kept when each block is made of whole blocks of the level before (a tree
    // reaching over a block's edge would be changed by two searches at once). A fresh start
    // wipes every stamp (the levels cover every node); so does a clock near its end.
    bool reuse = l > 0 && clock_ <= (1u << 30) &&
                 std::includes(levels[l - 1].begin(), levels[l - 1].end(), level.begin(), level.end());

    const uint32_t base = reuse ? clock_ + 1 : 1;
    std::vector<uint32_t> ends(level.size(), base);
    std::atomic<size_t> next{0};
    std::atomic<uint64_t> augs{0};
    auto block = [&](size_t b) { return std::make_pair(level[b], b + 1 < level.size() ? level[b + 1] : n); };
    auto work = [&] {
      Search s;
      for (size_t b; (b = next++) < level.size();) {
        std::tie(s.lo, s.hi) = block(b);
        s.time = base;
        augs += Run(s, reuse, level.size() == 1 ? threads : 1);
        ends[b] = s.time;
      }
    };
    std::vector<std::thread> pool;
    for (size_t t = 1; t < std::min(threads, level.size()); ++t) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
    augmentations_ += augs;
    std::vector<uint32_t> shift(level.size(), 0);
    uint64_t total = 0;  // the stamps the level used, all blocks together
    for (size_t b = 0; b < level.size(); ++b) total += uint64_t{ends[b]} - base + 1;
    if (base + total > (uint64_t{1} << 31)) {
      clock_ = ~uint32_t{0};  // too many to restamp: the next level starts afresh
      continue;
    }
    for (size_t b = 1; b < level.size(); ++b) shift[b] = shift[b - 1] + (ends[b - 1] - base + 1);
    clock_ = ends.back() + shift.back();
    if (level.size() > 1) {
      next = 0;
      auto restamp = [&] {
        for (size_t b; (b = next++) < level.size();) {
          const auto [lo, hi] = block(b);
          for (uint32_t v = lo; v < hi; ++v) {
            if (node_[v].ts >= base) node_[v].ts += shift[b];
          }
        }
      };
      pool.clear();
      for (size_t t = 1; t < std::min(threads, level.size()); ++t) pool.emplace_back(restamp);
      restamp();
      for (auto& th : pool) th.join();
    }
  }
}

uint64_t MaxFlow::Run(Search& s, bool reuse, size_t threads) {
  uint64_t augmentations = 0;
  s.head = s.tail = kFree;
  s.orphans.clear();
  if (reuse) {
    ReuseTrees(s, threads);
  } else {
    StartTrees(s);
  }
  for (;;) {
    while (s.head != kFree && node_[s.head].parent == kFree) PopActive(s);  // freed while waiting
    if (s.head == kFree) break;
    const uint32_t v = s.head;
    // Grow v's tree by one layer, or find an arc into the other tree.
    uint32_t mid = kFree;
    const bool src = !node_[v].sink;
    for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
      if ((src ? arc_[a].rcap : arc_[a].rrev) <= 0) continue;
      const uint32_t u = arc_[a].head;
      if (!s.Has(u)) continue;
      if (node_[u].parent == kFree) {
        node_[u].sink = !src;
        node_[u].parent = arc_[a].twin;
        node_[u].ts = node_[v].ts;
        node_[u].dist = node_[v].dist + 1;
        Activate(s, u);
      } else if (node_[u].sink == src) {
        mid = src ? a : arc_[a].twin;
        break;
      } else if (node_[u].ts <= node_[v].ts && node_[u].dist > node_[v].dist) {
        // Kolmogorov's heuristic: a shorter path to the terminal through v.
        node_[u].parent = arc_[a].twin;
        node_[u].ts = node_[v].ts;
        node_[u].dist = node_[v].dist + 1;
      }
    }
    ++s.time;
    if (mid == kFree) {
      PopActive(s);  // v has no more to give
      continue;
    }
    // v stays at the front: it may lead to more paths.
    Augment(s, mid);
    ++augmentations;
    while (!s.orphans.empty()) {
      const uint32_t o = s.orphans.front();
      s.orphans.pop_front();
      Adopt(s, o);
    }
  }
  return augmentations;
}

void MaxFlow::Augment(Search& s, uint32_t mid) {
  const uint32_t tail = arc_[arc_[mid].twin].head, tip = arc_[mid].head;
  // The bottleneck along source -> tail -> tip -> sink.
  float b = arc_[mid].rcap;
  uint32_t v = tail;
  for (uint32_t a; (a = node_[v].parent) != kTerminal; v = arc_[a].head) b = std::min(b, arc_[a].rrev);
  b = std::min(b, node_[v].tr);
  v = tip;
  for (uint32_t a; (a = node_[v].parent) != kTerminal; v = arc_[a].head) b = std::min(b, arc_[a].rcap);
  b = std::min(b, -node_[v].tr);
  // Push it; a saturated link makes its lower end an orphan.
  Push(mid, b);
  for (v = tail;;) {
    const uint32_t a = node_[v].parent;
    if (a == kTerminal) {
      node_[v].tr -= b;
      if (node_[v].tr <= 0) Orphan(s, v, true);
      break;
    }
    Push(arc_[a].twin, b);  // towards v, from its parent
    const uint32_t up = arc_[a].head;
    if (arc_[a].rrev <= 0) Orphan(s, v, true);
    v = up;
  }
  for (v = tip;;) {
    const uint32_t a = node_[v].parent;
    if (a == kTerminal) {
      node_[v].tr += b;
      if (node_[v].tr >= 0) Orphan(s, v, true);
      break;
    }
    Push(a, b);  // from v to its parent
    const uint32_t up = arc_[a].head;
    if (arc_[a].rcap <= 0) Orphan(s, v, true);
    v = up;
  }
}

void MaxFlow::Adopt(Search& s, uint32_t v) {
  const bool src = !node_[v].sink;
  constexpr uint32_t kInfinite = std::numeric_limits<uint32_t>::max();
  uint32_t best = kFree, dmin = kInfinite;
  // A new parent: a neighbour in the same tree with residual capacity towards v whose own
  // path leads to the terminal (not through another orphan), the one nearest the terminal.
  for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
    if ((src ? arc_[a].rrev : arc_[a].rcap) <= 0) continue;
    const uint32_t u = arc_[a].head;
    if (!s.Has(u) || node_[u].sink != !src || node_[u].parent == kFree) continue;
    uint32_t d = 0, k = u;
    bool rooted = true;
    for (;;) {
      if (node_[k].ts == s.time) {
        d += node_[k].dist;
        break;
      }
      const uint32_t p = node_[k].parent;
      ++d;
      if (p == kTerminal) {
        node_[k].ts = s.time;
        node_[k].dist = 1;
        break;
      }
      if (p == kOrphan) {
        rooted = false;
        break;
      }
      k = arc_[p].head;
    }
    if (!rooted) continue;
    if (d < dmin) {
      best = a;
      dmin = d;
    }
    for (k = u; node_[k].ts != s.time; k = arc_[node_[k].parent].head) {  // mark the path for later checks
      node_[k].ts = s.time;
      node_[k].dist = d--;
    }
  }
  if (best != kFree) {
    node_[v].parent = best;
    node_[v].ts = s.time;
    node_[v].dist = dmin + 1;
    return;
  }
  // None: v leaves its tree; its children become orphans, and neighbours that could grow
  // into it again become active.
  node_[v].parent = kFree;
  for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
    const uint32_t u = arc_[a].head;
    if (!s.Has(u)) continue;
    const uint32_t p = node_[u].parent;
    if (node_[u].sink != !src || p == kFree) continue;
    if ((src ? arc_[a].rrev : arc_[a].rcap) > 0) Activate(s, u);
    if (p != kTerminal && p != kOrphan && arc_[p].head == v) Orphan(s, u, false);
  }
}

std::string MaxFlow::CheckTrees() const {
  const uint32_t n = static_cast<uint32_t>(node_.size());
  for (uint32_t v = 0; v < n; ++v) {
    if (node_[v].parent == kFree) continue;
    uint32_t k = v, steps = 0;
    while (node_[k].parent != kTerminal) {
      const uint32_t p = node_[k].parent;
      if (p == kOrphan) return "node " + std::to_string(v) + ": an orphan on its path";
      const uint32_t up = arc_[p].head;
      if (node_[up].sink != node_[k].sink) return "node " + std::to_string(k) + ": parent in the other tree";
      const float r = node_[k].sink ? arc_[p].rcap : arc_[p].rrev;
      if (r <= 0) return "node " + std::to_string(k) + ": saturated parent arc";
      k = up;
      if (++steps > n) return "node " + std::to_string(v) + ": a cycle";
    }
    if (node_[k].sink ? node_[k].tr >= 0 : node_[k].tr <= 0) {
      return "root " + std::to_string(k) + ": no terminal residual";
    }
  }
  // Maximal: no residual arc leaves the source tree or enters the sink tree, and no node
  // outside a tree keeps a terminal residual.
  for (uint32_t v = 0; v < n; ++v) {
    if (node_[v].parent == kFree) {
      if (node_[v].tr != 0) return "free node " + std::to_string(v) + " with a terminal residual";
      continue;
    }
    for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
      const uint32_t u = arc_[a].head;
      const bool out = !node_[v].sink && arc_[a].rcap > 0 && (node_[u].parent == kFree || node_[u].sink);
      const bool in = node_[v].sink && arc_[a].rrev > 0 && (node_[u].parent == kFree || !node_[u].sink);
      if (out || in) {
        return "node " + std::to_string(v) + (out ? ": residual out of the source tree to "
                                                  : ": residual into the sink tree from ") +
               std::to_string(u) + (node_[u].parent == kFree ? " (free)" : "");
      }
    }
  }
  return "";
}

}  // namespace hvdb::edit
