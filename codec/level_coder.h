// The coding of one level's details, written once for both directions: the encoder and the
// decoder run the same template with an IO that either writes or reads each symbol, so the
// two cannot drift apart. docs/CODEC.md, "Details", is this file in prose.
#ifndef HVDB_CODEC_LEVEL_CODER_H_
#define HVDB_CODEC_LEVEL_CODER_H_

#include <algorithm>
#include <array>
#include <bit>
#include <cstdint>
#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "codec/internal.h"
#include "codec/range_coder.h"

namespace hvdb::codec {

// 128-bit products keep the plane prediction exact (GCC and Clang both have the type).
__extension__ typedef __int128 Int128;

inline constexpr int kRBuckets = 48;   // spacing context of position details
inline constexpr int kLevelBuckets = 12;
inline constexpr int kSizeBuckets = 24;
inline constexpr int kMagBuckets = 6;  // magnitude of the parent's detail

// Every adaptive context of a stream. Groups touch disjoint members, so groups can be coded
// on different threads.
struct Models {
  IntModel root[kChannels];
  IntModel pos_u[kRBuckets];    // u (intra), by spacing
  IntModel pos_v[kRBuckets][kSizeBuckets];  // v, by spacing and |u| (d lies near a ring)
  IntModel pos_w[kRBuckets][kSizeBuckets];  // w's residual from the plane, by |u| + |v|
  BitModel zerotree[kGroups][kLevelBuckets][2];
  IntModel val[kChannels][kLevelBuckets][kMagBuckets];
  IntModel tval[kChannels][kLevelBuckets][kMagBuckets];  // colour, by the reference's detail
  // Octree streams: a pair whose two points sit in cells the reference occupies codes its
  // colour detail as the residual from the reference's (what did not change costs a bit).
  BitModel tsame[2];
  IntModel tres[3];
};

struct EncIO {
  static constexpr bool kEncode = true;
  std::string buf;
  RangeEncoder rc{&buf};
  void S(IntModel& m, int64_t& v) { EncodeSigned(rc, m, v); }
  void U(IntModel& m, int64_t& v) { EncodeUnsigned(rc, m, static_cast<uint64_t>(v)); }
  unsigned B(BitModel& m, unsigned bit) {
    rc.Bit(m, bit);
    return bit;
  }
};

struct DecIO {
  static constexpr bool kEncode = false;
  RangeDecoder rc;
  DecIO(const uint8_t* p, size_t n) : rc(p, n) {}
  void S(IntModel& m, int64_t& v) { v = DecodeSigned(rc, m); }
  void U(IntModel& m, int64_t& v) { v = static_cast<int64_t>(DecodeUnsigned(rc, m)); }
  unsigned B(BitModel& m, unsigned) { return rc.Bit(m); }
};

// Temporal context of one pair: the reference frame's points nearest to the two decoded
// children (kNoChild: no usable reference point near them). The difference of their colours
// selects the context the pair's colour detail is coded in (the reference as a field over the
// surface, which holds when the surface is sampled differently from frame to frame).
struct TemporalHint {
  uint32_t a = kNoChild, b = kNoChild;
  bool exact = false;  // both children in cells the reference occupies (a and b are there)
  bool valid() const { return a != kNoChild; }
};

// What one level's pass reads and writes. Parents are in stream order.
struct LevelState {
  int k = 0;                  // level of the parents (>= 1)
  const Quantizer* q = nullptr;
  const Columns* cur = nullptr;   // parent values
  size_t n = 0;
  uint32_t singleton = kNoChild;  // the parent with one child, if any
  bool plane = true;              // w predicted from the plane (the encoder's choice per level)
  bool octree = false;            // an octree stream (version 2): its temporal prediction
  Columns det;                    // details (encoder: filled raw as first - second child)
  std::vector<uint8_t> swap;      // encoder: 1 where the children were swapped
  // Per group, per parent: 1 if an ancestor coded "subtree zero"; the bucket of the parent's
  // detail magnitude.
  std::array<std::vector<uint8_t>, kGroups> inherit, mag;
  // Encoder: per group, per parent: the subtree below is all zero details.
  std::array<std::vector<uint8_t>, kGroups> zero;
  // Temporal streams: the reference's values (same quantisation) and a hint per parent.
  const Columns* reference = nullptr;
  std::vector<TemporalHint> hints;
  int threads = 0;  // at most this many threads for the level (0: the machine's; 1: none spawned)
};

inline int LevelBucket(int k) { return std::min(k - 1, kLevelBuckets - 1); }
inline uint8_t MagBucket(uint64_t m) {
  return static_cast<uint8_t>(std::min<int>(std::bit_width(m), kMagBuckets - 1));
}
inline uint64_t Abs(int64_t v) { return v < 0 ? 0 - static_cast<uint64_t>(v) : static_cast<uint64_t>(v); }

// Rounded quotient num/den (den != 0), ties away from zero.
inline int64_t RoundDiv(Int128 num, Int128 den) {
  if (den < 0) num = -num, den = -den;
  Int128 q = num >= 0 ? (2 * num + den) / (2 * den) : -((-2 * num + den) / (2 * den));
  return static_cast<int64_t>(q);
}

// Local frame of the positions (operator C of 7.3.1): the plane through the 4-neighbourhood
// of parents {4j..4j+3} (grandchildren of one node) approximated by the cross product of its
// diagonals, exact in integers so every decoder predicts the same; and the neighbourhood's
// spacing R (the density term of the prediction B) as a context.
struct PlaneContext {
  int m = 2;               // axis closest to the normal: w is predicted, u and v coded
  int64_t nu = 0, nv = 0, nm = 0;
  int rb = 0;              // spacing bucket
};

inline PlaneContext MakePlane(const Columns& cur, size_t g0, size_t n) {
  PlaneContext pc;
  size_t cnt = std::min<size_t>(4, n - g0);
  int64_t p[4][3];
  for (size_t j = 0; j < cnt; ++j) {
    for (int a = 0; a < 3; ++a) p[j][a] = cur.ch[a][g0 + j];
  }
  Int128 e1[3] = {0, 0, 0}, e2[3] = {0, 0, 0};
  if (cnt == 4) {
    // Parents 0,1 and 2,3 are sibling pairs: which of 2 and 3 lies next to 1 is unknown, so
    // of the two diagonal pairs the one with the larger cross product (the less parallel one)
    // gives the plane.
    Int128 a1[3], a2[3], b1[3], b2[3];
    for (int a = 0; a < 3; ++a) {
      a1[a] = Int128{p[2][a]} - p[0][a], a2[a] = Int128{p[3][a]} - p[1][a];
      b1[a] = Int128{p[3][a]} - p[0][a], b2[a] = Int128{p[2][a]} - p[1][a];
    }
    auto mag = [](const Int128* x, const Int128* y) {
      Int128 c[3] = {x[1] * y[2] - x[2] * y[1], x[2] * y[0] - x[0] * y[2], x[0] * y[1] - x[1] * y[0]};
      Int128 m = 0;
      for (auto v : c) m += v < 0 ? -v : v;
      return m;
    };
    bool use_b = mag(b1, b2) > mag(a1, a2);
    for (int a = 0; a < 3; ++a) e1[a] = use_b ? b1[a] : a1[a], e2[a] = use_b ? b2[a] : a2[a];
  } else if (cnt == 3) {
    for (int a = 0; a < 3; ++a) e1[a] = Int128{p[1][a]} - p[0][a], e2[a] = Int128{p[2][a]} - p[0][a];
  } else if (cnt == 2) {
    for (int a = 0; a < 3; ++a) e1[a] = Int128{p[1][a]} - p[0][a];
  }
  Int128 len = 0;
  for (int a = 0; a < 3; ++a) len += (e1[a] < 0 ? -e1[a] : e1[a]) + (e2[a] < 0 ? -e2[a] : e2[a]);
  int64_t r = static_cast<int64_t>(len / 2);
  pc.rb = std::min<int>(std::bit_width(static_cast<uint64_t>(r)), kRBuckets - 1);
  Int128 nrm[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                     e1[0] * e2[1] - e1[1] * e2[0]};
  Int128 mx = 0;
  for (auto c : nrm) mx = std::max(mx, c < 0 ? -c : c);
  if (mx == 0) return pc;
  while (mx >= (Int128{1} << 24)) {
    for (auto& c : nrm) c >>= 1;
    mx >>= 1;
  }
  int m = 0;
  for (int a = 1; a < 3; ++a) {
    if ((nrm[a] < 0 ? -nrm[a] : nrm[a]) > (nrm[m] < 0 ? -nrm[m] : nrm[m])) m = a;
  }
  pc.m = m;
  pc.nm = static_cast<int64_t>(nrm[m]);
  pc.nu = static_cast<int64_t>(nrm[(m + 1) % 3]);
  pc.nv = static_cast<int64_t>(nrm[(m + 2) % 3]);
  return pc;
}

// Positions of parents [b, e): intra, the detail d = first - second child in the local frame
// (u, v in the plane's axes, w's residual from the plane), oriented so the first non-zero of
// (u, v, w) is positive (7.3.1's swap that halves the angle range). Positions are intra only:
// docs/CODEC.md, "Temporal prediction", says why.
template <typename IO>
void CodePositions(IO& io, Models& md, LevelState& L, size_t b, size_t e) {
  PlaneContext pc;
  size_t plane_group = SIZE_MAX;
  for (size_t i = b; i < e; ++i) {
    if (i == L.singleton) continue;
    if ((i & ~size_t{3}) != plane_group) {
      plane_group = i & ~size_t{3};
      pc = MakePlane(*L.cur, plane_group, L.n);
    }
    int64_t* d[3] = {&L.det.ch[0][i], &L.det.ch[1][i], &L.det.ch[2][i]};
    const int m = pc.m, ua = (m + 1) % 3, va = (m + 2) % 3;
    int64_t u = *d[ua], v = *d[va], w = *d[m];
    if constexpr (IO::kEncode) {
      if (u < 0 || (u == 0 && v < 0) || (u == 0 && v == 0 && w < 0)) {
        u = -u, v = -v, w = -w;
        for (int a = 0; a < 3; ++a) *d[a] = 0 - *d[a];
        L.swap[i] = 1;
      }
    }
    io.U(md.pos_u[pc.rb], u);
    const int ub = std::min<int>(std::bit_width(Abs(u)), kSizeBuckets - 1);
    if (u == 0) {
      io.U(md.pos_v[pc.rb][0], v);
    } else {
      io.S(md.pos_v[pc.rb][ub], v);
    }
    const int wb = std::min<int>(std::bit_width(Abs(u) + Abs(v)), kSizeBuckets - 1);
    int64_t pred = (pc.nm == 0 || !L.plane) ? 0 : RoundDiv(-(Int128{pc.nu} * u + Int128{pc.nv} * v), pc.nm);
    int64_t r = Diff(w, pred);
    io.S(md.pos_w[pc.rb][wb], r);
    if constexpr (!IO::kEncode) {
      w = static_cast<int64_t>(static_cast<uint64_t>(r) + static_cast<uint64_t>(pred));
      *d[ua] = u, *d[va] = v, *d[m] = w;
    }
  }
}

// The encoder's choice for a level: does the plane predict w better than no prediction? On
// clean scans it does; on fused depth maps several noisy layers overlap, pairs cross them and
// the plane of four parents says little (measured: docs/CODEC.md).
inline bool PlanePays(const LevelState& L) {
  double with = 0, without = 0;
  PlaneContext pc;
  size_t plane_group = SIZE_MAX;
  for (size_t i = 0; i < L.n; ++i) {
    if (i == L.singleton) continue;
    if ((i & ~size_t{3}) != plane_group) {
      plane_group = i & ~size_t{3};
      pc = MakePlane(*L.cur, plane_group, L.n);
    }
    if (pc.nm == 0) continue;
    int64_t u = L.det.ch[(pc.m + 1) % 3][i], v = L.det.ch[(pc.m + 2) % 3][i], w = L.det.ch[pc.m][i];
    int64_t pred = RoundDiv(-(Int128{pc.nu} * u + Int128{pc.nv} * v), pc.nm);
    with += std::bit_width(Abs(Diff(w, pred)));
    without += std::bit_width(Abs(w));
  }
  return with <= without;
}

// Any other attribute group of parents [b, e): zerotree significance (7.4: one flag says the
// detail of this pair and of every pair below it is zero; nothing more is coded for that
// subtree), then the detail per channel (prediction B = 0: a child is predicted by its parent,
// 7.3.2/7.3.3), in contexts of the level and of the parent's own detail magnitude.
template <typename IO>
void CodeGroup(IO& io, Models& md, int g, LevelState& L, size_t b, size_t e) {
  const int c0 = kGroupFirst[g], c1 = kGroupFirst[g + 1];
  const int lb = LevelBucket(L.k);
  auto& inherit = L.inherit[g];
  auto& mag = L.mag[g];
  for (size_t i = b; i < e; ++i) {
    if (i == L.singleton) continue;
    if constexpr (IO::kEncode) {
      if (L.swap[i]) {
        for (int c = c0; c < c1; ++c) L.det.ch[c][i] = 0 - L.det.ch[c][i];
      }
    }
    if (inherit[i]) {
      for (int c = c0; c < c1; ++c) L.det.ch[c][i] = 0;
      continue;
    }
    unsigned z = io.B(md.zerotree[g][lb][mag[i] == 0 ? 0 : 1], IO::kEncode ? L.zero[g][i] : 0);
    if (z) {
      for (int c = c0; c < c1; ++c) L.det.ch[c][i] = 0;
      inherit[i] = 1;  // the children inherit "zero"
      continue;
    }
    const bool temporal = g == 1 && L.reference && L.hints[i].valid();
    if (temporal && L.octree && L.k == 1 && L.hints[i].exact) {
      // Both points in cells the reference occupies: predict the detail as the reference's.
      const auto& ref = L.reference->ch;
      int64_t pred[3];
      bool same = true;
      for (int c = 0; c < 3; ++c) {
        pred[c] = Diff(ref[c0 + c][L.hints[i].a], ref[c0 + c][L.hints[i].b]);
        same = same && L.det.ch[c0 + c][i] == pred[c];
      }
      if (io.B(md.tsame[mag[i] == 0 ? 0 : 1], same)) {
        for (int c = 0; c < 3; ++c) L.det.ch[c0 + c][i] = pred[c];
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        int64_t r = Diff(L.det.ch[c0 + c][i], pred[c]);
        io.S(md.tres[c], r);
        L.det.ch[c0 + c][i] = static_cast<int64_t>(static_cast<uint64_t>(pred[c]) + static_cast<uint64_t>(r));
      }
      continue;
    }
    for (int c = c0; c < c1; ++c) {
      int64_t& dv = L.det.ch[c][i];
      if (temporal) {
        const auto& ref = L.reference->ch[c];
        const uint64_t rd = Abs(Diff(ref[L.hints[i].a], ref[L.hints[i].b]));
        io.S(md.tval[c][lb][MagBucket(rd)], dv);
      } else {
        io.S(md.val[c][lb][mag[i]], dv);
      }
    }
  }
}

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_LEVEL_CODER_H_
