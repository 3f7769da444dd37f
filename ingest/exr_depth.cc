// One-channel float32 OpenEXR depth maps (ingest/generator.h: ReadDepthExr, WriteDepthExr).
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>

#include <exception>
#include <filesystem>

#include "ingest/generator.h"

namespace hvdb::ingest {

namespace fs = std::filesystem;

Status WriteDepthExr(const std::string& path, const cv::Mat& depth) {
  if (depth.empty() || depth.type() != CV_32FC1)
    return Status::InvalidArgument(path + ": a depth map must be a non-empty one-channel float32 image");
  try {
    Imf::Header header(depth.cols, depth.rows);
    header.channels().insert("Z", Imf::Channel(Imf::FLOAT));
    Imf::OutputFile file(path.c_str(), header);
    Imf::FrameBuffer fb;
    fb.insert("Z", Imf::Slice(Imf::FLOAT, const_cast<char*>(reinterpret_cast<const char*>(depth.ptr<float>())),
                              sizeof(float), depth.step[0]));
    file.setFrameBuffer(fb);
    file.writePixels(depth.rows);
  } catch (const std::exception& e) {
    return Status::IOError(path + ": cannot write EXR depth: " + e.what());
  }
  return Status::OK();
}

Result<cv::Mat> ReadDepthExr(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return Status::NotFound(path + ": no such EXR depth file");
  try {
    Imf::InputFile file(path.c_str());
    const Imf::Header& header = file.header();
    if (!header.channels().findChannel("Z"))
      return Status::Corruption(path + ": EXR depth file has no channel \"Z\"");
    const Imath::Box2i dw = header.dataWindow();
    const int64_t w = int64_t{dw.max.x} - dw.min.x + 1, h = int64_t{dw.max.y} - dw.min.y + 1;
    if (w <= 0 || h <= 0 || w > 65536 || h > 65536)
      return Status::Corruption(path + ": EXR depth file has an invalid data window");
    cv::Mat depth(static_cast<int>(h), static_cast<int>(w), CV_32FC1);
    Imf::FrameBuffer fb;
    // Slice::Make handles the data window's origin; HALF/UINT channels are converted to float.
    fb.insert("Z", Imf::Slice::Make(Imf::FLOAT, depth.ptr<float>(), dw, sizeof(float),
                                    static_cast<size_t>(depth.step[0])));
    file.setFrameBuffer(fb);
    file.readPixels(dw.min.y, dw.max.y);
    return depth;
  } catch (const std::exception& e) {
    return Status::Corruption(path + ": not a readable EXR depth file: " + e.what());
  }
}

}  // namespace hvdb::ingest
