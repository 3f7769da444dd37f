// The hyperpoint: one sample of the video hypervolume (thesis 8.1), shared by every component.
//
// On disk and on the wire a point is a fixed 64-byte little-endian record; docs/FORMAT.md
// ("Point record") gives it byte by byte. In memory the struct has the same layout, so on a
// little-endian host Encode/Decode of an array is a memcpy.
#ifndef HVDB_STORAGE_POINT_H_
#define HVDB_STORAGE_POINT_H_

#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>

namespace hvdb {

// Bits of Point::flags.
enum PointFlags : uint8_t {
  kFlagHasNormal = 1u << 0,      // normal_oct holds a valid unit normal
  kFlagHasCovariance = 1u << 1,  // cov holds a valid covariance (else: isotropic default)
};

struct Point {
  uint64_t id = 0;        // stable id, unique within a dataset (0 on insert: engine assigns)
  float x = 0, y = 0, z = 0;  // position, metres
  uint32_t frame = 0;     // frame index; time t = frame / fps seconds
  // Symmetric 3x3 spatial covariance V = T1 T1' + T2 T2' + T3 T3' (m^2), upper triangle:
  // xx, xy, xz, yy, yz, zz. T4 = (0,0,0,dt) is implied by the dataset's frame rate.
  std::array<float, 6> cov{};
  std::array<int16_t, 2> normal_oct{};  // octahedral-encoded unit normal (see EncodeNormal)
  uint32_t label = 0;     // 32 label / selection bits, free for the editor
  uint8_t r = 0, g = 0, b = 0;  // colour, sRGB 8 bit
  uint8_t flags = 0;      // PointFlags
  uint16_t camera = 0;    // id of the source camera (for view-dependent blending)
  uint16_t reserved = 0;  // written as 0, ignored on read

  bool operator==(const Point&) const = default;
};

inline constexpr size_t kPointRecordSize = 64;
static_assert(sizeof(Point) == kPointRecordSize, "Point must be a 64-byte record");
static_assert(offsetof(Point, x) == 8 && offsetof(Point, frame) == 20 &&
                  offsetof(Point, cov) == 24 && offsetof(Point, normal_oct) == 48 &&
                  offsetof(Point, label) == 52 && offsetof(Point, r) == 56 &&
                  offsetof(Point, flags) == 59 && offsetof(Point, camera) == 60,
              "Point layout must match docs/FORMAT.md");

// Writes the 64-byte little-endian record of `p` to dst.
void EncodePoint(const Point& p, uint8_t* dst);
Point DecodePointFieldwise(const uint8_t* src);
// Inline, one copy on little-endian machines: queries decode every record of a bucket that
// straddles the region's boundary to test it.
inline Point DecodePoint(const uint8_t* src) {
  if constexpr (std::endian::native == std::endian::little) {
    Point p;
    std::memcpy(static_cast<void*>(&p), src, kPointRecordSize);
    p.reserved = 0;
    return p;
  } else {
    return DecodePointFieldwise(src);
  }
}
// Arrays: dst must hold points.size() * 64 bytes.
void EncodePoints(std::span<const Point> points, uint8_t* dst);
void DecodePoints(const uint8_t* src, size_t n, Point* out);

// Octahedral normal encoding (Cigolle et al. 2014) at 16 bits per component: max angular
// error ~0.003 degrees. The input need not be normalised; a zero vector encodes as +z.
std::array<int16_t, 2> EncodeNormal(float nx, float ny, float nz);
std::array<float, 3> DecodeNormal(std::array<int16_t, 2> oct);

// Covariance from spanning vectors T1..T3 (each 3D): V = sum Ti Ti^T.
std::array<float, 6> CovarianceFromSpanning(const float t1[3], const float t2[3],
                                            const float t3[3]);

}  // namespace hvdb

#endif  // HVDB_STORAGE_POINT_H_
