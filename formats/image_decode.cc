#include "formats/image_decode.h"
#include "formats/jpeg_error.h"

#include <csetjmp>
#include <cstdio>  // before jpeglib.h, which uses FILE and size_t without including them
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <vector>

#include <png.h>
#include <opencv2/imgproc.hpp>

namespace hvdb::formats {

namespace {

constexpr uint32_t kMaxSide = 16384;

Status TooLarge(const std::string& path, uint32_t w, uint32_t h) {
  return Status::InvalidArgument(path + ": " + std::to_string(w) + "x" + std::to_string(h) +
                                 " pixels is over the limit of 16384 a side");
}

// libpng's simplified API to 8-bit grey or RGB (alpha composed over black: stereo pairs have
// none). 16-bit samples: the API takes them for linear light and would apply a gamma, so such
// files are scaled by hand (the high byte).
Result<cv::Mat> DecodePng(const std::string& bytes, const std::string& path, bool colour) {
  png_image img;
  std::memset(&img, 0, sizeof img);
  img.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_memory(&img, bytes.data(), bytes.size()))
    return Status::InvalidArgument(path + ": not a readable PNG (" + img.message + ")");
  if (img.width > kMaxSide || img.height > kMaxSide) {
    png_image_free(&img);
    return TooLarge(path, img.width, img.height);
  }
  const bool wide = (img.format & PNG_FORMAT_FLAG_LINEAR) != 0;
  // Decoded as stored (grey or colour); a change between the two is cvtColor's below, as
  // imread does it (libpng's own weighs linear light).
  const bool stored_colour = (img.format & PNG_FORMAT_FLAG_COLOR) != 0;
  const int channels = stored_colour ? 3 : 1;
  img.format = stored_colour ? PNG_FORMAT_BGR : PNG_FORMAT_GRAY;
  if (wide) img.format |= PNG_FORMAT_FLAG_LINEAR;
  cv::Mat out(static_cast<int>(img.height), static_cast<int>(img.width),
              wide ? CV_16UC(channels) : CV_8UC(channels));
  png_color black{0, 0, 0};
  if (!png_image_finish_read(&img, &black, out.data, 0, nullptr)) {
    png_image_free(&img);
    return Status::InvalidArgument(path + ": corrupt PNG (" + img.message + ")");
  }
  if (wide) out.convertTo(out, CV_8U, 1.0 / 257);
  if (stored_colour != colour) cv::cvtColor(out, out, colour ? cv::COLOR_GRAY2BGR : cv::COLOR_BGR2GRAY);
  return out;
}

Result<cv::Mat> DecodeJpeg(const std::string& bytes, const std::string& path, bool colour) {
  jpeg_decompress_struct cinfo;
  JpegError err;
  UseJpegError(&cinfo, &err);
  cv::Mat out;
  if (setjmp(err.jump)) {
    jpeg_destroy_decompress(&cinfo);
    return Status::InvalidArgument(path + ": corrupt JPEG (" + err.message + ")");
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, reinterpret_cast<const unsigned char*>(bytes.data()),
               static_cast<unsigned long>(bytes.size()));
  jpeg_read_header(&cinfo, TRUE);
  if (cinfo.image_width > kMaxSide || cinfo.image_height > kMaxSide) {
    const auto w = cinfo.image_width, h = cinfo.image_height;
    jpeg_destroy_decompress(&cinfo);
    return TooLarge(path, w, h);
  }
  cinfo.out_color_space = colour ? JCS_EXT_BGR : JCS_GRAYSCALE;
  jpeg_start_decompress(&cinfo);
  out.create(static_cast<int>(cinfo.output_height), static_cast<int>(cinfo.output_width),
             colour ? CV_8UC3 : CV_8UC1);
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = out.ptr<uint8_t>(static_cast<int>(cinfo.output_scanline));
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  return out;
}

// Binary PGM (P5) and PPM (P6) with maxval <= 255.
Result<cv::Mat> DecodePnm(const std::string& bytes, const std::string& path, bool colour) {
  std::istringstream in(bytes);
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
    return Status::InvalidArgument(path + ": not an 8-bit binary PGM/PPM (P5/P6, maxval <= 255)");
  if (static_cast<uint32_t>(w) > kMaxSide || static_cast<uint32_t>(h) > kMaxSide)
    return TooLarge(path, static_cast<uint32_t>(w), static_cast<uint32_t>(h));
  in.get();  // the single whitespace before the samples
  const int channels = magic == "P6" ? 3 : 1;
  const size_t need = static_cast<size_t>(w) * h * channels;
  const auto at = static_cast<size_t>(in.tellg());
  if (at > bytes.size() || bytes.size() - at < need)
    return Status::InvalidArgument(path + ": truncated PGM/PPM (" + std::to_string(bytes.size() - std::min(at, bytes.size())) +
                                   " of " + std::to_string(need) + " sample bytes)");
  cv::Mat raw(h, w, channels == 3 ? CV_8UC3 : CV_8UC1);
  std::memcpy(raw.data, bytes.data() + at, need);
  if (maxval != 255) raw.convertTo(raw, CV_8U, 255.0 / maxval);
  cv::Mat out;
  if (channels == 3) {
    cv::cvtColor(raw, out, colour ? cv::COLOR_RGB2BGR : cv::COLOR_RGB2GRAY);
  } else {
    out = colour ? cv::Mat() : raw;
    if (colour) cv::cvtColor(raw, out, cv::COLOR_GRAY2BGR);
  }
  return out;
}

}  // namespace

Result<cv::Mat> ReadImageFile(const std::string& path, bool colour) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) return Status::NotFound(path + ": no such file");
  std::ifstream f(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  if (!f.good() && !f.eof()) return Status::IOError(path + ": cannot read");
  return DecodeImage(bytes, path, colour);
}

Result<cv::Mat> DecodeImage(const std::string& bytes, const std::string& path, bool colour) {
  const auto b = [&](size_t i) { return i < bytes.size() ? static_cast<uint8_t>(bytes[i]) : 0; };
  if (bytes.size() >= 8 && std::memcmp(bytes.data(), "\x89PNG\r\n\x1a\n", 8) == 0)
    return DecodePng(bytes, path, colour);
  if (b(0) == 0xFF && b(1) == 0xD8 && b(2) == 0xFF) return DecodeJpeg(bytes, path, colour);
  if (b(0) == 'P' && (b(1) == '5' || b(1) == '6')) return DecodePnm(bytes, path, colour);
  return Status::InvalidArgument(path + ": not a PNG, JPEG or binary PGM/PPM image");
}

}  // namespace hvdb::formats
