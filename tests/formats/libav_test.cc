// FFmpeg loaded on first use (formats/libav.h): the functions resolve, work, and a library that
// is not there is named with its package. That the binaries do not link FFmpeg is LeanBinaries'.
#include "formats/libav.h"

#include <gtest/gtest.h>

namespace hvdb::formats {
namespace {

TEST(LibAvTest, LoadsOnceAndEveryFunctionResolves) {
  ASSERT_TRUE(LoadLibAv().ok()) << LoadLibAv().ToString();
  ASSERT_TRUE(LoadLibAv().ok());  // the second call returns the first outcome
  const LibAv& av = Av();
#define HVDB_EXPECT_RESOLVED(name) EXPECT_NE(av.name, nullptr) << #name;
  HVDB_LIBAVUTIL_FUNCTIONS(HVDB_EXPECT_RESOLVED)
  HVDB_LIBAVCODEC_FUNCTIONS(HVDB_EXPECT_RESOLVED)
  HVDB_LIBAVFORMAT_FUNCTIONS(HVDB_EXPECT_RESOLVED)
  HVDB_LIBSWSCALE_FUNCTIONS(HVDB_EXPECT_RESOLVED)
#undef HVDB_EXPECT_RESOLVED
  // They are FFmpeg's: an error code's text, a codec by name.
  char buf[AV_ERROR_MAX_STRING_SIZE] = {};
  ASSERT_EQ(av.av_strerror(AVERROR_EOF, buf, sizeof buf), 0);
  EXPECT_STREQ(buf, "End of file");
  const AVCodec* png = av.avcodec_find_decoder_by_name("png");
  ASSERT_NE(png, nullptr);
  EXPECT_EQ(png->id, AV_CODEC_ID_PNG);
}

TEST(LibAvTest, AMissingLibraryIsNamedWithItsPackage) {
  void* handle = reinterpret_cast<void*>(1);
  const Status st = OpenLibrary("avcodec", 9999, &handle);
  EXPECT_EQ(st.code(), StatusCode::kUnsupported);
  EXPECT_EQ(handle, nullptr);
  EXPECT_NE(st.message().find("libavcodec.so.9999"), std::string::npos) << st.ToString();
  EXPECT_NE(st.message().find("apt install libavcodec9999"), std::string::npos) << st.ToString();
}

}  // namespace
}  // namespace hvdb::formats
