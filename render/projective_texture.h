// Colour from the source photos over the splats' geometry (thesis 6.3, eqs. 6.13-6.14): the
// points give each pixel of the virtual view its depth; its colour is then taken by projective
// texturing from the acquisition cameras that see that surface point, blended with
// view-dependent weights (the unstructured lumigraph's angular penalty, Buehler et al. 2001,
// per pixel: the angle at the surface point between the virtual and the source ray).
//
// Why: a splat carries one colour for a footprint of a pixel or more and is blended with its
// neighbours, so a point rendering is a low-pass version of the photos, and points from
// several cameras that disagree a little in depth blend into ghosts. Sampling the photos
// themselves at a consistent per-pixel depth keeps their sharpness (thesis 6.6 measures why
// this wins over point-sampled video).
#ifndef HVDB_RENDER_PROJECTIVE_TEXTURE_H_
#define HVDB_RENDER_PROJECTIVE_TEXTURE_H_

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "render/renderer.h"

namespace hvdb::render {

// One source view: its camera, its photo and what it sees (camera-space z per pixel, +inf
// where nothing: render the points from this camera and take Image::depth).
struct TextureView {
  Camera camera;
  std::span<const uint8_t> rgb;  // 8-bit sRGB, row-major, camera.width * camera.height * 3
  // depth_width * depth_height (0, 0: the camera's size): the depth may be rendered smaller
  // than the photo, it only decides visibility.
  std::span<const float> depth;
  uint32_t depth_width = 0, depth_height = 0;
};

struct TextureOptions {
  // A source sees the surface point when its depth there is within this fraction of the
  // point's depth in that source.
  float visibility_tolerance = 0.01f;
  // The best `max_views` sources (smallest angle) are blended, weighted by Buehler's penalty
  // relative to the next one: (1 - a / a_next) / a.
  int max_views = 3;
  std::array<float, 4> background{0, 0, 0, 1};  // what RenderOptions painted behind the splats
  unsigned threads = 0;                          // 0: hardware threads
};

struct TextureStats {
  uint64_t pixels = 0;     // pixels with a depth
  uint64_t textured = 0;   // of those, coloured from at least one source
};

// Recolours `image` (rendered from `camera` with its depth) in place: every pixel with a
// finite depth whose surface point some source sees gets the blend of those sources' photos
// (bilinear, in linear light) over the background by the pixel's coverage; the others keep the
// splats' colour. Errors: InvalidArgument when the image does not match the camera or a view's
// buffers do not match its camera.
Status ProjectiveTexture(const Camera& camera, std::span<const TextureView> views,
                         const TextureOptions& options, Image* image, TextureStats* stats = nullptr);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_PROJECTIVE_TEXTURE_H_
