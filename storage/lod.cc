#include "storage/lod.h"

#include <algorithm>

namespace hvdb {

int LevelOfId(uint64_t id, int max_level) {
  // splitmix64 finaliser: well mixed low bits.
  uint64_t z = id + 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  z ^= z >> 31;
  return LevelOfRank(z, max_level);
}

namespace {

int WidestAxis(std::span<const OrderRec> recs) {
  float lo[3] = {recs[0].c[0], recs[0].c[1], recs[0].c[2]}, hi[3] = {lo[0], lo[1], lo[2]};
  for (const OrderRec& r : recs) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], r.c[a]);
      hi[a] = std::max(hi[a], r.c[a]);
    }
  }
  int best = 0;
  for (int a = 1; a < 3; ++a) {
    if (hi[a] - lo[a] > hi[best] - lo[best]) best = a;
  }
  return best;
}

}  // namespace

void KdOrder(std::span<OrderRec> recs, std::span<const Point> points) {
  const size_t n = recs.size();
  // A pair's order only picks which of two neighbours goes one level up: either is right, so
  // pairs stay as they are (half of all the calls).
  if (n <= 2) return;
  // Left child: the largest power of two below n.
  const size_t left = std::bit_floor(n - 1);
  const int axis = WidestAxis(recs);
  std::nth_element(recs.begin(), recs.begin() + static_cast<std::ptrdiff_t>(left), recs.end(),
                   [axis, points](const OrderRec& a, const OrderRec& b) {
                     return a.c[axis] < b.c[axis] ||
                            (a.c[axis] == b.c[axis] && points[a.idx].id < points[b.idx].id);
                   });
  KdOrder(recs.subspan(0, left), points);
  KdOrder(recs.subspan(left), points);
}

std::vector<std::vector<Point>> SplitIntoLevels(std::span<Point> pts, int max_level) {
  std::vector<OrderRec> recs(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    recs[i] = {{pts[i].x, pts[i].y, pts[i].z}, static_cast<uint32_t>(i)};
  }
  KdOrder(recs, pts);
  std::vector<Point> ordered(pts.size());
  for (size_t m = 0; m < recs.size(); ++m) ordered[m] = pts[recs[m].idx];
  std::copy(ordered.begin(), ordered.end(), pts.begin());
  std::vector<std::vector<Point>> levels(static_cast<size_t>(max_level) + 1);
  for (size_t m = 0; m < pts.size(); ++m) {
    levels[static_cast<size_t>(LevelOfRank(m, max_level))].push_back(pts[m]);
  }
  return levels;
}

}  // namespace hvdb
