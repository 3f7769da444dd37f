// The photo file (docs/FORMAT.md "Photos"): NAME/photos/FFFFFFFF-CCCCC.photo holds one
// acquisition camera's photo of one frame, with that camera's calibration.
#ifndef HVDB_STORAGE_PHOTOS_H_
#define HVDB_STORAGE_PHOTOS_H_

#include <cstdint>
#include <string>

#include "storage/database.h"

namespace hvdb {

// The file name (without folder) of camera `camera`'s photo of `frame`.
std::string PhotoFileName(uint32_t frame, uint16_t camera);
std::string EncodePhoto(const Photo& photo);
// `what` names the file in errors (Corruption).
Result<Photo> DecodePhoto(const std::string& data, const std::string& what);

}  // namespace hvdb

#endif  // HVDB_STORAGE_PHOTOS_H_
