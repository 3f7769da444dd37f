// Octree streams' point order and pair hierarchy, and temporal streams' reference cells
// (point_order.h).
#include "codec/point_order.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "codec/octree.h"

namespace hvdb::codec {

// Octree streams: sorts the points by the Morton code of their cell (ties keep input order)
// and returns the codes.
std::vector<uint64_t> MortonSort(Columns* base, uint32_t attrs) {
  const size_t n = base->n;
  std::vector<std::pair<uint64_t, uint32_t>> key(n);
  for (size_t i = 0; i < n; ++i) {
    key[i] = {MortonCode(static_cast<uint32_t>(base->ch[0][i]), static_cast<uint32_t>(base->ch[1][i]),
                         static_cast<uint32_t>(base->ch[2][i])),
              static_cast<uint32_t>(i)};
  }
  std::sort(key.begin(), key.end());
  Columns sorted;
  sorted.Resize(n, attrs);
  for (int c = 0; c < kChannels; ++c) {
    if (sorted.ch[c].empty()) continue;
    for (size_t i = 0; i < n; ++i) sorted.ch[c][i] = base->ch[c][key[i].second];
  }
  *base = std::move(sorted);
  std::vector<uint64_t> codes(n);
  for (size_t i = 0; i < n; ++i) codes[i] = key[i].first;
  return codes;
}

// Octree streams: the order that makes consecutive points closer partners. Walking the Morton
// order two at a time, the nearest of points i + 1 .. i + 6 to point i (the first on ties)
// swaps places with point i + 1 (the curve jumps between cells often enough for this to pay in
// the attributes' details). Applied to `codes` and, when given, to `base`'s channels; decoders
// repeat it on the decoded codes.
void PairOrder(std::vector<uint64_t>* codes, Columns* base) {
  auto dist2 = [](uint64_t a, uint64_t b) {
    uint32_t ax, ay, az, bx, by, bz;
    MortonDecode(a, &ax, &ay, &az);
    MortonDecode(b, &bx, &by, &bz);
    const int64_t dx = int64_t{ax} - bx, dy = int64_t{ay} - by, dz = int64_t{az} - bz;
    return dx * dx + dy * dy + dz * dz;
  };
  constexpr size_t kWindow = 6;
  auto& v = *codes;
  for (size_t i = 0; i + 2 < v.size(); i += 2) {
    size_t best = i + 1;
    int64_t bd = dist2(v[i], v[i + 1]);
    for (size_t j = i + 2; j < std::min(v.size(), i + 1 + kWindow); ++j) {
      const int64_t dj = dist2(v[i], v[j]);
      if (dj < bd) bd = dj, best = j;
    }
    if (best != i + 1) {
      std::swap(v[i + 1], v[best]);
      if (base) {
        for (auto& ch : base->ch) {
          if (!ch.empty()) std::swap(ch[i + 1], ch[best]);
        }
      }
    }
  }
}

// Octree streams: the pair hierarchy of consecutive points. Level k's point i is the parent of
// points 2i and 2i + 1 of level k - 1 (the last of an odd level is unpaired), so decoders know
// it without being told, and in Morton order the pairs are neighbours.
void ConsecutiveHierarchy(Columns base, int levels, uint32_t attrs, Hierarchy* h) {
  h->level.clear();
  h->pairs.assign(1, {});
  h->level.push_back(std::move(base));
  for (int k = 1; k <= levels; ++k) {
    const Columns& below = h->level[k - 1];
    const size_t m = below.n, n = (m + 1) / 2;
    Columns up;
    up.Resize(n, attrs);
    std::vector<std::array<uint32_t, 2>> pairs(n);
    for (size_t i = 0; i < n; ++i) {
      const size_t a = 2 * i, b = 2 * i + 1;
      pairs[i] = {static_cast<uint32_t>(a), b < m ? static_cast<uint32_t>(b) : kNoChild};
      for (int c = 0; c < kChannels; ++c) {
        if (up.ch[c].empty()) continue;
        up.ch[c][i] = b < m ? LiftParent(below.ch[c][a], below.ch[c][b]) : below.ch[c][a];
      }
    }
    h->pairs.push_back(std::move(pairs));
    h->level.push_back(std::move(up));
  }
}

// Decoder side of the same: positions of levels 0..levels from level 0's cells.
std::vector<std::array<std::vector<int64_t>, 3>> PositionLevels(const std::vector<uint64_t>& codes,
                                                               int levels) {
  std::vector<std::array<std::vector<int64_t>, 3>> pos(levels + 1);
  for (auto& v : pos[0]) v.resize(codes.size());
  for (size_t i = 0; i < codes.size(); ++i) {
    uint32_t x, y, z;
    MortonDecode(codes[i], &x, &y, &z);
    pos[0][0][i] = x, pos[0][1][i] = y, pos[0][2][i] = z;
  }
  for (int k = 1; k <= levels; ++k) {
    for (int a = 0; a < 3; ++a) {
      const auto& below = pos[k - 1][a];
      const size_t m = below.size(), n = (m + 1) / 2;
      auto& up = pos[k][a];
      up.resize(n);
      for (size_t i = 0; i < n; ++i) {
        up[i] = 2 * i + 1 < m ? LiftParent(below[2 * i], below[2 * i + 1]) : below[2 * i];
      }
    }
  }
  return pos;
}

// The reference frame's distinct cells on this stream's grid (temporal octree streams).
std::vector<uint64_t> ReferenceCells(std::span<const Point> ref, const Quantizer& q) {
  std::vector<uint64_t> cells(ref.size());
  ParallelRange(ref.size(), [&](size_t b, size_t e) {
    int64_t c[kChannels];
    for (size_t i = b; i < e; ++i) {
      q.ToChannels(ref[i], c);
      cells[i] = MortonCode(static_cast<uint32_t>(c[0]), static_cast<uint32_t>(c[1]),
                            static_cast<uint32_t>(c[2]));
    }
  });
  std::sort(cells.begin(), cells.end());
  cells.erase(std::unique(cells.begin(), cells.end()), cells.end());
  return cells;
}

// Whether every point lands inside the reference's grid (so the stream can share it).
bool FitsGrid(std::span<const Point> pts, const Reference& r, int qp) {
  if (!(r.step > 0) || !std::isfinite(r.step) || r.qp != qp) return false;
  const double hi = static_cast<double>((uint64_t{1} << qp) - 1) + 0.5;
  for (const Point& p : pts) {
    const float xyz[3] = {p.x, p.y, p.z};
    for (int a = 0; a < 3; ++a) {
      const double v = (xyz[a] - r.origin[a]) / r.step;
      if (!(v >= -0.5 && v < hi)) return false;
    }
  }
  return true;
}

}  // namespace hvdb::codec
