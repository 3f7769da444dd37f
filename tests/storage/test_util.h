// Helpers shared by the storage tests: temp directories and seeded random points.
#ifndef HVDB_TESTS_STORAGE_TEST_UTIL_H_
#define HVDB_TESTS_STORAGE_TEST_UTIL_H_

#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "storage/database.h"
#include "storage/point.h"

namespace hvdb::testing {

// A fresh directory under /tmp, removed with everything in it on destruction.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = "/tmp/hvdb-test-XXXXXX";
    path_ = ::mkdtemp(tmpl.data());
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

inline Point RandomPoint(std::mt19937_64& rng, uint32_t frame, float extent = 10.f) {
  std::uniform_real_distribution<float> u(0.f, extent);
  std::uniform_int_distribution<int> c(0, 255);
  Point p;
  p.x = u(rng);
  p.y = u(rng);
  p.z = u(rng);
  p.frame = frame;
  p.r = static_cast<uint8_t>(c(rng));
  p.g = static_cast<uint8_t>(c(rng));
  p.b = static_cast<uint8_t>(c(rng));
  float s = 0.001f + u(rng) * 1e-4f;
  p.cov = {s * s, 0, 0, s * s, 0, s * s};
  p.flags = kFlagHasCovariance;
  p.label = static_cast<uint32_t>(rng() & 0xF);
  return p;
}

inline std::vector<Point> RandomPoints(std::mt19937_64& rng, size_t n, uint32_t frame,
                                       float extent = 10.f) {
  std::vector<Point> pts(n);
  for (auto& p : pts) p = RandomPoint(rng, frame, extent);
  return pts;
}

// A window over all of space and time, and the same restricted to frame f at `fps`.
inline Window EverythingWindow() {
  Window w;
  w.lo = {-1e9, -1e9, -1e9, -1e9};
  w.hi = {1e9, 1e9, 1e9, 1e9};
  return w;
}

inline Window FrameWindow(uint32_t f, double fps) {
  Window w = EverythingWindow();
  w.lo[3] = w.hi[3] = f / fps;
  return w;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_STORAGE_TEST_UTIL_H_
