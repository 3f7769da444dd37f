// The video tier's codec (storage/photo_video.h) with Debian's libavcodec: AV1 through
// SVT-AV1 (libsvtav1, preset 8, 4:2:0), else libaom (and libaom 4:4:4 for colour 4:2:0 cannot
// keep); decoded with libdav1d (else libavcodec's own AV1 decoder), in an IVF container. SVT-AV1 because on 2 cores it codes 16 Panoptic 1080p
// pictures in ~3.5 s where libaom (cpu-used 8) takes ~24 s for the same bytes and PSNR.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <list>
#include <memory>
#include <mutex>

#include <opencv2/core.hpp>

#include "formats/image_codec.h"
#include "formats/libav.h"
#include "media/media.h"
#include "storage/photo_video.h"

namespace hvdb::media {
namespace {

using formats::Av;

// SVT-AV1 and libaom need a picture of at least this many pixels a side, and 4:2:0 even sides:
// smaller or odd pictures are padded by repeating their edge, and cropped back on decoding.
constexpr int kMinSide = 64;
constexpr int kStartCrf = 50;  // Panoptic's 1080p Kinect views: ~41.5 dB at 50 (SVT, preset 8)

std::string AvError(int err) {
  char buf[AV_ERROR_MAX_STRING_SIZE] = {};
  Av().av_strerror(err, buf, sizeof buf);
  return buf;
}

// A seekable file in memory, for the IVF muxer (it patches the frame count) and demuxer.
struct MemoryFile {
  std::string bytes;
  const uint8_t* read = nullptr;
  int64_t size = 0;
  int64_t pos = 0;
  static int Write(void* opaque, uint8_t* buf, int n) {
    auto* f = static_cast<MemoryFile*>(opaque);
    if (size_t(f->pos) + size_t(n) > f->bytes.size()) f->bytes.resize(size_t(f->pos) + size_t(n));
    std::memcpy(f->bytes.data() + f->pos, buf, size_t(n));
    f->pos += n;
    return n;
  }
  static int Read(void* opaque, uint8_t* buf, int n) {
    auto* f = static_cast<MemoryFile*>(opaque);
    const int64_t left = f->size - f->pos;
    if (left <= 0) return AVERROR_EOF;
    const int m = int(std::min<int64_t>(n, left));
    std::memcpy(buf, f->read + f->pos, size_t(m));
    f->pos += m;
    return m;
  }
  static int64_t Seek(void* opaque, int64_t offset, int whence) {
    auto* f = static_cast<MemoryFile*>(opaque);
    const int64_t size = f->read != nullptr ? f->size : int64_t(f->bytes.size());
    whence &= ~AVSEEK_FORCE;
    if (whence == AVSEEK_SIZE) return size;
    const int64_t base = whence == SEEK_CUR ? f->pos : whence == SEEK_END ? size : 0;
    if (base + offset < 0) return AVERROR(EINVAL);
    f->pos = base + offset;
    return f->pos;
  }
};

// The PSNR of b against a (8-bit BGR) in each of BT.601's Y, Cb and Cr (full range, from the
// RGB values): the luma is the stated bound; the chroma too, so that colour 4:2:0 blurs (sharp
// saturated edges, e.g. rendered pictures) is caught.
struct Psnr3 {
  double y, cb, cr;
  double min() const { return std::min({y, cb, cr}); }
};
Psnr3 ChannelPsnr(const cv::Mat& a, const cv::Mat& b) {
  double sse[3] = {0, 0, 0};
  for (int y = 0; y < a.rows; ++y) {
    const uint8_t* p = a.ptr<uint8_t>(y);
    const uint8_t* q = b.ptr<uint8_t>(y);
    for (int x = 0; x < a.cols; ++x, p += 3, q += 3) {
      const double db = double(p[0]) - q[0], dg = double(p[1]) - q[1], dr = double(p[2]) - q[2];
      const double dy = 0.299 * dr + 0.587 * dg + 0.114 * db;
      const double dcb = -0.168736 * dr - 0.331264 * dg + 0.5 * db;
      const double dcr = 0.5 * dr - 0.418688 * dg - 0.081312 * db;
      sse[0] += dy * dy, sse[1] += dcb * dcb, sse[2] += dcr * dcr;
    }
  }
  double out[3];
  for (int c = 0; c < 3; ++c) {
    const double mse = sse[c] / (double(a.rows) * a.cols);
    out[c] = mse <= 1e-10 ? 100.0 : 10 * std::log10(255.0 * 255.0 / mse);
  }
  return {out[0], out[1], out[2]};
}

int Padded(int side) { return std::max(kMinSide, (side + 1) & ~1); }

// An IVF file's pictures in order, as BGR cropped to w x h, one at a time: a reader of picture
// i + 1 after picture i (a render walking the frames) goes on where it stopped.
class IvfDecoder {
 public:
  ~IvfDecoder() {
    Av().sws_freeContext(sws_);
    Av().av_frame_free(&frame_);
    Av().av_packet_free(&packet_);
    Av().avcodec_free_context(&codec_);
    Av().avformat_close_input(&fmt_);
    if (io_ != nullptr) Av().av_freep(&io_->buffer);
    Av().avio_context_free(&io_);
  }

  Status Open(std::string video, int w, int h, const std::string& what) {
    video_ = std::move(video);
    w_ = w, h_ = h;
    what_ = what;
    file_.read = reinterpret_cast<const uint8_t*>(video_.data());
    file_.size = int64_t(video_.size());
    constexpr int kBuffer = 1 << 16;
    auto* buffer = static_cast<uint8_t*>(Av().av_malloc(kBuffer));
    if (buffer == nullptr) return Status::Internal(what + ": out of memory");
    io_ = Av().avio_alloc_context(buffer, kBuffer, 0, &file_, &MemoryFile::Read, nullptr, &MemoryFile::Seek);
    if (io_ == nullptr) {
      Av().av_free(buffer);
      return Status::Internal(what + ": out of memory");
    }
    fmt_ = Av().avformat_alloc_context();
    packet_ = Av().av_packet_alloc();
    frame_ = Av().av_frame_alloc();
    if (fmt_ == nullptr || packet_ == nullptr || frame_ == nullptr) {
      return Status::Internal(what + ": out of memory");
    }
    fmt_->pb = io_;
    fmt_->flags |= AVFMT_FLAG_CUSTOM_IO;
    int err = Av().avformat_open_input(&fmt_, nullptr, Av().av_find_input_format("ivf"), nullptr);
    if (err < 0) {
      fmt_ = nullptr;  // freed by avformat_open_input (not our IO)
      return Bad("not an IVF video (" + AvError(err) + ")");
    }
    if (fmt_->nb_streams != 1 || fmt_->streams[0]->codecpar->codec_id != AV_CODEC_ID_AV1) {
      return Bad("not one AV1 stream");
    }
    const AVCodec* dec = Av().avcodec_find_decoder_by_name("libdav1d");
    if (dec == nullptr) dec = Av().avcodec_find_decoder(AV_CODEC_ID_AV1);
    if (dec == nullptr) return Status::Unsupported(what + ": this libavcodec decodes no AV1");
    codec_ = Av().avcodec_alloc_context3(dec);
    if (codec_ == nullptr) return Status::Internal(what + ": out of memory");
    Av().avcodec_parameters_to_context(codec_, fmt_->streams[0]->codecpar);
    codec_->thread_count = 0;
    if ((err = Av().avcodec_open2(codec_, dec, nullptr)) < 0) {
      return Status::Internal(what + ": cannot open " + dec->name + ": " + AvError(err));
    }
    return Status::OK();
  }

  // The next picture (false: the video has no more). Valid until the next call.
  Result<bool> Next(cv::Mat* out) {
    for (;;) {
      const int r = Av().avcodec_receive_frame(codec_, frame_);
      if (r == 0) break;
      if (r == AVERROR_EOF || (r == AVERROR(EAGAIN) && eof_)) return false;
      if (r != AVERROR(EAGAIN)) return Bad("a picture does not decode (" + AvError(r) + ")");
      const int e = Av().av_read_frame(fmt_, packet_);
      if (e < 0) {
        eof_ = true;
        Av().avcodec_send_packet(codec_, nullptr);
        continue;
      }
      const int s = Av().avcodec_send_packet(codec_, packet_);
      Av().av_packet_unref(packet_);
      if (s < 0) return Bad("a packet does not decode (" + AvError(s) + ")");
    }
    if (frame_->width < w_ || frame_->height < h_) {
      Av().av_frame_unref(frame_);
      return Bad("a picture smaller than its index says");
    }
    sws_ = Av().sws_getCachedContext(sws_, frame_->width, frame_->height, AVPixelFormat(frame_->format),
                                frame_->width, frame_->height, AV_PIX_FMT_BGR24,
                                SWS_BILINEAR | SWS_ACCURATE_RND | SWS_FULL_CHR_H_INT, nullptr,
                                nullptr, nullptr);
    if (sws_ == nullptr) return Status::Internal(what_ + ": no conversion to BGR");
    bgr_.create(frame_->height, frame_->width, CV_8UC3);
    uint8_t* dst[4] = {bgr_.data, nullptr, nullptr, nullptr};
    int stride[4] = {int(bgr_.step), 0, 0, 0};
    Av().sws_scale(sws_, frame_->data, frame_->linesize, 0, frame_->height, dst, stride);
    Av().av_frame_unref(frame_);
    *out = bgr_(cv::Rect(0, 0, w_, h_));
    ++next_;
    return true;
  }

  const std::string& video() const { return video_; }
  uint32_t next() const { return next_; }  // the number of the picture Next() returns

 private:
  Status Bad(const std::string& why) const { return Status::Corruption(what_ + ": " + why); }

  std::string video_;
  int w_ = 0, h_ = 0;
  std::string what_;
  MemoryFile file_;
  AVIOContext* io_ = nullptr;
  AVFormatContext* fmt_ = nullptr;
  AVCodecContext* codec_ = nullptr;
  AVPacket* packet_ = nullptr;
  AVFrame* frame_ = nullptr;
  SwsContext* sws_ = nullptr;
  cv::Mat bgr_;
  bool eof_ = false;
  uint32_t next_ = 0;
};

// Decoders stopped part-way, for the next picture of the same video (LRU; each one holds the
// video and the AV1 decoder's reference pictures, a few tens of MB at 1080p).
class DecoderCache {
 public:
  // A decoder of `video` (w x h) positioned at or before picture `index`: from the cache, or new.
  Result<std::unique_ptr<IvfDecoder>> Take(std::string_view video, uint32_t index, int w, int h,
                                           const std::string& what) {
    {
      std::lock_guard<std::mutex> l(mu_);
      for (auto it = idle_.begin(); it != idle_.end(); ++it) {
        if (it->w == w && it->h == h && it->d->next() <= index && it->d->video() == video) {
          std::unique_ptr<IvfDecoder> d = std::move(it->d);
          idle_.erase(it);
          return d;
        }
      }
    }
    auto d = std::make_unique<IvfDecoder>();
    HVDB_RETURN_IF_ERROR(d->Open(std::string(video), w, h, what));
    return d;
  }
  void Give(std::unique_ptr<IvfDecoder> d, int w, int h) {
    std::lock_guard<std::mutex> l(mu_);
    idle_.push_front(Idle{std::move(d), w, h});
    if (idle_.size() > kMax) idle_.pop_back();
  }

 private:
  struct Idle {
    std::unique_ptr<IvfDecoder> d;
    int w, h;
  };
  static constexpr size_t kMax = 10;  // a rig's cameras, walked frame by frame
  std::mutex mu_;
  std::list<Idle> idle_;
};

// The pictures (BGR, padded to the coded size) as an IVF file at `crf`: 4:2:0 by SVT-AV1 (else
// libaom), or, `full_chroma`, 4:4:4 by libaom (AV1's high profile; SVT-AV1 1.4 codes 4:2:0 only).
Result<std::string> EncodeAt(const std::vector<cv::Mat>& pictures, int crf, bool full_chroma,
                             std::string* name) {
  const AVCodec* enc = full_chroma ? nullptr : Av().avcodec_find_encoder_by_name("libsvtav1");
  if (enc == nullptr) enc = Av().avcodec_find_encoder_by_name("libaom-av1");
  if (enc == nullptr) {
    return Status::Unsupported(std::string("photo video: this libavcodec has no AV1 encoder (") +
                               (full_chroma ? "libaom-av1 for 4:4:4" : "libsvtav1 or libaom-av1") +
                               ")");
  }
  const AVPixelFormat pix = full_chroma ? AV_PIX_FMT_YUV444P : AV_PIX_FMT_YUV420P;
  const int w = pictures[0].cols, h = pictures[0].rows;
  AVFormatContext* fmt = nullptr;
  AVCodecContext* codec = Av().avcodec_alloc_context3(enc);
  AVFrame* frame = Av().av_frame_alloc();
  AVPacket* packet = Av().av_packet_alloc();
  SwsContext* sws = nullptr;
  MemoryFile file;
  struct Free {
    AVFormatContext*& fmt; AVCodecContext*& codec; AVFrame*& frame; AVPacket*& packet;
    SwsContext*& sws;
    ~Free() {
      Av().sws_freeContext(sws);
      Av().av_packet_free(&packet);
      Av().av_frame_free(&frame);
      Av().avcodec_free_context(&codec);
      if (fmt != nullptr) {
        if (fmt->pb != nullptr) {
          Av().av_freep(&fmt->pb->buffer);
          Av().avio_context_free(&fmt->pb);
        }
        Av().avformat_free_context(fmt);
      }
    }
  } free_all{fmt, codec, frame, packet, sws};
  if (Av().avformat_alloc_output_context2(&fmt, nullptr, "ivf", nullptr) < 0 || fmt == nullptr) {
    return Status::Internal("photo video: no IVF muxer in this libavformat");
  }
  codec->width = w;
  codec->height = h;
  codec->pix_fmt = pix;
  codec->time_base = AVRational{1, 30};
  codec->framerate = AVRational{30, 1};
  // One key picture per run: the run is decoded from its start anyway.
  codec->gop_size = int(pictures.size()) + 1;
  codec->thread_count = 0;
  AVDictionary* opts = nullptr;
  Av().av_dict_set_int(&opts, "crf", crf, 0);
  if (std::strcmp(enc->name, "libsvtav1") == 0) {
    Av().av_dict_set(&opts, "preset", "8", 0);
    *name = "libsvtav1 preset 8 crf " + std::to_string(crf);
  } else {
    Av().av_dict_set(&opts, "cpu-used", "6", 0);
    Av().av_dict_set(&opts, "row-mt", "1", 0);
    codec->bit_rate = 0;
    *name = "libaom-av1 cpu-used 6 crf " + std::to_string(crf) + (full_chroma ? " yuv444p" : "");
  }
  int err = Av().avcodec_open2(codec, enc, &opts);
  Av().av_dict_free(&opts);
  if (err < 0) return Status::Internal("photo video: cannot open " + std::string(enc->name) + ": " + AvError(err));
  AVStream* stream = Av().avformat_new_stream(fmt, nullptr);
  if (stream == nullptr) return Status::Internal("photo video: cannot add a stream");
  stream->time_base = codec->time_base;
  Av().avcodec_parameters_from_context(stream->codecpar, codec);
  constexpr int kBuffer = 1 << 16;
  auto* buffer = static_cast<uint8_t*>(Av().av_malloc(kBuffer));
  fmt->pb = Av().avio_alloc_context(buffer, kBuffer, 1, &file, nullptr, &MemoryFile::Write, &MemoryFile::Seek);
  if (fmt->pb == nullptr) return Status::Internal("photo video: cannot allocate the output");
  if ((err = Av().avformat_write_header(fmt, nullptr)) < 0) {
    return Status::Internal("photo video: cannot write the IVF header: " + AvError(err));
  }
  frame->format = codec->pix_fmt;
  frame->width = w;
  frame->height = h;
  if (Av().av_frame_get_buffer(frame, 0) < 0) return Status::Internal("photo video: no frame buffer");
  sws = Av().sws_getContext(w, h, AV_PIX_FMT_BGR24, w, h, pix,
                       SWS_BILINEAR | SWS_ACCURATE_RND, nullptr, nullptr, nullptr);
  if (sws == nullptr) return Status::Internal("photo video: no BGR to YUV conversion");
  auto send = [&](AVFrame* f) -> Status {
    int e = Av().avcodec_send_frame(codec, f);
    if (e < 0) return Status::Internal("photo video: the encoder refused a picture: " + AvError(e));
    for (;;) {
      e = Av().avcodec_receive_packet(codec, packet);
      if (e == AVERROR(EAGAIN) || e == AVERROR_EOF) return Status::OK();
      if (e < 0) return Status::Internal("photo video: " + AvError(e));
      Av().av_packet_rescale_ts(packet, codec->time_base, stream->time_base);
      packet->stream_index = stream->index;
      if ((e = Av().av_write_frame(fmt, packet)) < 0) {
        return Status::Internal("photo video: cannot write a packet: " + AvError(e));
      }
    }
  };
  for (size_t i = 0; i < pictures.size(); ++i) {
    if (Av().av_frame_make_writable(frame) < 0) return Status::Internal("photo video: frame not writable");
    const uint8_t* src[1] = {pictures[i].data};
    const int stride[1] = {int(pictures[i].step)};
    Av().sws_scale(sws, src, stride, 0, h, frame->data, frame->linesize);
    frame->pts = int64_t(i);
    HVDB_RETURN_IF_ERROR(send(frame));
  }
  HVDB_RETURN_IF_ERROR(send(nullptr));
  if ((err = Av().av_write_trailer(fmt)) < 0) return Status::Internal("photo video: " + AvError(err));
  Av().avio_flush(fmt->pb);
  return std::move(file.bytes);
}

class AvPhotoVideoCodec : public PhotoVideoCodec {
 public:
  Result<EncodedPhotoVideo> Encode(const std::vector<std::string_view>& images,
                                   double min_psnr_db) const override {
    if (images.empty()) return Status::InvalidArgument("photo video: no pictures to code");
    HVDB_RETURN_IF_ERROR(Ready());
    std::vector<cv::Mat> originals, padded;
    for (size_t i = 0; i < images.size(); ++i) {
      auto decoded = formats::DecodeImage(images[i], "photo video: picture " + std::to_string(i),
                                          formats::ImageMode::kColour);
      if (!decoded.ok()) return decoded.status();
      cv::Mat bgr = *decoded;
      if (!originals.empty() && bgr.size() != originals[0].size()) {
        return Status::InvalidArgument("photo video: picture " + std::to_string(i) + " is " +
                                       std::to_string(bgr.cols) + "x" + std::to_string(bgr.rows) +
                                       ", the first " + std::to_string(originals[0].cols) + "x" +
                                       std::to_string(originals[0].rows) + "; a run has one size");
      }
      cv::Mat pad;
      cv::copyMakeBorder(bgr, pad, 0, Padded(bgr.rows) - bgr.rows, 0, Padded(bgr.cols) - bgr.cols,
                         cv::BORDER_REPLICATE);
      originals.push_back(std::move(bgr));
      padded.push_back(std::move(pad));
    }
    const int w = originals[0].cols, h = originals[0].rows;
    // The highest CRF (fewest bytes) whose every picture meets the bound: from kStartCrf,
    // down in steps sized by the shortfall (~0.25 dB per CRF step here). Colour that 4:2:0
    // cannot keep (the chroma misses while the luma holds, or still misses at a low CRF) is
    // coded 4:4:4 instead, from kStartCrf again.
    int crf = kStartCrf;
    bool full_chroma = false;
    for (int attempt = 0; attempt < 16; ++attempt) {
      EncodedPhotoVideo out;
      out.width = uint32_t(w);
      out.height = uint32_t(h);
      HVDB_ASSIGN_OR_RETURN(out.video, EncodeAt(padded, crf, full_chroma, &out.codec));
      IvfDecoder check;
      HVDB_RETURN_IF_ERROR(check.Open(out.video, w, h, "photo video (just coded)"));
      cv::Mat pic;
      double worst_y = 100, worst_chroma = 100;
      for (size_t i = 0; i < originals.size(); ++i) {
        HVDB_ASSIGN_OR_RETURN(bool more, check.Next(&pic));
        if (!more) break;
        const Psnr3 p = ChannelPsnr(originals[i], pic);
        out.psnr.push_back(p.min());
        worst_y = std::min(worst_y, p.y);
        worst_chroma = std::min({worst_chroma, p.cb, p.cr});
      }
      if (out.psnr.size() != originals.size()) {
        return Status::Internal("photo video: " + std::to_string(out.psnr.size()) + " of " +
                                std::to_string(originals.size()) + " pictures came back");
      }
      const double worst = std::min(worst_y, worst_chroma);
      if (worst >= min_psnr_db) return out;
      if (!full_chroma && worst_chroma < min_psnr_db && (worst_y >= min_psnr_db || crf <= 20)) {
        full_chroma = true;
        crf = kStartCrf;
        continue;
      }
      if (crf == 0) break;
      crf = std::max(0, crf - std::clamp(int(std::ceil((min_psnr_db - worst) * 4)) + 2, 3, 20));
    }
    return Status::Internal("photo video: the pictures do not reach " +
                            std::to_string(min_psnr_db) + " dB PSNR in Y, Cb and Cr even at CRF 0");
  }

  Result<std::string> Decode(std::string_view video, uint32_t index, uint32_t width,
                             uint32_t height, const std::string& what) const override {
    HVDB_RETURN_IF_ERROR(Ready());
    if (width == 0 || height == 0) return Status::Corruption(what + ": a picture of no pixels");
    const int w = int(width), h = int(height);
    HVDB_ASSIGN_OR_RETURN(std::unique_ptr<IvfDecoder> d, cache_.Take(video, index, w, h, what));
    cv::Mat pic;
    while (d->next() <= index) {
      HVDB_ASSIGN_OR_RETURN(bool more, d->Next(&pic));
      if (!more) {
        return Status::Corruption(what + ": picture " + std::to_string(index) + " is missing (" +
                                  std::to_string(d->next()) + " pictures)");
      }
    }
    // Fast zlib (the default): the caller decodes it at once.
    auto encoded = formats::EncodePngImage(pic);
    if (!encoded.ok()) {
      return Status::Internal(what + ": cannot write picture " + std::to_string(index) + " as PNG (" +
                              encoded.status().message() + ")");
    }
    std::string png = std::move(*encoded);
    cache_.Give(std::move(d), w, h);
    return png;
  }

 private:
  // FFmpeg loaded (formats/libav.h), and quiet: SVT-AV1 prints its configuration to stderr
  // for every video unless told (SVT_LOG) not to.
  static Status Ready() {
    HVDB_RETURN_IF_ERROR(formats::LoadLibAv());
    static std::once_flag once;
    std::call_once(once, [] {
      setenv("SVT_LOG", "1", 0);
      Av().av_log_set_level(AV_LOG_ERROR);
    });
    return Status::OK();
  }
  mutable DecoderCache cache_;
};

}  // namespace

const PhotoVideoCodec& PhotoVideo() {
  static const AvPhotoVideoCodec codec;
  return codec;
}

void InstallPhotoVideoCodec() { SetPhotoVideoCodec(&PhotoVideo()); }

}  // namespace hvdb::media
