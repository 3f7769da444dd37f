// Image files (PNG, JPEG and whatever else OpenCV's imgcodecs reads) as RGBA pictures.
#include <algorithm>
#include <cmath>
#include <cstring>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "media/media.h"

namespace hvdb::media {

Result<Picture> DecodeImage(std::string_view data, const std::string& format, uint32_t max_side) {
  const std::string what = "import_media: the image (" + (format.empty() ? "?" : format) + ")";
  if (data.empty()) return Status::InvalidArgument(what + " is empty");
  cv::Mat img;
  try {
    const cv::Mat buf(1, static_cast<int>(data.size()), CV_8UC1,
                      const_cast<char*>(data.data()));
    img = cv::imdecode(buf, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return Status::InvalidArgument(what + " could not be decoded: " + e.what());
  }
  if (img.empty()) {
    return Status::InvalidArgument(what + " could not be decoded (" +
                                   std::to_string(data.size()) +
                                   " bytes: not an image file OpenCV reads, or corrupt)");
  }
  // 16-bit and float images to 8 bits.
  if (img.depth() == CV_16U) {
    img.convertTo(img, CV_8U, 1.0 / 257);
  } else if (img.depth() != CV_8U) {
    img.convertTo(img, CV_8U, 255.0);
  }
  cv::Mat rgba;
  switch (img.channels()) {
    case 1: cv::cvtColor(img, rgba, cv::COLOR_GRAY2RGBA); break;
    case 3: cv::cvtColor(img, rgba, cv::COLOR_BGR2RGBA); break;
    case 4: cv::cvtColor(img, rgba, cv::COLOR_BGRA2RGBA); break;
    default:
      return Status::InvalidArgument(what + " has " + std::to_string(img.channels()) +
                                     " channels (1, 3 or 4 are read)");
  }
  const int side = std::max(rgba.cols, rgba.rows);
  if (max_side > 0 && side > static_cast<int>(max_side)) {
    const double f = static_cast<double>(max_side) / side;
    const int w = std::max(1, static_cast<int>(std::lround(rgba.cols * f)));
    const int h = std::max(1, static_cast<int>(std::lround(rgba.rows * f)));
    cv::Mat small;
    cv::resize(rgba, small, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    rgba = small;
  }
  Picture p;
  p.width = rgba.cols;
  p.height = rgba.rows;
  p.rgba.resize(static_cast<size_t>(p.width) * p.height * 4);
  for (int y = 0; y < p.height; ++y) {
    std::memcpy(p.rgba.data() + static_cast<size_t>(y) * p.width * 4, rgba.ptr(y),
                static_cast<size_t>(p.width) * 4);
  }
  return p;
}

}  // namespace hvdb::media
