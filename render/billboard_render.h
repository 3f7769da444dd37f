// Drawing 3D video billboards (thesis 6.3): every billboard's pixels are reprojected into the
// virtual view by their depth, and each pixel of the view gets one view-dependent depth, the
// average of the front-most fragments weighted by their view's weight and alpha (eq. 6.13), and
// the largest alpha among them (eq. 6.15). Colour then comes from the billboards' photos by
// projective texturing at that depth (eq. 6.14, render/projective_texture.h), with each
// billboard's own depth deciding what its camera sees.
//
// Why a consistent depth first: blending the billboards' colours alone mixes texture values
// that their slightly different depths put at different places (ghosting, thesis fig. 6.7).
#ifndef HVDB_RENDER_BILLBOARD_RENDER_H_
#define HVDB_RENDER_BILLBOARD_RENDER_H_

#include <array>
#include <span>
#include <string>
#include <vector>

#include "render/renderer.h"
#include "storage/database.h"

namespace hvdb::render {

// A billboard ready to draw, in its camera's undistorted (pinhole) image.
struct BillboardSource {
  Camera camera;              // no distortion
  std::vector<float> depth;   // camera-space z (m) per pixel; +inf: none (or alpha < 1/2)
  std::vector<float> alpha;   // 0..1 per pixel
  std::vector<uint8_t> rgb;   // the photo, undistorted into `camera` (8-bit sRGB)
};

// The billboard of a stored photo (Photo::billboard, docs/FORMAT.md "Photo" version 2), with
// `rgb` its decoded photo (8-bit sRGB of the camera's size). InvalidArgument naming `what` when
// the photo has no billboard or a map does not decode to the camera's size and type.
Result<BillboardSource> DecodeBillboard(const Photo& photo, std::span<const uint8_t> rgb,
                                        const std::string& what);

struct BillboardDrawOptions {
  // Fragments within this fraction of a pixel's front-most depth are averaged (a fuzzy depth
  // test, as the point renderer's visibility splatting).
  float depth_tolerance = 0.01f;
  std::array<float, 4> background{0, 0, 0, 1};  // linear RGBA where nothing is drawn
  unsigned threads = 0;                          // 0: hardware threads
};

// Fills `image` (allocated to `view`'s size) with the view-dependent depth and alpha of the
// billboards (coverage = alpha) over the background colour; pixels no billboard reaches get
// +inf depth; the colour is the billboards' own, blended by the same weights. Colour the
// result with ProjectiveTexture over the same billboards for the sharper, consistent one.
Status DrawBillboardDepth(const Camera& view, std::span<const BillboardSource> sources,
                          const BillboardDrawOptions& options, Image* image);

}  // namespace hvdb::render

#endif  // HVDB_RENDER_BILLBOARD_RENDER_H_
