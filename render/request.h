// A render request and its replies as plain values (docs/PROTOCOL.md, "Rendering"): what a
// render job (render/job.h) is made from and what it gives per image. They carry what the
// wire protocol's Render and RenderReply messages carry (hvdb.proto), with the same defaults
// and meanings; the protocol library's render_convert.h converts them (ToWire / FromWire), so
// that render/ does not depend on the protocol. The command line and Python build a
// RenderRequest; hvdb-server decodes one from its wire message at the edge.
//
// Only the shape is fixed here (one of three kinds of view, 4 background values, ...);
// whether the values make sense is RenderJob::Create's to say, for every caller alike.
#ifndef HVDB_RENDER_REQUEST_H_
#define HVDB_RENDER_REQUEST_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "render/renderer.h"
#include "storage/database.h"

namespace hvdb::render {

// A look-at camera: from `eye` towards `target` (m), `up` the world direction shown upwards
// (none: 0 1 0), a vertical field of view in (0, 180) degrees, an image of width x height.
struct LookAtView {
  std::array<double, 3> eye{}, target{};
  std::optional<std::array<double, 3>> up;
  double fov_y_deg = 0;
  uint32_t width = 0, height = 0;
};

// One of the dataset's cameras (DatasetInfo::cameras), by its id.
struct DatasetCameraView {
  uint32_t id = 0;
};

// A virtual camera: full intrinsics and pose (storage's CameraInfo: width, height, fx fy cx
// cy, distortion, world_from_camera), a look-at, or a camera of the dataset.
using View = std::variant<CameraInfo, LookAtView, DatasetCameraView>;

// The encoding of the images: 8-bit sRGB PNG; OpenEXR (linear premultiplied float RGBA and
// depth Z); a path as one H.264 (else MPEG-4 part 2) video in MP4, or VP9 (else AV1) in WebM.
enum class ImageFormat : uint8_t { kPng, kExr, kMp4, kWebm };

struct RenderRequest {
  std::string dataset;
  // The points to draw; optional for a sequence whose views each show a frame (`frames`).
  std::optional<Region> region;
  // The level of detail: splats grow by 2^(lod/2). 0 .. the dataset's coarsest level
  // (storage's rule, Dataset::CheckLod).
  uint32_t lod = 0;
  std::optional<View> view;  // the camera of a single image
  // The point mode. Unset, with texture and billboards unset too: the best picture the frame
  // has (billboards where stored, else its photos, else the points in kVisibility). Given:
  // the points in that mode.
  std::optional<Mode> mode;
  bool view_dependent = false;  // weights by the dataset's cameras (thesis eqs. 5.15-5.17)
  uint32_t width = 0, height = 0;  // 0: the view's own size; else scaled to width x height
  std::optional<std::array<float, 4>> background;  // linear RGBA; none: opaque black
  RendererKind renderer = RendererKind::kAuto;
  float depth_threshold = 0;  // fuzzy depth test dz (m); 0: 0.02
  float cutoff_radius = 0;    // in standard deviations; 0: 2.5
  ImageFormat format = ImageFormat::kPng;
  // A sequence: image i is seen from path[i] and shows frames[i] (the whole frame) when frames
  // are given (as many as views), else `region`.
  std::vector<View> path;
  std::vector<uint32_t> frames;
  bool no_temporal_lod = false;
  uint32_t label_mask = 0;
  // A single view only: first a preview at a coarser level (lod + 4, at most the dataset's
  // coarsest) and half the size, then the image at `lod`.
  bool progressive = false;
  // The selection as an overlay: points with (label & highlight_mask) != 0 blended toward
  // highlight_color (sRGB RGBA in [0, 1]; none: orange at half strength).
  uint32_t highlight_mask = 0;
  std::optional<std::array<float, 4>> highlight_color;
  // Colour from the frame's photos over the splats' depth (a single view of one frame). Unset
  // (with mode and billboards unset): auto, see mode; false: not textured.
  std::optional<bool> texture;
  // The frame's billboards instead of its points (a single view of one frame). Unset: as
  // texture; false: none.
  std::optional<bool> billboards;
  // Shadows, on when shadow_light is given: the points carrying label bit shadow_casters cast
  // shadows from a point light there (m), or with shadow_directional from a light infinitely
  // far in that direction; darkened by shadow_strength (0: 0.6), a shadow map of
  // shadow_map_size texels a side (0: 1024).
  std::optional<std::array<double, 3>> shadow_light;
  bool shadow_directional = false;
  uint32_t shadow_casters = 0;
  float shadow_strength = 0;
  uint32_t shadow_map_size = 0;
  // kMp4 / kWebm: the path's images as one video at video_fps frames a second (0: 30).
  double video_fps = 0;
};

// One image's reply (of a sequence, a progressive request's preview, or a video's progress).
struct RenderReply {
  std::string png;   // format kPng
  std::string exr;   // format kExr
  // kMp4 / kWebm: replies before the last carry no image (progress: index of images), the
  // last one the whole encoded file here; video_codec names the encoder (e.g. "libx264").
  std::string video;
  std::string video_codec;
  uint32_t width = 0, height = 0;
  std::string renderer_used;    // e.g. "egl: llvmpipe (...)" or "cpu (16 threads)"
  std::string renderer_choice;  // which renderer ran and why (kAuto's reason)
  bool fallback = false;        // kAuto found no EGL context and used the CPU renderer
  uint64_t points = 0;          // points drawn
  double render_ms = 0;         // time spent in the renderer
  uint32_t index = 0;           // which image of a sequence (0 for a single image)
  uint32_t images = 0;          // the sequence's image count (path size), for progress
  bool last = false;            // the request's final reply
  bool preview = false;         // a progressive request's coarse image; the final one follows
  uint32_t lod = 0;             // the level of detail this image was drawn at
  // What drew this image: "visibility" or "probabilistic" (the points), "textured" or
  // "billboards"; mode_choice says why (auto's reason, or "asked for").
  std::string mode_used, mode_choice;
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_REQUEST_H_
