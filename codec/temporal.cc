#include "codec/temporal.h"

#include <algorithm>
#include <cmath>

#include <nanoflann.hpp>

namespace hvdb::codec {
namespace {

// Grid coordinates are integers below 2^31, exact in double: every build finds the same
// neighbours, which the decoder must.
struct Cloud {
  std::vector<double> xyz;
  size_t kdtree_get_point_count() const { return xyz.size() / 3; }
  double kdtree_get_pt(uint32_t i, size_t d) const { return xyz[3 * i + d]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const { return false; }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Cloud>,
                                                   Cloud, 3, uint32_t>;

}  // namespace

struct TemporalIndex::Tree {
  Cloud cloud;
  std::unique_ptr<KdTree> index;
};

TemporalIndex::TemporalIndex(std::span<const Point> reference, const Quantizer& q)
    : tree_(std::make_unique<Tree>()) {
  values_.Resize(reference.size(), q.attributes);
  tree_->cloud.xyz.resize(3 * reference.size());
  int64_t c[kChannels];
  for (size_t i = 0; i < reference.size(); ++i) {
    q.ToChannels(reference[i], c);
    for (int ch = 0; ch < kChannels; ++ch) {
      if (!values_.ch[ch].empty()) values_.ch[ch][i] = c[ch];
    }
    for (int a = 0; a < 3; ++a) tree_->cloud.xyz[3 * i + a] = static_cast<double>(c[a]);
  }
  if (reference.empty()) return;
  tree_->index = std::make_unique<KdTree>(3, tree_->cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  // Spacing from every k-th point (deterministic).
  std::vector<double> d;
  size_t stride = std::max<size_t>(1, reference.size() / 1000);
  for (size_t i = 0; i < reference.size(); i += stride) {
    uint32_t idx[2];
    double dist[2];
    nanoflann::KNNResultSet<double, uint32_t> rs(2);
    rs.init(idx, dist);
    tree_->index->findNeighbors(rs, &tree_->cloud.xyz[3 * i], nanoflann::SearchParams());
    if (rs.size() == 2) d.push_back(std::sqrt(dist[1]));
  }
  if (!d.empty()) {
    std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
    spacing_ = std::max(1.0, d[d.size() / 2]);
  }
}

TemporalIndex::~TemporalIndex() = default;

void TemporalIndex::Hints(LevelState& L, size_t b, size_t e) const {
  if (!tree_->index) return;
  // A child at level k-1 averages 2^(k-1) samples; the reference point that predicts it must
  // lie within a few of that level's spacings.
  double reach = 2.0 * spacing_;
  for (int k = 1; k < L.k; ++k) reach *= 1.4142135623730951;
  const double reach2 = reach * reach + 1.0;
  ParallelRange(e - b, [&](size_t lo, size_t hi) {
    for (size_t i = b + lo; i < b + hi; ++i) {
      TemporalHint h;
      if (i != L.singleton) {
        double child[2][3];
        for (int a = 0; a < 3; ++a) {
          int64_t ca, cb;
          Unlift(L.cur->ch[a][i], L.det.ch[a][i], &ca, &cb);
          child[0][a] = static_cast<double>(ca);
          child[1][a] = static_cast<double>(cb);
        }
        uint32_t idx[2];
        bool ok = true, exact = true;
        for (int j = 0; j < 2 && ok; ++j) {
          // The nearest reference point; among equally near ones the lowest index, so that
          // any decoder finds the same one (docs/CODEC.md).
          uint32_t cand[4];
          double dist[4];
          nanoflann::KNNResultSet<double, uint32_t> rs(4);
          rs.init(cand, dist);
          tree_->index->findNeighbors(rs, child[j], nanoflann::SearchParams());
          ok = rs.size() >= 1 && dist[0] <= reach2;
          if (!ok) break;
          exact = exact && dist[0] == 0;
          idx[j] = cand[0];
          for (size_t c = 1; c < rs.size() && dist[c] == dist[0]; ++c) idx[j] = std::min(idx[j], cand[c]);
        }
        if (ok) h.a = idx[0], h.b = idx[1], h.exact = exact;
      }
      L.hints[i] = h;
    }
  }, L.threads);
}

}  // namespace hvdb::codec
