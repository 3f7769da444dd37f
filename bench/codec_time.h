// codec-bench's temporal part: a generated recording whose background does not move, coded
// intra and against the previous frame (hvdb7 octree streams), as the issue's "point coding
// that predicts what did not move".
#ifndef HVDB_BENCH_CODEC_TIME_H_
#define HVDB_BENCH_CODEC_TIME_H_

#include <nlohmann/json.hpp>
#include <string>

namespace hvdb::bench {

// Generates a recording (ingest/generator.h: a room, three static spheres and a moving box;
// 3 bricks, no lens distortion) in `scratch`, turns each frame's ground-truth depth maps of
// the colour cameras into points (the exact geometry a noiseless depth camera would give, the
// colours as the cameras saw them, sensor noise included), and codes each frame intra and
// temporally. Returns the per-frame bits and the median savings.
nlohmann::json RunStaticBackground(const std::string& scratch, bool quick);

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_CODEC_TIME_H_
