// The multiresolution hierarchy inside one bucket (thesis 8.4, fig. 8.10).
//
// The points of a bucket are sorted by a kd-tree of bucket size 1 whose left child always
// holds a power of two of points, so positions 2j and 2j+1 are a pair of similar points,
// 4j..4j+3 a pair of pairs, and so on. The point at position m then belongs to level
// min(trailing_ones(m), l): every second point goes one level up. Level k holds about
// n / 2^(k+1) points (the top level n / 2^l), and levels >= i together hold about n / 2^i.
//
// (The thesis prints Lambda^-i = {i + j 2^(i+1)}, which overlaps between levels; the
// trailing-ones rule is the partition its figure 8.10 draws.)
#ifndef HVDB_STORAGE_LOD_H_
#define HVDB_STORAGE_LOD_H_

#include <bit>
#include <cstdint>
#include <span>
#include <vector>

#include "storage/point.h"

namespace hvdb {

inline int LevelOfRank(uint64_t m, int max_level) {
  int ones = std::countr_one(m);
  return ones < max_level ? ones : max_level;
}

// Level of a point held outside any tree (the in-memory buffer T0): a hash of its id stands
// in for its rank, which gives the same level proportions.
int LevelOfId(uint64_t id, int max_level);

// A point's position and its index into the caller's points: the in-bucket order moves these
// 16-byte records, not 64-byte points (the tree builder gathers the points once, at the end).
struct OrderRec {
  float c[3];
  uint32_t idx;
};

// Reorders `recs` by the bucket-size-1 kd-tree (split on the widest extent, ties by the id of
// points[idx]); a pair's order is left as it is (either point may go one level up). After it,
// the record at position m belongs to level LevelOfRank(m, l). Deterministic.
void KdOrder(std::span<OrderRec> recs, std::span<const Point> points);

// Orders `pts` with KdOrder and returns, for each level 0..max_level, the points of that level
// (in kd order).
std::vector<std::vector<Point>> SplitIntoLevels(std::span<Point> pts, int max_level);

}  // namespace hvdb

#endif  // HVDB_STORAGE_LOD_H_
