// Seeded synthetic Gaussian-splat clouds for the tests of formats/ (the file and GLB tests
// draw the same clouds from the same seeds: the fuzz corpus's seeds are made so).
#ifndef HVDB_TESTS_FORMATS_RANDOM_CLOUD_H_
#define HVDB_TESTS_FORMATS_RANDOM_CLOUD_H_

#include <cstddef>
#include <cstdint>

#include "formats/gaussians.h"

namespace hvdb::formats::test_clouds {

// splitmix64: the same numbers on every platform.
class Rng {
 public:
  explicit Rng(uint64_t seed) : s_(seed) {}
  uint64_t Next() {
    uint64_t z = (s_ += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
  }
  float Uniform(float lo, float hi) {
    return lo + (hi - lo) * static_cast<float>((Next() >> 40) * 0x1p-24);
  }

 private:
  uint64_t s_;
};

// Splats within every format's range: positions +-50, log scales -7..0.5, unnormalised
// quaternions, logits +-6, SH coefficients +-0.9.
inline GaussianCloud RandomCloud(uint64_t seed, int degree, size_t n) {
  Rng rng(seed);
  GaussianCloud c;
  c.sh_degree = degree;
  c.Resize(n);
  for (size_t i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) c.position[3 * i + k] = rng.Uniform(-50, 50);
    for (int k = 0; k < 3; ++k) c.scale[3 * i + k] = rng.Uniform(-7, 0.5f);  // anisotropic
    const float len = rng.Uniform(0.3f, 3);  // unnormalised, as trainers store them
    for (int k = 0; k < 4; ++k) c.rotation[4 * i + k] = len * rng.Uniform(-1, 1);
    c.opacity[i] = rng.Uniform(-6, 6);
    for (int k = 0; k < 3; ++k) c.sh_dc[3 * i + k] = rng.Uniform(-1.7f, 1.7f);
  }
  for (float& v : c.sh_rest) v = rng.Uniform(-0.9f, 0.9f);
  return c;
}

}  // namespace hvdb::formats::test_clouds

#endif  // HVDB_TESTS_FORMATS_RANDOM_CLOUD_H_
