#include "edit/neighbours.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <thread>

#include "storage/coding.h"

namespace hvdb::edit {

namespace {

// Points are sorted by the Morton order of sub-cells (16 per cell edge), so that cells come
// in Morton order and, within a cell, consecutive points (and so the graph cut's node numbers)
// are near each other. Sub-cell coordinates are 21-bit, offset by kBias
// so that points a little below the origin (another frame's) still fit.
constexpr int kSubBits = 4;
constexpr uint32_t kBias = 1u << 20;

uint64_t Key(int32_t x, int32_t y, int32_t z) {  // any coordinates below 2^21 (others: no cell)
  return Morton3(static_cast<uint32_t>(x), static_cast<uint32_t>(y), static_cast<uint32_t>(z));
}

uint64_t Hash(uint64_t key) {
  key ^= key >> 33;
  key *= 0xff51afd7ed558ccdULL;
  key ^= key >> 33;
  return key;
}

int32_t SubCellOf(float v, float origin, float cell) {
  const double c = std::floor((static_cast<double>(v) - origin) / cell * (1 << kSubBits)) + kBias;
  return static_cast<int32_t>(std::clamp(c, 0.0, double(2 * kBias - 1)));
}

// The k best (d2, position) pairs so far, sorted, each as one 64-bit key: the squared
// distance's bits (a non-negative float's bits order as it does) above the position, so that
// "nearer, or as near and lower position" is one integer comparison. Offering was most of a
// query's time with a float comparison and a tie test at each step of the insertion.
struct Best {
  explicit Best(int count) : k(static_cast<size_t>(count)) {}
  static uint64_t Key(float d2, uint32_t pos) {
    uint32_t bits;
    std::memcpy(&bits, &d2, 4);
    return uint64_t{bits} << 32 | pos;
  }
  void Offer(float d2, uint32_t pos) {
    const uint64_t key = Key(d2, pos);
    if (n == k && key >= keys[n - 1]) return;
    size_t i = n < k ? n++ : n - 1;
    for (; i > 0 && key < keys[i - 1]; --i) keys[i] = keys[i - 1];
    keys[i] = key;
  }
  float d(size_t i) const {
    const uint32_t bits = static_cast<uint32_t>(keys[i] >> 32);
    float v;
    std::memcpy(&v, &bits, 4);
    return v;
  }
  uint32_t p(size_t i) const { return static_cast<uint32_t>(keys[i]); }
  size_t k, n = 0;
  uint64_t keys[64];
};

// The candidates of one query cell: the points of the cells around it, in contiguous arrays.
struct Candidates {
  std::vector<float> x, y, z;
  std::vector<uint32_t> pos;
  std::vector<float> d2;
  void Clear() { x.clear(), y.clear(), z.clear(), pos.clear(); }
};

}  // namespace

PointGrid::PointGrid(const std::vector<float>& xyz, const std::array<float, 3>& origin, float cell)
    : origin_(origin), cell_(cell) {
  const size_t n = xyz.size() / 3;
  // Sort (cell key, input index) pairs: an LSD radix sort on the key's bytes that vary.
  std::vector<std::pair<uint64_t, uint32_t>> keyed(n), tmp(n);
  uint64_t all_or = 0, all_and = ~uint64_t{0};
  for (size_t i = 0; i < n; ++i) {
    const uint64_t key = Key(SubCellOf(xyz[3 * i], origin[0], cell), SubCellOf(xyz[3 * i + 1], origin[1], cell),
                             SubCellOf(xyz[3 * i + 2], origin[2], cell));
    keyed[i] = {key, static_cast<uint32_t>(i)};
    all_or |= key;
    all_and &= key;
  }
  const uint64_t varying = all_or ^ all_and;
  for (int shift = 0; shift < 64; shift += 8) {
    if (((varying >> shift) & 0xff) == 0) continue;
    size_t count[257] = {};
    for (const auto& e : keyed) ++count[((e.first >> shift) & 0xff) + 1];
    for (int d = 0; d < 256; ++d) count[d + 1] += count[d];
    for (const auto& e : keyed) tmp[count[(e.first >> shift) & 0xff]++] = e;
    keyed.swap(tmp);
  }
  id_.resize(n);
  x_.resize(n), y_.resize(n), z_.resize(n);
  for (size_t j = 0; j < n; ++j) {
    const uint32_t i = keyed[j].second;
    id_[j] = i;
    x_[j] = xyz[3 * i], y_[j] = xyz[3 * i + 1], z_[j] = xyz[3 * i + 2];
    // The cell's key is the sub-cell key without its low 3 * kSubBits bits.
    if (j == 0 || (keyed[j].first >> 3 * kSubBits) != (keyed[j - 1].first >> 3 * kSubBits)) {
      cells_.push_back({SubCellOf(x_[j], origin[0], cell) >> kSubBits,
                        SubCellOf(y_[j], origin[1], cell) >> kSubBits,
                        SubCellOf(z_[j], origin[2], cell) >> kSubBits, static_cast<uint32_t>(j), 0});
    }
    cells_.back().end = static_cast<uint32_t>(j + 1);
  }
  size_t slots = 16;
  while (slots < 2 * cells_.size()) slots *= 2;
  table_keys_.assign(slots, ~uint64_t{0});
  table_cells_.assign(slots, 0);
  for (uint32_t c = 0; c < cells_.size(); ++c) {
    const uint64_t key = Key(cells_[c].x, cells_[c].y, cells_[c].z);
    size_t s = Hash(key) & (slots - 1);
    while (table_keys_[s] != ~uint64_t{0}) s = (s + 1) & (slots - 1);
    table_keys_[s] = key;
    table_cells_[s] = c;
  }
}

int64_t PointGrid::Find(int32_t x, int32_t y, int32_t z) const {
  const uint64_t key = Key(x, y, z);
  for (size_t s = Hash(key) & (table_keys_.size() - 1);; s = (s + 1) & (table_keys_.size() - 1)) {
    if (table_keys_[s] == key) return table_cells_[s];
    if (table_keys_[s] == ~uint64_t{0}) return -1;
  }
}

void PointGrid::Nearest(const PointGrid& queries, int k, float radius,
                        std::vector<uint32_t>* out) const {
  const size_t kk = static_cast<size_t>(std::clamp(k, 1, 64));
  out->assign(queries.size() * kk, kNone);
  const bool same = &queries == this;
  const float r2 = radius * radius;
  // Rings of cells around the query's that can hold a point in range.
  const int reach = std::max(1, static_cast<int>(std::ceil(radius / cell_ - 1e-6f)));
  auto gather = [&](const Cell& qc, int ring, Candidates* cand) {
    cand->Clear();
    auto add = [&](int dx, int dy, int dz) {
      const int64_t c = Find(qc.x + dx, qc.y + dy, qc.z + dz);
      if (c < 0) return;
      for (uint32_t j = cells_[c].begin; j < cells_[c].end; ++j) {
        cand->x.push_back(x_[j]), cand->y.push_back(y_[j]), cand->z.push_back(z_[j]);
        cand->pos.push_back(j);
      }
    };
    // Ring 1 is gathered with ring 0 (the 3x3x3 block), the query's own cell first: the
    // nearest are mostly there, and the sooner the k-th best is near, the fewer candidates
    // are offered at all.
    if (ring == 1) add(0, 0, 0);
    for (int dz = -ring; dz <= ring; ++dz) {
      for (int dy = -ring; dy <= ring; ++dy) {
        for (int dx = -ring; dx <= ring; ++dx) {
          if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) == ring) add(dx, dy, dz);
        }
      }
    }
  };
  auto offer = [&](const Candidates& cand, float qx, float qy, float qz, uint32_t self, Best* best,
                   std::vector<float>* d2) {
    const size_t m = cand.pos.size();
    d2->resize(m);
    float* d = d2->data();
    const float *cx = cand.x.data(), *cy = cand.y.data(), *cz = cand.z.data();
    for (size_t i = 0; i < m; ++i) {  // vectorised
      const float ex = cx[i] - qx, ey = cy[i] - qy, ez = cz[i] - qz;
      d[i] = ex * ex + ey * ey + ez * ez;
    }
    // Only what beats the k-th best so far (or the radius until there are k) is offered.
    float bound = best->n == best->k ? best->d(best->k - 1) : r2;
    // In blocks of 16 tested at once (vectorised): once the bound is tight, most blocks hold
    // nothing that beats it.
    constexpr size_t kBlock = 16;
    size_t i = 0;
    for (; i + kBlock <= m; i += kBlock) {
      int any = 0;
      for (size_t j = 0; j < kBlock; ++j) any |= d[i + j] <= bound;
      if (!any) continue;
      for (size_t j = i; j < i + kBlock; ++j) {
        if (d[j] > bound || cand.pos[j] == self) continue;
        best->Offer(d[j], cand.pos[j]);
        if (best->n == best->k) bound = best->d(best->k - 1);
      }
    }
    for (; i < m; ++i) {
      if (d[i] > bound || cand.pos[i] == self) continue;
      best->Offer(d[i], cand.pos[i]);
      if (best->n == best->k) bound = best->d(best->k - 1);
    }
  };
  std::atomic<size_t> next{0};
  constexpr size_t kCellsPerTask = 64;
  auto work = [&] {
    // rings[0]: the 3x3x3 block; rings[r - 1]: ring r; gathered once per query cell, when a
    // query of the cell first needs it.
    std::vector<Candidates> rings(static_cast<size_t>(reach));
    std::vector<float> d2;
    for (size_t t; (t = next.fetch_add(kCellsPerTask)) < queries.cells_.size();) {
      for (size_t qi = t; qi < std::min(queries.cells_.size(), t + kCellsPerTask); ++qi) {
        const Cell& qc = queries.cells_[qi];
        int gathered = 0;
        for (uint32_t j = qc.begin; j < qc.end; ++j) {
          const float qx = queries.x_[j], qy = queries.y_[j], qz = queries.z_[j];
          Best best(static_cast<int>(kk));
          const uint32_t self = same ? j : kNone;
          for (int ring = 1; ring <= reach; ++ring) {
            if (gathered < ring) gather(qc, ring, &rings[static_cast<size_t>(ring - 1)]), gathered = ring;
            offer(rings[static_cast<size_t>(ring - 1)], qx, qy, qz, self, &best, &d2);
            // Rings up to r hold every point within r cell edges of the query: a k-th nearest
            // nearer than that is final.
            const float covered = static_cast<float>(ring) * cell_;
            if (best.n == kk && best.d(kk - 1) <= covered * covered) break;
          }
          for (size_t h = 0; h < best.n; ++h) (*out)[j * kk + h] = best.p(h);
        }
      }
    }
  };
  const size_t threads = std::clamp<size_t>(std::thread::hardware_concurrency(), 1, 16);
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads && queries.size() > 4096; ++t) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
}

}  // namespace hvdb::edit
