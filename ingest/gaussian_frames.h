// `hvdb-ingest run --gaussians`: each frame's Gaussians fitted to its calibrated colour photos
// (gaussian_fit.h), the first frame from its probabilistic points and each next one
// warm-started from the frame before, re-fitting only where the photos changed (3DGStream,
// Sun et al. 2024, keeps a frame's static Gaussians in the same spirit). The fitted splats are
// what the frame stores in a Gaussian-splat dataset.
#ifndef HVDB_INGEST_GAUSSIAN_FRAMES_H_
#define HVDB_INGEST_GAUSSIAN_FRAMES_H_

#include <optional>
#include <vector>

#include "ingest/gaussian_fit.h"
#include "ingest/recording.h"
#include "storage/status.h"

namespace hvdb::ingest {

struct GaussianFrameOptions {
  FitOptions fit;           // the first frame's fit (and each frame's options but iterations)
  int warm_iterations = 0;  // a warm-started frame's iterations (0: fit.iterations / 3)
  // Photos fitted at 1/scale of their size (1: full size), as 3DGS's -r.
  int resolution_scale = 4;
  float change_threshold = 0.06f;  // ChangedPixels' threshold for warm starts
  float warm_position_lr = 5.0f;   // a warm start's initial position rate, times fit's
  // A frame fitted from its points starts from at most this many (CloudFromPoints).
  size_t max_start_splats = 200'000;
  // Each view is fitted where the frame's points are: within this many pixels (at the fitted
  // size) of a projected point. A cloud clipped to its subject leaves the rest of the photo out.
  int coverage_radius = 6;
};

// OK when the recording has colour cameras to fit to (stereo bricks with a colour camera, depth
// cameras, or a ply recording's colour cameras); else InvalidArgument saying so.
Status CheckFitCameras(const Recording& recording);

// The frame's colour photos as training views: undistorted with their calibration (the
// rasteriser draws pinhole cameras), reduced to 1/scale (area averaging), RGB in [0, 1].
// InvalidArgument naming the camera for a photo that is missing or whose size is not its
// camera's.
Result<std::vector<FitView>> FrameFitViews(const Recording& recording, const FrameInput& frame,
                                           int resolution_scale);

// Fits frames in order, carrying each frame's result to the next.
class GaussianVideoFitter {
 public:
  explicit GaussianVideoFitter(GaussianFrameOptions options) : options_(std::move(options)) {}

  // Frame `index`'s Gaussians from its views and points. Warm-started when the previous call
  // was for index - 1 with the same cameras (sizes, intrinsics and poses) and succeeded;
  // otherwise from `points`.
  Result<formats::GaussianCloud> Fit(int index, std::vector<FitView> views,
                                     const std::vector<Point>& points, FitReport* report);

 private:
  GaussianFrameOptions options_;
  struct Previous {
    int index = -1;
    formats::GaussianCloud cloud;
    std::vector<FitView> views;
  };
  std::optional<Previous> previous_;
};

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_GAUSSIAN_FRAMES_H_
