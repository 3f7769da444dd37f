// Stream assembly: header, root layer, then the details level by level from the coarsest, in
// segments (docs/CODEC.md, "Segments"). The symbol-level coding is level_coder.h.
#include "codec/codec.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <thread>

#include "codec/internal.h"
#include "codec/level_coder.h"
#include "codec/octree.h"
#include "codec/point_order.h"
#include "codec/temporal.h"
#include "storage/coding.h"
#include "storage/crc32c.h"

namespace hvdb::codec {
namespace {

using EncIOs = std::array<std::unique_ptr<EncIO>, kGroups>;
using DecIOs = std::array<std::unique_ptr<DecIO>, kGroups>;

bool Coded(uint32_t attrs, int g) { return (attrs >> g) & 1u; }

void NewEncoders(uint32_t attrs, EncIOs* ios) {
  for (int g = 0; g < kGroups; ++g) {
    (*ios)[g] = Coded(attrs, g) ? std::make_unique<EncIO>() : nullptr;
  }
}

// Segment: u32 payload length, u32 CRC32C of the payload, payload = per coded group (in
// group order) u32 length + that group's range-coded bytes.
// `geometry`, when given, is group 0's sub-stream (an octree stream's segment 0).
void AppendSegment(uint32_t attrs, EncIOs* ios, std::string* out, StreamStats* stats,
                   const std::string* geometry = nullptr) {
  Writer w;
  for (int g = 0; g < kGroups; ++g) {
    if (!Coded(attrs, g)) continue;
    if (g == 0 && geometry) {
      w.Put<uint32_t>(static_cast<uint32_t>(geometry->size()));
      w.PutBytes(geometry->data(), geometry->size());
      if (stats) stats->bytes_by_attribute[0] += geometry->size();
      continue;
    }
    EncIO& io = *(*ios)[g];
    io.rc.Finish();
    w.Put<uint32_t>(static_cast<uint32_t>(io.buf.size()));
    w.PutBytes(io.buf.data(), io.buf.size());
    if (stats) stats->bytes_by_attribute[g] += io.buf.size();
  }
  const std::string& payload = w.data();
  Writer h;
  h.Put<uint32_t>(static_cast<uint32_t>(payload.size()));
  h.Put<uint32_t>(crc32c::Value(payload.data(), payload.size()));
  out->append(h.data());
  out->append(payload);
  if (stats) stats->header_bytes += 8 + 4 * static_cast<size_t>(std::popcount(attrs));
}

enum class SegmentRead { kOk, kIncomplete };

// Reads the segment at *pos. kIncomplete when the data ends inside it.
// `geometry`, when given, receives group 0's sub-stream instead of a decoder.
Status ReadSegment(std::string_view s, size_t* pos, uint32_t attrs, DecIOs* ios,
                   SegmentRead* result, StreamStats* stats, std::string_view* geometry = nullptr) {
  const auto* p = reinterpret_cast<const uint8_t*>(s.data());
  if (*pos > s.size() || s.size() - *pos < 8) {
    *result = SegmentRead::kIncomplete;
    return Status::OK();
  }
  uint32_t len = DecodeLE<uint32_t>(p + *pos), crc = DecodeLE<uint32_t>(p + *pos + 4);
  if (s.size() - *pos - 8 < len) {
    *result = SegmentRead::kIncomplete;
    return Status::OK();
  }
  const uint8_t* q = p + *pos + 8;
  if (crc32c::Value(q, len) != crc) {
    return Status::Corruption("hvdb7 segment at byte " + std::to_string(*pos) +
                              ": checksum mismatch");
  }
  size_t off = 0;
  for (int g = 0; g < kGroups; ++g) {
    if (!Coded(attrs, g)) {
      (*ios)[g] = nullptr;
      continue;
    }
    if (len - off < 4) return Status::Corruption("hvdb7 segment: sub-stream table truncated");
    uint32_t sub = DecodeLE<uint32_t>(q + off);
    off += 4;
    if (len - off < sub) return Status::Corruption("hvdb7 segment: sub-stream overruns segment");
    if (g == 0 && geometry) {
      *geometry = std::string_view(reinterpret_cast<const char*>(q + off), sub);
      (*ios)[g] = nullptr;
    } else {
      (*ios)[g] = std::make_unique<DecIO>(q + off, sub);
    }
    if (stats) stats->bytes_by_attribute[g] += sub;
    off += sub;
  }
  if (off != len) return Status::Corruption("hvdb7 segment: trailing bytes");
  if (stats) stats->header_bytes += 8 + 4 * static_cast<size_t>(std::popcount(attrs));
  *pos += 8 + len;
  *result = SegmentRead::kOk;
  return Status::OK();
}

Status CheckOverrun(const DecIOs& ios) {
  for (const auto& io : ios) {
    if (io && io->rc.overrun() > 0) {
      return Status::Corruption("hvdb7 sub-stream read past its end (corrupt data)");
    }
  }
  return Status::OK();
}

// Positions (pair geometry; octree streams carry them in segment 0) then, on two threads,
// the other groups of parents [b, e).
template <typename IO>
void CodeChunk(std::array<std::unique_ptr<IO>, kGroups>& ios, Models& md, LevelState& L,
               uint32_t attrs, const TemporalIndex* temporal, size_t b, size_t e,
               bool positions, int max_threads) {
  std::vector<int> groups;
  for (int g = 1; g < kGroups; ++g) {
    if (Coded(attrs, g)) groups.push_back(g);
  }
  auto run = [&](size_t first, size_t step) {
    for (size_t j = first; j < groups.size(); j += step) CodeGroup(*ios[groups[j]], md, groups[j], L, b, e);
  };
  const bool threads = !groups.empty() && e - b >= 4096 && ThreadCount(max_threads) > 1;
  // The encoder's groups need the orientation its position pass chooses, and temporal
  // groups the decoded positions; otherwise a decoder reads the groups while it reads the
  // positions (the positions are the longest pass).
  if (threads && !IO::kEncode && !temporal && positions) {
    std::thread t([&] { run(0, 2); });
    CodePositions(*ios[0], md, L, b, e);
    run(1, 2);
    t.join();
    return;
  }
  if (positions) CodePositions(*ios[0], md, L, b, e);
  if (temporal) temporal->Hints(L, b, e);
  if (threads && groups.size() >= 2) {
    std::thread t([&] { run(1, 2); });
    run(0, 2);
    t.join();
  } else {
    run(0, 1);
  }
}

void CodeRoot(EncIOs& ios, Models& md, const Columns& cur, uint32_t attrs) {
  for (int c = 0; c < kChannels; ++c) {
    if (!Coded(attrs, GroupOf(c))) continue;
    int64_t prev = 0;
    for (size_t i = 0; i < cur.n; ++i) {
      int64_t d = Diff(cur.ch[c][i], prev);
      ios[GroupOf(c)]->S(md.root[c], d);
      prev = cur.ch[c][i];
    }
  }
}

void DecodeRoot(DecIOs& ios, Models& md, Columns* cur, uint32_t attrs) {
  for (int c = 0; c < kChannels; ++c) {
    if (!Coded(attrs, GroupOf(c))) continue;
    uint64_t prev = 0;
    for (size_t i = 0; i < cur->n; ++i) {
      int64_t d;
      ios[GroupOf(c)]->S(md.root[c], d);
      prev += static_cast<uint64_t>(d);
      cur->ch[c][i] = static_cast<int64_t>(prev);
    }
  }
}

size_t ChildBase(size_t i, uint32_t singleton) {
  return 2 * i - ((singleton != kNoChild && i > singleton) ? 1 : 0);
}

// Children of the level's parents from parents and details (both sides), with the zerotree
// state they inherit.
void Expand(const LevelState& L, uint32_t attrs, Columns* next,
            std::array<std::vector<uint8_t>, kGroups>* inherit,
            std::array<std::vector<uint8_t>, kGroups>* mag, int threads) {
  const size_t n = L.n;
  const size_t m = 2 * n - (L.singleton != kNoChild ? 1 : 0);
  next->Resize(m, attrs);
  for (int g = 0; g < kGroups; ++g) {
    if (!Coded(attrs, g)) continue;
    (*inherit)[g].assign(m, 0);
    (*mag)[g].assign(m, 0);
  }
  ParallelRange(n, [&](size_t b, size_t e) {
    for (size_t i = b; i < e; ++i) {
      size_t cb = ChildBase(i, L.singleton);
      bool single = i == L.singleton;
      for (int c = 0; c < kChannels; ++c) {
        if (next->ch[c].empty()) continue;
        if (single) {
          next->ch[c][cb] = L.cur->ch[c][i];
        } else {
          Unlift(L.cur->ch[c][i], L.det.ch[c][i], &next->ch[c][cb], &next->ch[c][cb + 1]);
        }
      }
      for (int g = 1; g < kGroups; ++g) {
        if (!Coded(attrs, g)) continue;
        uint8_t inh = L.inherit[g][i], mb = 0;
        if (single) {
          mb = L.mag[g][i];
        } else if (!inh) {
          uint64_t mx = 0;
          for (int c = kGroupFirst[g]; c < kGroupFirst[g + 1]; ++c) mx = std::max(mx, Abs(L.det.ch[c][i]));
          mb = MagBucket(mx);
        }
        for (size_t j = 0; j < (single ? 1u : 2u); ++j) {
          (*inherit)[g][cb + j] = inh;
          (*mag)[g][cb + j] = mb;
        }
      }
    }
  }, threads);
}

// Subtree-zero flags per group and level (encoder): the pair's detail and every detail below
// it are zero.
std::vector<std::array<std::vector<uint8_t>, kGroups>> SubtreeZero(const Hierarchy& h,
                                                                  uint32_t attrs) {
  const int levels = static_cast<int>(h.level.size()) - 1;
  std::vector<std::array<std::vector<uint8_t>, kGroups>> sz(levels + 1);
  for (int k = 1; k <= levels; ++k) {
    const Columns& below = h.level[k - 1];
    const auto& pairs = h.pairs[k];
    for (int g = 1; g < kGroups; ++g) {
      if (!Coded(attrs, g)) continue;
      auto& out = sz[k][g];
      out.assign(pairs.size(), 0);
      for (size_t p = 0; p < pairs.size(); ++p) {
        auto [a, b] = pairs[p];
        bool zero = true;
        if (b != kNoChild) {
          for (int c = kGroupFirst[g]; c < kGroupFirst[g + 1] && zero; ++c) {
            zero = below.ch[c][a] == below.ch[c][b];
          }
        }
        if (k > 1) {
          zero = zero && sz[k - 1][g][a] && (b == kNoChild || sz[k - 1][g][b]);
        }
        out[p] = zero ? 1 : 0;
      }
    }
  }
  return sz;
}

Status CheckOptions(std::span<const Point> points, const EncodeOptions& o) {
  if (o.qp < 0 || o.qp > 30) return Status::InvalidArgument("qp must be 0 (exact) to 30 bits");
  if (o.qc < 1 || o.qc > 8) return Status::InvalidArgument("qc must be 1 to 8 bits");
  if (o.qn < 1 || o.qn > 16) return Status::InvalidArgument("qn must be 1 to 16 bits");
  if (o.qcov < 0 || o.qcov > 20) return Status::InvalidArgument("qcov must be 0 (exact) to 20 bits");
  if (o.levels < 0 || o.levels > 40) return Status::InvalidArgument("levels must be 0 (auto) to 40");
  if (o.chunk < 64) return Status::InvalidArgument("chunk must be at least 64 parents");
  if (o.effort < 0 || o.effort > 1) return Status::InvalidArgument("effort must be 0 or 1");
  if (o.threads < 0 || o.threads > 64) return Status::InvalidArgument("threads must be 0 (auto) to 64");
  if (o.geometry == EncodeOptions::Geometry::kOctree && (o.qp < 1 || o.qp > kMaxOctreeDepth)) {
    return Status::InvalidArgument("octree geometry codes grids of 1 to 21 bits (qp); use the pair "
                                   "geometry for exact floats or finer grids");
  }
  if ((o.attributes & ~kAllAttributes) != 0) return Status::InvalidArgument("unknown attribute bits");
  if (points.size() >= kNoChild) return Status::InvalidArgument("at most 2^32 - 2 points per stream");
  const bool log_cov = (o.attributes & kCovariance) && o.qcov > 0;
  for (const Point& p : points) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return Status::InvalidArgument("point " + std::to_string(p.id) +
                                     " has a non-finite position; the coder takes finite points");
    }
    if (log_cov && !std::all_of(p.cov.begin(), p.cov.end(), [](float v) { return std::isfinite(v); })) {
      return Status::InvalidArgument("point " + std::to_string(p.id) +
                                     " has a non-finite covariance (code it exactly with qcov 0)");
    }
  }
  return Status::OK();
}

Status CheckPositions(const Columns& c, const Quantizer& q) {
  int64_t lo = q.qp == 0 ? INT32_MIN : 0;
  int64_t hi = q.qp == 0 ? INT32_MAX : (int64_t{1} << q.qp) - 1;
  for (int a = 0; a < 3; ++a) {
    for (int64_t v : c.ch[a]) {
      if (v < lo || v > hi) return Status::Corruption("hvdb7 stream decodes to a position off its grid");
    }
  }
  return Status::OK();
}

}  // namespace

Status Encode(std::span<const Point> points, const EncodeOptions& options, std::string* out,
              StreamStats* stats, const Reference* reference) {
  Status st = CheckOptions(points, options);
  if (!st.ok()) return st;
  StreamStats local;
  StreamStats& S = stats ? *stats : local;
  S = StreamStats{};
  Header hd;
  hd.q.qp = options.qp;
  hd.q.qc = options.qc;
  hd.q.qn = options.qn;
  hd.q.qcov = options.qcov;
  uint32_t attrs = options.attributes | kPosition;
  if (attrs & (kNormal | kCovariance)) attrs |= kFlags;  // which points have them
  hd.q.attributes = hd.attributes = attrs;
  hd.points = points.size();
  hd.chunk = static_cast<uint32_t>(options.chunk);
  hd.flags = options.progressive ? kProgressive : 0;
  hd.q.Fit(points);
  const bool octree = options.geometry == EncodeOptions::Geometry::kOctree ||
                      (options.geometry == EncodeOptions::Geometry::kAuto && options.qp >= 1 &&
                       options.qp <= kMaxOctreeDepth);
  if (octree) {
    hd.flags |= kOctree;
    // Temporal: code on the reference's grid when the frame fits it, so what did not move
    // lands in the same cells.
    if (reference && FitsGrid(points, *reference, options.qp)) {
      for (int a = 0; a < 3; ++a) hd.q.origin[a] = reference->origin[a];
      hd.q.step = reference->step;
    }
  }
  const uint32_t level_attrs = octree ? attrs & ~kPosition : attrs;
  const int threads = ThreadCount(options.threads);
  const Quantizer& q = hd.q;

  Columns base;
  base.Resize(points.size(), attrs);
  ParallelRange(points.size(), [&](size_t b, size_t e) {
    int64_t c[kChannels];
    for (size_t i = b; i < e; ++i) {
      q.ToChannels(points[i], c);
      for (int ch = 0; ch < kChannels; ++ch) {
        if (!base.ch[ch].empty()) base.ch[ch][i] = c[ch];
      }
    }
  });
  int levels = options.levels > 0 ? options.levels : AutoLevels(points.size());
  Hierarchy h;
  std::string geometry;
  std::vector<uint64_t> ref_cells;
  if (octree) {
    // Positions go in segment 0; the other attributes ride a hierarchy of Morton neighbours
    // (none when positions are all there is).
    if (level_attrs == 0) levels = 0;
    std::vector<uint64_t> codes = MortonSort(&base, attrs);
    if (reference) ref_cells = ReferenceCells(reference->points, q);
    EncodeOctree(codes, q.qp, reference ? &ref_cells : nullptr, threads, &geometry);
    if (levels > 0) PairOrder(&codes, &base);
    ConsecutiveHierarchy(std::move(base), levels, attrs, &h);
  } else {
    // Effort 1: k-d tree candidates at every level (the fewest bits); 0: none (twice as fast).
    BuildHierarchy(std::move(base), levels, q.Has(2), options.effort >= 1 ? levels : 0, &h);
  }
  levels = static_cast<int>(h.level.size()) - 1;
  hd.levels = levels;
  auto sz = SubtreeZero(h, attrs);

  std::unique_ptr<TemporalIndex> tindex;
  if (reference && !octree && !(attrs & kColor)) {
    return Status::InvalidArgument("temporal coding of pair geometry needs the colour attribute "
                                   "(it is what the reference predicts)");
  }
  if (reference) {
    hd.flags |= kTemporal;
    hd.reference_points = reference->points.size();
    hd.reference_crc = ReferenceCrc(reference->points);
    if (attrs & kColor) tindex = std::make_unique<TemporalIndex>(reference->points, q);
  }

  auto md = std::make_unique<Models>();
  std::string body;
  // Root layer in curve order (octree streams: already in Morton order).
  std::vector<uint32_t> nodes;
  if (octree) {
    nodes.resize(h.level[levels].n);
    for (size_t i = 0; i < nodes.size(); ++i) nodes[i] = static_cast<uint32_t>(i);
  } else {
    nodes = CurveOrder(h.level[levels]);
  }
  Columns cur;
  cur.Resize(nodes.size(), attrs);
  for (int c = 0; c < kChannels; ++c) {
    if (cur.ch[c].empty()) continue;
    for (size_t i = 0; i < nodes.size(); ++i) cur.ch[c][i] = h.level[levels].ch[c][nodes[i]];
  }
  EncIOs ios;
  NewEncoders(level_attrs, &ios);
  CodeRoot(ios, *md, cur, level_attrs);
  AppendSegment(attrs, &ios, &body, &S, octree ? &geometry : nullptr);

  std::array<std::vector<uint8_t>, kGroups> inherit, mag;
  for (int g = 0; g < kGroups; ++g) {
    if (Coded(attrs, g)) inherit[g].assign(cur.n, 0), mag[g].assign(cur.n, 0);
  }
  hd.singleton.assign(levels, kNoChild);
  if (!options.progressive) NewEncoders(level_attrs, &ios);
  for (int k = levels; k >= 1; --k) {
    LevelState L;
    L.k = k;
    L.q = &q;
    L.cur = &cur;
    L.n = cur.n;
    L.det.Resize(L.n, attrs);
    L.swap.assign(L.n, 0);
    const Columns& below = h.level[k - 1];
    for (size_t i = 0; i < L.n; ++i) {
      auto [a, b] = h.pairs[k][nodes[i]];
      if (b == kNoChild) {
        L.singleton = static_cast<uint32_t>(i);
        continue;
      }
      for (int c = 0; c < kChannels; ++c) {
        if (!L.det.ch[c].empty()) L.det.ch[c][i] = Diff(below.ch[c][a], below.ch[c][b]);
      }
    }
    hd.singleton[k - 1] = L.singleton;
    L.plane = !octree && PlanePays(L);
    L.octree = octree;
    if (L.plane) hd.plane_mask |= uint64_t{1} << (k - 1);
    for (int g = 1; g < kGroups; ++g) {
      if (!Coded(attrs, g)) continue;
      L.zero[g].resize(L.n);
      for (size_t i = 0; i < L.n; ++i) L.zero[g][i] = sz[k][g][nodes[i]];
    }
    L.inherit = std::move(inherit);
    L.mag = std::move(mag);
    if (tindex) {
      L.reference = &tindex->values();
      L.hints.resize(L.n);
    }
    const size_t step = options.progressive ? options.chunk : std::max<size_t>(L.n, 1);
    for (size_t b = 0; b < L.n; b += step) {
      if (options.progressive) NewEncoders(level_attrs, &ios);
      CodeChunk(ios, *md, L, level_attrs, tindex.get(), b, std::min(L.n, b + step), !octree,
                threads);
      if (options.progressive) AppendSegment(level_attrs, &ios, &body, &S);
    }
    // Children in stream order.
    std::vector<uint32_t> next_nodes(2 * L.n - (L.singleton != kNoChild ? 1 : 0));
    for (size_t i = 0; i < L.n; ++i) {
      auto [a, b] = h.pairs[k][nodes[i]];
      size_t cb = ChildBase(i, L.singleton);
      if (b == kNoChild) {
        next_nodes[cb] = a;
      } else {
        next_nodes[cb] = L.swap[i] ? b : a;
        next_nodes[cb + 1] = L.swap[i] ? a : b;
      }
    }
    Columns next;
    Expand(L, attrs, &next, &inherit, &mag, threads);
    cur = std::move(next);
    nodes = std::move(next_nodes);
  }
  if (!options.progressive && levels > 0) AppendSegment(level_attrs, &ios, &body, &S);

  out->clear();
  WriteHeader(hd, out);
  S.header_bytes += out->size();
  out->append(body);
  S.points = points.size();
  S.levels = levels;
  S.total_bytes = out->size();
  S.temporal = reference != nullptr;
  return Status::OK();
}

Status Decode(std::string_view stream, std::vector<Point>* out, const DecodeOptions& options,
              StreamStats* stats) {
  StreamStats local;
  StreamStats& S = stats ? *stats : local;
  S = StreamStats{};
  if (options.threads < 0) {
    return Status::InvalidArgument("threads: " + std::to_string(options.threads) +
                                   " is negative (0: as many as help, 1: the calling thread only)");
  }
  Header hd;
  size_t pos = 0;
  Status st = ParseHeader(stream, &options, &hd, &pos);
  if (!st.ok()) return st;
  S.header_bytes = pos;
  const bool prefix = options.max_bytes > 0 && options.max_bytes < stream.size();
  if (prefix) {
    if (!(hd.flags & kProgressive)) {
      return Status::InvalidArgument("only progressive hvdb7 streams decode from a prefix "
                                     "(encode with --progressive)");
    }
    if (options.max_bytes < pos) {
      return Status::InvalidArgument("a prefix of " + std::to_string(options.max_bytes) +
                                     " bytes does not hold the stream's header (" +
                                     std::to_string(pos) + " bytes)");
    }
    stream = stream.substr(0, options.max_bytes);
  }
  const bool octree = (hd.flags & kOctree) != 0;
  std::unique_ptr<TemporalIndex> tindex;
  if (hd.flags & kTemporal) {
    if (!options.reference) {
      return Status::InvalidArgument("temporal hvdb7 stream: decoding needs its reference frame "
                                     "(the decoded previous frame)");
    }
    if (options.reference->points.size() != hd.reference_points ||
        ReferenceCrc(options.reference->points) != hd.reference_crc) {
      return Status::InvalidArgument("temporal hvdb7 stream: the reference given is not the frame "
                                     "it was coded against (point count or checksum differs)");
    }
    if (hd.attributes & kColor) tindex = std::make_unique<TemporalIndex>(options.reference->points, hd.q);
  }
  const uint32_t attrs = hd.attributes;
  const uint32_t level_attrs = octree ? attrs & ~kPosition : attrs;
  if (octree && level_attrs == 0 && hd.levels != 0) {
    return Status::Corruption("hvdb7 octree stream of positions only has hierarchy levels");
  }
  const Quantizer& q = hd.q;
  auto md = std::make_unique<Models>();
  Columns cur;
  cur.Resize(LevelSize(hd.points, hd.levels), attrs);
  DecIOs ios;
  SegmentRead sr;
  std::string_view geometry;
  st = ReadSegment(stream, &pos, attrs, &ios, &sr, &S, octree ? &geometry : nullptr);
  if (!st.ok()) return st;
  if (sr == SegmentRead::kIncomplete) {
    return prefix ? Status::InvalidArgument("a prefix of " + std::to_string(options.max_bytes) +
                                            " bytes does not hold the stream's " +
                                            (octree ? "geometry" : "root layer"))
                  : Status::Corruption("hvdb7 stream truncated in its root layer");
  }
  std::vector<std::array<std::vector<int64_t>, 3>> octree_pos;
  if (octree) {
    std::vector<uint64_t> ref_cells, codes;
    if (hd.flags & kTemporal) ref_cells = ReferenceCells(options.reference->points, q);
    st = DecodeOctree(geometry, q.qp, hd.points, (hd.flags & kTemporal) ? &ref_cells : nullptr,
                      ThreadCount(options.threads), &codes);
    if (!st.ok()) return st;
    if (hd.levels > 0) PairOrder(&codes, nullptr);
    octree_pos = PositionLevels(codes, hd.levels);
    for (int a = 0; a < 3; ++a) cur.ch[a] = octree_pos[hd.levels][a];
  }
  DecodeRoot(ios, *md, &cur, level_attrs);
  st = CheckOverrun(ios);
  if (st.ok()) st = CheckPositions(cur, q);
  if (!st.ok()) return st;

  const bool progressive = hd.flags & kProgressive;
  std::array<std::vector<uint8_t>, kGroups> inherit, mag;
  for (int g = 0; g < kGroups; ++g) {
    if (Coded(attrs, g)) inherit[g].assign(cur.n, 0), mag[g].assign(cur.n, 0);
  }
  if (!progressive && hd.levels > 0) {
    st = ReadSegment(stream, &pos, level_attrs, &ios, &sr, &S);
    if (!st.ok()) return st;
    if (sr == SegmentRead::kIncomplete) return Status::Corruption("hvdb7 stream truncated");
  }
  bool stopped = false;
  for (int k = hd.levels; k >= 1 && !stopped; --k) {
    LevelState L;
    L.k = k;
    L.q = &q;
    L.cur = &cur;
    L.n = cur.n;
    L.singleton = hd.singleton[k - 1];
    L.plane = (hd.plane_mask >> (k - 1)) & 1;
    L.octree = octree;
    L.det.Resize(L.n, attrs);
    if (octree) {
      for (int a = 0; a < 3; ++a) {
        const auto& below = octree_pos[k - 1][a];
        for (size_t i = 0; i < L.n; ++i) {
          if (i != L.singleton) L.det.ch[a][i] = Diff(below[2 * i], below[2 * i + 1]);
        }
      }
    }
    L.inherit = std::move(inherit);
    L.mag = std::move(mag);
    L.threads = options.threads;
    if (tindex) {
      L.reference = &tindex->values();
      L.hints.resize(L.n);
    }
    const size_t step = progressive ? hd.chunk : std::max<size_t>(L.n, 1);
    size_t done = 0;
    for (size_t b = 0; b < L.n; b += step) {
      if (progressive) {
        st = ReadSegment(stream, &pos, level_attrs, &ios, &sr, &S);
        if (!st.ok()) return st;
        if (sr == SegmentRead::kIncomplete) {
          if (!prefix) return Status::Corruption("hvdb7 stream truncated at level " + std::to_string(k));
          stopped = true;
          break;
        }
      }
      size_t e = std::min(L.n, b + step);
      CodeChunk(ios, *md, L, level_attrs, tindex.get(), b, e, !octree, options.threads);
      st = CheckOverrun(ios);
      if (!st.ok()) return st;
      done = e;
    }
    if (stopped) {
      // A prefix: the decoded pairs give their two children, the rest stay one point.
      Columns next;
      size_t m = ChildBase(done, L.singleton) + (L.n - done);
      next.Resize(m, attrs);
      LevelState part = std::move(L);
      const size_t cb_end = ChildBase(done, part.singleton);
      for (int c = 0; c < kChannels; ++c) {
        if (next.ch[c].empty()) continue;
        for (size_t i = 0; i < done; ++i) {
          size_t cb = ChildBase(i, part.singleton);
          if (i == part.singleton) {
            next.ch[c][cb] = cur.ch[c][i];
          } else {
            Unlift(cur.ch[c][i], part.det.ch[c][i], &next.ch[c][cb], &next.ch[c][cb + 1]);
          }
        }
        for (size_t i = done; i < part.n; ++i) next.ch[c][cb_end + (i - done)] = cur.ch[c][i];
      }
      cur = std::move(next);
    } else {
      Columns next;
      Expand(L, attrs, &next, &inherit, &mag, options.threads);
      cur = std::move(next);
    }
    st = CheckPositions(cur, q);
    if (!st.ok()) return st;
  }
  if (!prefix && pos != stream.size()) {
    return Status::Corruption("hvdb7 stream has " + std::to_string(stream.size() - pos) +
                              " bytes after its last segment");
  }
  out->resize(cur.n);
  ParallelRange(cur.n, [&](size_t b, size_t e) {
    int64_t c[kChannels] = {};
    for (size_t i = b; i < e; ++i) {
      for (int ch = 0; ch < kChannels; ++ch) {
        if (!cur.ch[ch].empty()) c[ch] = cur.ch[ch][i];
      }
      q.ToPoint(c, &(*out)[i]);
    }
  }, options.threads);
  S.points = cur.n;
  S.levels = hd.levels;
  S.total_bytes = pos;
  S.temporal = (hd.flags & kTemporal) != 0;
  return Status::OK();
}

Status ReadInfo(std::string_view stream, StreamInfo* info) {
  Header hd;
  size_t used = 0;
  DecodeOptions o;
  o.max_points = UINT64_MAX;
  Status st = ParseHeader(stream, &o, &hd, &used);
  if (!st.ok()) return st;
  info->version = (hd.flags & kOctree) ? kOctreeVersion : kVersion;
  info->octree = (hd.flags & kOctree) != 0;
  for (int a = 0; a < 3; ++a) info->origin[a] = hd.q.origin[a];
  info->step = hd.q.step;
  info->points = hd.points;
  info->attributes = hd.attributes;
  info->qp = hd.q.qp;
  info->qc = hd.q.qc;
  info->qn = hd.q.qn;
  info->qcov = hd.q.qcov;
  info->levels = hd.levels;
  info->progressive = hd.flags & kProgressive;
  info->temporal = hd.flags & kTemporal;
  return Status::OK();
}

}  // namespace hvdb::codec
