// Fixed-radius k-nearest neighbours for the graph cut: each frame's points binned in a uniform
// grid of cubic cells, queried a cell at a time.
//
// Written here rather than with a k-d tree (nanoflann, used before): the graph cut asks, for
// every point, for a few neighbours within a radius of a couple of cell sizes. A cell's queries
// share their candidates (the points of the 27 cells around it), gathered once into contiguous
// arrays and compared with plain loops the compiler vectorises; the k-d tree walked its nodes
// again for every query (650 ns a query on issue 15's real scene, a third of a cut).
#ifndef HVDB_EDIT_NEIGHBOURS_H_
#define HVDB_EDIT_NEIGHBOURS_H_

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace hvdb::edit {

class PointGrid {
 public:
  // xyz: 3 floats per point. All grids that are queried against each other share `origin` and
  // `cell` (the edge of a cell). Points are ordered by cell (Morton order of the cells, so
  // nearby cells are mostly near in the order), within a cell by their input index.
  PointGrid(const std::vector<float>& xyz, const std::array<float, 3>& origin, float cell);
  size_t size() const { return id_.size(); }
  // The input index of the point at position j of the grid's order.
  uint32_t input(size_t j) const { return id_[j]; }

  // For every point of `queries` (by position in its order), the positions in this grid's order
  // of its up to k (at most 64) nearest points within `radius` (a few cells), nearest first
  // (ties: lower position first), excluding itself when `queries` is this grid; written to
  // out[k * j ...], padded with kNone. On all cores.
  static constexpr uint32_t kNone = 0xffffffffu;
  void Nearest(const PointGrid& queries, int k, float radius, std::vector<uint32_t>* out) const;

 private:
  struct Cell {
    int32_t x, y, z;
    uint32_t begin, end;  // positions in the order
  };
  // The cell at (x, y, z), or -1.
  int64_t Find(int32_t x, int32_t y, int32_t z) const;

  std::array<float, 3> origin_;
  float cell_;
  std::vector<uint32_t> id_;          // position -> input index
  std::vector<float> x_, y_, z_;      // coordinates by position
  std::vector<Cell> cells_;           // in order
  std::vector<uint64_t> table_keys_;  // open addressing: cell key -> cell index
  std::vector<uint32_t> table_cells_;
};

}  // namespace hvdb::edit

#endif  // HVDB_EDIT_NEIGHBOURS_H_
