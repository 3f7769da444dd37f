#include "bench/peer_pcl.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <pcl/common/io.h>
#include <pcl/console/print.h>
#include <pcl/outofcore/outofcore_impl.h>
#include <pcl/point_types.h>

namespace hvdb::bench {

using PclPoint = pcl::PointXYZRGBNormal;
using Tree = pcl::outofcore::OutofcoreOctreeBase<pcl::outofcore::OutofcoreOctreeDiskContainer<PclPoint>, PclPoint>;

struct PclOctree::Impl {
  std::unique_ptr<Tree> tree;
};

namespace {

std::string RootFile(const std::string& dir) { return dir + "/tree.oct_idx"; }

[[noreturn]] void Fail(const std::string& what) {
  std::fprintf(stderr, "hvdb-bench: PCL outofcore: %s\n", what.c_str());
  std::exit(1);
}

}  // namespace

PclOctree::PclOctree(std::string dir, uint64_t depth)
    : dir_(std::move(dir)), depth_(depth), impl_(std::make_unique<Impl>()) {}

PclOctree::~PclOctree() = default;

std::unique_ptr<PclOctree> PclOctree::Build(const std::string& dir, const std::vector<Point>& pts) {
  pcl::console::setVerbosityLevel(pcl::console::L_ERROR);
  // Leaves of ~2048 points: 8^depth leaves.
  double leaves = std::max(1.0, static_cast<double>(pts.size()) / 2048.0);
  auto depth = static_cast<uint64_t>(std::max(1.0, std::round(std::log(leaves) / std::log(8.0))));
  std::unique_ptr<PclOctree> o(new PclOctree(dir, depth));
  try {
    Eigen::Vector3d lo(0, 0, 0), hi(1, 1, 1);
    o->impl_->tree = std::make_unique<Tree>(depth, lo, hi, boost::filesystem::path(RootFile(dir)),
                                            "ECEF");
    auto cloud = std::make_shared<pcl::PointCloud<PclPoint>>();
    cloud->resize(pts.size());
    for (size_t i = 0; i < pts.size(); ++i) {
      PclPoint& q = (*cloud)[i];
      const Point& p = pts[i];
      q.x = p.x;
      q.y = p.y;
      q.z = p.z;
      q.r = p.r;
      q.g = p.g;
      q.b = p.b;
      auto n = DecodeNormal(p.normal_oct);
      q.normal_x = n[0];
      q.normal_y = n[1];
      q.normal_z = n[2];
      q.curvature = 0;
    }
    o->impl_->tree->addPointCloud_and_genLOD(cloud);
    o->impl_->tree.reset();  // flushes every node to disk and writes the metadata
  } catch (const std::exception& e) {
    Fail(std::string("build: ") + e.what());
  }
  return o;
}

void PclOctree::Reopen() {
  try {
    impl_->tree.reset();
    impl_->tree = std::make_unique<Tree>(boost::filesystem::path(RootFile(dir_)), true);
  } catch (const std::exception& e) {
    Fail(std::string("open: ") + e.what());
  }
}

uint64_t PclOctree::Box(const double lo[3], const double hi[3]) {
  return BoxAtDepth(lo, hi, depth_);
}

uint64_t PclOctree::BoxAtDepth(const double lo[3], const double hi[3], uint64_t depth) {
  Tree::AlignedPointTVector out;
  try {
    impl_->tree->queryBBIncludes(Eigen::Vector3d(lo[0], lo[1], lo[2]),
                                 Eigen::Vector3d(hi[0], hi[1], hi[2]), depth, out);
  } catch (const std::exception& e) {
    Fail(std::string("query: ") + e.what());
  }
  return out.size();
}

}  // namespace hvdb::bench
