// 4D graph-cut object selection (thesis 9.3.2, eqs. 9.1-9.6).
//
// Nodes are the points of a region of interest over one or more frames. Intra-frame arcs join
// each point to its k nearest neighbours within `intra_radius` in its frame; inter-frame arcs
// join it to its k/2 nearest within `inter_radius` in frame t+1 (and so, from the other side,
// t-1). Arcs between evidently unrelated points (colour or normal difference above a threshold)
// are left out. Foreground and background strokes seed two colour GMMs (OpenCV EM, 5 full-
// covariance components); the energy (9.1) is minimised by Boykov-Kolmogorov max-flow
// (Boost.Graph).
#ifndef HVDB_EDIT_GRAPH_CUT_H_
#define HVDB_EDIT_GRAPH_CUT_H_

#include <cstdint>
#include <vector>

#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::edit {

struct GraphCutParams {
  int k = 8;                    // intra-frame neighbours; inter-frame uses k / 2
  double intra_radius = 0.02;   // metres
  double inter_radius = 0.04;   // metres
  double max_color_diff = 0.10;   // arcs with a larger normalised colour difference are dropped
  double max_normal_diff = 0.10;  // ... or normal difference (|n_i - n_j| / 2)
  int gmm_components = 5;
  double beta_c = 0.08, beta_n = 0.12;  // eq. 9.6
  double lambda_d = 1.0, lambda_i = 1.0, lambda_t = 1.0;  // eq. 9.1
  bool use_normals = true;  // false: colour-only link costs (for comparison)
};

enum class Seed : uint8_t { kUnknown = 0, kForeground = 1, kBackground = 2 };

struct GraphCutResult {
  std::vector<uint8_t> selected;  // per input point: 1 = in the selection
  double energy = 0;              // the minimum of E_A (= the max flow)
  uint64_t intra_edges = 0, inter_edges = 0;
  double neighbours_ms = 0, gmm_ms = 0, graph_ms = 0, maxflow_ms = 0;
};

// `points` may span several frames (their frame field); `seeds` has one entry per point.
// Needs at least one foreground and one background seed.
Result<GraphCutResult> RunGraphCut(const std::vector<Point>& points, const std::vector<Seed>& seeds,
                                   const GraphCutParams& params = {});

}  // namespace hvdb::edit

#endif  // HVDB_EDIT_GRAPH_CUT_H_
