// The photo file (docs/FORMAT.md "Photos"): NAME/photos/FFFFFFFF-CCCCC.photo holds one
// acquisition camera's photo of one frame, with that camera's calibration.
#ifndef HVDB_STORAGE_PHOTOS_H_
#define HVDB_STORAGE_PHOTOS_H_

#include <cstdint>
#include <cstring>
#include <string>

#include "storage/coding.h"
#include "storage/database.h"

namespace hvdb {

// The file name (without folder) of camera `camera`'s photo of `frame`.
std::string PhotoFileName(uint32_t frame, uint16_t camera);
std::string EncodePhoto(const Photo& photo);
// `what` names the file in errors (Corruption).
Result<Photo> DecodePhoto(const std::string& data, const std::string& what);

// What both photo formats (photos.cc, photo_video.cc) write with and where they live.
namespace photo_io {
template <typename T>
void Put(std::string* out, T v) {
  uint8_t b[sizeof(T)];
  EncodeLE<T>(b, v);
  out->append(reinterpret_cast<const char*>(b), sizeof(T));
}
inline void PutF64(std::string* out, double v) {
  uint64_t bits;
  std::memcpy(&bits, &v, 8);
  Put<uint64_t>(out, bits);
}
inline double GetF64(const uint8_t* p) {
  const uint64_t bits = DecodeLE<uint64_t>(p);
  double v;
  std::memcpy(&v, &bits, 8);
  return v;
}
inline std::string PhotoDir(const std::string& dataset_dir) { return dataset_dir + "/photos"; }
}  // namespace photo_io

}  // namespace hvdb

#endif  // HVDB_STORAGE_PHOTOS_H_
