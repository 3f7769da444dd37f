// The ingest pipeline: recording -> points -> dataset, frame by frame, on a pool of workers.
//
// Per frame (thesis 4, 5.1-5.3):
//   stereo  per brick: rectify the grey pair, match (S1-S5), depth from disparity (3.24) with
//           its uncertainty (5.8), warp into the brick's colour camera, probabilistic points
//           (5.9-5.12); merge the bricks; photo-consistency cleaning in every colour camera (5.3)
//   depth   per camera: undistort, probabilistic points; merge; photo-consistency cleaning
//   ply     the file's points as they are
// and one atomic bulk load per frame. Workers process frames in parallel and each commits the
// frame it made (the trees of new frames are built on the committing thread, so commits
// overlap too); one frame per worker is in memory.
//
// Resumable: frames already present in the dataset are skipped, so an ingest killed at any
// moment and started again continues with the frames not yet committed; a frame is never
// half present because its insert is one bulk load (atomic per frame).
#ifndef HVDB_INGEST_PIPELINE_H_
#define HVDB_INGEST_PIPELINE_H_

#include <functional>
#include <chrono>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "ingest/billboard.h"
#include "ingest/gaussian_frames.h"
#include "ingest/geometric_consistency.h"
#include "ingest/photo_consistency.h"
#include "ingest/points.h"
#include "ingest/recording.h"
#include "ingest/segmentation.h"
#include "ingest/stereo.h"

namespace hvdb::ingest {

struct IngestOptions {
  std::string dataset;
  uint32_t frame_offset = 0;   // recording frame i goes to dataset frame frame_offset + i
  int first = 0, count = -1;   // recording frames [first, first + count); -1 = to the end
  int workers = 0;             // 0 = hardware threads
  int max_in_flight = 0;       // live ingest (follow.cc): finished frames waiting; 0 = workers + 1
  StereoParams stereo;         // threads = 0: hardware threads / workers
  // stereo: frames on either side matched together with each frame by the spacetime matcher
  // (thesis 3.4; for projector patterns that change over time); -1: the recording's
  // `spacetime` (0 when it declares none: single-frame stereo).
  int spacetime = -1;
  // stereo (or depth with billboard_baseline): kBillboard makes each brick's depth (each depth
  // camera's) a billboard in its colour camera and smooths
  // it with the bilateral filter of thesis 6.2 over the frames around (temporal_radius) and
  // the other bricks' views before making points, in place of subpixel refinement
  // (stereo.subpixel is then best kParabola: thesis 6.5 filters integer disparities, but
  // those of a smooth surface are plateaus wider than the kernel).
  enum class Filter { kNone, kBillboard };
  Filter filter = Filter::kNone;
  BillboardFilterOptions billboard;
  // Depth recordings with the billboard filter: the baseline (m) over which the depth sensor
  // measures disparity (a Kinect v1's: 0.075), which makes its disparity space d = fx b / z.
  double billboard_baseline = 0;
  // With the billboard filter: only the object marked by brush strokes (thesis 6.4). A path
  // pattern of one stroke image per colour camera ({camera}; relative to the recording, as in
  // recording.yml) painted on recording frame `strokes_frame`: red (object) and blue (the
  // rest) strokes, anything else unmarked. Per frame each view is cut into the object and the
  // rest (segmentation's colour and depth models fitted to the strokes, a graph cut over the
  // frames of the window) and matted at the boundary; the billboards' alpha is the matte and
  // only the object becomes points.
  std::string object_strokes;
  int strokes_frame = 0;
  SegmentationOptions segmentation;
  MattingOptions matting;
  int stride = 1;              // depth: take every stride-th pixel
  bool normals = true;
  // Depth samples within this many pixels of a depth jump (> edge_jump of the depth) are
  // dropped before making points: mixed pixels at silhouettes (0: keep them).
  int edge_radius = 2;
  double edge_jump = 0.05;
  // Cross-view geometric consistency before photo-consistency (ingest/geometric_consistency.h).
  bool geometric_consistency = true;
  GeometricConsistencyOptions geometric;
  bool photo_consistency = true;
  PhotoConsistencyOptions photo;
  // Store each colour camera's image of each frame with the points (Dataset::PutPhoto), for
  // textured renders (Render.texture).
  bool photos = true;
  bool skip_bad_frames = false;  // a bad frame is reported and skipped instead of stopping
  // ply: points with a NaN or infinite coordinate are left out and counted (the frame's
  // FrameReport::skipped_invalid) instead of making their frame bad.
  bool skip_invalid = false;
  std::string depth_out;       // if set: DIR/NNNNNN/<camera>.depth.exr of every depth map made
  bool progress = false;       // a progress bar on stderr
  // Fit Gaussians to each frame's colour photos and store them instead of the points (the
  // dataset is a Gaussian-splat one): frames in order on one worker, each fit on every core,
  // each frame warm-started from the one before (ingest/gaussian_frames.h).
  bool gaussians = false;
  GaussianFrameOptions gaussian;
};

struct FrameReport {
  int frame = 0;               // recording frame
  uint32_t dataset_frame = 0;
  std::string status = "ingested";  // ingested | present (skipped on resume) | skipped (bad)
  std::string error;
  double valid_depth_pct = 0;  // stereo/depth: pixels with depth / pixels
  uint64_t points = 0, outliers_removed = 0;
  uint64_t skipped_invalid = 0;            // ply: points left out for a NaN or infinite coordinate
  std::map<std::string, double> stage_ms;  // load, rectify, stereo, points, photo, fit, commit
  std::optional<FitReport> fit;            // --gaussians: the frame's fit
};

struct IngestReport {
  int frames_total = 0, ingested = 0, present = 0, skipped = 0;
  uint64_t points = 0, bytes_read = 0;
  uint64_t skipped_invalid = 0;  // over the ingested frames (IngestOptions::skip_invalid)
  double seconds = 0, peak_rss_mb = 0;
  std::vector<FrameReport> frames;  // in frame order
  nlohmann::json ToJson() const;
};

// A camera of the calibration as the dataset stores it (its cameras, its photos); id: its index
// in the calibration, the Point::camera of the points it took.
CameraInfo ToCameraInfo(const CameraModel& camera, uint16_t id);

// Creates the dataset when it does not exist (fps and colour cameras from the recording; a
// Gaussian-splat dataset when `gaussians`). An existing one must have the recording's rate and
// be a Gaussian-splat dataset exactly when `gaussians`.
Status EnsureDataset(client::Backend& backend, const Recording& recording,
                     const std::string& dataset, bool gaussians = false);

// One frame's points, without committing them (tests and benchmarks use it directly).
class FrameProcessor {
 public:
  static Result<FrameProcessor> Make(const Recording& recording, const IngestOptions& options);
  // window: the frames around `input` in frame order (`input` itself at `centre`), as many on
  // either side as window_radius() (fewer at the recording's ends); empty: `input` alone.
  // billboards: with the billboard filter, receives each colour camera's filtered billboard
  // (by camera id) as the dataset stores it with the photo.
  Result<std::vector<Point>> Process(const FrameInput& input, FrameReport* report,
                                     const std::vector<const FrameInput*>& window = {},
                                     size_t centre = 0,
                                     std::map<uint16_t, PhotoBillboard>* billboards = nullptr) const;
  // The frames on either side each frame is matched with (0: none).
  int spacetime() const;
  // The frames on either side Process needs in its window: the spacetime matcher's and the
  // billboard filter's.
  int window_radius() const;

 private:
  // Brick j's (of input.stereo) depth in its colour camera by single-frame stereo, mixed
  // pixels removed.
  Result<cv::Mat> ColourDepth(const FrameInput& input, size_t j) const;
  // object_strokes: reads the strokes and fits each brick's segmentation model on them.
  Status FitObjectModels();
  // Threads for a stage of one frame (geometry, photo-consistency, the billboard filter).
  int StageThreads() const;

  const Recording* rec_ = nullptr;
  IngestOptions opt_;
  std::vector<std::shared_ptr<const struct Rectification>> rect_;  // per brick
  // object_strokes: per brick, the segmentation model and the strokes (undistorted, CV_8U).
  std::vector<std::shared_ptr<const SegmentationModel>> models_;
  std::vector<cv::Mat> strokes_;
};

// One frame made ready to commit: its points and photos, exactly what RunIngest commits for it
// (the follower of a live recording, ingest/live.h, commits the same).
struct PreparedFrame {
  int index = 0;
  Status status;               // not ok: a bad frame (nothing to commit)
  std::vector<Point> points;
  std::vector<Photo> photos;
  std::vector<FitView> fit_views;  // --gaussians: the photos as training views
  std::optional<GaussianColumns> gaussians;  // --gaussians: the points' Gaussian records
  uint64_t bytes = 0;          // read from the recording for it (its window's frames too)
};

// Loads one recording frame; RunIngest's reads the files (LoadFrame), the follower's hands out
// the frames it has already read.
using FrameLoader = std::function<Result<std::shared_ptr<const FrameInput>>(int index)>;

// Loads recording frame i with the frames [lo, hi] around it that the processor's window needs
// (lo <= i <= hi; the recording's ends, or for the follower the frames that completed), makes
// its points and (options.photos) its photos; fr gets the frame's statistics.
PreparedFrame PrepareFrame(const Recording& recording, const FrameProcessor& processor,
                           const IngestOptions& options, int i, int lo, int hi,
                           const FrameLoader& load, FrameReport* fr);

// --gaussians: fits a prepared frame's Gaussians (frames in order: `fitter` carries each to the
// next) and puts the splats, with their Gaussian records, in place of its points; a failure
// becomes the frame's status. fr gets the fit's report and time.
void FitPreparedFrame(GaussianVideoFitter& fitter, PreparedFrame* frame, FrameReport* fr);

// Commits a prepared frame: its photos, then its points in one bulk load (atomic per frame).
// Returns the points committed.
Result<uint64_t> CommitFrame(client::Backend& backend, const IngestOptions& options,
                             PreparedFrame&& frame, FrameReport* fr);

// Whether dataset frame f already holds points (resume: such frames are skipped).
Result<bool> FramePresent(client::Backend& backend, const std::string& dataset, uint32_t f,
                          double fps);

// The peak resident memory of this process in MiB.
double PeakRssMb();
// Milliseconds since t0 (the stage timings) and the machine's hardware threads (at least 1).
double MsSince(std::chrono::steady_clock::time_point t0);
int HardwareThreads();

// Runs the whole ingest. Returns an error for the first bad frame unless skip_bad_frames; the
// frames committed before it stay (run again to continue).
Result<IngestReport> RunIngest(const Recording& recording, client::Backend& backend,
                               const IngestOptions& options);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_PIPELINE_H_
