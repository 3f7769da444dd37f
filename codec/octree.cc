// Octree geometry: the payload layout, the chunk split and the context modelling of occupancy
// bits (docs/CODEC.md, "Octree geometry"). One template codes a chunk for both sides, so the
// encoder and the decoder cannot disagree about a context.
#include "codec/octree.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <memory>
#include <thread>

#include "codec/range_coder.h"
#include "storage/coding.h"

namespace hvdb::codec {
namespace {

// Adaptive probability of a 0 bit, in 1/65536: the mean of a fast and a slow estimate, which
// tracks both the contexts that change along the tree and the stable ones better than either
// rate alone. Both start fast (1/2, 1/4, ... by how often the context was used: a new context
// learns from its first bits) and settle at 1/16 and 1/128.
struct Ctx {
  uint16_t a = 32768, b = 32768;
  uint8_t n = 0;
  uint32_t P0() const { return (uint32_t{a} + b) >> 1; }
  void Adapt(unsigned bit) {
    const int slow = std::clamp(static_cast<int>(std::bit_width(n)), 1, 7);  // 1 below 2 uses, 7 from 64
    const int fast = std::min(slow, 4);
    n = static_cast<uint8_t>(n + (n < 255));
    // Fast early rates could reach 0 or 1: keep both estimates inside [1/2048, 1 - 1/2048].
    if (bit) {
      a = static_cast<uint16_t>(std::max(32, a - (a >> fast)));
      b = static_cast<uint16_t>(std::max(32, b - (b >> slow)));
    } else {
      a = static_cast<uint16_t>(std::min(65503, a + ((65535 - a) >> fast)));
      b = static_cast<uint16_t>(std::min(65503, b + ((65535 - b) >> slow)));
    }
  }
};

// Logistic mixing of two models' predictions (as in PAQ/lpaq): p = squash(w1 st(p1) + w2 st(p2))
// with weights learnt online. Each model keeps a context set small enough to learn fast; the
// mix gets what both know. All integer, so every platform decodes the same bits.
class Logistic {
 public:
  static const Logistic& Get() {
    static const Logistic t;
    return t;
  }
  // x in stretch units (1/256 of a logit) to P(1) in 1/4096, 1..4095.
  int Squash(int x) const {
    if (x > 2047) return 4095;
    if (x < -2047) return 1;
    const int w = x & 127, i = (x >> 7) + 16;
    return std::clamp((kT[i] * (128 - w) + kT[i + 1] * w + 64) >> 7, 1, 4095);
  }
  int Stretch(int p) const { return stretch_[p]; }  // inverse of Squash, p in 0..4095

 private:
  static constexpr int kT[33] = {1,    2,    3,    6,    10,   16,   27,   45,   73,   120,  194,
                                 310,  488,  747,  1101, 1546, 2047, 2549, 2994, 3348, 3607, 3785,
                                 3901, 3975, 4022, 4050, 4068, 4079, 4085, 4089, 4092, 4093, 4094};
  Logistic() {
    int pi = 0;
    for (int x = -2047; x <= 2047; ++x) {
      const int v = Squash(x);
      for (int i = pi; i <= v; ++i) stretch_[i] = static_cast<int16_t>(x);
      pi = v + 1;
    }
    for (int i = pi; i < 4096; ++i) stretch_[i] = 2047;
  }
  int16_t stretch_[4096];
};

struct Mixer {
  int32_t w[3] = {1 << 15, 1 << 15, 1 << 15};  // 16.16
};

// Codes `bit` with the mix of the contexts' predictions under mixer m (one weight per
// context, at most three), then trains the mixer and every context.
template <typename IO, typename... C>
unsigned MixBit(IO& io, Mixer& m, unsigned bit, C&... contexts) {
  static_assert(sizeof...(C) >= 2 && sizeof...(C) <= 3, "a mixer has three weights");
  const Logistic& L = Logistic::Get();
  Ctx* ctx[] = {&contexts...};
  int st[sizeof...(C)];
  int64_t dot = 0;
  for (size_t k = 0; k < sizeof...(C); ++k) {
    st[k] = L.Stretch(static_cast<int>((65536 - ctx[k]->P0()) >> 4));
    dot += int64_t{m.w[k]} * st[k];
  }
  const int p1 = L.Squash(static_cast<int>(dot >> 16));
  const unsigned got = io.BitP(static_cast<uint32_t>(4096 - p1) << 4, bit);
  const int err = (static_cast<int>(got) << 12) - p1;
  for (size_t k = 0; k < sizeof...(C); ++k) {
    m.w[k] += (st[k] * err) >> 11;
    ctx[k]->Adapt(got);
  }
  return got;
}

// range_coder.h's coder with 16-bit probabilities (occupancy bits are often far more skewed
// than its 11-bit models can say), behind the interface CodeNode/CodeChunk code against.
class Encoder {
 public:
  static constexpr bool kEncode = true;
  explicit Encoder(std::string* out) : rc_(out) {}
  unsigned Bit(Ctx& c, unsigned bit) {
    rc_.BitP(c.P0(), 16, bit);
    c.Adapt(bit);
    return bit;
  }
  // A bit with probability p0 of a 0 (1/65536 units, 1..65535), no model.
  unsigned BitP(uint32_t p0, unsigned bit) {
    rc_.BitP(p0, 16, bit);
    return bit;
  }
  uint32_t Raw(uint32_t v, int count) {
    rc_.Direct(v, count);
    return v;
  }
  void Finish() { rc_.Finish(); }

 private:
  RangeEncoder rc_;
};

class Decoder {
 public:
  static constexpr bool kEncode = false;
  Decoder(const uint8_t* p, size_t n) : rc_(p, n) {}
  unsigned Bit(Ctx& c, unsigned /*ignored*/) {
    const unsigned bit = rc_.BitP(c.P0(), 16);
    c.Adapt(bit);
    return bit;
  }
  unsigned BitP(uint32_t p0, unsigned /*ignored*/) { return rc_.BitP(p0, 16); }
  uint32_t Raw(uint32_t /*ignored*/, int count) { return static_cast<uint32_t>(rc_.Direct(count)); }
  size_t overrun() const { return rc_.overrun(); }

 private:
  RangeDecoder rc_;
};

// The inverse of MortonCode's interleaving for one axis (every third bit, 21 bits).
uint32_t Compact(uint64_t x) {
  x &= 0x1249249249249249ull;
  x = (x | x >> 2) & 0x10C30C30C30C30C3ull;
  x = (x | x >> 4) & 0x100F00F00F00F00Full;
  x = (x | x >> 8) & 0x1F0000FF0000FFull;
  x = (x | x >> 16) & 0x1F00000000FFFFull;
  x = (x | x >> 32) & 0x1FFFFFull;
  return static_cast<uint32_t>(x);
}

// Occupancy contexts: level class (leaf level, the one above, the rest) x child index x
// occupied near face neighbours of the node (3 bits) x already coded neighbours of the child
// on its low side (3 bits) x (far face neighbours 0..3, or the reference's bits) x siblings
// coded occupied so far (0..3+).
constexpr int kOccContexts = 3 * 8 * 8 * 8 * 4 * 4 * 4;

struct Models {
  Ctx count1[3][3][3][4][4][4];  // a single child? [reference][level class][siblings][parents][children]
  Ctx count2[3][3][3][4][4][4];  // two children (given more than one)?
  Ctx axis[3][3][7][4][4][7];  // a single child's x, y, z bits
  Ctx occ[kOccContexts];
  Ctx occ2[3][8][64][8][4];    // occupancy bits: [level class][child][face pattern][low][found]
  Ctx occ3[3][8][27][4][4];    // [level class][child][near planes' halves][parents][children]
  Ctx count1b[3][64][3][4];    // the count flags by the exact face pattern
  Ctx count2b[3][64][3][4];
  Ctx axis2[3][7][7][7][7];    // a single child's bits by all three axes' planes
  Mixer mix_occ[3][8], mix_count1[3], mix_count2[3], mix_axis[3][7];
  Ctx direct[3][4][3];  // [level class][levels left: 3, 4, 5-8, more][reference: none, one, more]
  Ctx dup_zero[3][3];  // [siblings][points of the leaf before: 1, 2, more]
  Ctx dup_len[3][32];
};

// The decoder's view of one level of a chunk: the distinct cells, sorted.
struct Level {
  std::vector<uint64_t> codes;
  std::vector<uint8_t> occ;  // child occupancy of each cell (coded by the level's pass)
  std::vector<uint8_t> lone;  // encoder: 1 when exactly one leaf cell lies below
  std::vector<uint64_t> leaf;  // encoder: the first leaf cell below
};

// Distinct cells per depth and their child occupancy, bottom up (encoder, and the reference).
std::vector<Level> BuildLevels(std::span<const uint64_t> leaves, int top, int depth) {
  std::vector<Level> lv(depth + 1);
  lv[depth].codes.assign(leaves.begin(), leaves.end());
  lv[depth].lone.assign(leaves.size(), 1);
  lv[depth].leaf.assign(leaves.begin(), leaves.end());
  for (int d = depth - 1; d >= top; --d) {
    const Level& B = lv[d + 1];
    Level& L = lv[d];
    for (size_t k = 0; k < B.codes.size(); ++k) {
      const uint64_t c = B.codes[k], p = c >> 3;
      if (L.codes.empty() || L.codes.back() != p) {
        L.codes.push_back(p);
        L.occ.push_back(0);
        L.lone.push_back(B.lone[k]);
        L.leaf.push_back(B.leaf[k]);
      } else {
        L.lone.back() = 0;
      }
      L.occ.back() = static_cast<uint8_t>(L.occ.back() | (1u << (c & 7)));
    }
  }
  return lv;
}

// The cells of one 32^3 cube of a level, with a one-cell margin that stays empty: 0 = empty,
// else 0x100 | the cell's child occupancy once coded. Neighbours outside the cube count as
// empty (G-PCC's occupancy atlas makes the same trade: a bounded, cache-resident table); the
// margin saves every lookup a bounds test.
class Atlas {
 public:
  static constexpr uint32_t kSide = 34;
  Atlas() : cells_(kSide * kSide * kSide, 0) {}
  static uint32_t Cell(uint32_t x, uint32_t y, uint32_t z) {
    return (((x & 31) + 1) * kSide + ((y & 31) + 1)) * kSide + ((z & 31) + 1);
  }
  // Loads cells [b, e) of `codes` (one cube), forgetting the previous cube.
  void Load(const std::vector<uint64_t>& codes, size_t b, size_t e) {
    for (uint32_t c : used_) cells_[c] = 0;
    used_.clear();
    for (size_t j = b; j < e; ++j) {
      uint32_t x, y, z;
      MortonDecode(codes[j], &x, &y, &z);
      const uint32_t c = Cell(x, y, z);
      cells_[c] = 0x100;
      used_.push_back(c);
    }
  }
  void SetOcc(uint32_t c, uint8_t occ) { cells_[c] = static_cast<uint16_t>(0x100 | occ); }
  // The 27 cells around `c`, indexed (dx + 1) * 9 + (dy + 1) * 3 + (dz + 1) (13: the cell).
  void Neighbours26(uint32_t c, uint16_t n[27]) const {
    const uint16_t* p = cells_.data() + c - kSide * kSide - kSide - 1;
    for (int dx = 0; dx < 3; ++dx) {
      for (int dy = 0; dy < 3; ++dy) {
        const uint16_t* row = p + (dx * kSide + dy) * kSide;
        n[dx * 9 + dy * 3 + 0] = row[0];
        n[dx * 9 + dy * 3 + 1] = row[1];
        n[dx * 9 + dy * 3 + 2] = row[2];
      }
    }
  }

 private:
  std::vector<uint16_t> cells_;
  std::vector<uint32_t> used_;
};

inline unsigned Occ(uint16_t v) { return v != 0; }

// The child-level cells around a node as a 4x4x4 bit cube (bit lx * 16 + ly * 4 + lz, local
// coordinate l = 2 * offset + child bit + 1 along each axis): what its 27 nodes' occupancy
// bytes say about the node's children's 26-neighbourhoods.
struct Local {
  uint64_t scatter[27][256];
  uint64_t face[8], other[8];  // the face and the edge/corner neighbours of child i
  int low[8][3];                // bits of its -x, -y, -z face neighbours
  Local() {
    for (int o = 0; o < 27; ++o) {
      const int off[3] = {o / 9 - 1, (o / 3) % 3 - 1, o % 3 - 1};
      for (int b = 0; b < 256; ++b) {
        uint64_t m = 0;
        for (int c = 0; c < 8; ++c) {
          if (!((b >> c) & 1)) continue;
          const int cb[3] = {c >> 2, (c >> 1) & 1, c & 1};
          int l[3];
          bool in = true;
          for (int a = 0; a < 3; ++a) {
            l[a] = 2 * off[a] + cb[a] + 1;
            in = in && l[a] >= 0 && l[a] <= 3;
          }
          if (in) m |= uint64_t{1} << (l[0] * 16 + l[1] * 4 + l[2]);
        }
        scatter[o][b] = m;
      }
    }
    for (int c = 0; c < 8; ++c) {
      const int l[3] = {(c >> 2) + 1, ((c >> 1) & 1) + 1, (c & 1) + 1};
      face[c] = other[c] = 0;
      low[c][0] = (l[0] - 1) * 16 + l[1] * 4 + l[2];
      low[c][1] = l[0] * 16 + (l[1] - 1) * 4 + l[2];
      low[c][2] = l[0] * 16 + l[1] * 4 + l[2] - 1;
      for (int dx = -1; dx <= 1; ++dx) {
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dz = -1; dz <= 1; ++dz) {
            const int k = std::abs(dx) + std::abs(dy) + std::abs(dz);
            if (k == 0) continue;
            const uint64_t bit = uint64_t{1} << ((l[0] + dx) * 16 + (l[1] + dy) * 4 + l[2] + dz);
            (k == 1 ? face[c] : other[c]) |= bit;
          }
        }
      }
    }
  }
};
const Local& LocalTables() {
  static const Local t;
  return t;
}

// Codes (encoder) or decodes one chunk: the subtree below `root` (a cell at depth `top`).
// Encoder: `enc` holds the chunk's levels and `counts` the points per leaf. Decoder: fills
// `leaves` (distinct cells) and `counts`; `budget` bounds the points (corruption guard).
// The layers of the 4x4x4 child-level cube: layer[a][l] holds the cells whose local
// coordinate along axis a is l (0 and 3 are the neighbouring nodes' children).
struct Layers {
  uint64_t layer[3][4];
  Layers() {
    for (int a = 0; a < 3; ++a) {
      for (int l = 0; l < 4; ++l) {
        layer[a][l] = 0;
        for (int b = 0; b < 64; ++b) {
          const int c[3] = {b >> 4, (b >> 2) & 3, b & 3};
          if (c[a] == l) layer[a][l] |= uint64_t{1} << b;
        }
      }
    }
  }
};
const Layers& LayerTables() {
  static const Layers t;
  return t;
}

// Where surfaces lie (G-PCC's planar buffer): per axis and per coordinate along it (hashed),
// the last node of this level whose children all sat in one half along that axis, which half,
// and where it was along the other two axes. A surface across the axis puts the nodes that
// share its coordinate into the same half.
class PlaneBuffer {
 public:
  static constexpr uint32_t kSlots = 4096;
  PlaneBuffer() { Clear(); }
  void Clear() {
    for (auto& a : slot_) std::fill(std::begin(a), std::end(a), Entry{});
  }
  // 0: nothing; 1 + half: a planar node within 1 cell; 3 + half: within 4; 5 + half: further.
  unsigned Class(int a, const uint32_t c[3]) const {
    const Entry& e = slot_[a][c[a] % kSlots];
    if (e.half < 0 || e.at != c[a]) return 0;
    const uint32_t u = c[(a + 1) % 3], v = c[(a + 2) % 3];
    const uint32_t d = (u > e.u ? u - e.u : e.u - u) + (v > e.v ? v - e.v : e.v - v);
    return (d <= 1 ? 1u : d <= 4 ? 3u : 5u) + static_cast<unsigned>(e.half);
  }
  void Note(const uint32_t c[3], unsigned occ) {
    static constexpr unsigned kLow[3] = {0x0F, 0x33, 0x55};  // children in the low half of x, y, z
    for (int a = 0; a < 3; ++a) {
      const int half = (occ & ~kLow[a]) == 0 ? 0 : (occ & kLow[a]) == 0 ? 1 : -1;
      if (half < 0) continue;
      slot_[a][c[a] % kSlots] = Entry{static_cast<int8_t>(half), c[a], c[(a + 1) % 3], c[(a + 2) % 3]};
    }
  }

 private:
  struct Entry {
    int8_t half = -1;
    uint32_t at = 0, u = 0, v = 0;
  };
  Entry slot_[3][kSlots];
};

// Codes one node's child occupancy. In sparse regions (at most one face neighbour), first
// whether it has one, two or more children (mostly chains of single children), then a single
// child as three axis decisions (each predicted by the side its neighbours lie on and by the
// planar buffer), or several as eight bits skipping those the count implies. Elsewhere the
// eight bits directly. Every occupancy bit is modelled by the node's and the child's coded
// neighbourhood.
template <typename IO>
unsigned CodeNode(IO& io, Models& md, int lc, unsigned sib, const uint16_t nb[6], uint64_t mask,
                  unsigned pcount, unsigned ref_occ, bool ref_has, unsigned want,
                  const PlaneBuffer& planes, const uint32_t xyz[3]) {
  const Local& lt = LocalTables();
  const Layers& ly = LayerTables();
  const unsigned pb = pcount == 0 ? 0 : pcount <= 2 ? 1 : pcount <= 5 ? 2 : 3;
  const int mc = std::popcount(mask);
  const unsigned mb = mc == 0 ? 0 : mc <= 2 ? 1 : mc <= 5 ? 2 : 3;
  const unsigned rc = ref_has ? 1 + (std::popcount(ref_occ) == 1 ? 0 : 1) : 0;
  const int wc = std::popcount(want);
  const unsigned faces = Occ(nb[0]) + Occ(nb[1]) + Occ(nb[2]) + Occ(nb[3]) + Occ(nb[4]) + Occ(nb[5]);
  const unsigned fb = faces == 0 ? 0 : faces <= 2 ? 1 : faces <= 4 ? 2 : 3;
  // Where a face neighbour or more is occupied (surfaces), the eight bits code best directly;
  // in sparse regions, first whether there are one, two or more children.
  const bool flags = faces <= 1;
  const unsigned fp = Occ(nb[0]) | Occ(nb[1]) << 1 | Occ(nb[2]) << 2 | Occ(nb[3]) << 3 |
                      Occ(nb[4]) << 4 | Occ(nb[5]) << 5;
  const unsigned single = flags ? MixBit(io, md.mix_count1[lc], wc == 1, md.count1[rc][lc][sib][pb][mb][fb],
                                         md.count1b[lc][fp][sib][mb])
                                : 0;
  if (single) {
    unsigned node = 0, child = 0;
    for (int a = 0; a < 3; ++a) {
      const unsigned side = (mask & ly.layer[a][0] ? 1u : 0u) | (mask & ly.layer[a][3] ? 2u : 0u);
      const unsigned face = Occ(nb[2 * a]) | Occ(nb[2 * a + 1]) << 1;
      const unsigned rbit = ref_has && std::popcount(ref_occ) == 1 ? 1 + ((std::countr_zero(ref_occ) >> (2 - a)) & 1) : 0;
      const unsigned plane = planes.Class(a, xyz);
      const unsigned bit = MixBit(io, md.mix_axis[lc][node], (std::countr_zero(want | 256u) >> (2 - a)) & 1,
                                  md.axis[rbit][lc][node][side][face][plane],
                                  md.axis2[lc][node][planes.Class(0, xyz)][planes.Class(1, xyz)][planes.Class(2, xyz)]);
      child = child << 1 | bit;
      node = 2 * node + 1 + bit;
    }
    return 1u << child;
  }
  const unsigned two = flags ? MixBit(io, md.mix_count2[lc], wc == 2, md.count2[rc][lc][sib][pb][mb][fb],
                                      md.count2b[lc][fp][sib][mb])
                             : 0;
  const unsigned need = flags ? (two ? 2 : 3) : 1;
  unsigned occ = 0;
  Ctx* base = md.occ + lc * (kOccContexts / 3);
  for (unsigned i = 0; i < 8; ++i) {
    const unsigned found = static_cast<unsigned>(std::popcount(occ));
    if (two && found == 2) break;
    if (8 - i == need - std::min(need, found) && found < need) {
      occ |= 1u << i;
      mask |= lt.scatter[13][1u << i];
      continue;
    }
    const unsigned cx = i >> 2, cy = (i >> 1) & 1, cz = i & 1;
    const unsigned near = Occ(cx ? nb[1] : nb[0]) << 2 | Occ(cy ? nb[3] : nb[2]) << 1 |
                          Occ(cz ? nb[5] : nb[4]);
    const int oc = std::popcount(mask & lt.other[i]);
    const unsigned ob = oc == 0 ? 0 : oc == 1 ? 1 : oc <= 3 ? 2 : 3;
    const unsigned cnt = std::min(3u, found);
    const unsigned r = ref_has ? 1 + ((ref_occ >> i) & 1) : two;
    // The child's -x, -y, -z neighbours (coded before it: siblings or earlier nodes' children).
    const unsigned lp = static_cast<unsigned>((mask >> lt.low[i][0]) & 1) |
                        static_cast<unsigned>((mask >> lt.low[i][1]) & 1) << 1 |
                        static_cast<unsigned>((mask >> lt.low[i][2]) & 1) << 2;
    Ctx& c = base[((((i * 8 + near) * 8 + lp) * 4 + ob) * 4 + std::min(r, 3u)) * 4 + cnt];
    unsigned agree = 0;
    for (int a = 0; a < 3; ++a) {
      const unsigned pc = planes.Class(a, xyz);
      if (pc == 1 || pc == 2) agree = agree * 3 + (((i >> (2 - a)) & 1) == pc - 1 ? 1 : 2);
      else agree = agree * 3;
    }
    const unsigned bit = MixBit(io, md.mix_occ[lc][i], (want >> i) & 1, c, md.occ2[lc][i][fp][lp][cnt],
                                md.occ3[lc][i][agree][pb][mb]);
    occ |= bit << i;
    if (bit) mask |= lt.scatter[13][1u << i];
  }
  return occ;
}

// Codes (encoder) or decodes one chunk: the subtree below `root` (a cell at depth `top`).
// Encoder: `enc` holds the chunk's levels and `counts` the points per leaf. Decoder: fills
// `leaves` (distinct cells) and `counts`; `budget` bounds the points (corruption guard).
template <typename IO>
bool CodeChunk(IO& io, uint64_t root, int top, int depth, const std::vector<Level>* enc,
               const std::vector<Level>* ref, std::vector<uint64_t>* leaves,
               std::vector<uint32_t>* counts, uint64_t budget) {
  auto md = std::make_unique<Models>();
  const Local& lt = LocalTables();
  Atlas atlas;
  auto planes = std::make_unique<PlaneBuffer>();
  std::vector<uint64_t> parents{root}, children;
  std::vector<uint8_t> sibs{3}, child_sibs;
  std::vector<uint64_t> direct;  // leaves coded directly (below isolated single children)
  for (int d = top; d < depth; ++d) {
    const int lc = d + 1 == depth ? 0 : d + 2 == depth ? 1 : 2;
    const size_t n = parents.size();
    children.clear();
    child_sibs.clear();
    planes->Clear();
    // The reference's cells at this depth, walked alongside (both sorted).
    const Level* rl = ref ? &(*ref)[d] : nullptr;
    size_t rpos = 0, epos = 0;
    size_t cube_end = 0;
    for (size_t j = 0; j < n; ++j) {
      const uint64_t code = parents[j];
      if (j == cube_end) {
        const uint64_t key = code >> 15;
        cube_end = j + 1;
        while (cube_end < n && (parents[cube_end] >> 15) == key) ++cube_end;
        atlas.Load(parents, j, cube_end);
      }
      uint32_t x, y, z;
      MortonDecode(code, &x, &y, &z);
      const uint32_t cell = Atlas::Cell(x, y, z);
      uint16_t n26[27];
      atlas.Neighbours26(cell, n26);
      const uint16_t nb[6] = {n26[4], n26[22], n26[10], n26[16], n26[12], n26[14]};
      // Branch-free: an empty cell scatters nothing, and the node itself (13) has no bits yet.
      uint64_t mask = 0;
      unsigned pcount = 0;
#pragma GCC unroll 27
      for (int o = 0; o < 27; ++o) {
        pcount += n26[o] != 0;
        mask |= lt.scatter[o][n26[o] & 0xFF];
      }
      pcount -= 1;
      unsigned ref_occ = 0;
      bool ref_has = false;
      if (rl) {
        while (rpos < rl->codes.size() && rl->codes[rpos] < code) ++rpos;
        if (rpos < rl->codes.size() && rl->codes[rpos] == code) ref_occ = rl->occ[rpos], ref_has = true;
      }
      if constexpr (IO::kEncode) {
        while ((*enc)[d].codes[epos] != code) ++epos;  // nodes coded directly are skipped
      }
      // An isolated node whose parent had one child holds, most likely, one point: then its
      // remaining bits go raw, once, instead of a chain of single children.
      const int left = depth - d;
      if (sibs[j] == 1 && pcount == 0 && left >= 3) {
        const unsigned lb = left == 3 ? 0 : left == 4 ? 1 : left <= 8 ? 2 : 3;
        const unsigned rb = !ref_has ? 0 : std::popcount(ref_occ) == 1 ? 1 : 2;
        const unsigned lone = IO::kEncode ? (*enc)[d].lone[epos] : 0;
        if (io.Bit(md->direct[lc][lb][rb], lone)) {
          const uint64_t leaf = IO::kEncode ? (*enc)[d].leaf[epos] : 0;
          uint64_t below = 0;
          for (int r = left - 1; r >= 0; --r) {
            below = below << 3 | io.Raw(static_cast<uint32_t>((leaf >> (3 * r)) & 7), 3);
          }
          direct.push_back(code << (3 * left) | below);
          atlas.SetOcc(cell, 0);
          if (children.size() + direct.size() > budget) return false;
          continue;
        }
      }
      const unsigned want = IO::kEncode ? (*enc)[d].occ[epos] : 0;
      const uint32_t xyz[3] = {x, y, z};
      const unsigned occ = CodeNode(io, *md, lc, sibs[j] - 1, nb, mask, pcount, ref_occ, ref_has,
                                    want, *planes, xyz);
      planes->Note(xyz, occ);
      atlas.SetOcc(cell, static_cast<uint8_t>(occ));
      const uint8_t s = static_cast<uint8_t>(std::min(3, std::popcount(occ)));
      for (unsigned i = 0; i < 8; ++i) {
        if ((occ >> i) & 1) {
          children.push_back(code << 3 | i);
          child_sibs.push_back(s);
        }
      }
      if (children.size() + direct.size() > budget) return false;
    }
    parents.swap(children);
    sibs.swap(child_sibs);
  }
  // The leaves in order: the tree's and the directly coded ones (single children, sibs 1).
  if (!direct.empty()) {
    std::sort(direct.begin(), direct.end());
    std::vector<uint64_t> all(parents.size() + direct.size());
    std::vector<uint8_t> all_sibs(all.size());
    size_t a = 0, b = 0;
    for (size_t k = 0; k < all.size(); ++k) {
      if (b == direct.size() || (a < parents.size() && parents[a] < direct[b])) {
        all[k] = parents[a];
        all_sibs[k] = sibs[a++];
      } else {
        all[k] = direct[b++];
        all_sibs[k] = 1;
      }
    }
    parents.swap(all);
    sibs.swap(all_sibs);
  }
  // Points per leaf: count - 1, mostly zero; where leaves crowd (siblings) and after a leaf
  // with several points, more likely not.
  const std::vector<uint64_t>& lv = parents;
  if constexpr (!IO::kEncode) *leaves = parents;
  if constexpr (!IO::kEncode) counts->resize(lv.size());
  uint64_t total = 0;
  unsigned prev = 0;
  for (size_t j = 0; j < lv.size(); ++j) {
    const uint32_t m = IO::kEncode ? (*counts)[j] - 1 : 0;
    uint32_t v = 0;
    const unsigned s = sibs[j] - 1u;
    if (io.Bit(md->dup_zero[s][prev], m != 0)) {
      const int k = IO::kEncode ? std::bit_width(m) - 1 : 0;
      int len = 0;
      while (len < 31 && io.Bit(md->dup_len[s][len], len < k)) ++len;
      v = (1u << len) | io.Raw(m & ((1u << len) - 1), len);
    }
    prev = std::min(v, 2u);
    if constexpr (!IO::kEncode) (*counts)[j] = v + 1;
    total += v + 1;
    if (total > budget) return false;
  }
  return true;
}

}  // namespace

uint64_t MortonCode(uint32_t x, uint32_t y, uint32_t z) {
  return Morton3(z, y, x);  // storage/coding.h interleaves its first argument lowest
}

void MortonDecode(uint64_t code, uint32_t* x, uint32_t* y, uint32_t* z) {
  *x = Compact(code >> 2);
  *y = Compact(code >> 1);
  *z = Compact(code);
}

namespace {

// The chunk split: depth 0 (one chunk) for small sets, else depth 1 or 2, so that both cores
// get work while each chunk's contexts still learn from enough points.
int SplitDepth(size_t n, int depth) {
  int s = n < (size_t{1} << 16) ? 0 : n < (size_t{1} << 20) ? 1 : 2;
  return std::min(s, std::max(0, depth - 2));
}

// Runs fn(i) for i in [0, n) on `threads` threads, largest work first (`order`).
template <typename Fn>
void ForEachChunk(const std::vector<size_t>& order, int threads, const Fn& fn) {
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t k; (k = next.fetch_add(1)) < order.size();) fn(order[k]);
  };
  std::vector<std::thread> pool;
  const int t = std::max(1, std::min<int>(threads, static_cast<int>(order.size())));
  for (int i = 1; i < t; ++i) pool.emplace_back(work);
  work();
  for (auto& th : pool) th.join();
}

std::vector<size_t> LargestFirst(const std::vector<uint64_t>& sizes) {
  std::vector<size_t> order(sizes.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return sizes[a] > sizes[b]; });
  return order;
}

}  // namespace

void EncodeOctree(std::span<const uint64_t> codes, int depth, const std::vector<uint64_t>* reference,
                  int threads, std::string* out) {
  const int top = SplitDepth(codes.size(), depth);
  const int shift = 3 * (depth - top);
  // Chunks: runs of codes with the same cell at depth `top`.
  std::vector<size_t> begin;
  for (size_t i = 0; i < codes.size(); ++i) {
    if (i == 0 || (codes[i] >> shift) != (codes[i - 1] >> shift)) begin.push_back(i);
  }
  const size_t m = begin.size();
  begin.push_back(codes.size());
  std::vector<uint64_t> sizes(m);
  for (size_t c = 0; c < m; ++c) sizes[c] = begin[c + 1] - begin[c];
  std::vector<Level> ref_levels;
  if (reference) ref_levels = BuildLevels(*reference, 0, depth);
  std::vector<std::string> bytes(m);
  ForEachChunk(LargestFirst(sizes), threads, [&](size_t c) {
    std::vector<uint64_t> leaves;
    std::vector<uint32_t> counts;
    for (size_t i = begin[c]; i < begin[c + 1]; ++i) {
      if (leaves.empty() || leaves.back() != codes[i]) {
        leaves.push_back(codes[i]);
        counts.push_back(0);
      }
      ++counts.back();
    }
    std::vector<Level> lv = BuildLevels(leaves, top, depth);
    Encoder io(&bytes[c]);
    CodeChunk(io, codes[begin[c]] >> shift, top, depth, &lv, reference ? &ref_levels : nullptr,
              nullptr, &counts, UINT64_MAX);
    io.Finish();
  });
  Writer w;
  w.Put<uint8_t>(static_cast<uint8_t>(top));
  w.Put<uint32_t>(static_cast<uint32_t>(m));
  for (size_t c = 0; c < m; ++c) {
    w.Put<uint32_t>(static_cast<uint32_t>(codes[begin[c]] >> shift));
    w.Put<uint32_t>(static_cast<uint32_t>(sizes[c]));
    w.Put<uint32_t>(static_cast<uint32_t>(bytes[c].size()));
  }
  out->append(w.data());
  for (const std::string& b : bytes) out->append(b);
}

Status DecodeOctree(std::string_view in, int depth, uint64_t points,
                    const std::vector<uint64_t>* reference, int threads, std::vector<uint64_t>* codes) {
  const auto* p = reinterpret_cast<const uint8_t*>(in.data());
  auto bad = [](const std::string& why) { return Status::Corruption("hvdb7 octree geometry: " + why); };
  if (in.size() < 5) return bad("payload shorter than its table");
  const int top = p[0];
  const uint32_t m = DecodeLE<uint32_t>(p + 1);
  if (top > 3 || top > depth) return bad("chunk depth " + std::to_string(top) + " out of range");
  if (m > (1u << (3 * top))) return bad("more chunks than cells at the chunk depth");
  if ((in.size() - 5) / 12 < m) return bad("chunk table truncated");
  std::vector<uint64_t> prefix(m), count(m), off(m + 1);
  size_t pos = 5 + 12 * size_t{m};
  uint64_t total = 0;
  off[0] = pos;
  for (uint32_t c = 0; c < m; ++c) {
    const uint8_t* e = p + 5 + 12 * size_t{c};
    prefix[c] = DecodeLE<uint32_t>(e);
    count[c] = DecodeLE<uint32_t>(e + 4);
    const uint64_t len = DecodeLE<uint32_t>(e + 8);
    if (prefix[c] >= (uint64_t{1} << (3 * top)) || (c > 0 && prefix[c] <= prefix[c - 1])) {
      return bad("chunk cells not increasing inside the grid");
    }
    if (count[c] == 0) return bad("empty chunk");
    total += count[c];
    off[c + 1] = off[c] + len;
  }
  if (total != points) return bad("chunks hold " + std::to_string(total) + " points, header says " +
                                  std::to_string(points));
  if (off[m] != in.size()) return bad("chunk lengths do not add up to the payload");
  std::vector<Level> ref_levels;
  if (reference) ref_levels = BuildLevels(*reference, 0, depth);
  std::vector<std::vector<uint64_t>> leaves(m);
  std::vector<std::vector<uint32_t>> counts(m);
  std::vector<uint8_t> ok(m, 0);
  ForEachChunk(LargestFirst(count), threads, [&](size_t c) {
    Decoder io(p + off[c], off[c + 1] - off[c]);
    const bool fit = CodeChunk(io, prefix[c], top, depth, nullptr, reference ? &ref_levels : nullptr,
                               &leaves[c], &counts[c], count[c]);
    uint64_t got = 0;
    for (uint32_t v : counts[c]) got += v;
    ok[c] = fit && io.overrun() == 0 && got == count[c];
  });
  codes->clear();
  codes->reserve(points);
  for (uint32_t c = 0; c < m; ++c) {
    if (!ok[c]) return bad("chunk " + std::to_string(c) + " is corrupt");
    for (size_t j = 0; j < leaves[c].size(); ++j) codes->insert(codes->end(), counts[c][j], leaves[c][j]);
  }
  return Status::OK();
}

}  // namespace hvdb::codec
