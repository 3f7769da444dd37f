#include "ingest/pipeline.h"

#include "formats/gaussian_points.h"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <optional>
#include <thread>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "ingest/generator.h"  // WriteDepthExr
#include "ingest/rectify.h"

namespace hvdb::ingest {

using Clock = std::chrono::steady_clock;

double MsSince(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

int HardwareThreads() { return std::max(1, static_cast<int>(std::thread::hardware_concurrency())); }

namespace {

double ValidPct(const cv::Mat& depth) {
  if (depth.empty()) return 0;
  return 100.0 * cv::countNonZero(depth > 0) / static_cast<double>(depth.total());
}

}  // namespace

double PeakRssMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

CameraInfo ToCameraInfo(const CameraModel& c, uint16_t id) {
  const render::Camera rc = c.ToRenderCamera();
  CameraInfo ci;
  ci.id = id;
  ci.name = c.name;
  ci.width = rc.width;
  ci.height = rc.height;
  ci.fx = rc.fx;
  ci.fy = rc.fy;
  ci.cx = rc.cx;
  ci.cy = rc.cy;
  ci.distortion = rc.distortion;
  ci.world_from_camera = rc.world_from_camera;
  return ci;
}

namespace {

// The frame's colour photos (the recorded PNG or JPEG files' bytes) with their cameras as they
// were for this frame, for textured renders (Dataset::PutPhoto), each with its camera's
// billboard when there is one. An image in another format, or too big for one protocol frame
// (16 MiB by default, with room to spare) together with its billboard's maps, is encoded from
// the decoded image: PNG, or JPEG at quality 95 when the PNG is still too big.
Result<std::vector<Photo>> FramePhotos(const Recording& rec, const FrameInput& in,
                                       std::map<uint16_t, PhotoBillboard>* billboards) {
  constexpr size_t kMaxPhotoBytes = 12u << 20;
  std::vector<Photo> out;
  auto read = [&](const std::string& path, const cv::Mat& image, const CameraModel& model,
                  int idx) -> Status {
    Photo photo{ToCameraInfo(model, static_cast<uint16_t>(idx)), {}, {}};
    if (auto b = billboards->find(photo.camera.id); b != billboards->end()) photo.billboard = std::move(b->second);
    const size_t maps = photo.billboard.displacement.size() + photo.billboard.alpha.size();
    if (maps >= kMaxPhotoBytes / 2)
      return Status::InvalidArgument(path + ": the billboard's maps of camera " + model.name + " take " +
                                     std::to_string(maps >> 20) + " MiB, more than a photo may carry "
                                     "with them; ingest without --filter billboard, or with --no-photos");
    const size_t limit = kMaxPhotoBytes - maps;
    std::ifstream f(path, std::ios::binary);
    std::string bytes((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
    if (!f.good() && !f.eof()) return Status::IOError(path + ": cannot read the colour image");
    const bool png = bytes.rfind("\x89PNG", 0) == 0, jpeg = bytes.rfind("\xff\xd8\xff", 0) == 0;
    if (!(png || jpeg) || bytes.size() > limit) {
      std::vector<uint8_t> enc;
      if (!cv::imencode(".png", image, enc) || enc.size() > limit) {
        if (!cv::imencode(".jpg", image, enc, {cv::IMWRITE_JPEG_QUALITY, 95}) || enc.size() > limit) {
          return Status::InvalidArgument(path + ": the colour image does not fit a protocol frame even as JPEG");
        }
      }
      bytes.assign(enc.begin(), enc.end());
    }
    photo.image = std::move(bytes);
    out.push_back(std::move(photo));
    return Status::OK();
  };
  for (const StereoView& v : in.stereo) {
    const int idx = rec.calibration.bricks[static_cast<size_t>(v.brick)].colour;
    HVDB_RETURN_IF_ERROR(read(v.colour_path, v.colour, rec.calibration.cameras[static_cast<size_t>(idx)], idx));
  }
  for (const DepthFrameView& v : in.depth) {
    HVDB_RETURN_IF_ERROR(read(v.colour_path, v.colour, v.model, v.camera));
  }
  return out;
}

// The window holding dataset frame f (t = f / fps, inclusive bounds) over all space.
Window FrameWindow(uint32_t f, double fps) {
  Window w;
  const double big = 1e30;
  for (int a = 0; a < 3; ++a) {
    w.lo[a] = -big;
    w.hi[a] = big;
  }
  w.lo[3] = w.hi[3] = f / fps;
  return w;
}


}  // namespace

// Whether dataset frame f holds any point: the first batch of a query on it.
Result<bool> FramePresent(client::Backend& backend, const std::string& dataset, uint32_t f,
                          double fps) {
  HVDB_ASSIGN_OR_RETURN(auto q, backend.Query(dataset, FrameWindow(f, fps), QueryOptions{}));
  Batch b;
  while (true) {
    HVDB_ASSIGN_OR_RETURN(bool more, q->Next(&b));
    if (!more) return false;
    if (!b.points.empty()) return true;
  }
}

nlohmann::json IngestReport::ToJson() const {
  nlohmann::json j;
  j["frames_total"] = frames_total;
  j["ingested"] = ingested;
  j["already_present"] = present;
  j["skipped"] = skipped;
  j["points"] = points;
  j["bytes_read"] = bytes_read;
  j["skipped_invalid"] = skipped_invalid;
  j["seconds"] = seconds;
  j["frames_per_s"] = seconds > 0 ? ingested / seconds : 0;
  j["points_per_s"] = seconds > 0 ? static_cast<double>(points) / seconds : 0;
  j["peak_rss_mb"] = peak_rss_mb;
  nlohmann::json fr = nlohmann::json::array();
  for (const auto& f : frames) {
    nlohmann::json e = {{"frame", f.frame},
                        {"dataset_frame", f.dataset_frame},
                        {"status", f.status},
                        {"valid_depth_pct", f.valid_depth_pct},
                        {"points", f.points},
                        {"outliers_removed", f.outliers_removed},
                        {"skipped_invalid", f.skipped_invalid},
                        {"stage_ms", f.stage_ms}};
    if (!f.error.empty()) e["error"] = f.error;
    if (f.fit) {
      e["fit"] = {{"iterations", f.fit->iterations}, {"loss", f.fit->loss},
                  {"psnr_training_views", f.fit->psnr}, {"seconds", f.fit->seconds},
                  {"splats_in", f.fit->splats_in}, {"splats", f.fit->splats_out}};
    }
    fr.push_back(e);
  }
  j["frames"] = fr;
  return j;
}

Status EnsureDataset(client::Backend& backend, const Recording& rec, const std::string& dataset,
                     bool gaussians) {
  auto info = backend.Describe(dataset);
  if (info.ok()) {
    if (std::abs(info->fps - rec.fps) > 1e-9)
      return Status::InvalidArgument("dataset '" + dataset + "' has " + std::to_string(info->fps) +
                                     " fps but the recording " + std::to_string(rec.fps) +
                                     "; ingest into a new dataset or one of the same rate");
    if (info->gaussians != gaussians) {
      return Status::InvalidArgument(
          "dataset '" + dataset + "' " +
          (gaussians ? "holds points without Gaussian attributes; --gaussians ingests into a new "
                       "dataset or a Gaussian-splat one"
                     : "is a Gaussian-splat dataset; ingest with --gaussians, or into another "
                       "dataset"));
    }
    return Status::OK();
  }
  if (!info.status().IsNotFound()) return info.status();
  DatasetInfo d;
  d.name = dataset;
  d.fps = rec.fps;
  d.gaussians = gaussians;
  // The colour cameras, with the calibration's index as id (Point::camera).
  Status bad;
  auto add = [&](int idx) {
    if (idx < 0 || static_cast<size_t>(idx) >= rec.calibration.cameras.size()) {
      bad = Status::InvalidArgument("recording: a camera it names is not in its calibration");
      return;
    }
    d.cameras.push_back(ToCameraInfo(rec.calibration.cameras[static_cast<size_t>(idx)],
                                     static_cast<uint16_t>(idx)));
  };
  if (rec.kind == RecordingKind::kStereo) {
    for (const auto& b : rec.calibration.bricks) add(b.colour);
  } else {  // depth; ply with colour cameras
    for (const auto& f : rec.files) add(rec.calibration.Find(f.camera));
  }
  HVDB_RETURN_IF_ERROR(bad);
  auto created = backend.CreateDataset(d);
  if (!created.ok() && created.status().code() != StatusCode::kAlreadyExists) return created.status();
  return Status::OK();
}

Result<FrameProcessor> FrameProcessor::Make(const Recording& rec, const IngestOptions& options) {
  FrameProcessor p;
  p.rec_ = &rec;
  p.opt_ = options;
  if (p.opt_.stride < 1) return Status::InvalidArgument("stride must be >= 1");
  if (p.opt_.gaussians) HVDB_RETURN_IF_ERROR(CheckFitCameras(rec));
  if (p.opt_.filter == IngestOptions::Filter::kBillboard) {
    if (rec.kind == RecordingKind::kPly)
      return Status::InvalidArgument("the billboard filter works on depth maps: a PLY recording has "
                                     "none; ingest it without --filter billboard");
    if (rec.kind == RecordingKind::kDepth && !(p.opt_.billboard_baseline > 0 && p.opt_.billboard_baseline < 10))
      return Status::InvalidArgument(
          "the billboard filter works in disparity space: for a depth recording give the sensor's "
          "baseline with --billboard-baseline METRES (a Kinect v1's is 0.075)");
    HVDB_RETURN_IF_ERROR(p.opt_.billboard.Validate());
  }
  if (rec.kind == RecordingKind::kStereo) {
    for (const Brick& b : rec.calibration.bricks) {
      HVDB_ASSIGN_OR_RETURN(Rectification r,
                            PrepareRectification(rec.calibration.cameras[b.left],
                                                 rec.calibration.cameras[b.right]));
      HVDB_RETURN_IF_ERROR(p.opt_.stereo.Validate(r.size));
      p.rect_.push_back(std::make_shared<const Rectification>(std::move(r)));
    }
  }
  if (!p.opt_.object_strokes.empty()) HVDB_RETURN_IF_ERROR(p.FitObjectModels());
  return p;
}

int FrameProcessor::StageThreads() const {
  // The cores of the machine shared by the workers that process frames at once.
  return std::max(1, HardwareThreads() / std::max(1, opt_.workers));
}

int FrameProcessor::window_radius() const {
  const int bb = opt_.filter == IngestOptions::Filter::kBillboard ? opt_.billboard.temporal_radius : 0;
  return std::max(spacetime(), rec_->kind == RecordingKind::kPly ? 0 : bb);
}

int FrameProcessor::spacetime() const {
  if (rec_->kind != RecordingKind::kStereo) return 0;
  return opt_.spacetime >= 0 ? opt_.spacetime : rec_->spacetime;
}

Result<std::vector<Point>> FrameProcessor::Process(const FrameInput& in, FrameReport* rep,
                                                   const std::vector<const FrameInput*>& window,
                                                   size_t centre,
                                                   std::map<uint16_t, PhotoBillboard>* billboards) const {
  const Recording& rec = *rec_;
  const Calibration& cal = rec.calibration;
  std::vector<Point> points;
  if (rec.kind == RecordingKind::kPly) {
    points = in.points;
    rep->points = points.size();
    rep->skipped_invalid = in.skipped_invalid;
    return points;
  }
  PointOptions po;
  po.sigma_c = cal.SigmaC();
  po.normals = opt_.normals;
  po.stride = opt_.stride;
  po.frame = rep->dataset_frame;
  // Camera models (pinhole versions for the depth views) must outlive the colour views below.
  std::vector<CameraModel> colour_models;
  std::vector<cv::Mat> colour_images;
  std::vector<int> colour_ids;  // Point::camera of the points each colour camera made
  // The depth maps the points came from, for the geometric consistency test.
  std::vector<CameraModel> depth_models;
  std::vector<cv::Mat> depth_maps;
  std::vector<uint16_t> depth_ids;
  double valid = 0;
  size_t views = 0;
  // With the billboard filter: the centre frame's billboards with their filtered
  // displacements, stored with the photos once the cleaning below has run.
  struct FilteredBoard {
    uint16_t id;
    Billboard board;
    cv::Mat displacement;
  };
  std::vector<FilteredBoard> filtered_boards;
  // --depth-out: DIR/NNNNNN/<camera>.depth.exr, and with object strokes <camera>.alpha.png.
  auto out_path = [&](const std::string& file) {
    char dir[16];
    std::snprintf(dir, sizeof dir, "%06d", in.index);
    const auto path = std::filesystem::path(opt_.depth_out) / dir;
    std::error_code ec;
    std::filesystem::create_directories(path, ec);
    return (path / file).string();
  };
  auto write_depth = [&](const std::string& camera, const cv::Mat& depth) -> Status {
    if (opt_.depth_out.empty()) return Status::OK();
    return WriteDepthExr(out_path(camera + ".depth.exr"), depth);
  };
  std::vector<const FrameInput*> frames = window;
  if (frames.empty()) frames = {&in}, centre = 0;
  if (centre >= frames.size() || frames[centre] != &in)
    return Status::InvalidArgument("frame window: its centre is not the frame processed");
  const bool billboard = opt_.filter == IngestOptions::Filter::kBillboard;
  const bool segment = billboard && !models_.empty();
  // For the billboard filter, per view (a brick's colour camera, or a depth camera): its
  // camera and depth in every frame of the window within the filter's reach.
  struct ViewDepths {
    std::vector<CameraModel> camera;  // per frame of `frames` (a depth camera may move)
    double scale = 0;                 // d = scale / z
    cv::Mat colour_image;             // the centre frame's, undistorted
    uint16_t id = 0;
    int brick = -1;                   // stereo: the brick (its segmentation model)
    std::vector<cv::Mat> depth;       // per frame; empty: none
    std::vector<cv::Mat> colour;      // per frame, undistorted (with object strokes)
  };
  std::vector<ViewDepths> boards;
  auto within_reach = [&](size_t f) {
    return std::abs(static_cast<int>(f) - static_cast<int>(centre)) <= opt_.billboard.temporal_radius;
  };
  if (rec.kind == RecordingKind::kStereo) {
    const int st = spacetime();
    // Whether frame w of the window has the brick of in.stereo[j] at j.
    auto has_brick = [&](size_t w, size_t j) -> Status {
      const auto& pairs = frames[w]->stereo;
      if (j >= pairs.size() || pairs[j].brick != frames[centre]->stereo[j].brick)
        return Status::InvalidArgument("frame window: frame " + std::to_string(frames[w]->index) +
                                       " lacks brick " + std::to_string(frames[centre]->stereo[j].brick));
      return Status::OK();
    };
    // The brick's rectified pair in frame w of the window.
    auto pair_at = [&](size_t w, size_t j, const Rectification& r, cv::Mat* l, cv::Mat* rr) -> Status {
      HVDB_RETURN_IF_ERROR(has_brick(w, j));
      Rectify(r, frames[w]->stereo[j].left, frames[w]->stereo[j].right, l, rr);
      return Status::OK();
    };
    for (size_t j = 0; j < in.stereo.size(); ++j) {
      const StereoView& v = in.stereo[j];
      const Brick& b = cal.bricks[static_cast<size_t>(v.brick)];
      const Rectification& r = *rect_[static_cast<size_t>(v.brick)];
      auto t0 = Clock::now();
      // The spacetime matcher's window: the same brick's pairs of the frames within `st`.
      std::vector<cv::Mat> lefts, rights;
      size_t st_centre = 0;
      for (size_t w = 0; w < frames.size(); ++w) {
        if (w != centre && (st == 0 || std::abs(static_cast<int>(w) - static_cast<int>(centre)) > st)) continue;
        if (w == centre) st_centre = lefts.size();
        cv::Mat lw, rw;
        HVDB_RETURN_IF_ERROR(pair_at(w, j, r, &lw, &rw));
        lefts.push_back(lw);
        rights.push_back(rw);
      }
      rep->stage_ms["rectify"] += MsSince(t0);
      t0 = Clock::now();
      HVDB_ASSIGN_OR_RETURN(DisparityMap dm,
                            lefts.size() > 1 ? MatchSpacetime(lefts, rights, st_centre, opt_.stereo)
                                             : MatchStereo(lefts[0], rights[0], opt_.stereo));
      rep->stage_ms["stereo"] += MsSince(t0);
      t0 = Clock::now();
      const double fx = r.left.K(0, 0);
      cv::Mat depth = DepthFromDisparity(dm.d, r.baseline, fx, r.doffs);
      cv::Mat sigma = DepthSigmaFromDisparity(dm.d, dm.dx, r.baseline, fx, cal.SigmaC());
      valid += ValidPct(depth);
      ++views;
      const CameraModel colour = Pinhole(cal.cameras[static_cast<size_t>(b.colour)]);
      WarpedDepth w = WarpDepth(r.left, depth, sigma, colour);
      if (opt_.edge_radius > 0) w.depth = RemoveDepthEdges(w.depth, opt_.edge_jump, opt_.edge_radius);
      const cv::Mat colour_image = Undistort(cal.cameras[static_cast<size_t>(b.colour)], v.colour);
      colour_models.push_back(cal.cameras[static_cast<size_t>(b.colour)]);
      colour_images.push_back(v.colour);
      colour_ids.push_back(b.colour);
      if (billboard) {
        // The frames around, matched on their own (single-frame stereo) for the filter.
        ViewDepths bd{std::vector<CameraModel>(frames.size(), colour), colour.K(0, 0) * r.baseline,
                      colour_image, static_cast<uint16_t>(b.colour), v.brick,
                      std::vector<cv::Mat>(frames.size()), std::vector<cv::Mat>(frames.size())};
        bd.depth[centre] = w.depth;
        bd.colour[centre] = colour_image;
        rep->stage_ms["points"] += MsSince(t0);
        for (size_t f = 0; f < frames.size(); ++f) {
          if (f == centre || !within_reach(f)) continue;
          t0 = Clock::now();
          HVDB_RETURN_IF_ERROR(has_brick(f, j));
          HVDB_ASSIGN_OR_RETURN(bd.depth[f], ColourDepth(*frames[f], j));
          if (segment)
            bd.colour[f] = Undistort(cal.cameras[static_cast<size_t>(b.colour)], frames[f]->stereo[j].colour);
          rep->stage_ms["stereo"] += MsSince(t0);
        }
        boards.push_back(std::move(bd));
        continue;
      }
      HVDB_RETURN_IF_ERROR(write_depth(colour.name, w.depth));
      DepthView dv;
      dv.camera = &colour;
      dv.depth = w.depth;
      dv.sigma_z = w.carried;
      dv.colour = colour_image;
      dv.camera_id = static_cast<uint16_t>(b.colour);
      std::vector<Point> pts = PointsFromDepth(dv, po);
      points.insert(points.end(), pts.begin(), pts.end());
      depth_models.push_back(colour);
      depth_maps.push_back(dv.depth);
      depth_ids.push_back(dv.camera_id);
      rep->stage_ms["points"] += MsSince(t0);
    }
  } else {
    // A depth map undistorted (nearest: never blend across edges), mixed pixels dropped.
    auto depth_of = [&](const DepthFrameView& v) {
      cv::Mat d = Undistort(v.model, v.depth, /*nearest=*/true);
      return opt_.edge_radius > 0 ? RemoveDepthEdges(d, opt_.edge_jump, opt_.edge_radius) : d;
    };
    // Without the billboard filter the views are independent: their points are made on all
    // cores at once, then merged in camera order (deterministic).
    struct Made {
      cv::Mat depth, colour;
      std::vector<Point> pts;
    };
    std::vector<Made> made(in.depth.size());
    if (!billboard) {
      auto t0 = Clock::now();
      std::atomic<size_t> next{0};
      auto work = [&] {
        for (size_t j = next++; j < in.depth.size(); j = next++) {
          const DepthFrameView& v = in.depth[j];
          const CameraModel pin = Pinhole(v.model);
          DepthView dv;
          dv.camera = &pin;
          dv.depth = made[j].depth = depth_of(v);
          dv.colour = made[j].colour = Undistort(v.model, v.colour);
          dv.camera_id = static_cast<uint16_t>(v.camera);
          made[j].pts = PointsFromDepth(dv, po);
        }
      };
      std::vector<std::thread> pool;
      const int n = std::min<int>(StageThreads(), static_cast<int>(in.depth.size()));
      for (int t = 1; t < n; ++t) pool.emplace_back(work);
      work();
      for (auto& t : pool) t.join();
      size_t total = points.size();
      for (const Made& m : made) total += m.pts.size();
      points.reserve(total);
      rep->stage_ms["points"] += MsSince(t0);
    }
    for (size_t j = 0; j < in.depth.size(); ++j) {
      const DepthFrameView& v = in.depth[j];
      auto t0 = Clock::now();
      const CameraModel pin = Pinhole(v.model);
      DepthView dv;
      dv.camera = &pin;
      dv.depth = billboard ? depth_of(v) : made[j].depth;
      dv.colour = billboard ? Undistort(v.model, v.colour) : made[j].colour;
      dv.camera_id = static_cast<uint16_t>(v.camera);
      valid += ValidPct(dv.depth);
      ++views;
      if (billboard) {
        // The sensor measures disparity over its baseline: that is the billboard's space.
        ViewDepths bd{std::vector<CameraModel>(frames.size()), pin.K(0, 0) * opt_.billboard_baseline,
                      dv.colour, dv.camera_id, -1, std::vector<cv::Mat>(frames.size()), {}};
        for (size_t f = 0; f < frames.size(); ++f) {
          if (!within_reach(f)) continue;
          const auto& around = frames[f]->depth;
          if (j >= around.size() || around[j].camera != v.camera)
            return Status::InvalidArgument("frame window: frame " + std::to_string(frames[f]->index) +
                                           " lacks camera " + std::to_string(v.camera));
          bd.camera[f] = f == centre ? pin : Pinhole(around[j].model);  // this frame's pose
          bd.depth[f] = f == centre ? dv.depth : depth_of(around[j]);
        }
        boards.push_back(std::move(bd));
        colour_models.push_back(v.model);
        colour_images.push_back(v.colour);
        colour_ids.push_back(v.camera);
        rep->stage_ms["points"] += MsSince(t0);
        continue;
      }
      points.insert(points.end(), made[j].pts.begin(), made[j].pts.end());
      std::vector<Point>().swap(made[j].pts);
      depth_models.push_back(pin);
      depth_maps.push_back(dv.depth);
      depth_ids.push_back(dv.camera_id);
      colour_models.push_back(v.model);
      colour_images.push_back(v.colour);
      colour_ids.push_back(v.camera);
      rep->stage_ms["points"] += MsSince(t0);
    }
  }
  if (billboard && !boards.empty()) {
    // Thesis 6.1-6.2, 6.7: billboards of every brick in every frame, the centre frame's
    // filtered, and points from the filtered billboards.
    auto t0 = Clock::now();
    // With object strokes (6.4): each view cut into the object and the rest over the frames
    // it has, and matted; the mattes are the billboards' alpha. Without: alpha 1.
    std::vector<std::vector<cv::Mat>> alphas(boards.size(), std::vector<cv::Mat>(frames.size()));
    if (segment) {
      for (size_t j = 0; j < boards.size(); ++j) {
        const ViewDepths& bd = boards[j];
        const auto& model = models_[static_cast<size_t>(bd.brick)];
        if (model == nullptr) return Status::Internal("no segmentation model for brick " + std::to_string(bd.brick));
        std::vector<size_t> have;
        std::vector<cv::Mat> cs, ds, ss;
        for (size_t f = 0; f < frames.size(); ++f) {
          if (bd.depth[f].empty()) continue;
          have.push_back(f);
          cs.push_back(bd.colour[f]);
          ds.push_back(bd.depth[f]);
          ss.push_back(frames[f]->index == opt_.strokes_frame ? strokes_[static_cast<size_t>(bd.brick)] : cv::Mat());
        }
        HVDB_ASSIGN_OR_RETURN(std::vector<cv::Mat> labels, SegmentFrames(*model, cs, ds, ss, opt_.segmentation));
        for (size_t k = 0; k < have.size(); ++k) {
          HVDB_ASSIGN_OR_RETURN(alphas[j][have[k]], BayesianMatte(cs[k], labels[k], opt_.matting));
          if (!opt_.depth_out.empty() && have[k] == centre) {
            cv::Mat a8;
            alphas[j][have[k]].convertTo(a8, CV_8U, 255);
            const std::string path = out_path(bd.camera[centre].name + ".alpha.png");
            if (!cv::imwrite(path, a8)) return Status::IOError(path + ": cannot write the matte");
          }
        }
      }
      rep->stage_ms["segment"] += MsSince(t0);
      t0 = Clock::now();
    }
    std::vector<std::vector<Billboard>> bbs(frames.size(), std::vector<Billboard>(boards.size()));
    std::vector<std::vector<const Billboard*>> ptrs(frames.size(),
                                                    std::vector<const Billboard*>(boards.size()));
    for (size_t f = 0; f < frames.size(); ++f) {
      for (size_t j = 0; j < boards.size(); ++j) {
        const ViewDepths& bd = boards[j];
        if (bd.depth[f].empty()) continue;
        // A view with too little depth for a plane has no billboard in that frame.
        auto made = MakeBillboard(bd.camera[f], bd.depth[f], alphas[j][f],
                                  f == centre ? bd.colour_image : cv::Mat(), bd.scale);
        if (!made.ok()) continue;
        bbs[f][j] = std::move(made).value();
        ptrs[f][j] = &bbs[f][j];
      }
    }
    BillboardFilterOptions fo = opt_.billboard;
    if (fo.threads == 0) fo.threads = StageThreads();
    HVDB_ASSIGN_OR_RETURN(std::vector<cv::Mat> filtered, FilterBillboards(ptrs, centre, fo));
    rep->stage_ms["billboard"] += MsSince(t0);
    t0 = Clock::now();
    for (size_t j = 0; j < boards.size(); ++j) {
      const Billboard* bb = ptrs[centre][j];
      if (bb == nullptr) continue;
      DepthView dv;
      dv.camera = &boards[j].camera[centre];
      dv.depth = BillboardDepth(*bb, filtered[j]);
      dv.sigma_z = BillboardDepthSigma(*bb, filtered[j], cal.SigmaC());
      dv.colour = boards[j].colour_image;
      dv.camera_id = boards[j].id;
      HVDB_RETURN_IF_ERROR(write_depth(boards[j].camera[centre].name, dv.depth));
      if (billboards != nullptr) filtered_boards.push_back({boards[j].id, *bb, filtered[j]});
      std::vector<Point> pts = PointsFromDepth(dv, po);
      points.insert(points.end(), pts.begin(), pts.end());
      depth_models.push_back(boards[j].camera[centre]);
      depth_maps.push_back(dv.depth);
      depth_ids.push_back(dv.camera_id);
    }
    rep->stage_ms["points"] += MsSince(t0);
  }
  rep->valid_depth_pct = views ? valid / static_cast<double>(views) : 0;
  // Removes the points a cleaning stage did not keep, counting them.
  auto keep_only = [&](const std::vector<uint8_t>& keep) {
    size_t out = 0;
    for (size_t i = 0; i < points.size(); ++i)
      if (keep[i]) points[out++] = points[i];
    rep->outliers_removed += points.size() - out;
    points.resize(out);
  };
  if (opt_.geometric_consistency && depth_maps.size() > 1 && !points.empty()) {
    auto t0 = Clock::now();
    std::vector<DepthMapView> dm;
    for (size_t i = 0; i < depth_maps.size(); ++i) dm.push_back({&depth_models[i], depth_maps[i], depth_ids[i]});
    GeometricConsistencyOptions go = opt_.geometric;
    if (go.threads == 0) go.threads = StageThreads();
    keep_only(GeometricConsistencyMask(points, dm, go));
    rep->stage_ms["geometry"] += MsSince(t0);
  }
  if (billboards != nullptr && !filtered_boards.empty()) {
    // What the geometric test removed (samples other views see through) leaves the billboards
    // too: a sample is kept where a point of its camera survived at its pixel (or, with a
    // stride, at its block's sample). Photo-consistency is not applied: projective texturing
    // takes colour from the photos where their cameras see the surface, and a billboard with
    // holes where its colour disagreed would let the other views' fragments fill them.
    auto t0 = Clock::now();
    std::map<uint16_t, std::pair<const CameraModel*, cv::Mat>> kept;
    for (const FilteredBoard& fb : filtered_boards)
      kept[fb.id] = {&fb.board.camera, cv::Mat(fb.displacement.size(), CV_8U, cv::Scalar(0))};
    for (const Point& p : points) {
      auto k = kept.find(p.camera);
      if (k == kept.end()) continue;
      const cv::Point2d px = k->second.first->Project(cv::Vec3d(p.x, p.y, p.z));
      cv::Mat& m = k->second.second;
      const int u = static_cast<int>(std::lround(px.x)), v = static_cast<int>(std::lround(px.y));
      if (u >= 0 && v >= 0 && u < m.cols && v < m.rows) m.at<uint8_t>(v, u) = 1;
    }
    const int st = std::max(1, opt_.stride);
    for (FilteredBoard& fb : filtered_boards) {
      const cv::Mat& k = kept[fb.id].second;
      cv::Mat& d = fb.displacement;
      for (int y = 0; y < d.rows; ++y)
        for (int x = 0; x < d.cols; ++x)
          if (!k.at<uint8_t>(y - y % st, x - x % st)) d.at<float>(y, x) = std::numeric_limits<float>::quiet_NaN();
      HVDB_ASSIGN_OR_RETURN((*billboards)[fb.id], EncodeBillboard(fb.board, d));
    }
    rep->stage_ms["billboard"] += MsSince(t0);
  }
  if (opt_.photo_consistency && !points.empty()) {
    auto t0 = Clock::now();
    // Each view is tested at the resolution the points sample it at: with a stride s, a point
    // stands for an s x s block and its splat covers one, so the image is averaged over such
    // blocks (the intrinsics follow the image's size). The same test, s^2 fewer pixels.
    std::vector<ColourView> cv_views;
    for (size_t i = 0; i < colour_models.size(); ++i) {
      cv::Mat image = colour_images[i];
      if (opt_.stride > 1 && !image.empty())
        cv::resize(image, image, cv::Size((image.cols + opt_.stride - 1) / opt_.stride,
                                          (image.rows + opt_.stride - 1) / opt_.stride),
                   0, 0, cv::INTER_AREA);
      cv_views.push_back(ColourView{&colour_models[i], image, colour_ids[i]});
    }
    PhotoConsistencyOptions pc = opt_.photo;
    if (pc.threads == 0) pc.threads = StageThreads();
    keep_only(PhotoConsistencyMask(points, cv_views, pc));
    rep->stage_ms["photo"] += MsSince(t0);
  }
  rep->points = points.size();
  return points;
}

PreparedFrame PrepareFrame(const Recording& rec, const FrameProcessor& proc,
                           const IngestOptions& opt, int i, int lo, int hi,
                           const FrameLoader& load, FrameReport* fr) {
  PreparedFrame d;
  d.index = i;
  auto t0 = Clock::now();
  std::vector<std::shared_ptr<const FrameInput>> loaded;
  for (int w = lo; w <= hi && d.status.ok(); ++w) {
    Result<std::shared_ptr<const FrameInput>> f = load(w);
    if (f.ok()) {
      loaded.push_back(std::move(f).value());
    } else {
      d.status = f.status();
    }
  }
  fr->stage_ms["load"] = MsSince(t0);
  if (!d.status.ok()) return d;
  std::vector<const FrameInput*> window;
  for (const auto& f : loaded) window.push_back(f.get());
  const size_t centre = static_cast<size_t>(i - lo);
  for (const auto& f : loaded) d.bytes += f->bytes_read;
  std::map<uint16_t, PhotoBillboard> billboards;
  Result<std::vector<Point>> points =
      proc.Process(*window[centre], fr, window.size() > 1 ? window : std::vector<const FrameInput*>{},
                   centre, opt.photos ? &billboards : nullptr);
  if (!points.ok()) {
    d.status = points.status();
    return d;
  }
  d.points = std::move(points).value();
  if (opt.photos) {
    auto photos = FramePhotos(rec, *window[centre], &billboards);
    if (!photos.ok()) {
      d.status = photos.status();
      d.points.clear();
      return d;
    }
    d.photos = std::move(photos).value();
  }
  if (opt.gaussians) {
    auto views = FrameFitViews(rec, *window[centre], opt.gaussian.resolution_scale);
    if (!views.ok()) {
      d.status = views.status();
      d.points.clear();
      d.photos.clear();
      return d;
    }
    d.fit_views = std::move(views).value();
  }
  return d;
}

void FitPreparedFrame(GaussianVideoFitter& fitter, PreparedFrame* d, FrameReport* fr) {
  const auto t0 = Clock::now();
  FitReport fit;
  auto cloud = fitter.Fit(d->index, std::move(d->fit_views), d->points, &fit);
  if (cloud.ok()) {
    d->points.clear();
    d->gaussians.emplace();
    formats::CloudToPoints(*cloud, fr->dataset_frame, &d->points, &*d->gaussians);
    fr->fit = fit;
    fr->points = d->points.size();
  } else {
    d->status = cloud.status();
  }
  fr->stage_ms["fit"] = MsSince(t0);
}

Result<uint64_t> CommitFrame(client::Backend& backend, const IngestOptions& opt,
                             PreparedFrame&& d, FrameReport* fr) {
  HVDB_RETURN_IF_ERROR(d.status);
  auto t0 = Clock::now();
  // Photos first: a frame whose points are in is skipped when an ingest resumes, so its
  // photos must be in already.
  for (const Photo& photo : d.photos) HVDB_RETURN_IF_ERROR(backend.PutPhoto(opt.dataset, fr->dataset_frame, photo));
  if (!d.photos.empty()) fr->stage_ms["photos"] = MsSince(t0);
  t0 = Clock::now();
  const uint64_t n = d.points.size();
  auto loaded = n ? backend.BulkLoad(opt.dataset, fr->dataset_frame, std::move(d.points),
                                     d.gaussians ? &*d.gaussians : nullptr)
                  : Result<uint64_t>(uint64_t{0});
  fr->stage_ms["commit"] = MsSince(t0);
  return loaded;
}

}  // namespace hvdb::ingest
