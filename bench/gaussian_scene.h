// A synthetic scene shaped like a trained 3DGS scene, seeded, for the render benchmarks
// (gaussian-render-bench, render-bench-gpu): flat splats lying on surfaces (a floor, a back wall
// and a dozen spheres, splats spread by area), each with two tangent scales about the local
// spacing and a thin normal one, so that most are a few pixels across on screen; opacities
// mostly high with a tail of faint ones; SH of degree 3 with small view-dependent terms.
#ifndef HVDB_BENCH_GAUSSIAN_SCENE_H_
#define HVDB_BENCH_GAUSSIAN_SCENE_H_

#include <cstddef>
#include <cstdint>

#include "formats/gaussians.h"
#include "render/gaussian_raster.h"
#include "render/renderer.h"

namespace hvdb::bench {

// n splats on a floor (y = 1, y points down), a back wall (z = 6) and 12 spheres.
formats::GaussianCloud GaussianScene(size_t n, uint32_t seed);
// The camera that sees GaussianScene whole.
render::Camera GaussianSceneCamera(uint32_t width, uint32_t height);
// The rasteriser's picture as 8-bit RGB (ToRgba8 without alpha), for PSNR and PNG files.
formats::Srgb8Image ToSrgb8(const render::GaussianImage& image);

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_GAUSSIAN_SCENE_H_
