// PNG (8-bit sRGB, through image_codec.h's libpng writer) and OpenEXR (float) images.
#include "formats/image_io.h"
#include "formats/image_codec.h"

#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfIO.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <stdexcept>
#include <opencv2/core.hpp>

namespace hvdb::formats {

namespace {

uint8_t ToByte(float v) {
  float c = std::clamp(v, 0.0f, 1.0f);
  return static_cast<uint8_t>(std::lround(c * 255.0f));
}

// ToByte(LinearToSrgb(v)) without a pow per channel (which made encoding a 1080p frame cost
// more than rendering it): the byte is the number of thresholds SrgbToLinear((k - 0.5) / 255),
// k = 1..255, at or below v; a table indexed by v's upper bits gives the count at the start of
// v's bucket, and at most a step or two more are checked.
class SrgbEncoder {
 public:
  SrgbEncoder() {
    for (int k = 1; k <= 255; ++k) thr_[k] = SrgbToLinear((static_cast<float>(k) - 0.5f) / 255.0f);
    thr_[256] = std::numeric_limits<float>::infinity();
    uint32_t byte = 0;
    for (uint32_t bucket = 0; bucket < kBuckets; ++bucket) {
      float lo;
      uint32_t bits = bucket << kShift;
      std::memcpy(&lo, &bits, 4);
      while (byte < 255 && lo >= thr_[byte + 1]) ++byte;
      table_[bucket] = static_cast<uint8_t>(byte);
    }
  }
  uint8_t operator()(float v) const {
    if (!(v > 0)) return 0;  // NaN too
    if (v >= 1) return 255;
    uint32_t bits;
    std::memcpy(&bits, &v, 4);
    uint32_t b = table_[bits >> kShift];
    while (v >= thr_[b + 1]) ++b;
    return static_cast<uint8_t>(b);
  }

 private:
  static constexpr int kShift = 15;
  static constexpr uint32_t kBuckets = (0x3f800000u >> kShift) + 1;  // floats in [0, 1]
  float thr_[257];
  uint8_t table_[kBuckets];
};

const SrgbEncoder& Encoder() {
  static const SrgbEncoder* encoder = new SrgbEncoder();
  return *encoder;
}

// OpenEXR writes through an OStream; this one appends to a string.
class StringOStream : public Imf::OStream {
 public:
  explicit StringOStream(std::string* out) : Imf::OStream("memory"), out_(out) {}
  void write(const char c[], int n) override {
    if (pos_ + static_cast<uint64_t>(n) > out_->size()) out_->resize(pos_ + n);
    std::memcpy(out_->data() + pos_, c, static_cast<size_t>(n));
    pos_ += static_cast<uint64_t>(n);
  }
  uint64_t tellp() override { return pos_; }
  void seekp(uint64_t pos) override { pos_ = pos; }

 private:
  std::string* out_;
  uint64_t pos_ = 0;
};

// And this one reads from bytes in memory.
class StringIStream : public Imf::IStream {
 public:
  explicit StringIStream(const std::string& in) : Imf::IStream("memory"), in_(in) {}
  bool read(char c[], int n) override {
    if (n < 0 || pos_ + static_cast<uint64_t>(n) > in_.size()) {
      throw std::runtime_error("the EXR data ends early");
    }
    std::memcpy(c, in_.data() + pos_, static_cast<size_t>(n));
    pos_ += static_cast<uint64_t>(n);
    return pos_ < in_.size();
  }
  uint64_t tellg() override { return pos_; }
  void seekg(uint64_t pos) override { pos_ = pos; }

 private:
  const std::string& in_;
  uint64_t pos_ = 0;
};

Status CheckImage(const Image& img) {
  if (img.width == 0 || img.height == 0 || img.rgba.size() != img.pixels() * 4) {
    return Status::InvalidArgument("image: empty, or rgba does not hold width x height x 4");
  }
  return Status::OK();
}

Status WriteFile(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Status::IOError(path + ": cannot open for writing");
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) return Status::IOError(path + ": write failed");
  return Status::OK();
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  return std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
                    [](char a, char b) { return std::tolower(a) == std::tolower(b); });
}

}  // namespace

float SrgbToLinear(float v) {
  return v <= 0.04045f ? v / 12.92f : std::pow((v + 0.055f) / 1.055f, 2.4f);
}

float LinearToSrgb(float v) {
  return v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
}

Srgb8Image ToSrgb8(const Image& img) {
  Srgb8Image out;
  out.width = img.width;
  out.height = img.height;
  out.channels = 3;
  for (size_t i = 0; i < img.pixels(); ++i) {
    if (img.rgba[i * 4 + 3] < 1.0f - 0.5f / 255.0f) {
      out.channels = 4;
      break;
    }
  }
  out.data.resize(img.pixels() * out.channels);
  const SrgbEncoder& srgb = Encoder();
  for (size_t i = 0; i < img.pixels(); ++i) {
    const float* p = &img.rgba[i * 4];
    float a = p[3];
    // Premultiplied to straight colour (PNG stores straight alpha).
    float inv = a > 0 ? 1.0f / a : 0.0f;
    for (int c = 0; c < 3; ++c) {
      float straight = out.channels == 4 ? p[c] * inv : p[c];
      out.data[i * out.channels + c] = srgb(straight);
    }
    if (out.channels == 4) out.data[i * 4 + 3] = ToByte(a);
  }
  return out;
}

Result<std::string> EncodePng(const Image& img) {
  HVDB_RETURN_IF_ERROR(CheckImage(img));
  Srgb8Image s = ToSrgb8(img);
  const cv::Mat m(static_cast<int>(s.height), static_cast<int>(s.width),
                  CV_8UC(static_cast<int>(s.channels)), s.data.data());
  return EncodePngImage(m, /*rgb_order=*/true);
}

Status WritePng(const Image& img, const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(std::string bytes, EncodePng(img));
  return WriteFile(path, bytes);
}

Result<std::string> EncodeExr(const Image& img) {
  HVDB_RETURN_IF_ERROR(CheckImage(img));
  const int w = static_cast<int>(img.width), h = static_cast<int>(img.height);
  std::vector<float> depth = img.depth;
  if (depth.size() != img.pixels()) depth.assign(img.pixels(), INFINITY);
  std::string out;
  try {
    Imf::Header header(w, h);
    for (const char* c : {"R", "G", "B", "A", "Z"}) {
      header.channels().insert(c, Imf::Channel(Imf::FLOAT));
    }
    StringOStream stream(&out);
    Imf::OutputFile file(stream, header);
    Imf::FrameBuffer fb;
    const size_t px = 4 * sizeof(float);
    char* base = reinterpret_cast<char*>(const_cast<float*>(img.rgba.data()));
    const char* names[] = {"R", "G", "B", "A"};
    for (int c = 0; c < 4; ++c) {
      fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), px, px * w));
    }
    fb.insert("Z", Imf::Slice(Imf::FLOAT, reinterpret_cast<char*>(depth.data()), sizeof(float),
                              sizeof(float) * w));
    file.setFrameBuffer(fb);
    file.writePixels(h);
  } catch (const std::exception& e) {
    return Status::Internal(std::string("OpenEXR encoding failed: ") + e.what());
  }
  return out;
}

Result<Image> DecodeExr(const std::string& bytes) {
  Image img;
  try {
    StringIStream stream(bytes);
    Imf::InputFile file(stream);
    Imath::Box2i dw = file.header().dataWindow();
    int64_t w = int64_t{dw.max.x} - dw.min.x + 1, h = int64_t{dw.max.y} - dw.min.y + 1;
    if (w < 1 || h < 1 || w > kMaxImageSize || h > kMaxImageSize) {
      return Status::InvalidArgument("EXR: image size " + std::to_string(w) + "x" +
                                     std::to_string(h) + " is outside 1..4096 per side");
    }
    img.width = static_cast<uint32_t>(w);
    img.height = static_cast<uint32_t>(h);
    img.rgba.assign(img.pixels() * 4, 0.0f);
    img.depth.assign(img.pixels(), INFINITY);
    Imf::FrameBuffer fb;
    const size_t px = 4 * sizeof(float);
    // The data window may not start at 0: shift the base so that (min.x, min.y) is pixel 0.
    const ptrdiff_t origin = (static_cast<ptrdiff_t>(dw.min.y) * w + dw.min.x);
    char* base = reinterpret_cast<char*>(img.rgba.data()) - origin * static_cast<ptrdiff_t>(px);
    const char* names[] = {"R", "G", "B", "A"};
    for (int c = 0; c < 4; ++c) {
      fb.insert(names[c], Imf::Slice(Imf::FLOAT, base + c * sizeof(float), px, px * w, 1, 1,
                                     c == 3 ? 1.0 : 0.0));
    }
    char* zbase = reinterpret_cast<char*>(img.depth.data()) -
                  origin * static_cast<ptrdiff_t>(sizeof(float));
    fb.insert("Z", Imf::Slice(Imf::FLOAT, zbase, sizeof(float), sizeof(float) * w, 1, 1, INFINITY));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
  } catch (const std::exception& e) {
    return Status::InvalidArgument(std::string("EXR: ") + e.what());
  }
  img.coverage.resize(img.pixels());
  for (size_t i = 0; i < img.pixels(); ++i) img.coverage[i] = img.rgba[i * 4 + 3];
  return img;
}

Status WriteExr(const Image& img, const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(std::string bytes, EncodeExr(img));
  return WriteFile(path, bytes);
}

Status WriteImage(const Image& img, const std::string& path) {
  if (EndsWith(path, ".png")) return WritePng(img, path);
  if (EndsWith(path, ".exr")) return WriteExr(img, path);
  return Status::InvalidArgument(path +
                                 ": the image format comes from the extension, .png or "
                                 ".exr");
}

Status WriteSrgb8Png(const Srgb8Image& s, const std::string& path) {
  if (s.data.size() != size_t{s.width} * s.height * s.channels || s.width == 0 ||
      (s.channels != 1 && s.channels != 3 && s.channels != 4)) {
    return Status::InvalidArgument("image: size and data do not agree");
  }
  const cv::Mat m(static_cast<int>(s.height), static_cast<int>(s.width),
                  CV_8UC(static_cast<int>(s.channels)), const_cast<uint8_t*>(s.data.data()));
  HVDB_ASSIGN_OR_RETURN(std::string bytes, EncodePngImage(m, /*rgb_order=*/true));
  return WriteFile(path, bytes);
}

Result<Srgb8Image> ReadSrgb8(const std::string& path) {
  HVDB_ASSIGN_OR_RETURN(cv::Mat m, ReadImageFile(path, ImageMode::kAsStored));
  if (m.depth() != CV_8U) return Status::InvalidArgument(path + ": not an 8-bit image");
  Srgb8Image s;
  s.width = static_cast<uint32_t>(m.cols);
  s.height = static_cast<uint32_t>(m.rows);
  s.channels = static_cast<uint32_t>(m.channels());
  s.data.resize(size_t{s.width} * s.height * s.channels);
  for (int y = 0; y < m.rows; ++y) {
    std::memcpy(s.data.data() + static_cast<size_t>(y) * s.width * s.channels, m.ptr(y),
                size_t{s.width} * s.channels);
  }
  if (s.channels >= 3) {
    for (size_t i = 0; i < s.data.size(); i += s.channels) std::swap(s.data[i], s.data[i + 2]);
  }
  return s;
}

}  // namespace hvdb::formats
