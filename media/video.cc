// Video files (anything Debian's libavformat demuxes and libavcodec decodes: mp4, webm, mkv,
// ...) as RGBA pictures, read from memory through a custom AVIOContext.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <cstdarg>
#include <memory>
#include <mutex>

#include "formats/libav.h"
#include "media/media.h"

namespace hvdb::media {
namespace {

using formats::Av;

struct MemoryFile {
  const uint8_t* data;
  int64_t size;
  int64_t pos = 0;
};

int ReadPacket(void* opaque, uint8_t* buf, int n) {
  auto* f = static_cast<MemoryFile*>(opaque);
  const int64_t left = f->size - f->pos;
  if (left <= 0) return AVERROR_EOF;
  const int m = static_cast<int>(std::min<int64_t>(n, left));
  std::memcpy(buf, f->data + f->pos, m);
  f->pos += m;
  return m;
}

int64_t Seek(void* opaque, int64_t offset, int whence) {
  auto* f = static_cast<MemoryFile*>(opaque);
  if (whence & AVSEEK_SIZE) return f->size;
  whence &= ~AVSEEK_FORCE;
  int64_t to;
  switch (whence) {
    case SEEK_SET: to = offset; break;
    case SEEK_CUR: to = f->pos + offset; break;
    case SEEK_END: to = f->size + offset; break;
    default: return -1;
  }
  if (to < 0 || to > f->size) return -1;
  f->pos = to;
  return to;
}

// libav's messages while this thread decodes a request's video go into the request's error
// (not the server's stderr): the first error line says what was wrong with the file.
thread_local std::string* tl_log = nullptr;

void CaptureLog(void* avcl, int level, const char* fmt, va_list vl) {
  if (tl_log == nullptr) return Av().av_log_default_callback(avcl, level, fmt, vl);
  if (level > AV_LOG_ERROR || !tl_log->empty()) return;
  char line[256];
  int prefix = 0;  // without "[codec @ 0x...]": the same words for the same file every time
  Av().av_log_format_line(avcl, level, fmt, vl, line, sizeof line, &prefix);
  std::string l = line;
  while (!l.empty() && (l.back() == '\n' || l.back() == ' ')) l.pop_back();
  *tl_log = l;
}

struct LogScope {
  explicit LogScope(std::string* s) {
    static std::once_flag once;
    std::call_once(once, [] { Av().av_log_set_callback(CaptureLog); });
    tl_log = s;
  }
  ~LogScope() { tl_log = nullptr; }
};

// A demuxer that names another resource (an HLS or DASH playlist's segments, a concat list's
// files, a QuickTime reference) would open it on the server: every such open is refused, and
// the protocol whitelist (which nested demuxers inherit) allows none.
thread_local std::string* tl_refused = nullptr;

int RefuseOpen(AVFormatContext*, AVIOContext**, const char* url, int, AVDictionary**) {
  if (tl_refused != nullptr && tl_refused->empty()) *tl_refused = url != nullptr ? url : "";
  return AVERROR(EPERM);
}

std::string AvError(int err, const std::string& log = "") {
  char buf[AV_ERROR_MAX_STRING_SIZE] = {};
  Av().av_strerror(err, buf, sizeof buf);
  return log.empty() ? std::string(buf) : std::string(buf) + ": " + log;
}

// Owners of libav's objects, freed in reverse order of creation.
struct Demuxer {
  AVIOContext* io = nullptr;
  AVFormatContext* fmt = nullptr;
  AVCodecContext* codec = nullptr;
  AVPacket* packet = nullptr;
  AVFrame* frame = nullptr;
  SwsContext* sws = nullptr;
  ~Demuxer() {
    Av().sws_freeContext(sws);
    Av().av_frame_free(&frame);
    Av().av_packet_free(&packet);
    Av().avcodec_free_context(&codec);
    Av().avformat_close_input(&fmt);
    if (io != nullptr) Av().av_freep(&io->buffer);
    Av().avio_context_free(&io);
  }
};

}  // namespace

Result<std::vector<Picture>> DecodeVideo(std::string_view data, const std::string& format,
                                         uint32_t max_frames, uint32_t max_side,
                                         uint64_t max_points, const Budget& budget) {
  const std::string what = "import_media: the video (" + (format.empty() ? "?" : format) + ")";
  if (data.empty()) return Status::InvalidArgument(what + " is empty");
  HVDB_RETURN_IF_ERROR(formats::LoadLibAv());
  MemoryFile file{reinterpret_cast<const uint8_t*>(data.data()),
                  static_cast<int64_t>(data.size())};
  std::string log;
  LogScope scope(&log);  // outlives the demuxer: its teardown may log too
  Demuxer d;
  constexpr int kBuffer = 64 << 10;
  auto* buffer = static_cast<uint8_t*>(Av().av_malloc(kBuffer));
  if (buffer == nullptr) return Status::Internal(what + ": out of memory");
  d.io = Av().avio_alloc_context(buffer, kBuffer, 0, &file, ReadPacket, nullptr, Seek);
  if (d.io == nullptr) {
    Av().av_free(buffer);
    return Status::Internal(what + ": out of memory");
  }
  d.fmt = Av().avformat_alloc_context();
  d.fmt->pb = d.io;
  d.fmt->flags |= AVFMT_FLAG_CUSTOM_IO;
  // The extension helps the probe of formats without a signature.
  const AVInputFormat* hint = format.empty() ? nullptr : Av().av_find_input_format(format.c_str());
  std::string refused;
  tl_refused = &refused;
  struct ClearRefused {
    ~ClearRefused() { tl_refused = nullptr; }
  } clear_refused;
  d.fmt->io_open = RefuseOpen;
  AVDictionary* opts = nullptr;
  Av().av_dict_set(&opts, "protocol_whitelist", "none", 0);
  int err = Av().avformat_open_input(&d.fmt, nullptr, hint, &opts);
  Av().av_dict_free(&opts);
  const auto outside = [&]() {
    return Status::InvalidArgument(what + " refers to '" + refused +
                                   "', outside the bytes sent; only the file itself is read");
  };
  if (err < 0) {
    // On failure avformat_open_input frees the context (not our custom IO).
    d.fmt = nullptr;
    if (!refused.empty()) return outside();
    return Status::InvalidArgument(what + " could not be demuxed: " + AvError(err, log));
  }
  err = Av().avformat_find_stream_info(d.fmt, nullptr);
  if (!refused.empty()) return outside();
  if (err < 0) {
    return Status::InvalidArgument(what + ": no stream information: " + AvError(err, log));
  }
  const AVCodec* decoder = nullptr;
  const int stream = Av().av_find_best_stream(d.fmt, AVMEDIA_TYPE_VIDEO, -1, -1, &decoder, 0);
  if (stream < 0 || decoder == nullptr) {
    return Status::InvalidArgument(what + " has no video stream that libavcodec decodes (" +
                                   AvError(stream, log) + ")");
  }
  // The declared size first: a frame over the limit is refused before a decoder exists, and
  // the decoder itself refuses any later frame over it (a stream may change size).
  const AVCodecParameters* par = d.fmt->streams[stream]->codecpar;
  if (par->width < 0 || par->height < 0 || uint64_t(par->width) > kMaxPictureSide ||
      uint64_t(par->height) > kMaxPictureSide ||
      uint64_t(par->width) * uint64_t(par->height) > kMaxPicturePixels) {
    return Status::LimitExceeded(what + " declares " + std::to_string(par->width) + "x" +
                                 std::to_string(par->height) + " pixels a frame, over the limit "
                                 "of " + std::to_string(kMaxPictureSide) + " a side and " +
                                 std::to_string(kMaxPicturePixels >> 20) + " M pixels");
  }
  d.codec = Av().avcodec_alloc_context3(decoder);
  Av().avcodec_parameters_to_context(d.codec, par);
  d.codec->max_pixels = static_cast<int64_t>(kMaxPicturePixels);
  d.codec->thread_count = 1;  // one request, one core; and its memory is what is reserved
  err = Av().avcodec_open2(d.codec, decoder, nullptr);
  if (err < 0) {
    return Status::InvalidArgument(what + ": the " + decoder->name +
                                   " decoder did not open: " + AvError(err, log));
  }
  d.packet = Av().av_packet_alloc();
  d.frame = Av().av_frame_alloc();

  std::vector<Picture> out;
  std::string decode_error;
  // The decoder's own pictures (the frame, its references, the converter's copy), reserved at
  // kDecoderBytesPerPixel of the largest frame seen; the pictures made, as they are made.
  constexpr uint64_t kDecoderBytesPerPixel = 24;
  uint64_t largest = 0, total_points = 0;
  // Converts the decoded frame to RGBA at the texel grid's size.
  auto take = [&]() -> Status {
    const int fw = d.frame->width, fh = d.frame->height;
    if (fw <= 0 || fh <= 0) return Status::InvalidArgument(what + ": a frame has no pixels");
    int w = fw, h = fh;
    const int side = std::max(fw, fh);
    if (max_side > 0 && side > static_cast<int>(max_side)) {
      const double f = static_cast<double>(max_side) / side;
      w = std::max(1, static_cast<int>(std::lround(fw * f)));
      h = std::max(1, static_cast<int>(std::lround(fh * f)));
    }
    HVDB_RETURN_IF_ERROR(budget.CheckTime(what));
    const uint64_t per = uint64_t{static_cast<uint32_t>(w)} * h;
    // Refused before the rest is decoded (frames past the video's end repeat its last).
    if (out.empty() && per * max_frames > max_points) {
      return TooManyPoints(per, max_frames, Kind::kVideo);
    }
    // Every frame counts, whatever its size: a stream may grow after its first frame.
    total_points += per;
    if (total_points > max_points) {
      return Status::InvalidArgument("import_media.frames: the video's first " +
                                     std::to_string(out.size() + 1) + " frames already hold " +
                                     std::to_string(total_points) +
                                     " points, over the limit of " + std::to_string(max_points) +
                                     " points an import; give fewer frames or fewer texels");
    }
    const uint64_t pixels = uint64_t{static_cast<uint32_t>(fw)} * static_cast<uint32_t>(fh);
    if (pixels > largest) {
      HVDB_RETURN_IF_ERROR(budget.Reserve((pixels - largest) * kDecoderBytesPerPixel,
                                          what + ": its decoder's pictures"));
      largest = pixels;
    }
    HVDB_RETURN_IF_ERROR(budget.Reserve(per * 4, what + ": its frames"));
    d.sws = Av().sws_getCachedContext(d.sws, fw, fh, static_cast<AVPixelFormat>(d.frame->format), w,
                                 h, AV_PIX_FMT_RGBA, SWS_AREA | SWS_ACCURATE_RND, nullptr,
                                 nullptr, nullptr);
    if (d.sws == nullptr) {
      return Status::InvalidArgument(what + ": no conversion from pixel format " +
                                     std::to_string(d.frame->format) + " to RGBA");
    }
    Picture p;
    p.width = w;
    p.height = h;
    p.rgba.resize(static_cast<size_t>(w) * h * 4);
    uint8_t* dst[4] = {p.rgba.data(), nullptr, nullptr, nullptr};
    int stride[4] = {w * 4, 0, 0, 0};
    Av().sws_scale(d.sws, d.frame->data, d.frame->linesize, 0, fh, dst, stride);
    out.push_back(std::move(p));
    return Status::OK();
  };
  // Drains the decoder's frames; stops at max_frames.
  auto drain = [&]() -> Status {
    while (out.size() < max_frames) {
      const int r = Av().avcodec_receive_frame(d.codec, d.frame);
      if (r == AVERROR(EAGAIN) || r == AVERROR_EOF) return Status::OK();
      if (r < 0) {
        decode_error = AvError(r, log);
        return Status::OK();
      }
      Status st = take();
      Av().av_frame_unref(d.frame);
      if (!st.ok()) return st;
    }
    return Status::OK();
  };
  bool eof = false;
  while (out.size() < max_frames && !eof) {
    err = Av().av_read_frame(d.fmt, d.packet);
    if (err < 0) {
      // End of file, or a damaged tail: flush what the decoder holds.
      if (err != AVERROR_EOF) decode_error = AvError(err, log);
      eof = true;
      Av().avcodec_send_packet(d.codec, nullptr);
    } else {
      if (d.packet->stream_index == stream) {
        // A full decoder (EAGAIN) takes the packet once its frames are out.
        int r = Av().avcodec_send_packet(d.codec, d.packet);
        if (r == AVERROR(EAGAIN)) {
          HVDB_RETURN_IF_ERROR(drain());
          r = Av().avcodec_send_packet(d.codec, d.packet);
        }
        if (r < 0 && r != AVERROR(EAGAIN)) decode_error = AvError(r, log);
      }
      Av().av_packet_unref(d.packet);
    }
    HVDB_RETURN_IF_ERROR(drain());
  }
  if (!refused.empty()) return outside();
  if (out.empty()) {
    if (decode_error.empty()) decode_error = log;
    return Status::InvalidArgument(what + ": no frame decoded" +
                                   (decode_error.empty() ? "" : " (" + decode_error + ")"));
  }
  return out;
}

}  // namespace hvdb::media
