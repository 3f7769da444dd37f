// The point order of octree streams (their Morton order, the swaps that make consecutive points
// closer partners, the hierarchy of consecutive pairs) and the reference frame's cells and grid
// of temporal streams: what Encode and Decode (codec.cc) both derive from positions alone.
#ifndef HVDB_CODEC_POINT_ORDER_H_
#define HVDB_CODEC_POINT_ORDER_H_

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "codec/codec.h"
#include "codec/internal.h"

namespace hvdb::codec {

// Octree streams: sorts the points by the Morton code of their cell (ties keep input order)
// and returns the codes.
std::vector<uint64_t> MortonSort(Columns* base, uint32_t attrs);

// Octree streams: the order that makes consecutive points closer partners. Walking the Morton
// order two at a time, the nearest of points i + 1 .. i + 6 to point i (the first on ties)
// swaps places with point i + 1 (the curve jumps between cells often enough for this to pay in
// the attributes' details). Applied to `codes` and, when given, to `base`'s channels; decoders
// repeat it on the decoded codes.
void PairOrder(std::vector<uint64_t>* codes, Columns* base);

// Octree streams: the pair hierarchy of consecutive points. Level k's point i is the parent of
// points 2i and 2i + 1 of level k - 1 (the last of an odd level is unpaired), so decoders know
// it without being told, and in Morton order the pairs are neighbours.
void ConsecutiveHierarchy(Columns base, int levels, uint32_t attrs, Hierarchy* h);

// Decoder side of the same: positions of levels 0..levels from level 0's cells.
std::vector<std::array<std::vector<int64_t>, 3>> PositionLevels(const std::vector<uint64_t>& codes,
                                                               int levels);

// The reference frame's distinct cells on this stream's grid (temporal octree streams).
std::vector<uint64_t> ReferenceCells(std::span<const Point> ref, const Quantizer& q);

// Whether every point lands inside the reference's grid (so the stream can share it).
bool FitsGrid(std::span<const Point> pts, const Reference& r, int qp);

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_POINT_ORDER_H_
