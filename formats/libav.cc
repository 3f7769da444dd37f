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
  // major version has another ABI. Each library opened, then its functions looked up.
  void* handle = nullptr;
  std::string soname;
  auto open = [&](const char* name, int major) {
    soname = Soname(name, major);
    return OpenLibrary(name, major, &handle);
  };
#define HVDB_LIBAV_LOAD(name) \
  HVDB_RETURN_IF_ERROR(SharedLibraryFunction(handle, soname, #name, &g_lib.name));
  HVDB_RETURN_IF_ERROR(open("avutil", LIBAVUTIL_VERSION_MAJOR));
  HVDB_LIBAVUTIL_FUNCTIONS(HVDB_LIBAV_LOAD)
  HVDB_RETURN_IF_ERROR(open("avcodec", LIBAVCODEC_VERSION_MAJOR));
  HVDB_LIBAVCODEC_FUNCTIONS(HVDB_LIBAV_LOAD)
  HVDB_RETURN_IF_ERROR(open("avformat", LIBAVFORMAT_VERSION_MAJOR));
  HVDB_LIBAVFORMAT_FUNCTIONS(HVDB_LIBAV_LOAD)
  HVDB_RETURN_IF_ERROR(open("swscale", LIBSWSCALE_VERSION_MAJOR));
  HVDB_LIBSWSCALE_FUNCTIONS(HVDB_LIBAV_LOAD)
#undef HVDB_LIBAV_LOAD
  return Status::OK();
}

}  // namespace

Status OpenLibrary(const char* name, int major, void** handle) {
  return OpenSharedLibrary(Soname(name, major), "video (FFmpeg)", handle);
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
