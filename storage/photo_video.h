// The video tier of photos (docs/FORMAT.md "Photo video run"): one camera's photos over a run
// of frames coded as ONE video file (NAME/photos/AAAAAAAA-BBBBBBBB-CCCCC-XXXXXXXX.ivf) plus an
// index (NAME/photos/AAAAAAAA-BBBBBBBB-CCCCC.pvx) holding each frame's picture number and its calibration and billboard,
// exactly. storage/ links no codec: the coding is behind PhotoVideoCodec, which media/
// implements with libavcodec (media/photo_video.cc) and installs (media::InstallPhotoVideoCodec).
#ifndef HVDB_STORAGE_PHOTO_VIDEO_H_
#define HVDB_STORAGE_PHOTO_VIDEO_H_

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "storage/database.h"

namespace hvdb {

// The PSNR every coded picture keeps against its photo in each of BT.601's Y (luma), Cb and Cr,
// computed from the 8-bit RGB pictures.
inline constexpr double kPhotoVideoMinPsnr = 40.0;
// Pictures in one run at most: what a compaction holds in memory (decoded, ~6 MB each at
// 1080p) and how far a reader decodes from the run's one key picture.
inline constexpr size_t kPhotoVideoMaxPictures = 32;

struct EncodedPhotoVideo {
  std::string video;          // the container's bytes (IVF, AV1)
  std::vector<double> psnr;   // per picture: the lowest of its Y, Cb, Cr PSNR (dB) vs the input
  std::string codec;          // what coded it, e.g. "libsvtav1 preset 8 crf 45"
  uint32_t width = 0, height = 0;  // the pictures' size (the coded one may be padded)
};

class PhotoVideoCodec {
 public:
  virtual ~PhotoVideoCodec() = default;
  // Codes the images (PNG/JPEG files' bytes, all of one size) as one video, in order, at the
  // lowest quality at which every decoded picture keeps PSNR >= min_psnr_db in Y, Cb and Cr.
  virtual Result<EncodedPhotoVideo> Encode(const std::vector<std::string_view>& images,
                                           double min_psnr_db) const = 0;
  // Picture `index` of `video`, width x height (cropped from the coded size), as a PNG file's
  // bytes; Corruption naming `what` if it does not decode.
  virtual Result<std::string> Decode(std::string_view video, uint32_t index, uint32_t width,
                                     uint32_t height, const std::string& what) const = 0;
};

// The process's codec (null until one is installed: the video tier's photos then read as
// Unsupported). Installed once at start-up; the pointer must outlive every dataset.
void SetPhotoVideoCodec(const PhotoVideoCodec* codec);
const PhotoVideoCodec* GetPhotoVideoCodec();

// One picture of a run, as its index lists it.
struct PhotoVideoEntry {
  uint32_t frame = 0;
  double psnr = 0;  // the lowest of its Y, Cb, Cr PSNR, as verified after coding
  Photo meta;       // the photo less its image (calibration and billboard, exact)
};
struct PhotoVideoIndex {
  uint16_t camera = 0;
  uint32_t first = 0, last = 0;  // frames of the first and last picture
  uint64_t video_bytes = 0;
  uint32_t video_crc = 0;        // crc32c (unmasked) of the video file
  uint32_t width = 0, height = 0;  // the pictures' size
  double min_psnr = 0;           // the bound the run was coded to
  std::string codec;
  std::vector<PhotoVideoEntry> entries;  // by frame, ascending; entry i is picture i
};

// The file names (without folder) of camera `camera`'s run over [first, last]: its index
// (AAAAAAAA-BBBBBBBB-CCCCC.pvx) and the video it names (...-CCCCC-XXXXXXXX.ivf, X: the video's
// CRC-32C in hex, so that a run coded again never overwrites the video its old index names).
std::string PhotoVideoIndexName(uint32_t first, uint32_t last, uint16_t camera);
std::string PhotoVideoFileName(uint32_t first, uint32_t last, uint16_t camera, uint32_t video_crc);
// Parses an index's file name ("...pvx"); false if it is not one.
bool ParsePhotoVideoName(const std::string& name, uint32_t* first, uint32_t* last,
                         uint16_t* camera);
std::string EncodePhotoVideoIndex(const PhotoVideoIndex& index);
Result<PhotoVideoIndex> DecodePhotoVideoIndex(const std::string& data, const std::string& what);

}  // namespace hvdb

#endif  // HVDB_STORAGE_PHOTO_VIDEO_H_
