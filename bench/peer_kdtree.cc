#include "bench/peer_kdtree.h"

#include <nanoflann.hpp>

namespace hvdb::bench {

namespace {

struct Adaptor {
  const std::vector<Point>* pts;
  size_t kdtree_get_point_count() const { return pts->size(); }
  float kdtree_get_pt(size_t idx, size_t dim) const {
    const Point& p = (*pts)[idx];
    return dim == 0 ? p.x : dim == 1 ? p.y : p.z;
  }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const {
    return false;
  }
};

using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Adaptor>,
                                                  Adaptor, 3, uint32_t>;

}  // namespace

struct KdTreePeer::Impl {
  Adaptor adaptor;
  std::unique_ptr<Index> index;
};

KdTreePeer::KdTreePeer(const std::vector<Point>& pts, size_t leaf_size)
    : impl_(std::make_unique<Impl>()) {
  impl_->adaptor.pts = &pts;
  impl_->index = std::make_unique<Index>(3, impl_->adaptor,
                                         nanoflann::KDTreeSingleIndexAdaptorParams(leaf_size));
}

KdTreePeer::~KdTreePeer() = default;

// nanoflann answers k-NN and radius queries; a box query walks its tree directly: the left
// child holds points with coordinate <= divlow, the right child >= divhigh.
uint64_t KdTreePeer::Box(const double lo[3], const double hi[3], std::vector<Point>* out) const {
  const Index& ix = *impl_->index;
  const std::vector<Point>& pts = *impl_->adaptor.pts;
  const size_t before = out->size();
  if (ix.root_node == nullptr) return 0;
  const Index::Node* stack[128];
  int top = 0;
  stack[top++] = ix.root_node;
  while (top > 0) {
    const Index::Node* n = stack[--top];
    if (n->child1 == nullptr && n->child2 == nullptr) {
      for (size_t i = n->node_type.lr.left; i < n->node_type.lr.right; ++i) {
        const Point& p = pts[ix.vAcc[i]];
        if (p.x >= lo[0] && p.x <= hi[0] && p.y >= lo[1] && p.y <= hi[1] && p.z >= lo[2] &&
            p.z <= hi[2]) {
          out->push_back(p);
        }
      }
      continue;
    }
    const int f = n->node_type.sub.divfeat;
    if (hi[f] >= n->node_type.sub.divhigh) stack[top++] = n->child2;
    if (lo[f] <= n->node_type.sub.divlow) stack[top++] = n->child1;
  }
  return out->size() - before;
}

}  // namespace hvdb::bench
