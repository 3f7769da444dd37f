// Reads a video file as a player would (libavformat + libavcodec): its container, codec, frame
// rate, and every frame decoded, with its size and centre colour. For the video export tests
// (tests/render/video_test.cc, tests/client/render_cli_test.cc).
#ifndef HVDB_TESTS_RENDER_VIDEO_PROBE_H_
#define HVDB_TESTS_RENDER_VIDEO_PROBE_H_

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
}

#include <array>
#include <fstream>
#include <string>
#include <vector>

namespace hvdb::testing {

// What a player sees in a video file.
struct Probe {
  int frames = 0;
  int width = 0, height = 0;
  double fps = 0;
  std::string codec, container;
  std::vector<std::array<double, 3>> centre_rgb;  // each frame's centre pixel, RGB 0..255
  std::string error;
};

inline Probe DecodeFile(const std::string& path) {
  Probe p;
  AVFormatContext* fmt = nullptr;
  if (avformat_open_input(&fmt, path.c_str(), nullptr, nullptr) < 0) {
    p.error = "not a video file";
    return p;
  }
  avformat_find_stream_info(fmt, nullptr);
  p.container = fmt->iformat->name;
  const int si = av_find_best_stream(fmt, AVMEDIA_TYPE_VIDEO, -1, -1, nullptr, 0);
  if (si < 0) {
    p.error = "no video stream";
    avformat_close_input(&fmt);
    return p;
  }
  const AVStream* st = fmt->streams[si];
  const AVCodec* dec = avcodec_find_decoder(st->codecpar->codec_id);
  AVCodecContext* ctx = avcodec_alloc_context3(dec);
  avcodec_parameters_to_context(ctx, st->codecpar);
  avcodec_open2(ctx, dec, nullptr);
  p.codec = dec->name;
  p.fps = av_q2d(st->avg_frame_rate);
  AVPacket* pkt = av_packet_alloc();
  AVFrame* frame = av_frame_alloc();
  auto drain = [&] {
    while (avcodec_receive_frame(ctx, frame) == 0) {
      ++p.frames;
      p.width = frame->width;
      p.height = frame->height;
      // YUV 4:2:0 (BT.601, limited range, as swscale wrote it) at the centre, back to RGB.
      const int x = frame->width / 2, y = frame->height / 2;
      const double Y = frame->data[0][y * frame->linesize[0] + x] - 16.0;
      const double U = frame->data[1][(y / 2) * frame->linesize[1] + x / 2] - 128.0;
      const double V = frame->data[2][(y / 2) * frame->linesize[2] + x / 2] - 128.0;
      p.centre_rgb.push_back({1.164 * Y + 1.596 * V, 1.164 * Y - 0.392 * U - 0.813 * V,
                              1.164 * Y + 2.017 * U});
    }
  };
  while (av_read_frame(fmt, pkt) >= 0) {
    if (pkt->stream_index == si) {
      avcodec_send_packet(ctx, pkt);
      drain();
    }
    av_packet_unref(pkt);
  }
  avcodec_send_packet(ctx, nullptr);
  drain();
  av_frame_free(&frame);
  av_packet_free(&pkt);
  avcodec_free_context(&ctx);
  avformat_close_input(&fmt);
  return p;
}

// `bytes` written to DIR/probe.bin, then decoded.
inline Probe Decode(const std::string& bytes, const std::string& dir) {
  const std::string path = dir + "/probe.bin";
  std::ofstream(path, std::ios::binary) << bytes;
  return DecodeFile(path);
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_RENDER_VIDEO_PROBE_H_
