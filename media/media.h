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
#include "storage/job_limits.h"
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
// One import inserts at most this many points (all frames together): what one commit can hold.
// An import is one transaction, logged as one record of at most 1 GiB (storage/wal.cc), and a
// point is a 64-byte record: 16 M points are 1.02 GB.
inline constexpr uint64_t kMaxImportPoints = 16'000'000;
// The largest picture a header may declare (an image, a video frame, a mesh's texture), checked
// before anything is allocated: 32768 a side and 2^28 pixels (16384 x 16384).
inline constexpr uint32_t kMaxPictureSide = 32768;
inline constexpr uint64_t kMaxPicturePixels = uint64_t{1} << 28;
// Nesting a glTF may have, checked before assimp's recursive parsers see it: JSON arrays and
// objects inside each other, and nodes below nodes.
inline constexpr int kMaxJsonDepth = 64;
inline constexpr int kMaxNodeDepth = 128;

// The bounds one import decodes under: its job's (memory reserved before each large buffer is
// made, a deadline checked between frames and batches). Default: none (tools and tests).
struct Budget {
  const JobLimits* limits = nullptr;
  JobLease* lease = nullptr;
  Status Reserve(uint64_t bytes, const std::string& what) const {
    return lease == nullptr ? Status::OK() : lease->Reserve(bytes, what);
  }
  void Release(uint64_t bytes) const {
    if (lease != nullptr) lease->Release(bytes);
  }
  Status CheckTime(const std::string& what) const {
    return limits == nullptr ? Status::OK() : limits->CheckTime(what);
  }
};

// The kind a request means: an explicit one, else the file's signature (PNG, JPEG, PLY, GLB),
// else its extension; anything else is tried as a video (libavformat probes the bytes).
Kind DetectKind(std::string_view data, const std::string& format, Kind hint);

// An 8-bit RGBA picture, rows top to bottom.
struct Picture {
  int width = 0, height = 0;
  std::vector<uint8_t> rgba;  // width * height * 4
};

// image.cc: decodes an image file and area-averages it down so that its longer side has at
// most `max_side` pixels (0: no limit). PNG (libpng) and JPEG (libjpeg) are decoded row by row
// into the smaller picture, so memory follows the output, not the declared size; binary
// PGM/PPM; BMP, TIFF, WebP and the other still formats through libavcodec (DecodeVideo's one
// frame). The header's size is checked against kMaxPicture* and against the bytes sent before
// anything is allocated. InvalidArgument naming the format on a bad file, LimitExceeded over
// a limit or the budget.
Result<Picture> DecodeImage(std::string_view data, const std::string& format, uint32_t max_side,
                            const Budget& budget = {});

// video.cc: the first `max_frames` frames of a video file, each scaled so that the longer side
// has at most `max_side` pixels (alpha 255, or the file's). InvalidArgument naming the format
// when the file cannot be demuxed, has no video stream or no frame decodes; TooManyPoints as
// soon as the first frame shows that max_frames of its size pass `max_points`, or when the
// frames decoded so far (every one counted, whatever its size) with the last one repeated to
// max_frames do. Frames over kMaxPicture* are refused before they are decoded.
Result<std::vector<Picture>> DecodeVideo(std::string_view data, const std::string& format,
                                         uint32_t max_frames, uint32_t max_side,
                                         uint64_t max_points = kMaxImportPoints,
                                         const Budget& budget = {});

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
//
// Only the bytes sent are read: assimp gets an I/O system that serves the file itself and
// refuses every other name (an external buffer, texture or .mtl is an InvalidArgument naming
// it; data: URIs are decoded inside the file). OBJ, PLY, STL, OFF, glTF and GLB are read; their
// declared sizes (GLB chunks, glTF buffers and accessors, PLY and OFF element counts) and
// glTF's nesting (kMaxJsonDepth, kMaxNodeDepth) are checked against the bytes before assimp
// parses them (mesh_check.cc), and the scene it builds is validated (indices, counts) before
// it is sampled. assimp runs in a child process (CPU- and data-limited): its crash or hang on a
// malformed file is this call's InvalidArgument or LimitExceeded, not the caller's end.
Result<std::vector<Point>> SampleMesh(std::string_view data, const std::string& format,
                                      const Placement& place, double spacing, uint32_t label,
                                      const Budget& budget = {});

// mesh_check.cc: the checks of a mesh file's declared structure made before assimp reads it
// (see SampleMesh). `format` is the lower-case extension; "" picks by signature.
// InvalidArgument naming what is wrong.
Status CheckMeshFile(std::string_view data, const std::string& format, const std::string& what);

// The default sample spacing of a mesh with `area` m^2 (after scale): 2 mm, coarser where that
// would give over 200 000 points a frame.
double MeshSpacing(double area);

// media.cc: checks `req` (InvalidArgument naming the field), decodes the medium and inserts it
// into its frames of `ds` in one transaction, within `limits` (its buffers reserved on the
// job's memory budget, its deadline checked). Nothing is written on any error.
Result<CommitInfo> Import(Dataset& ds, const ImportRequest& req, const JobLimits& limits = {});

// photo_video.cc: the video tier's codec (storage/photo_video.h: AV1 in IVF through
// libavcodec), and its installation as the process's (SetPhotoVideoCodec), which every program
// that reads or compacts photos calls once at start-up (service::Service does).
const PhotoVideoCodec& PhotoVideo();
void InstallPhotoVideoCodec();

// 3x3 rotation (row-major) of Placement::rotate_deg.
std::array<double, 9> RotationMatrix(const std::array<double, 3>& rotate_deg);

}  // namespace hvdb::media

#endif  // HVDB_MEDIA_MEDIA_H_
