// Other media composited into a dataset (issue 33): an image or a video becomes a textured plane
// of surfels, a mesh becomes surfels sampled over its surface. The file's bytes are decoded here,
// once, at the edge of the executor (service::Service::ImportMedia), and the result is inserted
// into a range of frames in one transaction, so `hvdb undo LSN` removes it again.
//
// One file per media kind: image.cc (PNG, JPEG, ... through OpenCV), video.cc (whatever
// Debian's libavformat/libavcodec decode), mesh.cc (OBJ, PLY, glTF/GLB, ... through assimp);
// plane.cc turns decoded pictures into surfels; media.cc checks a request and commits it.
#ifndef HVDB_MEDIA_MEDIA_H_
#define HVDB_MEDIA_MEDIA_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "storage/database.h"
#include "storage/photo_video.h"

namespace hvdb::media {

enum class Kind { kAuto, kImage, kVideo, kMesh };
const char* KindName(Kind k);  // "auto", "image", "video", "mesh"
// "image" / "video" / "mesh" / "auto" or "" (auto).
Result<Kind> ParseKind(const std::string& s);

// Where the medium goes: p' = at + R (scale p), R = Rz Ry Rx (degrees, about the fixed axes:
// X first). A plane is centred on its local origin, in its local XY plane, image up along +y,
// facing +z (its normal); a mesh's bounding-box centre is its local origin.
struct Placement {
  std::array<double, 3> at{0, 0, 0};
  double scale = 1;
  std::array<double, 3> rotate_deg{0, 0, 0};
  double width = 1;  // planes: the width in metres before `scale`
};

struct ImportRequest {
  std::string data;    // the file's bytes
  Kind kind = Kind::kAuto;
  std::string format;  // the file's extension ("png", "mp4", "obj"; any case, dot optional)
  // Dataset frames first..last inclusive; absent: every frame of the dataset (frame 0 when it
  // has none). Both or neither.
  std::optional<uint32_t> first_frame, last_frame;
  Placement place;
  std::optional<int> label_bit;  // 0..31: set on every inserted point
  // Planes: surfels along the longer side (a larger picture is area-averaged down to it);
  // 0: kDefaultImageTexels / kDefaultVideoTexels. At most kMaxTexels.
  uint32_t texels = 0;
  // Meshes: metres between samples (after `scale`); 0: from the surface area (MeshSpacing).
  double spacing = 0;
};

inline constexpr uint32_t kDefaultImageTexels = 512;
inline constexpr uint32_t kDefaultVideoTexels = 256;
inline constexpr uint32_t kMaxTexels = 4096;
// One import inserts at most this many points (all frames together): 20M points are 1.3 GB
// of records in one transaction.
inline constexpr uint64_t kMaxImportPoints = 20'000'000;

// The kind a request means: an explicit one, else the file's signature (PNG, JPEG, PLY, GLB),
// else its extension; anything else is tried as a video (libavformat probes the bytes).
Kind DetectKind(std::string_view data, const std::string& format, Kind hint);

// An 8-bit RGBA picture, rows top to bottom.
struct Picture {
  int width = 0, height = 0;
  std::vector<uint8_t> rgba;  // width * height * 4
};

// image.cc: decodes an image file and area-averages it down so that its longer side has at
// most `max_side` pixels (0: no limit). InvalidArgument naming the format on a bad file.
Result<Picture> DecodeImage(std::string_view data, const std::string& format, uint32_t max_side);

// video.cc: the first `max_frames` frames of a video file, each scaled so that the longer side
// has at most `max_side` pixels (alpha 255). InvalidArgument naming the format when the file
// cannot be demuxed, has no video stream or no frame decodes, and TooManyPoints as soon as the
// first frame shows that max_frames of its size pass `max_points`.
Result<std::vector<Picture>> DecodeVideo(std::string_view data, const std::string& format,
                                         uint32_t max_frames, uint32_t max_side,
                                         uint64_t max_points = kMaxImportPoints);

// The error of an import over kMaxImportPoints: `per_frame` points in each of `frames`.
Status TooManyPoints(uint64_t per_frame, uint64_t frames, Kind kind);

// plane.cc: one surfel per texel (texels with alpha < 128 are left out), in frame `frame`:
// colour = the texel's, normal = the plane's, a Gaussian footprint of 0.6 texel spacing (so the
// plane renders closed) and a thin one across it. The plane is place.width * place.scale metres
// wide.
std::vector<Point> PlaneSurfels(const Picture& pic, const Placement& place, uint32_t frame,
                                uint32_t label);

// mesh.cc: a mesh file sampled area-uniformly (deterministic: a fixed seed) at `spacing`
// metres (0: MeshSpacing), placed by `place` (width unused). Normals follow the triangles'
// winding (interpolated vertex normals where the file has them); colours come from the
// embedded base-colour texture, else the vertex colours, else the material's diffuse colour.
Result<std::vector<Point>> SampleMesh(std::string_view data, const std::string& format,
                                      const Placement& place, double spacing, uint32_t label);

// The default sample spacing of a mesh with `area` m^2 (after scale): 2 mm, coarser where that
// would give over 200 000 points a frame.
double MeshSpacing(double area);

// media.cc: checks `req` (InvalidArgument naming the field), decodes the medium and inserts it
// into its frames of `ds` in one transaction. Nothing is written on any error.
Result<CommitInfo> Import(Dataset& ds, const ImportRequest& req);

// photo_video.cc: the video tier's codec (storage/photo_video.h: AV1 in IVF through
// libavcodec), and its installation as the process's (SetPhotoVideoCodec), which every program
// that reads or compacts photos calls once at start-up (service::Service does).
const PhotoVideoCodec& PhotoVideo();
void InstallPhotoVideoCodec();

// 3x3 rotation (row-major) of Placement::rotate_deg.
std::array<double, 9> RotationMatrix(const std::array<double, 3>& rotate_deg);

}  // namespace hvdb::media

#endif  // HVDB_MEDIA_MEDIA_H_
