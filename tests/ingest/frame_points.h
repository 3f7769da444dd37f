// A dataset frame's points in a form two ingests can be compared by (live_test, slurm_test), and
// as the query returns them (gaussian_ingest_test reads their Gaussian records by id).
#ifndef HVDB_TESTS_INGEST_FRAME_POINTS_H_
#define HVDB_TESTS_INGEST_FRAME_POINTS_H_

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <string>
#include <vector>

#include "client/backend.h"

namespace hvdb::ingest::testing {

// Dataset frame f's points as the query returns them (ids kept).
inline std::vector<Point> QueryFramePoints(client::Backend& b, const std::string& dataset,
                                           uint32_t f, double fps) {
  Window w;
  for (int a = 0; a < 3; ++a) {
    w.lo[a] = -1e9;
    w.hi[a] = 1e9;
  }
  w.lo[3] = w.hi[3] = f / fps;
  std::vector<Point> out;
  auto q = b.Query(dataset, w, QueryOptions{});
  EXPECT_TRUE(q.ok()) << q.status().ToString();
  if (!q.ok()) return out;
  Batch batch;
  while (true) {
    auto more = (*q)->Next(&batch);
    EXPECT_TRUE(more.ok());
    if (!more.ok() || !*more) break;
    out.insert(out.end(), batch.points.begin(), batch.points.end());
  }
  return out;
}

// Dataset frame f's points with their ids cleared (ids follow the order frames were committed
// in), sorted bytewise: two ingests made the same points exactly when these are equal.
inline std::vector<Point> FramePoints(client::Backend& b, const std::string& dataset, uint32_t f,
                                      double fps) {
  std::vector<Point> out = QueryFramePoints(b, dataset, f, fps);
  for (Point& p : out) p.id = 0;
  std::sort(out.begin(), out.end(),
            [](const Point& a, const Point& c) { return std::memcmp(&a, &c, sizeof a) < 0; });
  return out;
}

}  // namespace hvdb::ingest::testing

#endif  // HVDB_TESTS_INGEST_FRAME_POINTS_H_
