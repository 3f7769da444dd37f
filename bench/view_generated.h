// view-bench's second part: novel views of a generated structured-light recording, one brick
// left out, with and without 3D video billboards (thesis ch. 6).
#ifndef HVDB_BENCH_VIEW_GENERATED_H_
#define HVDB_BENCH_VIEW_GENERATED_H_

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <string>

#include "render/metrics.h"

namespace hvdb::bench {

// BGR cv::Mat <-> RGB(A) Srgb8Image, for PSNR and for the pictures (both parts of view-bench).
render::Srgb8Image FromMat(const cv::Mat& bgr);
cv::Mat ToMat(const render::Srgb8Image& image);

struct GeneratedViewOptions {
  std::string scratch;  // folder for the recording and the datasets
  std::string images;   // "": no images; else per held-out brick billboards | points | photo
  bool quick = false;   // small images, one brick held out (CI smoke run)
};

// For each interior brick h of a 4-brick recording: the other three are ingested twice by
// RunIngest (what hvdb-ingest does) into an embedded dataset, with the subpixel LM and with
// the billboard filter, and frame 2 is rendered from h's colour camera through the Render
// request: points (view-dependent), textured points, and (billboard ingest) the billboards.
// PSNR against h's photo over the pixels where h sees the scene (its ground-truth depth).
// Appends figures; returns 0, or 1 after printing an error.
int RunGeneratedViews(const GeneratedViewOptions& options, nlohmann::json& figures);

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_VIEW_GENERATED_H_
