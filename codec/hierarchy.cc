// The multiresolution decomposition of thesis 7.2: pair neighbouring points, contract each
// pair to its average, repeat.
//
// The thesis solves a minimum-weight perfect matching over a 12-nearest-neighbour graph
// (Cook and Rohe's blossom code). We match greedily instead, as the issue allows: candidate
// partners are a point's 8 nearest neighbours (nanoflann k-d tree; at effort 0 only its
// neighbours along a Morton curve, which keeps most true neighbours within a few places), and
// an edge is taken when it is the lightest for both of its points ("locally dominant"; the
// same 1/2-approximation as sorted greedy matching, in linear time). Unmatched points get
// further rounds over the unmatched alone; what is left is paired along the curve; then two
// passes of 2-opt move the matching toward the minimum. Edge weights follow eq. 7.1.
#include <algorithm>
#include <cmath>
#include <numeric>

#include <nanoflann.hpp>
#include <cstdlib>

#include "codec/internal.h"
#include "storage/coding.h"

namespace hvdb::codec {
namespace {

constexpr int kWindow = 6;
constexpr int kRounds = 6;
constexpr size_t kNearest = 8;
constexpr int kImprovePasses = 2;

// Float coordinates: neighbours only guide the encoder's pairing, so rounding is harmless.
struct LevelCloud {
  std::vector<float> xyz;
  size_t kdtree_get_point_count() const { return xyz.size() / 3; }
  float kdtree_get_pt(uint32_t i, size_t d) const { return xyz[3 * i + d]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const { return false; }
};
using LevelTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, LevelCloud>,
                                                      LevelCloud, 3, uint32_t>;

struct Vec3 {
  double x = 0, y = 0, z = 0;
};

// Unit normal of an octahedral pair at any quantisation (only its direction is used).
Vec3 OctNormal(int64_t u, int64_t v) {
  double x = static_cast<double>(u), y = static_cast<double>(v);
  double m = std::max(std::abs(x), std::abs(y));
  if (m == 0) return {0, 0, 1};
  // The octahedral map is scale free up to the folding at |x|+|y| = 1: normalise to the
  // largest representable magnitude of the channel first.
  double scale = std::max(1.0, std::abs(x) + std::abs(y));
  x /= scale;
  y /= scale;
  double z = 1.0 - std::abs(x) - std::abs(y);
  if (z < 0) {
    double ox = x;
    x = (1.0 - std::abs(y)) * (ox >= 0 ? 1 : -1);
    y = (1.0 - std::abs(ox)) * (y >= 0 ? 1 : -1);
  }
  double len = std::sqrt(x * x + y * y + z * z);
  return {x / len, y / len, z / len};
}

}  // namespace

std::vector<uint32_t> CurveOrder(const Columns& cur) {
  const size_t n = cur.n;
  std::vector<uint32_t> order(n);
  if (n == 0) return order;
  const auto& X = cur.ch[0];
  const auto& Y = cur.ch[1];
  const auto& Z = cur.ch[2];
  int64_t lo[3] = {X[0], Y[0], Z[0]}, hi[3] = {X[0], Y[0], Z[0]};
  for (size_t i = 0; i < n; ++i) {
    lo[0] = std::min(lo[0], X[i]), hi[0] = std::max(hi[0], X[i]);
    lo[1] = std::min(lo[1], Y[i]), hi[1] = std::max(hi[1], Y[i]);
    lo[2] = std::min(lo[2], Z[i]), hi[2] = std::max(hi[2], Z[i]);
  }
  int shift = 0;
  for (int a = 0; a < 3; ++a) {
    int bits = std::bit_width(static_cast<uint64_t>(hi[a]) - static_cast<uint64_t>(lo[a]));
    shift = std::max(shift, bits - 21);
  }
  std::vector<std::pair<uint64_t, uint32_t>> keyed(n);
  ParallelRange(n, [&](size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) {
      auto rel = [&](int64_t v, int64_t l) {
        return (static_cast<uint64_t>(v) - static_cast<uint64_t>(l)) >> shift;
      };
      uint64_t code = Morton3(rel(X[i], lo[0]), rel(Y[i], lo[1]), rel(Z[i], lo[2]));
      keyed[i] = {code, static_cast<uint32_t>(i)};
    }
  });
  std::sort(keyed.begin(), keyed.end());
  for (size_t i = 0; i < n; ++i) order[i] = keyed[i].second;
  return order;
}

namespace {

// One level of matching: fills pairs (indices into `cur`), in curve order.
void MatchLevel(const Columns& cur, bool use_normals, bool use_knn, int normal_scale_bits,
                std::vector<std::array<uint32_t, 2>>* pairs) {
  const size_t n = cur.n;
  const auto& X = cur.ch[0];
  const auto& Y = cur.ch[1];
  const auto& Z = cur.ch[2];
  std::vector<uint32_t> order = CurveOrder(cur);

  std::vector<Vec3> normal;
  if (use_normals) {
    normal.resize(n);
    ParallelRange(n, [&](size_t b, size_t e) {
      for (size_t i = b; i < e; ++i) {
        normal[i] = OctNormal(cur.ch[6][i] << normal_scale_bits, cur.ch[7][i] << normal_scale_bits);
      }
    });
  }
  // Eq. 7.1: w = e_X + e_N, here as the distance scaled by (1 + 2 e_N) (squared: no root).
  // Eq. 7.3 adds the alignment with either point's previous contraction, which keeps the
  // thesis's least-squares planes stable; our planes are exact cross products, and the terms
  // cost bits on every data set measured (+0.4 % on Panoptic, +0.6 % on the bunny at weight
  // 0.5), so they are left out.
  auto weight = [&](uint32_t i, uint32_t j) {
    double dx = static_cast<double>(X[j] - X[i]), dy = static_cast<double>(Y[j] - Y[i]),
           dz = static_cast<double>(Z[j] - Z[i]);
    double f = 1.0;
    if (use_normals) {
      f += 1.0 - (normal[i].x * normal[j].x + normal[i].y * normal[j].y + normal[i].z * normal[j].z);
    }
    return (dx * dx + dy * dy + dz * dz) * f * f;
  };

  // Candidates: the kNearest neighbours (k-d tree) and, for points whose neighbours are all
  // taken, the unmatched points next to them along the curve.
  std::vector<uint32_t> knn;
  if (use_knn) {
    knn.assign(n * kNearest, kNoChild);
    LevelCloud cloud;
    cloud.xyz.resize(3 * n);
    for (size_t i = 0; i < n; ++i) {
      cloud.xyz[3 * i] = static_cast<float>(X[i] - X[0]);
      cloud.xyz[3 * i + 1] = static_cast<float>(Y[i] - Y[0]);
      cloud.xyz[3 * i + 2] = static_cast<float>(Z[i] - Z[0]);
    }
    LevelTree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    ParallelRange(n, [&](size_t b, size_t e) {
      uint32_t idx[kNearest + 1];
      float d2[kNearest + 1];
      for (size_t i = b; i < e; ++i) {
        nanoflann::KNNResultSet<float, uint32_t> rs(kNearest + 1);
        rs.init(idx, d2);
        tree.findNeighbors(rs, &cloud.xyz[3 * i], nanoflann::SearchParams());
        size_t k = 0;
        for (size_t j = 0; j < rs.size() && k < kNearest; ++j) {
          if (idx[j] != i) knn[i * kNearest + k++] = idx[j];
        }
      }
    });
  }
  std::vector<uint32_t> partner(n, kNoChild);
  std::vector<uint32_t> list = order;  // unmatched points in curve order
  std::vector<uint32_t> best(n, kNoChild);
  for (int round = 0; round < kRounds && list.size() > 1; ++round) {
    const size_t m = list.size();
    ParallelRange(m, [&](size_t b, size_t e) {
      for (size_t p = b; p < e; ++p) {
        const uint32_t i = list[p];
        double bw = std::numeric_limits<double>::infinity();
        uint32_t bj = kNoChild;
        auto consider = [&](uint32_t j) {
          if (j == kNoChild || j == i || partner[j] != kNoChild) return;
          double w = weight(i, j);
          if (w < bw || (w == bw && j < bj)) bw = w, bj = j;
        };
        if (use_knn) {
          for (size_t k = 0; k < kNearest; ++k) consider(knn[i * kNearest + k]);
        }
        if (bj == kNoChild) {
          size_t q0 = p >= kWindow ? p - kWindow : 0, q1 = std::min(m, p + kWindow + 1);
          for (size_t q = q0; q < q1; ++q) consider(list[q]);
        }
        best[i] = bj;
      }
    });
    for (uint32_t i : list) {
      uint32_t j = best[i];
      if (j != kNoChild && i < j && best[j] == i) {
        partner[i] = j;
        partner[j] = i;
      }
    }
    std::vector<uint32_t> rest;
    rest.reserve(m);
    for (uint32_t i : list) {
      if (partner[i] == kNoChild) rest.push_back(i);
    }
    if (rest.size() == m) break;  // no progress: pair along the curve
    list.swap(rest);
  }
  for (size_t p = 0; p + 1 < list.size(); p += 2) {
    if (partner[list[p]] != kNoChild) continue;
    partner[list[p]] = list[p + 1];
    partner[list[p + 1]] = list[p];
  }
  // Local improvement toward the minimum-weight matching (2-opt on pairs): for a point a
  // paired with b and a neighbour c paired with d, re-pair as (a, c) and (b, d) when the sum
  // of the two lengths drops. Measured: 3 % fewer position bits on Panoptic and SJTU, 7 % on
  // the bunny (the sum of squares or of log-lengths as the cost gave less).
  {
    // Candidates c: the k-d tree's neighbours, or (effort 0) the neighbours along the curve.
    std::vector<uint32_t> rank;
    if (!use_knn) {
      rank.resize(n);
      for (size_t r = 0; r < n; ++r) rank[order[r]] = static_cast<uint32_t>(r);
    }
    auto candidate = [&](uint32_t a, size_t k) -> uint32_t {
      if (use_knn) return knn[a * kNearest + k];
      size_t off = k / 2 + 1;
      size_t r = rank[a];
      if (k % 2 == 0) return r + off < n ? order[r + off] : kNoChild;
      return r >= off ? order[r - off] : kNoChild;
    };
    auto cost = [&](uint32_t i, uint32_t j) { return std::sqrt(weight(i, j)); };
    for (int pass = 0; pass < kImprovePasses; ++pass) {
      for (uint32_t a = 0; a < n; ++a) {
        uint32_t b = partner[a];
        if (b == kNoChild) continue;
        for (size_t k = 0; k < kNearest; ++k) {
          uint32_t c = candidate(a, k);
          if (c == kNoChild || c == b) continue;
          uint32_t d = partner[c];
          if (d == kNoChild || d == a) continue;
          double now = cost(a, b) + cost(c, d);
          if (cost(a, c) + cost(b, d) < now - 1e-9) {
            partner[a] = c, partner[c] = a, partner[b] = d, partner[d] = b;
            b = c;
          }
        }
      }
    }
  }
  // Parents in curve order of their first child, so the next level's order is near-sorted.
  pairs->clear();
  pairs->reserve((n + 1) / 2);
  std::vector<uint8_t> done(n, 0);
  for (uint32_t i : order) {
    if (done[i]) continue;
    uint32_t j = partner[i];
    done[i] = 1;
    if (j == kNoChild) {
      pairs->push_back({i, kNoChild});
    } else {
      done[j] = 1;
      pairs->push_back({i, j});
    }
  }
}

}  // namespace

void BuildHierarchy(Columns base, int levels, bool use_normals, int knn_levels, Hierarchy* h) {
  h->level.clear();
  h->pairs.clear();
  h->level.push_back(std::move(base));
  h->pairs.emplace_back();  // level 0 has no pairs
  // Normals quantised to qn bits are scaled back to 16 bits for their direction.
  int normal_scale_bits = 0;
  if (use_normals) {
    int64_t m = 0;
    for (size_t i = 0; i < h->level[0].n; ++i) {
      m = std::max({m, std::abs(h->level[0].ch[6][i]), std::abs(h->level[0].ch[7][i])});
    }
    normal_scale_bits = std::max(0, 15 - static_cast<int>(std::bit_width(static_cast<uint64_t>(m))));
  }
  for (int k = 1; k <= levels; ++k) {
    const Columns& cur = h->level[k - 1];
    if (cur.n <= 1) break;
    std::vector<std::array<uint32_t, 2>> pairs;
    MatchLevel(cur, use_normals, k <= knn_levels, normal_scale_bits, &pairs);
    Columns next;
    next.n = pairs.size();
    for (int c = 0; c < kChannels; ++c) {
      if (cur.ch[c].empty()) continue;
      next.ch[c].resize(next.n);
      const auto& src = cur.ch[c];
      auto& dst = next.ch[c];
      for (size_t p = 0; p < next.n; ++p) {
        auto [a, b] = pairs[p];
        dst[p] = b == kNoChild ? src[a] : LiftParent(src[a], src[b]);
      }
    }
    h->level.push_back(std::move(next));
    h->pairs.push_back(std::move(pairs));
  }
}

}  // namespace hvdb::codec
