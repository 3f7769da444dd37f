// Shadows of labelled points on a rendered image (thesis 9.4: the editor shows where a selected
// object would cast its shadow): a shadow map of the caster splats seen from the light, then
// every visible pixel of the render looked up in it.
//
// It is a pass over a finished Image (its colour and per-pixel depth), so both renderers, CPU
// and EGL, get the same shadows from the same code: their images differ only by what their
// splatting already differs by (tests/render/shadow_test.cc checks it).
//
//  1. Casters: the points carrying label bit `caster_bit`. The light's camera is fitted to their
//     bounds: a pinhole at a point light aimed at their centre, or for a directional light a
//     pinhole 1000 bounding radii away along the light's direction (rays parallel to 0.1%: an
//     orthographic view without a second splat projection to keep in step with the renderers).
//  2. The shadow map (1.5 texels per median splat standard deviation, 64..map_size a side):
//     each caster splat projected into that camera with the renderers' own EWA
//     set-up (ProjectSplat: its footprint, cutoff and depth slope), the nearest fragment depth
//     kept per texel.
//  3. Receivers: each pixel the render covers is lifted to its world position (its depth along
//     its ray), projected into the light's camera and compared with the 3x3 texels around it
//     (percentage-closer filtering, so splat edges do not alias); in shadow by a tap when it is
//     farther than the map by more than the bias (the render's fuzzy depth threshold plus one
//     texel's size). Its splat colour (not the background's share) is darkened by
//     strength * shadowed taps / 9. Pixels no tap shadows are left exactly as they were.
// Casters do shadow themselves where a part of them lies behind another part as seen from the
// light (their far side is darkened): a shadow map cannot tell a caster pixel from a receiver,
// and that is also what light does.
#ifndef HVDB_RENDER_SHADOW_H_
#define HVDB_RENDER_SHADOW_H_

#include <array>
#include <cstdint>
#include <span>

#include "render/renderer.h"

namespace hvdb::render {

struct ShadowOptions {
  // A point light's position (m), or with `directional` the direction towards the light.
  std::array<double, 3> light{0, 0, 0};
  bool directional = false;
  uint32_t caster_bit = 0;   // points with label bit caster_bit set cast shadows (0..31)
  float strength = 0.6f;     // how much a fully shadowed pixel is darkened, [0, 1]
  // Shadow map texels a side, at most: fewer where the casters' splats are large enough
  // (1.5 texels per standard deviation of the median splat resolves their outline; more only
  // rasterises more fragments), at least 64.
  uint32_t map_size = 1024;
};

// What ApplyShadows did (for benchmarks and tests).
struct ShadowStats {
  uint64_t casters = 0;          // points with the caster bit
  uint64_t shadowed_pixels = 0;  // pixels darkened at all
  double milliseconds = 0;
};

// Checks the options alone: InvalidArgument naming the field (shadow_light, shadow_casters,
// shadow_strength) and saying what is allowed.
Status CheckShadowOptions(const ShadowOptions& shadow);

// Darkens `image`, a render of `points` through `camera` (at the image's size) with `options`,
// where the casters among `points` shadow it. No casters: nothing changes. InvalidArgument for
// bad options, or a point light inside the casters' bounds (it would have to see all around).
Status ApplyShadows(std::span<const Point> points, const Camera& camera,
                    const RenderOptions& options, const ShadowOptions& shadow, Image* image,
                    ShadowStats* stats = nullptr);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_SHADOW_H_
