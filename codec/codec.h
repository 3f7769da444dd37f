// hvdb7: the progressive multiresolution point coder of thesis chapter 7.
//
// A point set is decomposed into a forest of pairs (7.2: neighbours paired greedily by the
// weights of eqs. 7.1-7.3, each pair contracted to its average, recursively), the detail of
// every pair is coded relative to a local reference frame built from the neighbouring average
// points (7.3: C and B per attribute), and the details are entropy coded with zerotree
// significance and an adaptive arithmetic coder (7.4). Coarse levels come first, so any prefix
// of a progressive stream decodes to a complete, coarser point set. A frame can be coded
// against the decoded previous frame (temporal prediction). docs/CODEC.md has the bitstream.
//
// Errors are Status values, as in storage/; nothing here throws.
#ifndef HVDB_CODEC_CODEC_H_
#define HVDB_CODEC_CODEC_H_

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::codec {

// Attributes a stream can carry (bits of EncodeOptions::attributes).
enum Attribute : uint32_t {
  kPosition = 1u << 0,
  kColor = 1u << 1,
  kNormal = 1u << 2,
  kCovariance = 1u << 3,
  kId = 1u << 4,
  kFrame = 1u << 5,
  kLabel = 1u << 6,
  kCamera = 1u << 7,
  kFlags = 1u << 8,
};
inline constexpr uint32_t kAllAttributes = (1u << 9) - 1;
inline constexpr uint32_t kDefaultAttributes = kPosition | kColor | kNormal | kFlags;

struct EncodeOptions {
  // Position bits per axis over the largest extent of the bounding box (as Draco's -qp);
  // 0 codes the float values exactly.
  int qp = 11;
  // Colour: bits of luma; chroma gets one bit less (7.3.2). 8 is lossless.
  int qc = 8;
  // Normal: bits per octahedral coordinate. 16 is lossless (the stored resolution).
  int qn = 10;
  // Covariance: fractional bits of the log-Cholesky coordinates (docs/CODEC.md); 0 is exact.
  int qcov = 6;
  uint32_t attributes = kDefaultAttributes;  // kPosition is always coded
  // Progressive: the details of each level in chunks that decode on their own prefix.
  bool progressive = false;
  // Levels of the pair hierarchy; 0 picks them so the root layer has at most 512 points.
  int levels = 0;
  // Parents per progressive chunk.
  int chunk = 16384;
  // Pairing effort: 1 takes candidates from k-d tree neighbours (fewer bits), 0 from the
  // space-filling curve alone (faster; servers coding on the fly use it). Pair geometry only.
  int effort = 1;
  // How positions are coded. kAuto: the octree (version 2 streams) when qp is 1..21, the pair
  // hierarchy (version 1) for exact floats (qp 0) and finer grids. kOctree with another qp is
  // refused; kPairs always gives version 1 streams.
  enum class Geometry { kAuto, kOctree, kPairs };
  Geometry geometry = Geometry::kAuto;
  // Threads the encoder may use (0: as many as the machine has, at most 4).
  int threads = 0;
};

// The decoded previous frame a temporal stream was coded against (see EncodeTemporal).
struct Reference {
  std::vector<Point> points;  // as returned by Decode of the reference stream
  // The reference stream's grid (ReadInfo gives it). When set and the frame fits in it, an
  // octree stream codes on the same grid, so cells that did not move are predicted exactly.
  double origin[3] = {0, 0, 0};
  double step = 0;  // 0: unknown (the frame gets its own grid)
  int qp = 0;
};

struct DecodeOptions {
  // Decode only the first `max_bytes` of the stream (a progressive prefix); 0: all of it.
  size_t max_bytes = 0;
  // Streams that claim more points are refused before anything is allocated.
  uint64_t max_points = 1ull << 27;
  const Reference* reference = nullptr;  // required for temporal streams
  // Threads the decoder may use: 0 as many as help (up to the machine's cores); 1 decodes on
  // the calling thread alone (WebAssembly without SharedArrayBuffer has no std::thread).
  int threads = 0;
};

// What was spent where, for the benchmark and the CLI.
struct StreamStats {
  uint64_t points = 0;
  int levels = 0;
  size_t header_bytes = 0;
  size_t bytes_by_attribute[9] = {};  // indexed by the bit position of Attribute
  size_t total_bytes = 0;
  bool temporal = false;
};

// Codes `points`. With `reference` (the decoded previous frame), codes temporally: details
// are predicted from the reference's co-located pairs. Points are reordered (hierarchy order);
// the decoder returns them in that order.
Status Encode(std::span<const Point> points, const EncodeOptions& options, std::string* out,
              StreamStats* stats = nullptr, const Reference* reference = nullptr);

// Decodes a stream (or a prefix of a progressive one, see DecodeOptions::max_bytes). Corrupt,
// truncated (non-progressive) and foreign data give Corruption or InvalidArgument.
Status Decode(std::string_view stream, std::vector<Point>* out, const DecodeOptions& options = {},
              StreamStats* stats = nullptr);

// Parses only the header: what a stream holds.
struct StreamInfo {
  uint8_t version = 0;
  uint64_t points = 0;
  uint32_t attributes = 0;
  int qp = 0, qc = 0, qn = 0, qcov = 0;
  int levels = 0;
  bool progressive = false;
  bool temporal = false;
  bool octree = false;  // version 2: positions coded by the octree
  double origin[3] = {0, 0, 0};
  double step = 1;  // the position grid (set a Reference's grid from these)
};
Status ReadInfo(std::string_view stream, StreamInfo* info);

// Comma-separated attribute names ("position,color,normal") to a mask, and back.
Status ParseAttributes(std::string_view list, uint32_t* mask);
std::string AttributeNames(uint32_t mask);

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_CODEC_H_
