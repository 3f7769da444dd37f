#include "edit/maxflow.h"

#include <algorithm>
#include <atomic>
#include <limits>
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
  // Time stamps start afresh: ones left by an earlier search (another block's, or the last
  // cut's) must not pass for this search's marks.
  s.time = 1;
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

void MaxFlow::Solve() {
  // The flow found so far is kept (a re-cut continues from it); the search trees are grown
  // afresh. Reusing them too (Kolmogorov's "reuse trees") was measured slower for a re-cut:
  // retrained colour models change every node's terminal links, so every node is revisited
  // anyway, without the one-link pre-pass that cancels most of the change (issue 15's real
  // scene: 2.6 s and 0.24 M augmentations against 0.53 s and 0.07 M).
  //
  // Blocks first (set_levels), on all cores: the graph cut numbers its nodes by place, so a block
  // of consecutive nodes is a compact piece of the scene, and most of the flow goes between
  // nearby nodes. Each block's max-flow with the arcs that leave it held at zero is a flow of
  // the whole graph (blocks share no node and no arc), so the whole graph's search continues
  // from it and only routes what must cross between blocks; a block's nodes and arcs also
  // stay in the cache while it is solved.
  const uint32_t n = static_cast<uint32_t>(node_.size());
  const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  for (const std::vector<uint32_t>& level : levels_) {
    std::atomic<size_t> next{0};
    std::atomic<uint64_t> augs{0};
    auto work = [&] {
      Search s;
      for (size_t b; (b = next++) < level.size();) {
        s.lo = level[b];
        s.hi = b + 1 < level.size() ? level[b + 1] : n;
        augs += Run(s);
      }
    };
    std::vector<std::thread> pool;
    for (size_t t = 1; t < std::min(threads, level.size()); ++t) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
    augmentations_ += augs;
    }
  Search all;
  all.lo = 0;
  all.hi = n;
  augmentations_ += Run(all);
}

uint64_t MaxFlow::Run(Search& s) {
  uint64_t augmentations = 0;
  s.head = s.tail = kFree;
  s.orphans.clear();
  StartTrees(s);
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
