// Lossless octree coding of positions on a grid (hvdb7 version 2's geometry, docs/CODEC.md
// "Octree geometry").
//
// The grid's cells are visited breadth first in Morton order; each occupied node sends its
// eight child-occupancy bits through an adaptive binary range coder whose context is what the
// decoder already knows around that child: which of the node's six face neighbours are
// occupied, which neighbours of the child itself were already coded (siblings, and children of
// the nodes before it), how many siblings came before, and, for temporal streams, whether the
// reference frame occupies the child (what did not move costs almost nothing). MPEG G-PCC
// (TMC13) codes occupancy from neighbour configurations in the same spirit; this is written
// here, not taken from it, because TMC13 is a reference model, not a library. The tree is cut
// at a shallow depth into chunks that are coded independently, so decoders use both cores.
#ifndef HVDB_CODEC_OCTREE_H_
#define HVDB_CODEC_OCTREE_H_

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "storage/status.h"

namespace hvdb::codec {

// Up to 21 bits per axis: codes fit 63 bits.
inline constexpr int kMaxOctreeDepth = 21;

// Bit 3i+2 of the code is bit i of x, 3i+1 of y, 3i of z.
uint64_t MortonCode(uint32_t x, uint32_t y, uint32_t z);
void MortonDecode(uint64_t code, uint32_t* x, uint32_t* y, uint32_t* z);

// Codes `codes` (Morton codes of cells of a 2^depth grid, sorted ascending; equal codes are
// several points in one cell) into `out` (appended). `reference`, when not null, holds the
// sorted distinct cells of the frame a temporal stream is coded against. `threads` >= 1.
void EncodeOctree(std::span<const uint64_t> codes, int depth, const std::vector<uint64_t>* reference,
                  int threads, std::string* out);

// Decodes exactly `points` codes, sorted, from `in` (the whole payload). Corruption when the
// payload is inconsistent (counts, lengths, a coder that reads past its bytes).
Status DecodeOctree(std::string_view in, int depth, uint64_t points,
                    const std::vector<uint64_t>* reference, int threads, std::vector<uint64_t>* codes);

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_OCTREE_H_
