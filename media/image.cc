// Image files as RGBA pictures, decoded under the import's bounds.
//
// Written against libpng and libjpeg directly rather than OpenCV's imdecode, which allocates
// the whole picture the header declares (a 629-byte JPEG saying 20000 x 20000 took 2.8 GB):
// here the declared size is checked against limits and against the bytes sent first, then rows
// are decoded one at a time and area-averaged into the (smaller) texel grid as they come, so
// that memory follows the output. JPEGs are also decoded at 1/2, 1/4 or 1/8 scale by libjpeg
// itself where the grid is that much smaller. Other still formats (BMP, TIFF, WebP, ...) go
// through libavcodec's bounded decoders (video.cc).
#include <csetjmp>
#include <cstdio>
#include <cstring>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <png.h>

#include "formats/jpeg_error.h"
#include "media/media.h"

namespace hvdb::media {
namespace {

// A source row's pixels land in at most two output columns (and its rows in at most two
// output rows) with the area of their overlap, as OpenCV's INTER_AREA weighs them; only two
// output rows of sums are held. No downscale: rows are copied.
class AreaSink {
 public:
  AreaSink(int src_w, int src_h, int dst_w, int dst_h, Picture* out)
      : sw_(src_w), sh_(src_h), out_(out) {
    out->width = dst_w;
    out->height = dst_h;
    out->rgba.assign(static_cast<size_t>(dst_w) * dst_h * 4, 0);
    copy_ = dst_w == src_w && dst_h == src_h;
    if (copy_) return;
    fx_ = static_cast<double>(dst_w) / src_w;
    fy_ = static_cast<double>(dst_h) / src_h;
    cols_.resize(static_cast<size_t>(src_w));
    for (int x = 0; x < src_w; ++x) cols_[static_cast<size_t>(x)] = Split(x, fx_, dst_w);
    acc_[0].assign(static_cast<size_t>(dst_w) * 4, 0.0);
    acc_[1].assign(static_cast<size_t>(dst_w) * 4, 0.0);
  }

  // The next source row, RGBA.
  void Row(const uint8_t* px) {
    if (copy_) {
      std::memcpy(out_->rgba.data() + static_cast<size_t>(y_) * sw_ * 4, px,
                  static_cast<size_t>(sw_) * 4);
      ++y_;
      return;
    }
    const Cell r = Split(y_, fy_, out_->height);
    while (cur_ < r.i) Flush();
    for (int k = 0; k < 2; ++k) {
      const double wy = k == 0 ? r.w0 : r.w1;
      if (wy <= 0) continue;
      double* a = acc_[k].data();
      for (int x = 0; x < sw_; ++x) {
        const Cell& c = cols_[static_cast<size_t>(x)];
        const uint8_t* s = px + 4 * x;
        double* d0 = a + 4 * c.i;
        const double w0 = wy * c.w0;
        for (int ch = 0; ch < 4; ++ch) d0[ch] += w0 * s[ch];
        if (c.w1 > 0) {
          const double w1 = wy * c.w1;
          for (int ch = 0; ch < 4; ++ch) d0[4 + ch] += w1 * s[ch];
        }
      }
    }
    ++y_;
  }

  void Finish() {
    if (copy_) return;
    while (cur_ < out_->height) Flush();
  }

 private:
  struct Cell {
    int i = 0;             // the first output cell
    double w0 = 0, w1 = 0;  // overlap with it and with the next (output units)
  };
  static Cell Split(int x, double f, int n) {
    const double a = x * f, b = (x + 1) * f;
    Cell c;
    c.i = std::min(static_cast<int>(a), n - 1);
    if (b > c.i + 1 && c.i + 1 < n) {
      c.w0 = c.i + 1 - a;
      c.w1 = b - (c.i + 1);
    } else {
      c.w0 = b - a;
    }
    return c;
  }
  void Flush() {
    uint8_t* o = out_->rgba.data() + static_cast<size_t>(cur_) * out_->width * 4;
    for (size_t k = 0; k < acc_[0].size(); ++k) {
      o[k] = static_cast<uint8_t>(std::clamp(std::lround(acc_[0][k]), 0L, 255L));
    }
    std::swap(acc_[0], acc_[1]);
    std::fill(acc_[1].begin(), acc_[1].end(), 0.0);
    ++cur_;
  }

  int sw_, sh_;
  Picture* out_;
  bool copy_ = true;
  double fx_ = 1, fy_ = 1;
  std::vector<Cell> cols_;
  std::vector<double> acc_[2];
  int y_ = 0, cur_ = 0;
};

// The output size: the longer side at most max_side (0: no limit), as before.
void OutputSize(int w, int h, uint32_t max_side, int* ow, int* oh) {
  *ow = w;
  *oh = h;
  const int side = std::max(w, h);
  if (max_side > 0 && side > static_cast<int>(max_side)) {
    const double f = static_cast<double>(max_side) / side;
    *ow = std::max(1, static_cast<int>(std::lround(w * f)));
    *oh = std::max(1, static_cast<int>(std::lround(h * f)));
  }
}

Status CheckDeclared(const std::string& what, uint64_t w, uint64_t h) {
  if (w == 0 || h == 0) return Status::InvalidArgument(what + " declares no pixels");
  if (w > kMaxPictureSide || h > kMaxPictureSide || w * h > kMaxPicturePixels) {
    return Status::LimitExceeded(what + " declares " + std::to_string(w) + "x" +
                                 std::to_string(h) + " pixels, over the limit of " +
                                 std::to_string(kMaxPictureSide) + " a side and " +
                                 std::to_string(kMaxPicturePixels >> 20) + " M pixels");
  }
  return Status::OK();
}

Status TooFewBytes(const std::string& what, uint64_t w, uint64_t h, size_t bytes) {
  return Status::InvalidArgument(what + " declares " + std::to_string(w) + "x" +
                                 std::to_string(h) + " pixels, more than its " +
                                 std::to_string(bytes) +
                                 " bytes can code (a truncated file, or a decompression bomb)");
}

uint32_t Be32(const uint8_t* p) {
  return uint32_t{p[0]} << 24 | uint32_t{p[1]} << 16 | uint32_t{p[2]} << 8 | p[3];
}

// Rows of a long decode check the deadline this often.
constexpr int kRowsPerCheck = 256;

// ---- PNG (libpng's progressive row API; errors longjmp back with their message).

struct PngSource {
  const uint8_t* data;
  size_t size, pos;
  char message[200];
};

void PngRead(png_structp png, png_bytep out, png_size_t n) {
  auto* s = static_cast<PngSource*>(png_get_io_ptr(png));
  if (n > s->size - s->pos) png_error(png, "the file ends early");
  std::memcpy(out, s->data + s->pos, n);
  s->pos += n;
}

void PngError(png_structp png, png_const_charp msg) {
  auto* s = static_cast<PngSource*>(png_get_error_ptr(png));
  std::snprintf(s->message, sizeof s->message, "%s", msg);
  png_longjmp(png, 1);
}

void PngWarning(png_structp, png_const_charp) {}

Result<Picture> DecodePng(std::string_view data, const std::string& what, uint32_t max_side,
                          const Budget& budget) {
  const auto* b = reinterpret_cast<const uint8_t*>(data.data());
  // IHDR is the first chunk; the sum of the IDAT chunks bounds what the pixels can be:
  // deflate expands at most 1032:1.
  if (data.size() < 33 || std::memcmp(b + 12, "IHDR", 4) != 0) {
    return Status::InvalidArgument(what + " could not be decoded: not a readable PNG (no IHDR chunk)");
  }
  const uint64_t w = Be32(b + 16), h = Be32(b + 20);
  HVDB_RETURN_IF_ERROR(CheckDeclared(what, w, h));
  const uint32_t depth = b[24], colour_type = b[25];
  const uint32_t samples = colour_type == 2 ? 3 : colour_type == 4 ? 2 : colour_type == 6 ? 4 : 1;
  uint64_t idat = 0;
  for (size_t at = 8; at + 12 <= data.size();) {
    const uint64_t len = Be32(b + at);
    if (std::memcmp(b + at + 4, "IDAT", 4) == 0) idat += len;
    at += 12 + std::min<uint64_t>(len, data.size());
  }
  const uint64_t raw = h * (1 + (w * samples * depth + 7) / 8);
  if (raw > 1032 * idat + 1024) return TooFewBytes(what, w, h, data.size());

  PngSource src{b, data.size(), 0, {}};
  png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &src, PngError, PngWarning);
  if (png == nullptr) return Status::Internal(what + ": libpng did not start");
  png_infop info = png_create_info_struct(png);
  Picture pic;
  std::vector<uint8_t> rows;  // one row, or the whole picture when interlaced
  int ow = 0, oh = 0;
  std::string failure;
  Status budget_error;
  if (setjmp(png_jmpbuf(png))) {
    png_destroy_read_struct(&png, &info, nullptr);
    return Status::InvalidArgument(what + " could not be decoded: not a readable PNG (" + src.message + ")");
  }
  png_set_read_fn(png, &src, PngRead);
  png_set_user_limits(png, kMaxPictureSide, kMaxPictureSide);
  png_set_chunk_malloc_max(png, 8u << 20);  // text and ICC chunks are bombs too
  png_read_info(png, info);
  png_set_expand(png);  // palette and low-bit grey to 8 bits, tRNS to alpha
  png_set_scale_16(png);
  png_set_gray_to_rgb(png);
  png_set_add_alpha(png, 0xff, PNG_FILLER_AFTER);
  const int passes = png_set_interlace_handling(png);
  png_read_update_info(png, info);
  if (png_get_rowbytes(png, info) != w * 4) png_error(png, "unexpected row layout");
  OutputSize(static_cast<int>(w), static_cast<int>(h), max_side, &ow, &oh);
  // Interlaced pictures come in passes over the whole picture: held whole.
  const uint64_t held = (passes > 1 ? h : 1) * w * 4 + uint64_t(ow) * oh * 4 + uint64_t(ow) * 64;
  budget_error = budget.Reserve(held, what);
  if (budget_error.ok()) {
    rows.resize(passes > 1 ? w * h * 4 : w * 4);
    AreaSink sink(static_cast<int>(w), static_cast<int>(h), ow, oh, &pic);
    if (passes > 1) {
      std::vector<png_bytep> ptrs(h);
      for (uint64_t y = 0; y < h; ++y) ptrs[y] = rows.data() + y * w * 4;
      png_read_image(png, ptrs.data());
      for (uint64_t y = 0; y < h; ++y) sink.Row(ptrs[y]);
    } else {
      for (uint64_t y = 0; y < h; ++y) {
        if (y % kRowsPerCheck == 0) {
          budget_error = budget.CheckTime(what);
          if (!budget_error.ok()) break;
        }
        png_read_row(png, rows.data(), nullptr);
        sink.Row(rows.data());
      }
    }
    if (budget_error.ok()) sink.Finish();
  }
  png_destroy_read_struct(&png, &info, nullptr);
  budget.Release(held - uint64_t(ow) * oh * 4);  // the picture itself stays reserved
  if (!budget_error.ok()) return budget_error;
  return pic;
}

// ---- JPEG (libjpeg-turbo: RGBA out, scaled while decoding).

Result<Picture> DecodeJpeg(std::string_view data, const std::string& what, uint32_t max_side,
                           const Budget& budget) {
  jpeg_decompress_struct cinfo;
  formats::JpegError err;
  formats::UseJpegError(&cinfo, &err);
  Picture pic;
  std::vector<uint8_t> row;
  Status early;  // a limit or the budget, found between libjpeg's calls
  uint64_t held = 0;
  if (setjmp(err.jump)) {
    // What was reserved goes back with the job's lease.
    jpeg_destroy_decompress(&cinfo);
    return Status::InvalidArgument(what + " could not be decoded: not a readable JPEG (" + err.message + ")");
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, reinterpret_cast<const unsigned char*>(data.data()),
               static_cast<unsigned long>(data.size()));
  jpeg_read_header(&cinfo, TRUE);
  const uint64_t w = cinfo.image_width, h = cinfo.image_height;
  early = CheckDeclared(what, w, h);
  if (early.ok() && !cinfo.progressive_mode && !cinfo.arith_code) {
    // Huffman-coded sequential scans spend at least 2 bits on each 8x8 block (a DC and an
    // end-of-block code) of the component at full resolution.
    if (((w + 7) / 8) * ((h + 7) / 8) / 4 > data.size()) early = TooFewBytes(what, w, h, data.size());
  }
  if (early.ok()) {
    // libjpeg scales by 1/2, 1/4, 1/8 while it decodes: the largest that still covers the grid.
    int ow = 0, oh = 0;
    OutputSize(static_cast<int>(w), static_cast<int>(h), max_side, &ow, &oh);
    unsigned denom = 1;
    while (denom < 8 && (w + 2 * denom - 1) / (2 * denom) >= static_cast<uint64_t>(ow) &&
           (h + 2 * denom - 1) / (2 * denom) >= static_cast<uint64_t>(oh)) {
      denom *= 2;
    }
    cinfo.scale_num = 1;
    cinfo.scale_denom = denom;
    cinfo.out_color_space = JCS_EXT_RGBA;
    // Progressive (and multi-scan) files keep every coefficient of the picture: 2 bytes each.
    uint64_t coefficients = 0;
    if (jpeg_has_multiple_scans(&cinfo)) {
      for (int c = 0; c < cinfo.num_components; ++c) {
        const jpeg_component_info& ci = cinfo.comp_info[c];
        coefficients += uint64_t{ci.width_in_blocks + 1} * (ci.height_in_blocks + 1) * 128;
      }
    }
    jpeg_calc_output_dimensions(&cinfo);
    const uint64_t sw = cinfo.output_width, sh = cinfo.output_height;
    OutputSize(static_cast<int>(sw), static_cast<int>(sh), max_side, &ow, &oh);
    held = coefficients + sw * 4 * 2 + uint64_t(ow) * oh * 4 + uint64_t(ow) * 64;
    early = budget.Reserve(held, what);
    if (!early.ok()) held = 0;
    if (early.ok()) {
      jpeg_start_decompress(&cinfo);
      row.resize(static_cast<size_t>(cinfo.output_width) * 4);
      AreaSink sink(static_cast<int>(cinfo.output_width), static_cast<int>(cinfo.output_height),
                    ow, oh, &pic);
      while (cinfo.output_scanline < cinfo.output_height) {
        if (cinfo.output_scanline % kRowsPerCheck == 0) {
          early = budget.CheckTime(what);
          if (!early.ok()) break;
        }
        JSAMPROW r = row.data();
        jpeg_read_scanlines(&cinfo, &r, 1);
        sink.Row(row.data());
      }
      if (early.ok()) {
        sink.Finish();
        jpeg_finish_decompress(&cinfo);
      }
    }
  }
  jpeg_destroy_decompress(&cinfo);
  budget.Release(held - std::min<uint64_t>(held, uint64_t(pic.width) * pic.height * 4));
  if (!early.ok()) return early;
  return pic;
}

// ---- Binary PGM (P5) and PPM (P6), maxval <= 255.

Result<Picture> DecodePnm(std::string_view data, const std::string& what, uint32_t max_side,
                          const Budget& budget) {
  size_t at = 2;
  auto field = [&](uint64_t* v) {
    for (;;) {
      while (at < data.size() && std::isspace(static_cast<unsigned char>(data[at]))) ++at;
      if (at < data.size() && data[at] == '#') {
        while (at < data.size() && data[at] != '\n') ++at;
        continue;
      }
      break;
    }
    *v = 0;
    size_t digits = 0;
    while (at < data.size() && std::isdigit(static_cast<unsigned char>(data[at])) && digits < 10) {
      *v = *v * 10 + static_cast<uint64_t>(data[at] - '0');
      ++at;
      ++digits;
    }
    return digits > 0;
  };
  uint64_t w = 0, h = 0, maxval = 0;
  if (!field(&w) || !field(&h) || !field(&maxval) || maxval == 0 || maxval > 255 ||
      at >= data.size()) {
    return Status::InvalidArgument(what + " is not an 8-bit binary PGM/PPM (P5/P6, maxval <= 255)");
  }
  HVDB_RETURN_IF_ERROR(CheckDeclared(what, w, h));
  ++at;  // the single whitespace before the samples
  const uint64_t channels = data[1] == '6' ? 3 : 1;
  if (w * h * channels > data.size() - at) return TooFewBytes(what, w, h, data.size());
  int ow = 0, oh = 0;
  OutputSize(static_cast<int>(w), static_cast<int>(h), max_side, &ow, &oh);
  HVDB_RETURN_IF_ERROR(budget.Reserve(uint64_t(ow) * oh * 4 + w * 4, what));
  budget.Release(w * 4);
  Picture pic;
  AreaSink sink(static_cast<int>(w), static_cast<int>(h), ow, oh, &pic);
  std::vector<uint8_t> row(w * 4);
  const auto* s = reinterpret_cast<const uint8_t*>(data.data()) + at;
  for (uint64_t y = 0; y < h; ++y) {
    for (uint64_t x = 0; x < w; ++x, s += channels) {
      for (uint64_t c = 0; c < 3; ++c) {
        row[4 * x + c] = static_cast<uint8_t>((s[channels == 3 ? c : 0] * 255 + maxval / 2) / maxval);
      }
      row[4 * x + 3] = 255;
    }
    sink.Row(row.data());
  }
  sink.Finish();
  return pic;
}

}  // namespace

Result<Picture> DecodeImage(std::string_view data, const std::string& format, uint32_t max_side,
                            const Budget& budget) {
  const std::string what = "import_media: the image (" + (format.empty() ? "?" : format) + ")";
  if (data.empty()) return Status::InvalidArgument(what + " is empty");
  const auto b = [&](size_t i) { return i < data.size() ? static_cast<uint8_t>(data[i]) : 0; };
  if (data.size() >= 8 && std::memcmp(data.data(), "\x89PNG\r\n\x1a\n", 8) == 0) {
    return DecodePng(data, what, max_side, budget);
  }
  if (b(0) == 0xFF && b(1) == 0xD8 && b(2) == 0xFF) return DecodeJpeg(data, what, max_side, budget);
  if (b(0) == 'P' && (b(1) == '5' || b(1) == '6')) return DecodePnm(data, what, max_side, budget);
  // Any other still format: libavcodec's image decoders, with the same bounds as a video's
  // frames.
  Result<std::vector<Picture>> frames = DecodeVideo(data, format, 1, max_side, kMaxImportPoints,
                                                    budget);
  if (!frames.ok()) {
    if (!frames.status().IsInvalidArgument()) return frames.status();
    return Status::InvalidArgument(what + " could not be decoded (" +
                                   std::to_string(data.size()) +
                                   " bytes: not a PNG, JPEG, PGM/PPM or other picture that "
                                   "libavcodec reads, or corrupt): " + frames.status().message());
  }
  return std::move(frames->front());
}

}  // namespace hvdb::media
