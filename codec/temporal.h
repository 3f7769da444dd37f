// Temporal coding (beyond the thesis): a frame coded against the decoded previous frame.
//
// Frames of 3D video are re-sampled every frame (a fusion of depth maps does not put the
// samples where it put them before), so the previous frame cannot predict a pair's detail
// directly. It can describe the attributes as fields over the surface: positions are decoded
// before the other attributes of a chunk, so both sides know the two children's positions, and
// the reference points nearest to them show how much the colour changes across the pair there.
// That selects the context of the pair's colour detail. Using the reference's difference as the
// prediction itself was measured and lost (it adds the previous frame's noise): docs/CODEC.md,
// "Temporal coding", has the figures.
#ifndef HVDB_CODEC_TEMPORAL_H_
#define HVDB_CODEC_TEMPORAL_H_

#include <memory>
#include <span>
#include <vector>

#include "codec/internal.h"
#include "codec/level_coder.h"

namespace hvdb::codec {

class TemporalIndex {
 public:
  // The reference's points in the channels of the stream being coded (its quantiser).
  TemporalIndex(std::span<const Point> reference, const Quantizer& q);
  ~TemporalIndex();
  const Columns& values() const { return values_; }
  // Fills L.hints for the parents [b, e) whose position details are known.
  void Hints(LevelState& L, size_t b, size_t e) const;

 private:
  struct Tree;
  Columns values_;
  std::unique_ptr<Tree> tree_;
  double spacing_ = 1.0;  // median nearest-neighbour distance of the reference, grid units
};

}  // namespace hvdb::codec

#endif  // HVDB_CODEC_TEMPORAL_H_
