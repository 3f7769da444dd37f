// PNG and JPEG through libpng and libjpeg-turbo directly, not OpenCV's imgcodecs: imgcodecs
// brings about 120 more shared libraries (GDAL and the formats it reads) into every process
// that links it, and the dynamic loader's work on them was half of an `hvdb` command's start
// (bench/README.md, "The editor at the kernels' speed").
#include <csetjmp>
#include <cstddef>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t without including them
#include <cstring>
#include <string>
#include <vector>

#include <jpeglib.h>
#include <jerror.h>
#include <png.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "formats/image_io.h"

namespace hvdb::formats {

namespace {

bool IsPng(std::string_view b) {
  return b.size() >= 8 && std::memcmp(b.data(), "\x89PNG\r\n\x1a\n", 8) == 0;
}
bool IsJpeg(std::string_view b) {
  return b.size() >= 3 && static_cast<uint8_t>(b[0]) == 0xFF &&
         static_cast<uint8_t>(b[1]) == 0xD8 && static_cast<uint8_t>(b[2]) == 0xFF;
}

Status TooLarge(const std::string& what, uint32_t w, uint32_t h) {
  return Status::InvalidArgument(what + ": " + std::to_string(w) + "x" + std::to_string(h) +
                                 " pixels is over the limit of 16384 a side");
}

struct MemorySource;
bool ReadPng16(MemorySource* src, cv::Mat* out, std::vector<png_bytep>* rows, std::string* msg);
Result<Srgb8Image> DecodePng16To8(std::string_view bytes, const std::string& what);

bool Is16BitPng(std::string_view b) {  // IHDR's bit depth is byte 24
  return IsPng(b) && b.size() > 24 && static_cast<uint8_t>(b[24]) == 16;
}

// libpng's simplified API: any colour type and depth to 8-bit grey, RGB or RGBA. (16-bit
// files go by DecodePng16To8: the simplified API takes their samples for linear light.)
Result<Srgb8Image> DecodePng(std::string_view bytes, const std::string& what) {
  if (Is16BitPng(bytes)) return DecodePng16To8(bytes, what);
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_memory(&img, bytes.data(), bytes.size())) {
    return Status::InvalidArgument(what + ": not a readable PNG (" + img.message + ")");
  }
  if (img.width > 16384 || img.height > 16384) {
    png_image_free(&img);
    return TooLarge(what, img.width, img.height);
  }
  const bool alpha = img.format & PNG_FORMAT_FLAG_ALPHA;
  const bool colour = img.format & PNG_FORMAT_FLAG_COLOR;
  Srgb8Image out;
  out.width = img.width;
  out.height = img.height;
  out.channels = alpha ? 4 : colour ? 3 : 1;
  img.format = alpha ? PNG_FORMAT_RGBA : colour ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
  out.data.resize(size_t{out.width} * out.height * out.channels);
  if (!png_image_finish_read(&img, nullptr, out.data.data(), 0, nullptr)) {
    png_image_free(&img);
    return Status::InvalidArgument(what + ": corrupt PNG (" + img.message + ")");
  }
  return out;
}

struct JpegError {
  jpeg_error_mgr mgr;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

void OnJpegError(j_common_ptr cinfo) {
  auto* err = reinterpret_cast<JpegError*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, err->message);
  std::longjmp(err->jump, 1);
}

// Warnings pass (a few stray bytes before a marker are common in camera files), but a file
// that ends early is an error: libjpeg would fill the rest of the picture with grey.
void OnJpegWarning(j_common_ptr cinfo, int level) {
  if (level == -1 && cinfo->err->msg_code == JWRN_JPEG_EOF) OnJpegError(cinfo);
}

// Grey stays grey; everything else comes out as RGB (CMYK is refused by libjpeg's converter).
Result<Srgb8Image> DecodeJpeg(std::string_view bytes, const std::string& what) {
  jpeg_decompress_struct cinfo;
  JpegError err;
  cinfo.err = jpeg_std_error(&err.mgr);
  err.mgr.error_exit = OnJpegError;
  err.mgr.emit_message = OnJpegWarning;
  Srgb8Image out;
  // Nothing with a destructor is created between setjmp and a longjmp to it.
  if (setjmp(err.jump)) {
    jpeg_destroy_decompress(&cinfo);
    return Status::InvalidArgument(what + ": corrupt JPEG (" + err.message + ")");
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, reinterpret_cast<const unsigned char*>(bytes.data()),
               static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(&cinfo, TRUE);
  const bool grey = cinfo.num_components == 1;
  cinfo.out_color_space = grey ? JCS_GRAYSCALE : JCS_RGB;
  if (cinfo.image_width > 16384 || cinfo.image_height > 16384) {
    const uint32_t w = cinfo.image_width, h = cinfo.image_height;
    jpeg_destroy_decompress(&cinfo);
    return TooLarge(what, w, h);
  }
  jpeg_start_decompress(&cinfo);
  out.width = cinfo.output_width;
  out.height = cinfo.output_height;
  out.channels = static_cast<uint32_t>(cinfo.output_components);
  out.data.resize(size_t{out.width} * out.height * out.channels);
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = out.data.data() + size_t{cinfo.output_scanline} * out.width * out.channels;
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  return out;
}

void AppendToString(png_structp png, png_bytep data, size_t n) {
  static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<const char*>(data), n);
}

void FlushNothing(png_structp) {}

[[noreturn]] void OnPngError(png_structp png, png_const_charp message) {
  auto* msg = static_cast<std::string*>(png_get_error_ptr(png));
  *msg = message;
  png_longjmp(png, 1);
}

void QuietPngWarning(png_structp, png_const_charp) {}

struct MemorySource {
  const uint8_t* data;
  size_t size, at;
};

void ReadFromMemory(png_structp png, png_bytep out, size_t n) {
  auto* src = static_cast<MemorySource*>(png_get_io_ptr(png));
  if (n > src->size - src->at) png_error(png, "unexpected end of file");
  std::memcpy(out, src->data + src->at, n);
  src->at += n;
}

// A 16-bit PNG with its samples as stored (the simplified API would apply a gamma to them):
// billboards keep their displacement maps so. Everything the longjmp may skip lives in the
// caller; out is BGR(A) ordered, as OpenCV's.
bool ReadPng16(MemorySource* src, cv::Mat* out, std::vector<png_bytep>* rows, std::string* msg) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, msg, OnPngError,
                                           QuietPngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_set_read_fn(png, src, ReadFromMemory);
  png_read_info(png, info);
  const png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
  if (w > 16384 || h > 16384) png_error(png, "image too large");
  png_set_swap(png);  // the file's big-endian samples as the machine's
  if (png_get_color_type(png, info) & PNG_COLOR_MASK_COLOR) png_set_bgr(png);
  png_read_update_info(png, info);
  const int channels = png_get_channels(png, info);
  out->create(static_cast<int>(h), static_cast<int>(w), CV_16UC(channels));
  rows->resize(h);
  for (png_uint_32 y = 0; y < h; ++y) (*rows)[y] = out->ptr(static_cast<int>(y));
  png_read_image(png, rows->data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

// A 16-bit PNG's high bytes, as OpenCV's 8-bit decode gives them; grey with alpha as RGBA.
Result<Srgb8Image> DecodePng16To8(std::string_view bytes, const std::string& what) {
  MemorySource src{reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), 0};
  cv::Mat m;
  std::vector<png_bytep> rows;
  std::string msg;
  if (!ReadPng16(&src, &m, &rows, &msg)) {
    return Status::InvalidArgument(what + ": corrupt PNG (" + msg + ")");
  }
  const int in = m.channels();
  Srgb8Image out;
  out.width = static_cast<uint32_t>(m.cols);
  out.height = static_cast<uint32_t>(m.rows);
  out.channels = in == 1 ? 1 : in == 3 ? 3 : 4;
  out.data.resize(size_t{out.width} * out.height * out.channels);
  uint8_t* o = out.data.data();
  for (int y = 0; y < m.rows; ++y) {
    const uint16_t* r = m.ptr<uint16_t>(y);
    for (int x = 0; x < m.cols; ++x, r += in, o += out.channels) {
      if (in == 1) {
        o[0] = static_cast<uint8_t>(r[0] >> 8);
      } else if (in == 2) {
        o[0] = o[1] = o[2] = static_cast<uint8_t>(r[0] >> 8);
        o[3] = static_cast<uint8_t>(r[1] >> 8);
      } else {  // BGR(A) to RGB(A)
        o[0] = static_cast<uint8_t>(r[2] >> 8);
        o[1] = static_cast<uint8_t>(r[1] >> 8);
        o[2] = static_cast<uint8_t>(r[0] >> 8);
        if (in == 4) o[3] = static_cast<uint8_t>(r[3] >> 8);
      }
    }
  }
  return out;
}

}  // namespace

Result<Srgb8Image> DecodePngOrJpeg(std::string_view bytes, const std::string& what) {
  if (IsPng(bytes)) return DecodePng(bytes, what);
  if (IsJpeg(bytes)) return DecodeJpeg(bytes, what);
  return Status::InvalidArgument(what + ": not a PNG or JPEG file (" +
                                 std::to_string(bytes.size()) + " bytes)");
}

Result<std::string> EncodePngBytes(const Srgb8Image& s) {
  if (s.width == 0 || s.height == 0 || s.data.size() != size_t{s.width} * s.height * s.channels ||
      (s.channels != 1 && s.channels != 3 && s.channels != 4)) {
    return Status::InvalidArgument("image: size and data do not agree");
  }
  std::string out, message;
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &message, OnPngError,
                                            QuietPngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_write_struct(&png, &info);
    return Status::Internal("PNG encoding failed: out of memory");
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    return Status::Internal("PNG encoding failed: " + message);
  }
  png_set_write_fn(png, &out, AppendToString, FlushNothing);
  // As OpenCV wrote them: zlib level 1 with run-length matches, fast for rendered frames.
  png_set_compression_level(png, 1);
  png_set_compression_strategy(png, 3 /* Z_RLE */);
  png_set_IHDR(png, info, s.width, s.height, 8,
               s.channels == 4 ? PNG_COLOR_TYPE_RGBA
               : s.channels == 3 ? PNG_COLOR_TYPE_RGB
                                 : PNG_COLOR_TYPE_GRAY,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  const size_t stride = size_t{s.width} * s.channels;
  for (uint32_t y = 0; y < s.height; ++y) {
    png_write_row(png, s.data.data() + y * stride);
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

cv::Mat DecodeToMat(std::string_view bytes, bool colour) {
  if (!colour && Is16BitPng(bytes)) {
    MemorySource src{reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), 0};
    cv::Mat out;
    std::vector<png_bytep> rows;
    std::string msg;
    if (!ReadPng16(&src, &out, &rows, &msg)) return {};
    return out;
  }
  auto img = DecodePngOrJpeg(bytes, "image");
  if (!img.ok()) return {};
  const int ch = static_cast<int>(img->channels);
  cv::Mat m(static_cast<int>(img->height), static_cast<int>(img->width), CV_8UC(ch),
            img->data.data());
  cv::Mat out;
  if (colour) {
    cv::cvtColor(m, out, ch == 1 ? cv::COLOR_GRAY2BGR : ch == 3 ? cv::COLOR_RGB2BGR : cv::COLOR_RGBA2BGR);
  } else if (ch == 1) {
    out = m.clone();
  } else {
    cv::cvtColor(m, out, ch == 3 ? cv::COLOR_RGB2BGR : cv::COLOR_RGBA2BGRA);
  }
  return out;
}

}  // namespace hvdb::formats
