#include "formats/libav.h"

#include <cstdio>
#include <cstdlib>
#include <mutex>
#include <string>

#include "storage/shared_library.h"

namespace hvdb::formats {
namespace {

LibAv g_lib;
Status g_status;
bool g_loaded = false;

std::string Soname(const char* name, int major) {
  return "lib" + std::string(name) + ".so." + std::to_string(major);
}

Status LoadAll() {
  // By the sonames of the headers hvdb was built with (libavcodec.so.59 on Debian 12): another
  // major version has another ABI.
  void* util = nullptr;
  void* codec = nullptr;
  void* format = nullptr;
  void* scale = nullptr;
  HVDB_RETURN_IF_ERROR(OpenLibrary("avutil", LIBAVUTIL_VERSION_MAJOR, &util));
  HVDB_RETURN_IF_ERROR(OpenLibrary("avcodec", LIBAVCODEC_VERSION_MAJOR, &codec));
  HVDB_RETURN_IF_ERROR(OpenLibrary("avformat", LIBAVFORMAT_VERSION_MAJOR, &format));
  HVDB_RETURN_IF_ERROR(OpenLibrary("swscale", LIBSWSCALE_VERSION_MAJOR, &scale));
  const std::string util_so = Soname("avutil", LIBAVUTIL_VERSION_MAJOR);
  const std::string codec_so = Soname("avcodec", LIBAVCODEC_VERSION_MAJOR);
  const std::string format_so = Soname("avformat", LIBAVFORMAT_VERSION_MAJOR);
  const std::string scale_so = Soname("swscale", LIBSWSCALE_VERSION_MAJOR);
#define X_UTIL(name) \
  HVDB_RETURN_IF_ERROR(SharedLibraryFunction(util, util_so, #name, &g_lib.name));
#define X_CODEC(name) \
  HVDB_RETURN_IF_ERROR(SharedLibraryFunction(codec, codec_so, #name, &g_lib.name));
#define X_FORMAT(name) \
  HVDB_RETURN_IF_ERROR(SharedLibraryFunction(format, format_so, #name, &g_lib.name));
#define X_SCALE(name) \
  HVDB_RETURN_IF_ERROR(SharedLibraryFunction(scale, scale_so, #name, &g_lib.name));
  HVDB_LIBAVUTIL_FUNCTIONS(X_UTIL)
  HVDB_LIBAVCODEC_FUNCTIONS(X_CODEC)
  HVDB_LIBAVFORMAT_FUNCTIONS(X_FORMAT)
  HVDB_LIBSWSCALE_FUNCTIONS(X_SCALE)
#undef X_UTIL
#undef X_CODEC
#undef X_FORMAT
#undef X_SCALE
  return Status::OK();
}

}  // namespace

Status OpenLibrary(const char* name, int major, void** handle) {
  return OpenSharedLibrary(Soname(name, major), "lib" + std::string(name) + std::to_string(major),
                           "video (FFmpeg)", handle);
}

Status LoadLibAv() {
  static std::once_flag once;
  std::call_once(once, [] {
    g_status = LoadAll();
    g_loaded = g_status.ok();
  });
  return g_status;
}

const LibAv& Av() {
  if (!g_loaded) {
    std::fputs("hvdb: FFmpeg used before LoadLibAv() succeeded\n", stderr);
    std::abort();
  }
  return g_lib;
}

}  // namespace hvdb::formats
