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

float Coord(const Point& p, int axis) { return axis == 0 ? p.x : axis == 1 ? p.y : p.z; }

int WidestAxis(std::span<Point> pts) {
  float lo[3] = {pts[0].x, pts[0].y, pts[0].z}, hi[3] = {lo[0], lo[1], lo[2]};
  for (const Point& p : pts) {
    for (int a = 0; a < 3; ++a) {
      float v = Coord(p, a);
      lo[a] = std::min(lo[a], v);
      hi[a] = std::max(hi[a], v);
    }
  }
  int best = 0;
  for (int a = 1; a < 3; ++a) {
    if (hi[a] - lo[a] > hi[best] - lo[best]) best = a;
  }
  return best;
}

// kd-tree of bucket size 1, left child = largest power of two below n, in place.
void KdOrder(std::span<Point> pts) {
  size_t n = pts.size();
  if (n <= 1) return;
  size_t left = std::bit_floor(n - 1);
  int axis = WidestAxis(pts);
  std::nth_element(pts.begin(), pts.begin() + static_cast<std::ptrdiff_t>(left), pts.end(),
                   [axis](const Point& a, const Point& b) {
                     float ca = Coord(a, axis), cb = Coord(b, axis);
                     return ca < cb || (ca == cb && a.id < b.id);
                   });
  KdOrder(pts.subspan(0, left));
  KdOrder(pts.subspan(left));
}

}  // namespace

std::vector<std::vector<Point>> SplitIntoLevels(std::span<Point> pts, int max_level) {
  KdOrder(pts);
  std::vector<std::vector<Point>> levels(static_cast<size_t>(max_level) + 1);
  for (size_t m = 0; m < pts.size(); ++m) {
    levels[static_cast<size_t>(LevelOfRank(m, max_level))].push_back(pts[m]);
  }
  return levels;
}

}  // namespace hvdb
