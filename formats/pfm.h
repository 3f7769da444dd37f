// Portable Float Map (PFM) files: the disparity maps of the Middlebury benchmark and of
// `hvdb-ingest stereo`. Header "Pf" (1 channel) or "PF" (3 channels), "width height", scale
// (negative = little-endian), then float32 rows stored bottom-to-top.
#ifndef HVDB_FORMATS_PFM_H_
#define HVDB_FORMATS_PFM_H_

#include <opencv2/core.hpp>
#include <string>

#include "storage/status.h"

namespace hvdb::formats {

// CV_32F with 1 or 3 channels; written little-endian (scale -1), rows bottom-to-top as the
// format says. inf / nan values are written as they are.
Status WritePfm(const std::string& path, const cv::Mat& image);

// Returns CV_32FC1 or CV_32FC3 in top-to-bottom row order. Errors name the file: NotFound
// when it cannot be opened, Corruption for malformed headers and truncated data.
Result<cv::Mat> ReadPfm(const std::string& path);

}  // namespace hvdb::formats

#endif  // HVDB_FORMATS_PFM_H_
