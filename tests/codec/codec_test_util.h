// Helpers the codec tests share: a real Panoptic frame with distinct ids, and encoding and
// decoding that fail the test on an error.
#ifndef HVDB_TESTS_CODEC_CODEC_TEST_UTIL_H_
#define HVDB_TESTS_CODEC_CODEC_TEST_UTIL_H_

#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "codec/codec.h"
#include "formats/ply.h"

namespace hvdb::codec::testing_util {

inline std::vector<Point> Panoptic(int frame) {
  formats::ReadOptions ro;
  ro.scale = 0.01;
  char path[512];
  std::snprintf(path, sizeof path,
                HVDB_SHARED_DATA "/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds/"
                                 "ptcloud_hd%08d.ply",
                frame);
  auto r = formats::ReadPly(path, ro);
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  std::vector<Point> pts = r.ok() ? std::move(r).value() : std::vector<Point>{};
  for (size_t i = 0; i < pts.size(); ++i) {
    pts[i].id = 1000000 + i;  // distinct ids: the tests match decoded points by id
    pts[i].frame = static_cast<uint32_t>(frame);
    pts[i].camera = static_cast<uint16_t>(i % 10);
    pts[i].label = (i % 7 == 0) ? 4u : 0u;
  }
  return pts;
}

inline std::map<uint64_t, Point> ById(const std::vector<Point>& pts) {
  std::map<uint64_t, Point> m;
  for (const Point& p : pts) m[p.id] = p;
  return m;
}

inline std::string MustEncode(const std::vector<Point>& pts, const EncodeOptions& o,
                              const Reference* ref = nullptr, StreamStats* stats = nullptr) {
  std::string s;
  Status st = Encode(pts, o, &s, stats, ref);
  EXPECT_TRUE(st.ok()) << st.ToString();
  return s;
}

inline std::vector<Point> MustDecode(const std::string& s, const DecodeOptions& o = {}) {
  std::vector<Point> out;
  Status st = Decode(s, &out, o);
  EXPECT_TRUE(st.ok()) << st.ToString();
  return out;
}

}  // namespace hvdb::codec::testing_util

#endif  // HVDB_TESTS_CODEC_CODEC_TEST_UTIL_H_
