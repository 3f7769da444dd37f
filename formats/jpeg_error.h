// libjpeg's error handling as hvdb reads JPEGs (formats/image_codec.cc, media/image.cc): an
// error longjmps back to the caller's setjmp with libjpeg's message, and a warning is an error
// too, since libjpeg only warns about corrupt data (a truncated file decodes with grey at the
// end). Trace messages are dropped.
#ifndef HVDB_FORMATS_JPEG_ERROR_H_
#define HVDB_FORMATS_JPEG_ERROR_H_

#include <csetjmp>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t without including them

#include <jerror.h>
#include <jpeglib.h>

namespace hvdb::formats {

struct JpegError {
  jpeg_error_mgr mgr;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

inline void OnJpegError(j_common_ptr cinfo) {
  auto* e = reinterpret_cast<JpegError*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, e->message);
  std::longjmp(e->jump, 1);
}

inline void OnJpegMessage(j_common_ptr cinfo, int level) {
  if (level < 0) OnJpegError(cinfo);
}

// Installs the handlers on `cinfo` (before jpeg_create_decompress); set err->jump after.
inline void UseJpegError(jpeg_decompress_struct* cinfo, JpegError* err) {
  cinfo->err = jpeg_std_error(&err->mgr);
  err->mgr.error_exit = OnJpegError;
  err->mgr.emit_message = OnJpegMessage;
  err->message[0] = 0;
}

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_JPEG_ERROR_H_
