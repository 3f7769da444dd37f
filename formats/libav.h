// FFmpeg's libraries (libavformat, libavcodec, libavutil, libswscale), loaded on first use.
//
// Why not linked: those four bring ~110 more shared libraries (codecs, TLS, X11, VA-API), and
// the dynamic loader mapped and relocated all of them at every start of every hvdb binary,
// most of which never touch a video (`hvdb --help`, a query, a server that only serves points).
// Loaded with dlopen by the soname the headers were built against, they cost only the
// commands that decode or encode video, once per process.
//
//   HVDB_RETURN_IF_ERROR(LoadLibAv());  // where a video path begins: a clear error if FFmpeg is missing
//   Av().avcodec_open2(...);            // afterwards, the same functions under the same names
#pragma once

extern "C" {
#include <libavcodec/avcodec.h>
#include <libavformat/avformat.h>
#include <libavutil/imgutils.h>
#include <libavutil/log.h>
#include <libswscale/swscale.h>
}

#include "storage/status.h"

namespace hvdb::formats {

// Every FFmpeg function hvdb calls, with the library that defines it.
#define HVDB_LIBAVUTIL_FUNCTIONS(X)                                                               \
  X(av_d2q) X(av_dict_free) X(av_dict_set) X(av_dict_set_int) X(av_frame_alloc) X(av_frame_free) \
  X(av_frame_get_buffer) X(av_frame_make_writable) X(av_frame_unref) X(av_free) X(av_freep)       \
  X(av_log_default_callback) X(av_log_format_line) X(av_log_set_callback) X(av_log_set_level)     \
  X(av_malloc) X(av_strerror)
#define HVDB_LIBAVCODEC_FUNCTIONS(X)                                                             \
  X(av_packet_alloc) X(av_packet_free) X(av_packet_rescale_ts) X(av_packet_unref)                \
  X(avcodec_alloc_context3) X(avcodec_find_decoder) X(avcodec_find_decoder_by_name)              \
  X(avcodec_find_encoder_by_name) X(avcodec_free_context) X(avcodec_open2)                       \
  X(avcodec_parameters_from_context) X(avcodec_parameters_to_context) X(avcodec_receive_frame)   \
  X(avcodec_receive_packet) X(avcodec_send_frame) X(avcodec_send_packet)
#define HVDB_LIBAVFORMAT_FUNCTIONS(X)                                                            \
  X(av_find_best_stream) X(av_find_input_format) X(av_interleaved_write_frame) X(av_read_frame)  \
  X(av_write_frame) X(av_write_trailer) X(avformat_alloc_context)                                \
  X(avformat_alloc_output_context2) X(avformat_close_input) X(avformat_find_stream_info)         \
  X(avformat_free_context) X(avformat_new_stream) X(avformat_open_input)                         \
  X(avformat_write_header) X(avio_alloc_context) X(avio_context_free) X(avio_flush)
#define HVDB_LIBSWSCALE_FUNCTIONS(X) \
  X(sws_freeContext) X(sws_getCachedContext) X(sws_getContext) X(sws_scale)

struct LibAv {
#define HVDB_LIBAV_MEMBER(name) decltype(&::name) name = nullptr;
  HVDB_LIBAVUTIL_FUNCTIONS(HVDB_LIBAV_MEMBER)
  HVDB_LIBAVCODEC_FUNCTIONS(HVDB_LIBAV_MEMBER)
  HVDB_LIBAVFORMAT_FUNCTIONS(HVDB_LIBAV_MEMBER)
  HVDB_LIBSWSCALE_FUNCTIONS(HVDB_LIBAV_MEMBER)
#undef HVDB_LIBAV_MEMBER
};

// Loads the four libraries once per process (thread-safe); later calls return the first
// outcome. Unsupported, naming the library and the Debian package, when one is missing.
Status LoadLibAv();

// The functions; only after LoadLibAv() returned OK (aborts otherwise: a programming error).
const LibAv& Av();

// dlopen of lib<name>.so.<major>, or Unsupported naming it and its Debian package (libav.cc's
// step, apart for its test).
Status OpenLibrary(const char* name, int major, void** handle);

}  // namespace hvdb::formats
