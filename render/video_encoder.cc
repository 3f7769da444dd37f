#include "render/video_encoder.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <future>
#include <mutex>
#include <thread>
#include <vector>

#include "formats/libav.h"
#include "render/splat.h"

namespace hvdb::render {

namespace {

using formats::Av;

std::string AvError(int err) {
  char buf[AV_ERROR_MAX_STRING_SIZE] = {};
  Av().av_strerror(err, buf, sizeof buf);
  return buf;
}

// Linear [0, 1] to 8-bit sRGB through a table: a pow per channel would cost more than the
// encoding at 1080p.
constexpr int kLutSize = 16384;
const std::vector<uint8_t>& SrgbLut() {
  static const std::vector<uint8_t> lut = [] {
    std::vector<uint8_t> t(kLutSize + 1);
    for (int i = 0; i <= kLutSize; ++i) {
      t[size_t(i)] = uint8_t(std::lround(255.f * LinearToSrgb(float(i) / kLutSize)));
    }
    return t;
  }();
  return lut;
}

// The file in memory, seekable (the MP4 muxer goes back to patch sizes and writes its index).
struct MemoryFile {
  std::string bytes;
  size_t pos = 0;
  // FFmpeg 5 passes a non-const buffer (6.1 made it const).
  static int Write(void* opaque, uint8_t* buf, int size) {
    auto* f = static_cast<MemoryFile*>(opaque);
    if (f->pos + size_t(size) > f->bytes.size()) f->bytes.resize(f->pos + size_t(size));
    std::memcpy(f->bytes.data() + f->pos, buf, size_t(size));
    f->pos += size_t(size);
    return size;
  }
  static int64_t Seek(void* opaque, int64_t offset, int whence) {
    auto* f = static_cast<MemoryFile*>(opaque);
    whence &= ~AVSEEK_FORCE;
    if (whence == AVSEEK_SIZE) return int64_t(f->bytes.size());
    int64_t base = whence == SEEK_CUR ? int64_t(f->pos) : whence == SEEK_END ? int64_t(f->bytes.size()) : 0;
    if (base + offset < 0) return AVERROR(EINVAL);
    f->pos = size_t(base + offset);
    return int64_t(f->pos);
  }
};

class AvEncoder : public VideoEncoder {
 public:
  ~AvEncoder() override {
    if (pending_.valid()) pending_.wait();  // it uses the contexts freed below
    if (sws_ != nullptr) Av().sws_freeContext(sws_);
    Av().av_frame_free(&frame_);
    Av().av_packet_free(&packet_);
    Av().avcodec_free_context(&codec_);
    if (format_ != nullptr) {
      if (format_->pb != nullptr) {
        Av().av_freep(&format_->pb->buffer);
        Av().avio_context_free(&format_->pb);
      }
      Av().avformat_free_context(format_);
    }
  }

  Status Open(VideoContainer container, uint32_t width, uint32_t height, double fps) {
    width_ = width;
    height_ = height;
    // libx264 and libvpx report every file's statistics on stderr; errors come back as codes.
    static std::once_flag quiet;
    std::call_once(quiet, [] { Av().av_log_set_level(AV_LOG_ERROR); });
    const std::vector<const char*> names =
        container == VideoContainer::kMp4
            ? std::vector<const char*>{"libx264", "mpeg4"}
            : std::vector<const char*>{"libvpx-vp9", "libsvtav1", "libaom-av1"};
    const AVCodec* enc = nullptr;
    for (const char* n : names) {
      if ((enc = Av().avcodec_find_encoder_by_name(n)) != nullptr) break;
    }
    if (enc == nullptr) {
      return Status::Unsupported(std::string("video: this libavcodec has no ") +
                                 VideoContainerName(container) + " encoder (tried " + names[0] +
                                 " and the others of render/video_encoder.h)");
    }
    name_ = enc->name;
    const char* muxer = container == VideoContainer::kMp4 ? "mp4" : "webm";
    if (Av().avformat_alloc_output_context2(&format_, nullptr, muxer, nullptr) < 0 || format_ == nullptr) {
      return Status::Internal(std::string("video: no ") + muxer + " muxer in this libavformat");
    }
    codec_ = Av().avcodec_alloc_context3(enc);
    codec_->width = int(width);
    codec_->height = int(height);
    codec_->pix_fmt = AV_PIX_FMT_YUV420P;
    const AVRational rate = Av().av_d2q(fps, 100000);
    codec_->time_base = av_inv_q(rate);
    codec_->framerate = rate;
    codec_->gop_size = 60;
    codec_->thread_count = 0;  // as many as the cores
    if (format_->oformat->flags & AVFMT_GLOBALHEADER) codec_->flags |= AV_CODEC_FLAG_GLOBAL_HEADER;
    AVDictionary* opts = nullptr;
    if (name_ == "libx264") {
      Av().av_dict_set(&opts, "preset", "ultrafast", 0);
      Av().av_dict_set(&opts, "crf", "20", 0);
    } else if (name_ == "mpeg4") {
      codec_->flags |= AV_CODEC_FLAG_QSCALE;
      codec_->global_quality = FF_QP2LAMBDA * 3;
    } else if (name_ == "libvpx-vp9") {
      Av().av_dict_set(&opts, "deadline", "realtime", 0);
      Av().av_dict_set(&opts, "cpu-used", "8", 0);
      Av().av_dict_set(&opts, "row-mt", "1", 0);
      Av().av_dict_set(&opts, "crf", "32", 0);
      codec_->bit_rate = 0;
    } else if (name_ == "libsvtav1") {
      Av().av_dict_set(&opts, "preset", "12", 0);
    } else if (name_ == "libaom-av1") {
      Av().av_dict_set(&opts, "cpu-used", "8", 0);
      Av().av_dict_set(&opts, "usage", "realtime", 0);
    }
    int err = Av().avcodec_open2(codec_, enc, &opts);
    Av().av_dict_free(&opts);
    if (err < 0) return Status::Internal("video: cannot open " + name_ + ": " + AvError(err));
    stream_ = Av().avformat_new_stream(format_, nullptr);
    if (stream_ == nullptr) return Status::Internal("video: cannot add a stream");
    stream_->time_base = codec_->time_base;
    stream_->avg_frame_rate = rate;
    Av().avcodec_parameters_from_context(stream_->codecpar, codec_);
    constexpr int kBuffer = 1 << 16;
    auto* buffer = static_cast<uint8_t*>(Av().av_malloc(kBuffer));
    format_->pb = Av().avio_alloc_context(buffer, kBuffer, 1, &file_, nullptr, &MemoryFile::Write,
                                     &MemoryFile::Seek);
    if (format_->pb == nullptr) return Status::Internal("video: cannot allocate the output");
    err = Av().avformat_write_header(format_, nullptr);
    if (err < 0) return Status::Internal("video: cannot write the header: " + AvError(err));
    frame_ = Av().av_frame_alloc();
    packet_ = Av().av_packet_alloc();
    frame_->format = codec_->pix_fmt;
    frame_->width = codec_->width;
    frame_->height = codec_->height;
    if (Av().av_frame_get_buffer(frame_, 0) < 0) return Status::Internal("video: no frame buffer");
    sws_ = Av().sws_getContext(int(width), int(height), AV_PIX_FMT_RGB24, int(width), int(height),
                          AV_PIX_FMT_YUV420P, SWS_BILINEAR, nullptr, nullptr, nullptr);
    if (sws_ == nullptr) return Status::Internal("video: no RGB to YUV converter");
    rgb_.resize(size_t{width} * height * 3);
    return Status::OK();
  }

  Status Add(const Image& image) override {
    if (finished_) return Status::InvalidArgument("video: Add after Finish");
    // The previous frame's conversion and encoding ran while the caller drew this one.
    HVDB_RETURN_IF_ERROR(Wait());
    if (image.width != width_ || image.height != height_) {
      return Status::InvalidArgument("video: image " + std::to_string(frames_) + " is " +
                                     std::to_string(image.width) + "x" + std::to_string(image.height) +
                                     ", the video " + std::to_string(width_) + "x" +
                                     std::to_string(height_) + "; every view must have one size");
    }
    const std::vector<uint8_t>& lut = SrgbLut();
    // In bands of rows on every core: at 1080p this costs as much as x264's ultrafast preset.
    const unsigned threads = std::max(1u, std::thread::hardware_concurrency());
    constexpr size_t kRows = 32;
    internal::ParallelFor((height_ + kRows - 1) / kRows, threads, [&](size_t band) {
      const size_t lo = band * kRows * width_, hi = std::min<size_t>(height_, (band + 1) * kRows) * width_;
      for (size_t i = lo; i < hi; ++i) {
        for (size_t c = 0; c < 3; ++c) {
          const float v = std::clamp(image.rgba[4 * i + c], 0.f, 1.f);
          rgb_[3 * i + c] = lut[size_t(v * kLutSize + 0.5f)];
        }
      }
    });
    const int64_t pts = int64_t(frames_++);
    pending_ = std::async(std::launch::async, [this, pts] {
      if (Av().av_frame_make_writable(frame_) < 0) return Status::Internal("video: frame not writable");
      const uint8_t* src[1] = {rgb_.data()};
      const int stride[1] = {int(width_ * 3)};
      Av().sws_scale(sws_, src, stride, 0, int(height_), frame_->data, frame_->linesize);
      frame_->pts = pts;
      return Send(frame_);
    });
    return Status::OK();
  }

  Result<std::string> Finish() override {
    if (finished_) return Status::InvalidArgument("video: Finish twice");
    finished_ = true;
    HVDB_RETURN_IF_ERROR(Wait());
    HVDB_RETURN_IF_ERROR(Send(nullptr));
    int err = Av().av_write_trailer(format_);
    if (err < 0) return Status::Internal("video: cannot finish the file: " + AvError(err));
    Av().avio_flush(format_->pb);
    return std::move(file_.bytes);
  }

  std::string codec() const override { return name_; }
  uint64_t frames() const override { return frames_; }

 private:
  // The encoding of the last frame added (on a thread of its own), finished; its status.
  Status Wait() {
    if (!pending_.valid()) return Status::OK();
    return pending_.get();
  }

  // Sends a frame (nullptr: flush) and writes the packets the encoder has ready.
  Status Send(const AVFrame* frame) {
    int err = Av().avcodec_send_frame(codec_, frame);
    if (err < 0) return Status::Internal("video: " + name_ + " refused a frame: " + AvError(err));
    for (;;) {
      err = Av().avcodec_receive_packet(codec_, packet_);
      if (err == AVERROR(EAGAIN) || err == AVERROR_EOF) return Status::OK();
      if (err < 0) return Status::Internal("video: " + name_ + ": " + AvError(err));
      Av().av_packet_rescale_ts(packet_, codec_->time_base, stream_->time_base);
      packet_->stream_index = stream_->index;
      err = Av().av_interleaved_write_frame(format_, packet_);
      if (err < 0) return Status::Internal("video: cannot write a packet: " + AvError(err));
    }
  }

  uint32_t width_ = 0, height_ = 0;
  std::string name_;
  AVFormatContext* format_ = nullptr;
  AVCodecContext* codec_ = nullptr;
  AVStream* stream_ = nullptr;
  AVFrame* frame_ = nullptr;
  AVPacket* packet_ = nullptr;
  SwsContext* sws_ = nullptr;
  MemoryFile file_;
  std::vector<uint8_t> rgb_;  // the frame being encoded (written only after Wait())
  std::future<Status> pending_;
  uint64_t frames_ = 0;
  bool finished_ = false;
};

}  // namespace

const char* VideoContainerName(VideoContainer c) {
  return c == VideoContainer::kMp4 ? "mp4" : "webm";
}

Result<std::unique_ptr<VideoEncoder>> VideoEncoder::Create(VideoContainer container,
                                                           uint32_t width, uint32_t height,
                                                           double fps) {
  if (width < 2 || height < 2 || width > kMaxImageSize || height > kMaxImageSize ||
      width % 2 != 0 || height % 2 != 0) {
    return Status::InvalidArgument("video: the size " + std::to_string(width) + "x" +
                                   std::to_string(height) +
                                   " must be even on both sides (YUV 4:2:0), 2.." +
                                   std::to_string(kMaxImageSize));
  }
  if (!(fps > 0 && fps <= 1000)) {
    return Status::InvalidArgument("render.video_fps: must be in (0, 1000] frames a second");
  }
  HVDB_RETURN_IF_ERROR(formats::LoadLibAv());  // before the encoder: its teardown calls FFmpeg
  auto enc = std::make_unique<AvEncoder>();
  HVDB_RETURN_IF_ERROR(enc->Open(container, width, height, fps));
  return std::unique_ptr<VideoEncoder>(std::move(enc));
}

}  // namespace hvdb::render
