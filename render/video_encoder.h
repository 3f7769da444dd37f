// Rendered images into one video file (MP4 or WebM) with Debian's libavcodec/libavformat: the
// `hvdb render --video` export and the page's "Render video" both get it through a Render
// request with format IMAGE_MP4 / IMAGE_WEBM (render/job.cc feeds it the path's images).
//
// Codecs: the fastest encoder Debian's libavcodec has for the container, tried in order:
//   MP4:  libx264 (preset ultrafast, CRF 20), else mpeg4 (MPEG-4 part 2, q 3)
//   WebM: libvpx-vp9 (realtime, cpu-used 8, row-mt), else libsvtav1 (preset 12), else libaom-av1
// (Debian 12's libavcodec59 links libx264, libvpx, libsvtav1 and libaom: the first of each is
// what runs.) Frames are 8-bit sRGB converted to YUV 4:2:0 by libswscale, so widths and
// heights must be even. The file is built in memory (a seekable buffer: MP4 writes its index
// last) and handed back whole by Finish().
#ifndef HVDB_RENDER_VIDEO_ENCODER_H_
#define HVDB_RENDER_VIDEO_ENCODER_H_

#include <memory>
#include <string>

#include "render/renderer.h"

namespace hvdb::render {

enum class VideoContainer { kMp4, kWebm };
const char* VideoContainerName(VideoContainer c);  // "mp4", "webm"

class VideoEncoder {
 public:
  // InvalidArgument for odd or out-of-range sizes or a frame rate outside (0, 1000];
  // Unsupported when this libavcodec has none of the container's encoders.
  static Result<std::unique_ptr<VideoEncoder>> Create(VideoContainer container, uint32_t width,
                                                      uint32_t height, double fps);
  virtual ~VideoEncoder() = default;
  // Encodes the next frame (its linear RGBA composited over black, as sRGB). InvalidArgument
  // when its size is not the video's. The image is converted before Add returns; the YUV
  // conversion and encoding run on a thread of their own while the caller draws the next one
  // (their errors come back from the next Add or Finish).
  virtual Status Add(const Image& image) = 0;
  // Flushes the encoder and returns the file's bytes; Add afterwards fails.
  virtual Result<std::string> Finish() = 0;
  // The encoder in use, e.g. "libx264".
  virtual std::string codec() const = 0;
  virtual uint64_t frames() const = 0;
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_VIDEO_ENCODER_H_
