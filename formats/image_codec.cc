#include "formats/image_codec.h"
#include "formats/jpeg_error.h"

#include <zlib.h>

#include <algorithm>
#include <csetjmp>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t without including them
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <vector>

#include <png.h>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::formats {

namespace {

constexpr uint32_t kMaxSide = 16384;
// deflate's best case: 258 bytes from a match coded in 2 bits, about 1032:1.
constexpr uint64_t kMaxInflation = 1032;

Status TooLarge(const std::string& what, uint32_t w, uint32_t h) {
  return Status::InvalidArgument(what + ": " + std::to_string(w) + "x" + std::to_string(h) +
                                 " pixels is over the limit of 16384 a side");
}

// libpng's error callback longjmps to the reader's setjmp with the message kept here.
struct PngSource {
  const uint8_t* data;
  size_t size, at;
  std::string message;
};

[[noreturn]] void OnPngError(png_structp png, png_const_charp message) {
  *static_cast<std::string*>(png_get_error_ptr(png)) = message;
  png_longjmp(png, 1);
}

void QuietPngWarning(png_structp, png_const_charp) {}

void ReadFromMemory(png_structp png, png_bytep out, size_t n) {
  auto* src = static_cast<PngSource*>(png_get_io_ptr(png));
  if (n > src->size - src->at) png_error(png, "unexpected end of file");
  std::memcpy(out, src->data + src->at, n);
  src->at += n;
}

// libpng's transforms give imread's pictures: palettes and low-depth grey expanded, BGR order,
// 16-bit samples the machine's (kAsStored) or their high byte. kGrey reads colour files as BGR
// and converts after (as DecodeImage's caller below), so that every mode shares this reader.
// Everything a longjmp may skip (the Mat, the row pointers) lives in the caller.
bool ReadPng(PngSource* src, ImageMode mode, cv::Mat* out, std::vector<png_bytep>* rows) {
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &src->message, OnPngError,
                                           QuietPngWarning);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (png == nullptr || info == nullptr) {
    png_destroy_read_struct(&png, &info, nullptr);
    src->message = "out of memory";
    return false;
  }
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  png_set_read_fn(png, src, ReadFromMemory);
  png_read_info(png, info);
  const png_uint_32 w = png_get_image_width(png, info), h = png_get_image_height(png, info);
  // The filtered rows must fit what the file's compressed bytes can inflate to: a small file
  // declaring a huge picture is refused before the picture is allocated.
  const uint64_t raw = uint64_t{h} * (1 + png_get_rowbytes(png, info));
  if (w > kMaxSide || h > kMaxSide || raw > kMaxInflation * src->size + 4096) {
    src->message = std::to_string(w) + "x" + std::to_string(h) + " pixels is " +
                   (w > kMaxSide || h > kMaxSide ? "over the limit of 16384 a side"
                                                 : "more than the file's bytes can hold");
    png_destroy_read_struct(&png, &info, nullptr);
    return false;
  }
  const int type = png_get_color_type(png, info);
  const int depth = png_get_bit_depth(png, info);
  const bool trns = png_get_valid(png, info, PNG_INFO_tRNS) != 0;
  if (type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(png);
  if (type == PNG_COLOR_TYPE_GRAY && depth < 8) png_set_expand_gray_1_2_4_to_8(png);
  bool alpha = (type & PNG_COLOR_MASK_ALPHA) != 0;
  if (mode == ImageMode::kAsStored) {
    // As imread: transparency chunks become alpha in colour and palette files only (a grey
    // file's is dropped, so that grey maps stay one channel).
    if (trns && (type & PNG_COLOR_MASK_COLOR)) {
      png_set_tRNS_to_alpha(png);
      alpha = true;
    } else if (trns && !alpha) {
      png_set_strip_alpha(png);
    }
    if (depth == 16) png_set_swap(png);  // the file's big-endian samples as the machine's
  } else {
    if (alpha || trns) png_set_strip_alpha(png);  // palette_to_rgb expands tRNS too
    alpha = false;
    if (depth == 16) png_set_strip_16(png);
  }
  const bool colour = (type & PNG_COLOR_MASK_COLOR) != 0;
  if (!colour && (alpha || mode == ImageMode::kColour)) png_set_gray_to_rgb(png);
  png_set_bgr(png);
  png_set_interlace_handling(png);
  png_read_update_info(png, info);
  const int channels = png_get_channels(png, info);
  const int out_depth = png_get_bit_depth(png, info) == 16 ? CV_16U : CV_8U;
  out->create(static_cast<int>(h), static_cast<int>(w), CV_MAKETYPE(out_depth, channels));
  rows->resize(h);
  for (png_uint_32 y = 0; y < h; ++y) (*rows)[y] = out->ptr(static_cast<int>(y));
  png_read_image(png, rows->data());
  png_read_end(png, nullptr);
  png_destroy_read_struct(&png, &info, nullptr);
  return true;
}

Result<cv::Mat> DecodePng(std::string_view bytes, const std::string& what, ImageMode mode) {
  PngSource src{reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size(), 0, {}};
  cv::Mat out;
  std::vector<png_bytep> rows;
  if (!ReadPng(&src, mode, &out, &rows)) {
    return Status::InvalidArgument(what + ": not a readable PNG (" + src.message + ")");
  }
  if (mode == ImageMode::kGrey && out.channels() == 3) cv::cvtColor(out, out, cv::COLOR_BGR2GRAY);
  return out;
}

// libjpeg's warnings pass (stray bytes before a marker, an odd ICC chunk: common in camera
// files, and OpenCV reads them), except a file that ends early: libjpeg would fill the rest
// of the picture with grey.
void OnJpegWarning(j_common_ptr cinfo, int level) {
  if (level == -1 && cinfo->err->msg_code == JWRN_JPEG_EOF) OnJpegError(cinfo);
}

// The EXIF orientation (1..8) in an APP1 marker; 1 (as stored) when absent or unreadable.
int ExifOrientation(const jpeg_decompress_struct& cinfo) {
  for (jpeg_saved_marker_ptr m = cinfo.marker_list; m != nullptr; m = m->next) {
    if (m->marker != JPEG_APP0 + 1 || m->data_length < 14 ||
        std::memcmp(m->data, "Exif\0\0", 6) != 0) {
      continue;
    }
    const uint8_t* t = m->data + 6;  // the TIFF header
    const size_t n = m->data_length - 6;
    const bool le = t[0] == 'I';
    auto u16 = [&](size_t at) -> uint32_t {
      return at + 2 > n ? 0 : le ? t[at] | t[at + 1] << 8 : t[at] << 8 | t[at + 1];
    };
    auto u32 = [&](size_t at) -> uint32_t {
      return at + 4 > n ? 0 : le ? u16(at) | u16(at + 2) << 16 : u16(at) << 16 | u16(at + 2);
    };
    const size_t ifd = u32(4);
    const uint32_t entries = u16(ifd);
    for (uint32_t e = 0; e < entries && ifd + 2 + 12 * (e + 1) <= n; ++e) {
      const size_t at = ifd + 2 + 12 * e;
      if (u16(at) == 0x0112) {  // Orientation, a SHORT in the value field
        const uint32_t v = u16(at + 8);
        return v >= 1 && v <= 8 ? static_cast<int>(v) : 1;
      }
    }
  }
  return 1;
}

// The picture turned upright as its EXIF orientation says, as imread and imdecode do.
void Orient(int orientation, cv::Mat* m) {
  switch (orientation) {  // OpenCV's ExifTransform, case for case
    case 2: cv::flip(*m, *m, 1); break;
    case 3: cv::flip(*m, *m, -1); break;
    case 4: cv::flip(*m, *m, 0); break;
    case 5: cv::transpose(*m, *m); break;
    case 6: cv::transpose(*m, *m); cv::flip(*m, *m, 1); break;
    case 7: cv::transpose(*m, *m); cv::flip(*m, *m, -1); break;
    case 8: cv::transpose(*m, *m); cv::flip(*m, *m, 0); break;
    default: break;
  }
}

// CMYK (Adobe's files store it inverted) to BGR, as OpenCV's decoder converts it.
cv::Mat CmykToBgr(const cv::Mat& cmyk, bool inverted) {
  cv::Mat bgr(cmyk.rows, cmyk.cols, CV_8UC3);
  for (int y = 0; y < cmyk.rows; ++y) {
    const uint8_t* in = cmyk.ptr<uint8_t>(y);
    uint8_t* out = bgr.ptr<uint8_t>(y);
    for (int x = 0; x < cmyk.cols; ++x, in += 4, out += 3) {
      const int c = inverted ? in[0] : 255 - in[0], m = inverted ? in[1] : 255 - in[1];
      const int yy = inverted ? in[2] : 255 - in[2], k = inverted ? in[3] : 255 - in[3];
      out[0] = static_cast<uint8_t>(yy * k / 255);
      out[1] = static_cast<uint8_t>(m * k / 255);
      out[2] = static_cast<uint8_t>(c * k / 255);
    }
  }
  return bgr;
}

Result<cv::Mat> DecodeJpeg(std::string_view bytes, const std::string& what, ImageMode mode) {
  jpeg_decompress_struct cinfo;
  JpegError err;
  UseJpegError(&cinfo, &err);
  err.mgr.emit_message = OnJpegWarning;
  cv::Mat out;
  if (setjmp(err.jump)) {
    jpeg_destroy_decompress(&cinfo);
    return Status::InvalidArgument(what + ": corrupt JPEG (" + err.message + ")");
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, reinterpret_cast<const unsigned char*>(bytes.data()),
               static_cast<unsigned long>(bytes.size()));
  // EXIF orientation is applied for colour and grey, not as stored (imread's IMREAD_UNCHANGED).
  if (mode != ImageMode::kAsStored) jpeg_save_markers(&cinfo, JPEG_APP0 + 1, 0xFFFF);
  jpeg_read_header(&cinfo, TRUE);
  if (cinfo.image_width > kMaxSide || cinfo.image_height > kMaxSide) {
    const auto w = cinfo.image_width, h = cinfo.image_height;
    jpeg_destroy_decompress(&cinfo);
    return TooLarge(what, w, h);
  }
  // Read now: the saved markers live in the image's pool, which jpeg_finish_decompress frees.
  const int orientation = mode == ImageMode::kAsStored ? 1 : ExifOrientation(cinfo);
  const bool cmyk = cinfo.jpeg_color_space == JCS_CMYK || cinfo.jpeg_color_space == JCS_YCCK;
  const bool colour = mode == ImageMode::kColour ||
                      (mode == ImageMode::kAsStored && cinfo.num_components != 1);
  cinfo.out_color_space = cmyk ? JCS_CMYK : colour ? JCS_EXT_BGR : JCS_GRAYSCALE;
  jpeg_start_decompress(&cinfo);
  out.create(static_cast<int>(cinfo.output_height), static_cast<int>(cinfo.output_width),
             CV_8UC(cinfo.output_components));
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = out.ptr<uint8_t>(static_cast<int>(cinfo.output_scanline));
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  const bool inverted = cinfo.saw_Adobe_marker;
  jpeg_destroy_decompress(&cinfo);
  if (cmyk) {
    out = CmykToBgr(out, inverted);
    if (!colour) cv::cvtColor(out, out, cv::COLOR_BGR2GRAY);
  }
  Orient(orientation, &out);
  return out;
}

// Binary PGM (P5) and PPM (P6) with maxval <= 255: a dozen lines, and neither libpng nor
// libjpeg reads them.
Result<cv::Mat> DecodePnm(std::string_view bytes, const std::string& what, ImageMode mode) {
  std::istringstream in{std::string(bytes.substr(0, std::min<size_t>(bytes.size(), 512)))};
  std::string magic;
  in >> magic;
  int w = 0, h = 0, maxval = 0;
  auto field = [&](int* v) {
    in >> std::ws;
    while (in.peek() == '#') {
      std::string comment;
      std::getline(in, comment);
      in >> std::ws;
    }
    in >> *v;
  };
  field(&w);
  field(&h);
  field(&maxval);
  if (!in || w <= 0 || h <= 0 || maxval <= 0 || maxval > 255)
    return Status::InvalidArgument(what + ": not an 8-bit binary PGM/PPM (P5/P6, maxval <= 255)");
  if (static_cast<uint32_t>(w) > kMaxSide || static_cast<uint32_t>(h) > kMaxSide)
    return TooLarge(what, static_cast<uint32_t>(w), static_cast<uint32_t>(h));
  in.get();  // the single whitespace before the samples
  const int channels = magic == "P6" ? 3 : 1;
  const size_t need = static_cast<size_t>(w) * h * channels;
  const auto at = static_cast<size_t>(in.tellg());
  if (at > bytes.size() || bytes.size() - at < need)
    return Status::InvalidArgument(what + ": truncated PGM/PPM (" +
                                   std::to_string(bytes.size() - std::min(at, bytes.size())) +
                                   " of " + std::to_string(need) + " sample bytes)");
  cv::Mat raw(h, w, channels == 3 ? CV_8UC3 : CV_8UC1);
  std::memcpy(raw.data, bytes.data() + at, need);
  if (maxval != 255) raw.convertTo(raw, CV_8U, 255.0 / maxval);
  const bool colour = mode == ImageMode::kColour || (mode == ImageMode::kAsStored && channels == 3);
  cv::Mat out;
  if (channels == 3) {
    cv::cvtColor(raw, out, colour ? cv::COLOR_RGB2BGR : cv::COLOR_RGB2GRAY);
  } else if (colour) {
    cv::cvtColor(raw, out, cv::COLOR_GRAY2BGR);
  } else {
    out = raw;
  }
  return out;
}

void AppendToString(png_structp png, png_bytep data, size_t n) {
  static_cast<std::string*>(png_get_io_ptr(png))->append(reinterpret_cast<const char*>(data), n);
}

void FlushNothing(png_structp) {}

}  // namespace

Result<cv::Mat> ReadImageFile(const std::string& path, ImageMode mode) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return Status::NotFound(path + ": no such file");
  std::ifstream f(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (!f.good() && !f.eof()) return Status::IOError(path + ": cannot read");
  return DecodeImage(bytes, path, mode);
}

Result<cv::Mat> DecodeImage(std::string_view bytes, const std::string& what, ImageMode mode) {
  const auto b = [&](size_t i) { return i < bytes.size() ? static_cast<uint8_t>(bytes[i]) : 0; };
  if (bytes.size() >= 8 && std::memcmp(bytes.data(), "\x89PNG\r\n\x1a\n", 8) == 0)
    return DecodePng(bytes, what, mode);
  if (b(0) == 0xFF && b(1) == 0xD8 && b(2) == 0xFF) return DecodeJpeg(bytes, what, mode);
  if (b(0) == 'P' && (b(1) == '5' || b(1) == '6')) return DecodePnm(bytes, what, mode);
  return Status::InvalidArgument(what + ": not a PNG, JPEG or binary PGM/PPM image");
}

Result<std::string> EncodePngImage(const cv::Mat& m, bool rgb_order, int zlib_level) {
  const int channels = m.channels();
  if (m.empty() || m.dims != 2 || (m.depth() != CV_8U && m.depth() != CV_16U) ||
      (channels != 1 && channels != 3 && channels != 4) || zlib_level < 0 || zlib_level > 9) {
    return Status::InvalidArgument("PNG: an 8- or 16-bit picture of 1, 3 or 4 channels is needed");
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
  png_set_compression_level(png, zlib_level);
  png_set_compression_strategy(png, Z_RLE);
  png_set_filter(png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);  // one filter, as imencode
  png_set_IHDR(png, info, static_cast<png_uint_32>(m.cols), static_cast<png_uint_32>(m.rows),
               m.depth() == CV_16U ? 16 : 8,
               channels == 4   ? PNG_COLOR_TYPE_RGBA
               : channels == 3 ? PNG_COLOR_TYPE_RGB
                               : PNG_COLOR_TYPE_GRAY,
               PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  if (m.depth() == CV_16U) png_set_swap(png);  // the machine's samples as PNG's big-endian
  if (channels >= 3 && !rgb_order) png_set_bgr(png);
  for (int y = 0; y < m.rows; ++y) png_write_row(png, m.ptr(y));
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  return out;
}

}  // namespace hvdb::formats
