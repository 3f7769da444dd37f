// Max-flow / min-cut of the graph-cut selection: the Boykov-Kolmogorov algorithm (two search
// trees grown from the terminals, reused across augmentations) over arrays laid out by the
// graph cut, with Kolmogorov's timestamp/distance heuristic for re-attaching orphans, and a
// warm start for a re-cut: the previous flow is kept and the changed terminal capacities are
// reparametrised into it (Kohli & Torr, "Dynamic graph cuts", PAMI 2007).
//
// Written here, not Boost's boykov_kolmogorov_max_flow (used before): a re-cut after one more
// stroke must start from the previous flow, which Boost's interface cannot (it resets the
// residual capacities on every call), and a flat array layout with terminal links folded into
// one signed residual per node is what Kolmogorov's own implementation uses.
#ifndef HVDB_EDIT_MAXFLOW_H_
#define HVDB_EDIT_MAXFLOW_H_

#include <cstddef>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

namespace hvdb::edit {

class MaxFlow {
 public:
  // Arcs of node v are [start[v], start[v + 1]); arc a goes to head[a], twin[a] is its reverse
  // and cap[a] its capacity. n = start.size() - 1 nodes; no terminal nodes (see SetTerminals).
  MaxFlow(std::vector<uint32_t> start, std::vector<uint32_t> head, std::vector<uint32_t> twin,
          std::vector<float> cap);
  struct Arc {
    uint32_t head;  // the node it goes to
    uint32_t twin;  // the reverse arc
    float rcap;     // residual capacity
    // The reverse arc's residual capacity, kept here too: a sink tree grows through reverse
    // residuals, and reading them from the twin was a cache miss per arc (two thirds of the
    // search's time on issue 15's real scene).
    float rrev;
  };
  // The same with the arcs laid out already (rcap = capacity, rrev = the twin's capacity).
  MaxFlow(std::vector<uint32_t> start, std::vector<Arc> arcs);
  size_t nodes() const { return node_.size(); }
  // Node v's capacities from the source (to_source) and to the sink. The first call sets them;
  // later calls change them while keeping the flow found so far (a reparametrisation: the
  // difference goes into v's terminal residual), so that Solve() continues from there.
  void SetTerminals(uint32_t v, float to_source, float to_sink);
  // Finds a maximum flow, continuing from the flow found so far: first within each block of
  // each level (below) on all cores, then over the whole graph.
  void Solve();
  // Levels of blocks of consecutive nodes, finest first, each given as the sorted first nodes
  // of its blocks (the first 0). None by default: the whole graph at once. A level whose blocks
  // are unions of the finer level's blocks continues from that level's search trees.
  void set_levels(std::vector<std::vector<uint32_t>> levels) { levels_ = std::move(levels); }
  // After Solve: whether v is on the source side of the minimum cut.
  bool SourceSide(uint32_t v) const { return node_[v].parent != kFree && !node_[v].sink; }
  uint64_t augmentations() const { return augmentations_; }
  // For tests: "" when the search trees are consistent (every tree node's parent arcs lead to
  // its terminal through residual arcs of its own tree, without cycles), else the first fault.
  std::string CheckTrees() const;
  // The summed capacity of the links from nodes with side(v) true to nodes with it false.
  // Links are symmetric here (the graph cut's are), so a link's capacity is the mean of its
  // two residuals whatever flows through it.
  template <typename Side>
  double CutLinks(Side&& side) const {
    double sum = 0;
    for (uint32_t v = 0; v + 1 < start_.size(); ++v) {
      if (!side(v)) continue;
      for (uint32_t a = start_[v]; a < start_[v + 1]; ++a) {
        if (!side(arc_[a].head)) sum += 0.5 * (static_cast<double>(arc_[a].rcap) + arc_[a].rrev);
      }
    }
    return sum;
  }

 private:
  static constexpr uint32_t kFree = 0xffffffffu, kTerminal = 0xfffffffeu, kOrphan = 0xfffffffdu;
  // One search: the nodes [lo, hi) with the arcs among them (a block, or the whole graph),
  // its queue of active nodes, its orphans and its clock for Kolmogorov's time stamps.
  struct Search {
    uint32_t lo = 0, hi = 0;
    uint32_t head = kFree, tail = kFree;  // active nodes, a list through Node::next
    std::deque<uint32_t> orphans;
    uint32_t time = 0;
    bool Has(uint32_t v) const { return v - lo < hi - lo; }
  };
  // Max-flow within s, its clock starting at s.time; returns the augmentations. reuse: keep the
  // search trees that searches of smaller blocks inside s left (ReuseTrees, on `threads`
  // threads), else StartTrees.
  uint64_t Run(Search& s, bool reuse, size_t threads);
  void Activate(Search& s, uint32_t v);
  void PopActive(Search& s);
  void Augment(Search& s, uint32_t mid);  // mid: an arc from the source tree into the sink tree
  void Adopt(Search& s, uint32_t v);
  void Orphan(Search& s, uint32_t v, bool front);
  void StartTrees(Search& s);  // a one-link pre-pass, then every node with a terminal residual a root
  void ReuseTrees(Search& s, size_t threads);  // activates the tree nodes that can grow across block boundaries

  // Arcs and nodes as structs: the search touches all fields of one at once (a cache line
  // instead of three to six).
  void Push(uint32_t a, float b) {  // b units along arc a
    Arc& t = arc_[arc_[a].twin];
    arc_[a].rcap -= b;
    arc_[a].rrev += b;
    t.rcap += b;
    t.rrev -= b;
  }
  struct Node {
    float tr = 0;             // terminal residual: > 0 from the source, < 0 to the sink
    uint32_t parent = kFree;  // arc from v to its parent, or kFree / kTerminal / kOrphan
    uint32_t ts = 0, dist = 0;  // Kolmogorov's heuristic: time stamp, distance to terminal
    uint32_t next = 0;        // the next active node, while active
    uint8_t sink = 0;         // tree of v: 0 source, 1 sink
    uint8_t active = 0;       // v is in queue_
  };
  std::vector<uint32_t> start_;
  std::vector<Arc> arc_;
  std::vector<Node> node_;
  std::vector<float> to_src_, to_snk_;  // the capacities SetTerminals was given
  std::vector<std::vector<uint32_t>> levels_;
  uint64_t augmentations_ = 0;
  uint32_t clock_ = 0;  // the last time stamp given (Solve)
};

}  // namespace hvdb::edit

#endif  // HVDB_EDIT_MAXFLOW_H_
