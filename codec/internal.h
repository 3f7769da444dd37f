// Internals shared by the encoder and decoder: points as integer channels, the pair
// hierarchy, and the stream header. Not a public header.
#ifndef HVDB_CODEC_INTERNAL_H_
#define HVDB_CODEC_INTERNAL_H_

#include <array>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "codec/codec.h"

namespace hvdb::codec {

// Integer channels, grouped by attribute (group index = bit index of Attribute).
inline constexpr int kChannels = 19;
inline constexpr int kGroups = 9;
inline constexpr int kGroupFirst[kGroups + 1] = {0, 3, 6, 8, 14, 15, 16, 17, 18, 19};
inline int GroupOf(int channel) {
  int g = 0;
  while (kGroupFirst[g + 1] <= channel) ++g;
  return g;
}

// How floats become the integers the hierarchy works on, and back (docs/CODEC.md, "Channels").
struct Quantizer {
  int qp = 11, qc = 8, qn = 10, qcov = 6;
  uint32_t attributes = kDefaultAttributes;
  double origin[3] = {0, 0, 0};
  double step = 1.0;  // position grid step (qp > 0)

  // Picks origin and step from the bounding box.
  void Fit(std::span<const Point> pts);
  bool Has(int group) const { return (attributes >> group) & 1u; }
  // Channel values of one point (only the coded groups are written).
  void ToChannels(const Point& p, int64_t* c) const;
  void ToPoint(const int64_t* c, Point* p) const;
};

// Structure-of-arrays channel values of one level.
struct Columns {
  size_t n = 0;
  std::array<std::vector<int64_t>, kChannels> ch;
  void Resize(size_t count, uint32_t attributes);
};

// The S-transform (integer Haar lifting): exact, and the parent does not depend on which
// child is first: s = floor((a + b) / 2), d = a - b. Unsigned arithmetic: ids wrap.
inline int64_t LiftParent(int64_t a, int64_t b) {
  uint64_t d = static_cast<uint64_t>(a) - static_cast<uint64_t>(b);
  return static_cast<int64_t>(static_cast<uint64_t>(b) +
                              static_cast<uint64_t>(static_cast<int64_t>(d) >> 1));
}
inline void Unlift(int64_t s, int64_t d, int64_t* a, int64_t* b) {
  uint64_t bb = static_cast<uint64_t>(s) - static_cast<uint64_t>(d >> 1);
  *b = static_cast<int64_t>(bb);
  *a = static_cast<int64_t>(bb + static_cast<uint64_t>(d));
}
inline int64_t Diff(int64_t a, int64_t b) {
  return static_cast<int64_t>(static_cast<uint64_t>(a) - static_cast<uint64_t>(b));
}

inline constexpr uint32_t kNoChild = 0xFFFFFFFFu;

// The pair forest, bottom up (encoder side). level[0] is the input; level[k] (k >= 1) holds
// the parents of level[k-1], pairs[k][i] the two children of parent i (second kNoChild for the
// one unpaired point of an odd level).
struct Hierarchy {
  std::vector<Columns> level;
  std::vector<std::vector<std::array<uint32_t, 2>>> pairs;
};

// Indices of the points in Morton order of their positions.
std::vector<uint32_t> CurveOrder(const Columns& cur);

// Builds `levels` levels over `base` (moved in) by greedy matching (7.2); the finest
// `knn_levels` take their candidates from a k-d tree.
void BuildHierarchy(Columns base, int levels, bool use_normals, int knn_levels, Hierarchy* h);

// Number of levels when EncodeOptions::levels is 0.
int AutoLevels(uint64_t n);
inline uint64_t LevelSize(uint64_t n, int k) {
  for (int i = 0; i < k; ++i) n = (n + 1) / 2;
  return n;
}

// Runs fn(begin, end) over [0, n) on up to `max_threads` threads (0: the machine's cores, at
// most 4); 1 spawns none (WebAssembly without SharedArrayBuffer has no threads).
template <typename Fn>
void ParallelRange(size_t n, const Fn& fn, int max_threads = 0) {
  size_t threads = std::min<size_t>(std::max(1u, std::thread::hardware_concurrency()), 4);
  if (max_threads > 0) threads = std::min<size_t>(threads, static_cast<size_t>(max_threads));
  if (threads == 1 || n < 8192) return fn(size_t{0}, n);
  std::vector<std::thread> pool;
  size_t chunk = (n + threads - 1) / threads;
  for (size_t t = 1; t < threads; ++t) {
    size_t b = t * chunk, e = std::min(n, b + chunk);
    if (b < e) pool.emplace_back([&fn, b, e] { fn(b, e); });
  }
  fn(0, std::min(n, chunk));
  for (auto& th : pool) th.join();
}

// Stream header (docs/CODEC.md, "Header").
inline constexpr char kMagic[4] = {'H', 'V', '7', 'C'};
inline constexpr uint8_t kVersion = 1;
enum HeaderFlags : uint8_t { kProgressive = 1, kTemporal = 2 };

struct Header {
  uint8_t flags = 0;
  uint32_t attributes = 0;
  uint64_t points = 0;
  int levels = 0;
  uint32_t chunk = 0;
  Quantizer q;
  std::vector<uint32_t> singleton;  // per level 1..L: index of the unpaired parent or kNoChild
  uint64_t plane_mask = 0;          // bit k-1: level k predicts w from the plane
  uint64_t reference_points = 0;
  uint32_t reference_crc = 0;
};
void WriteHeader(const Header& h, std::string* out);
// Parses and checks the header; *used gets its size in bytes.
Status ParseHeader(std::string_view s, const DecodeOptions* opts, Header* h, size_t* used);

// CRC32C of a reference frame's records: a temporal stream names the frame it needs.
uint32_t ReferenceCrc(std::span<const Point> pts);

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_INTERNAL_H_
