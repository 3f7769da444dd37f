#include "ingest/recording.h"

#include <atomic>
#include <cmath>
#include <functional>
#include <thread>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "formats/ply.h"
#include "ingest/generator.h"  // ReadDepthExr

namespace hvdb::ingest {

namespace fs = std::filesystem;

namespace {

const char* KindName(RecordingKind k) {
  switch (k) {
    case RecordingKind::kStereo: return "stereo";
    case RecordingKind::kDepth: return "depth";
    case RecordingKind::kPly: return "ply";
  }
  return "?";
}

const char* EncodingName(DepthEncoding e) {
  switch (e) {
    case DepthEncoding::kExr: return "exr";
    case DepthEncoding::kPng16: return "png16";
    case DepthEncoding::kInverse8: return "inverse8";
  }
  return "?";
}

std::string ReadString(const cv::FileNode& n, const std::string& def = "") {
  if (n.empty()) return def;
  std::string s;
  n >> s;
  return s;
}

// Reads an image the way hvdb needs it; the error names the file.
Result<cv::Mat> ReadImage(const std::string& path, int flags, const char* what) {
  if (!fs::exists(path)) return Status::NotFound(path + ": missing " + what);
  cv::Mat m = cv::imread(path, flags);
  if (m.empty()) return Status::Corruption(path + ": cannot decode the " + what + " image");
  return m;
}

Status CheckSize(const cv::Mat& m, const cv::Size& want, const std::string& path,
                 const std::string& camera) {
  if (m.size() != want) {
    std::ostringstream o;
    o << path << ": image is " << m.cols << "x" << m.rows << " but calibration of camera '"
      << camera << "' says " << want.width << "x" << want.height
      << " (wrong calibration file, or images of another camera?)";
    return Status::InvalidArgument(o.str());
  }
  return Status::OK();
}

}  // namespace

std::string Recording::Path(const std::string& pattern, int i, const std::string& camera) const {
  std::string out;
  const int frame = SourceFrame(i);
  for (size_t p = 0; p < pattern.size();) {
    if (pattern[p] == '{') {
      const size_t close = pattern.find('}', p);
      if (close != std::string::npos) {
        const std::string key = pattern.substr(p + 1, close - p - 1);
        if (key == "camera") {
          out += camera;
          p = close + 1;
          continue;
        }
        if (key.rfind("frame", 0) == 0) {
          int width = 0;
          if (key.size() > 5 && key[5] == ':') width = std::atoi(key.c_str() + 6);  // {frame:06d}
          char buf[32];
          std::snprintf(buf, sizeof buf, "%0*d", width, frame);
          out += buf;
          p = close + 1;
          continue;
        }
      }
    }
    out += pattern[p++];
  }
  if (!out.empty() && out[0] == '/') return out;
  return (fs::path(dir) / out).string();
}

Result<cv::Matx44d> ReadPoseFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound(path + ": missing pose file");
  cv::Matx44d m;
  for (int i = 0; i < 16; ++i) {
    std::string tok;
    if (!(in >> tok)) return Status::Corruption(path + ": a pose needs 16 numbers (4x4, row-major)");
    char* end = nullptr;
    m.val[i] = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || !std::isfinite(m.val[i]))
      return Status::Corruption(path + ": '" + tok + "' is not a number");
  }
  if (std::abs(m(3, 0)) + std::abs(m(3, 1)) + std::abs(m(3, 2)) > 1e-6 || std::abs(m(3, 3) - 1) > 1e-6)
    return Status::Corruption(path + ": last row of the pose must be 0 0 0 1");
  return m;
}

Result<Recording> OpenRecording(const std::string& dir) {
  const std::string yml = (fs::path(dir) / "recording.yml").string();
  if (!fs::exists(yml))
    return Status::NotFound(yml + ": not a recording (no recording.yml; see docs/RECORDING.md)");
  Recording r;
  r.dir = dir;
  std::string kind;
  try {
    cv::FileStorage f(yml, cv::FileStorage::READ);
    if (!f.isOpened()) return Status::Corruption(yml + ": not an OpenCV FileStorage YAML file");
    if (ReadString(f["format"]) != "hvdb-recording")
      return Status::Corruption(yml + ": 'format' must be \"hvdb-recording\"");
    int version = 0;
    f["version"] >> version;
    if (version != 1) return Status::Unsupported(yml + ": version " + std::to_string(version) + " (this hvdb-ingest reads 1)");
    kind = ReadString(f["kind"]);
    f["frames"] >> r.frames;
    if (!f["fps"].empty()) f["fps"] >> r.fps;
    if (!f["first_frame"].empty()) f["first_frame"] >> r.first_frame;
    if (!f["frame_step"].empty()) f["frame_step"] >> r.frame_step;
    if (kind == "stereo") r.kind = RecordingKind::kStereo;
    else if (kind == "depth") r.kind = RecordingKind::kDepth;
    else if (kind == "ply") r.kind = RecordingKind::kPly;
    else return Status::InvalidArgument(yml + ": kind must be stereo, depth or ply, not '" + kind + "'");
    if (r.kind == RecordingKind::kStereo && !f["spacetime"].empty()) {
      f["spacetime"] >> r.spacetime;
      if (r.spacetime < 0 || r.spacetime > 8) {
        return Status::InvalidArgument(yml + ": spacetime must be 0..8 frames on either side, got " +
                                       std::to_string(r.spacetime));
      }
    }
    if (r.kind == RecordingKind::kStereo && !f["structured_light"].empty()) {
      int sl = 1;
      f["structured_light"] >> sl;
      if (sl != 0 && sl != 1)
        return Status::InvalidArgument(yml + ": structured_light must be 0 or 1, got " + std::to_string(sl));
      r.structured_light = sl == 1;
    }
    if (r.kind == RecordingKind::kPly) {
      r.ply = ReadString(f["ply"]);
      if (r.ply.empty()) r.ply = "frames/{frame:06d}.ply";
      if (!f["ply_scale"].empty()) f["ply_scale"] >> r.ply_scale;
    }
    if (r.kind == RecordingKind::kDepth) {
      const std::string enc = ReadString(f["depth_encoding"], "exr");
      if (enc == "exr") r.depth_encoding = DepthEncoding::kExr;
      else if (enc == "png16") r.depth_encoding = DepthEncoding::kPng16;
      else if (enc == "inverse8") r.depth_encoding = DepthEncoding::kInverse8;
      else return Status::InvalidArgument(yml + ": depth_encoding must be exr, png16 or inverse8");
      if (!f["depth_scale"].empty()) f["depth_scale"] >> r.depth_scale;
      if (!f["depth_invalid"].empty()) {
        r.depth_invalid.clear();
        for (const auto& v : f["depth_invalid"]) r.depth_invalid.push_back(static_cast<int>(v));
      }
      if (!f["z_near"].empty()) f["z_near"] >> r.z_near;
      if (!f["z_far"].empty()) f["z_far"] >> r.z_far;
      if (!f["world_scale"].empty()) f["world_scale"] >> r.world_scale;
    }
    const cv::FileNode cams = f["cameras"];
    if (!cams.empty()) {
      for (const auto& n : cams) {
        CameraFiles cf;
        cf.camera = ReadString(n["name"]);
        cf.colour = ReadString(n["colour"]);
        cf.depth = ReadString(n["depth"]);
        cf.pose = ReadString(n["pose"]);
        cf.left = ReadString(n["left"]);
        cf.right = ReadString(n["right"]);
        r.files.push_back(cf);
      }
    }
  } catch (const cv::Exception& e) {
    return Status::Corruption(yml + ": cannot parse: " + e.what());
  }
  if (r.frames <= 0) return Status::InvalidArgument(yml + ": 'frames' must be positive");
  if (!(r.fps > 0) || r.frame_step <= 0 || r.first_frame < 0)
    return Status::InvalidArgument(yml + ": fps and frame_step must be positive, first_frame >= 0");
  if (r.kind == RecordingKind::kPly) {
    if (!(r.ply_scale > 0)) return Status::InvalidArgument(yml + ": ply_scale must be positive");
    if (r.files.empty()) return r;
    // Colour cameras beside the point clouds (photos for textured renders and --gaussians):
    // calibrated in calibration.yml, in the clouds' units after ply_scale.
    const std::string cal_path = (fs::path(dir) / "calibration.yml").string();
    HVDB_ASSIGN_OR_RETURN(r.calibration, LoadCalibration(cal_path));
    for (auto& cf : r.files) {
      if (r.calibration.Find(cf.camera) < 0)
        return Status::InvalidArgument(yml + ": camera '" + cf.camera + "' is not in calibration.yml");
      if (!cf.depth.empty() || !cf.pose.empty() || !cf.left.empty() || !cf.right.empty())
        return Status::InvalidArgument(yml + ": camera '" + cf.camera +
                                       "': a ply recording's cameras have colour images only");
      if (cf.colour.empty()) cf.colour = "frames/{frame:06d}/{camera}.png";
    }
    return r;
  }
  if (r.depth_encoding == DepthEncoding::kInverse8 && !(r.z_near > 0 && r.z_far > r.z_near))
    return Status::InvalidArgument(yml + ": inverse8 depth needs 0 < z_near < z_far");
  if (!(r.depth_scale > 0) || !(r.world_scale > 0))
    return Status::InvalidArgument(yml + ": depth_scale and world_scale must be positive");
  const std::string cal_path = (fs::path(dir) / "calibration.yml").string();
  HVDB_ASSIGN_OR_RETURN(r.calibration, LoadCalibration(cal_path));
  const Calibration& cal = r.calibration;
  if (r.kind == RecordingKind::kStereo) {
    if (cal.bricks.empty()) return Status::InvalidArgument(cal_path + ": a stereo recording needs bricks");
    // Default patterns: frames/NNNNNN/<camera>.png, one entry per brick.
    std::vector<CameraFiles> given = r.files;
    r.files.clear();
    for (const Brick& b : cal.bricks) {
      CameraFiles cf;
      cf.camera = cal.cameras[b.colour].name;
      cf.left = "frames/{frame:06d}/" + cal.cameras[b.left].name + ".png";
      cf.right = "frames/{frame:06d}/" + cal.cameras[b.right].name + ".png";
      cf.colour = "frames/{frame:06d}/" + cal.cameras[b.colour].name + ".png";
      for (const auto& g : given)
        if (g.camera == cf.camera) {
          if (!g.left.empty()) cf.left = g.left;
          if (!g.right.empty()) cf.right = g.right;
          if (!g.colour.empty()) cf.colour = g.colour;
        }
      r.files.push_back(cf);
    }
  } else {
    if (r.files.empty()) {  // default: every calibrated camera, canonical layout
      for (const auto& c : cal.cameras) {
        CameraFiles cf;
        cf.camera = c.name;
        r.files.push_back(cf);
      }
    }
    const char* ext = r.depth_encoding == DepthEncoding::kExr ? ".depth.exr" : ".depth.png";
    for (auto& cf : r.files) {
      if (cal.Find(cf.camera) < 0)
        return Status::InvalidArgument(yml + ": camera '" + cf.camera + "' is not in calibration.yml");
      if (cf.colour.empty()) cf.colour = "frames/{frame:06d}/{camera}.png";
      if (cf.depth.empty()) cf.depth = std::string("frames/{frame:06d}/{camera}") + ext;
    }
  }
  return r;
}

Status SaveRecording(const Recording& r) {
  const std::string yml = (fs::path(r.dir) / "recording.yml").string();
  try {
    cv::FileStorage f(yml, cv::FileStorage::WRITE);
    if (!f.isOpened()) return Status::IOError(yml + ": cannot write");
    f << "format" << "hvdb-recording" << "version" << 1 << "kind" << KindName(r.kind) << "frames"
      << r.frames << "fps" << r.fps << "first_frame" << r.first_frame << "frame_step" << r.frame_step;
    if (r.kind == RecordingKind::kStereo && r.spacetime > 0) f << "spacetime" << r.spacetime;
    if (r.kind == RecordingKind::kStereo && !r.structured_light) f << "structured_light" << 0;
    if (r.kind == RecordingKind::kPly) {
      if (!r.ply.empty()) f << "ply" << r.ply;
      f << "ply_scale" << r.ply_scale;
    }
    if (r.kind == RecordingKind::kDepth) {
      f << "depth_encoding" << EncodingName(r.depth_encoding) << "depth_scale" << r.depth_scale
        << "depth_invalid" << r.depth_invalid << "world_scale" << r.world_scale;
      if (r.depth_encoding == DepthEncoding::kInverse8) f << "z_near" << r.z_near << "z_far" << r.z_far;
    }
    if (!r.files.empty()) {
      f << "cameras" << "[";
      for (const auto& cf : r.files) {
        f << "{" << "name" << cf.camera;
        if (!cf.colour.empty()) f << "colour" << cf.colour;
        if (!cf.depth.empty()) f << "depth" << cf.depth;
        if (!cf.pose.empty()) f << "pose" << cf.pose;
        if (!cf.left.empty()) f << "left" << cf.left;
        if (!cf.right.empty()) f << "right" << cf.right;
        f << "}";
      }
      f << "]";
    }
  } catch (const cv::Exception& e) {
    return Status::IOError(yml + ": " + e.what());
  }
  return Status::OK();
}

namespace {

Result<cv::Mat> LoadDepth(const Recording& r, const std::string& path, const cv::Size& want,
                          const std::string& camera) {
  cv::Mat depth;
  if (r.depth_encoding == DepthEncoding::kExr) {
    if (!fs::exists(path)) return Status::NotFound(path + ": missing depth map");
    HVDB_ASSIGN_OR_RETURN(depth, ReadDepthExr(path));
    for (int y = 0; y < depth.rows; ++y) {
      float* row = depth.ptr<float>(y);
      for (int x = 0; x < depth.cols; ++x) {
        if (std::isnan(row[x]))
          return Status::Corruption(path + ": NaN depth at pixel (" + std::to_string(x) + ", " +
                                    std::to_string(y) + "); use +inf or 0 for 'no depth'");
        if (std::isinf(row[x]) || row[x] < 0) row[x] = 0;
      }
    }
  } else {
    HVDB_ASSIGN_OR_RETURN(cv::Mat raw, ReadImage(path, cv::IMREAD_ANYDEPTH | cv::IMREAD_GRAYSCALE, "depth"));
    if (r.depth_encoding == DepthEncoding::kPng16 && raw.depth() != CV_16U)
      return Status::InvalidArgument(path + ": depth_encoding png16 needs a 16-bit grey PNG");
    if (r.depth_encoding == DepthEncoding::kInverse8 && raw.depth() != CV_8U)
      return Status::InvalidArgument(path + ": depth_encoding inverse8 needs an 8-bit grey PNG");
    depth.create(raw.size(), CV_32F);
    for (int y = 0; y < raw.rows; ++y) {
      float* out = depth.ptr<float>(y);
      for (int x = 0; x < raw.cols; ++x) {
        const int v = raw.depth() == CV_16U ? raw.at<uint16_t>(y, x) : raw.at<uint8_t>(y, x);
        bool invalid = false;
        for (int bad : r.depth_invalid) invalid |= v == bad;
        if (invalid) {
          out[x] = 0;
        } else if (r.depth_encoding == DepthEncoding::kPng16) {
          out[x] = static_cast<float>(v * r.depth_scale);
        } else {  // MPEG-style inverse depth: v/255 spans 1/z_far .. 1/z_near
          out[x] = static_cast<float>(
              1.0 / (v / 255.0 * (1.0 / r.z_near - 1.0 / r.z_far) + 1.0 / r.z_far));
        }
      }
    }
  }
  HVDB_RETURN_IF_ERROR(CheckSize(depth, want, path, camera));
  return depth;
}

}  // namespace

namespace {

// fn(k) for the cameras k = 0..n-1 on all cores (decoding a camera's images is independent of
// the others'); the first error in camera order.
Status ForEachCamera(size_t n, const std::function<Status(size_t)>& fn) {
  std::vector<Status> st(n);
  std::atomic<size_t> next{0};
  auto work = [&] {
    for (size_t k = next++; k < n; k = next++) st[k] = fn(k);
  };
  const size_t threads = std::min<size_t>(n, std::max(1u, std::thread::hardware_concurrency()));
  std::vector<std::thread> pool;
  for (size_t t = 1; t < threads; ++t) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
  for (const Status& s : st) HVDB_RETURN_IF_ERROR(s);
  return Status::OK();
}

}  // namespace

Result<FrameInput> LoadFrame(const Recording& r, int index, bool skip_invalid) {
  if (index < 0 || index >= r.frames)
    return Status::InvalidArgument("frame " + std::to_string(index) + " is outside the recording (0.." +
                                   std::to_string(r.frames - 1) + ")");
  FrameInput in;
  in.index = index;
  auto size_of = [](const std::string& p) -> uint64_t {
    std::error_code ec;
    auto s = fs::file_size(p, ec);
    return ec ? 0 : s;
  };
  const Calibration& cal = r.calibration;
  if (r.kind == RecordingKind::kPly) {
    const std::string path = r.Path(r.ply, index);
    if (!fs::exists(path)) return Status::NotFound(path + ": missing point cloud of frame " + std::to_string(index));
    formats::ReadOptions o;
    o.scale = r.ply_scale;
    o.frame = static_cast<uint32_t>(index);
    o.force_frame = true;
    o.skip_invalid = skip_invalid;
    formats::ReadStats stats;
    HVDB_ASSIGN_OR_RETURN(in.points, formats::ReadPly(path, o, &stats));
    in.skipped_invalid = stats.skipped_non_finite;
    in.bytes_read += size_of(path);
    // Its colour cameras' photos, as depth views without depth.
    std::vector<DepthFrameView> photos(r.files.size());
    const Status read = ForEachCamera(r.files.size(), [&](size_t k) -> Status {
      const CameraFiles& cf = r.files[k];
      DepthFrameView& v = photos[k];
      v.camera = cal.Find(cf.camera);
      v.model = cal.cameras[static_cast<size_t>(v.camera)];
      v.colour_path = r.Path(cf.colour, index, cf.camera);
      HVDB_ASSIGN_OR_RETURN(v.colour, ReadImage(v.colour_path, cv::IMREAD_COLOR, "colour"));
      return CheckSize(v.colour, v.model.size, v.colour_path, cf.camera);
    });
    HVDB_RETURN_IF_ERROR(read);
    for (DepthFrameView& v : photos) in.bytes_read += size_of(v.colour_path), in.depth.push_back(std::move(v));
    return in;
  }
  if (r.kind == RecordingKind::kStereo) {
    std::vector<StereoView> views(cal.bricks.size());
    std::vector<uint64_t> bytes(cal.bricks.size(), 0);
    const Status loaded = ForEachCamera(cal.bricks.size(), [&](size_t b) -> Status {
      const Brick& brick = cal.bricks[b];
      const CameraFiles& cf = r.files[b];
      StereoView v;
      v.brick = static_cast<int>(b);
      const std::string lp = r.Path(cf.left, index), rp = r.Path(cf.right, index),
                        cp = r.Path(cf.colour, index);
      HVDB_ASSIGN_OR_RETURN(v.left, ReadImage(lp, cv::IMREAD_GRAYSCALE, "left grey"));
      HVDB_ASSIGN_OR_RETURN(v.right, ReadImage(rp, cv::IMREAD_GRAYSCALE, "right grey"));
      HVDB_ASSIGN_OR_RETURN(v.colour, ReadImage(cp, cv::IMREAD_COLOR, "colour"));
      v.colour_path = cp;
      HVDB_RETURN_IF_ERROR(CheckSize(v.left, cal.cameras[brick.left].size, lp, cal.cameras[brick.left].name));
      HVDB_RETURN_IF_ERROR(CheckSize(v.right, cal.cameras[brick.right].size, rp, cal.cameras[brick.right].name));
      HVDB_RETURN_IF_ERROR(CheckSize(v.colour, cal.cameras[brick.colour].size, cp, cal.cameras[brick.colour].name));
      bytes[b] = size_of(lp) + size_of(rp) + size_of(cp);
      views[b] = std::move(v);
      return Status::OK();
    });
    HVDB_RETURN_IF_ERROR(loaded);
    for (size_t b = 0; b < views.size(); ++b) in.bytes_read += bytes[b], in.stereo.push_back(std::move(views[b]));
    return in;
  }
  std::vector<DepthFrameView> views(r.files.size());
  std::vector<uint64_t> bytes(r.files.size(), 0);
  const Status loaded = ForEachCamera(r.files.size(), [&](size_t k) -> Status {
    const CameraFiles& cf = r.files[k];
    DepthFrameView v;
    v.camera = cal.Find(cf.camera);
    v.model = cal.cameras[static_cast<size_t>(v.camera)];
    const std::string cp = r.Path(cf.colour, index, cf.camera), dp = r.Path(cf.depth, index, cf.camera);
    HVDB_ASSIGN_OR_RETURN(v.colour, ReadImage(cp, cv::IMREAD_COLOR, "colour"));
    v.colour_path = cp;
    HVDB_RETURN_IF_ERROR(CheckSize(v.colour, v.model.size, cp, cf.camera));
    HVDB_ASSIGN_OR_RETURN(v.depth, LoadDepth(r, dp, v.model.size, cf.camera));
    if (r.world_scale != 1.0) v.depth *= r.world_scale;
    if (!cf.pose.empty()) {  // camera-to-world per frame: R = Rcw^T, T = -R C
      const std::string pp = r.Path(cf.pose, index, cf.camera);
      HVDB_ASSIGN_OR_RETURN(cv::Matx44d cw, ReadPoseFile(pp));
      cv::Matx33d rcw(cw(0, 0), cw(0, 1), cw(0, 2), cw(1, 0), cw(1, 1), cw(1, 2), cw(2, 0), cw(2, 1), cw(2, 2));
      // Re-orthonormalise: poses in text files carry ~1e-4 rounding, above Validate's tolerance.
      cv::Mat w, u, vt;
      cv::SVD::compute(cv::Mat(rcw), w, u, vt);
      cv::Mat rot = u * vt;
      rcw = cv::Matx33d(rot);
      const cv::Vec3d centre(cw(0, 3) * r.world_scale, cw(1, 3) * r.world_scale, cw(2, 3) * r.world_scale);
      v.model.R = rcw.t();
      v.model.T = -(v.model.R * centre);
      bytes[k] += size_of(pp);
    } else if (r.world_scale != 1.0) {
      v.model.T *= r.world_scale;
    }
    bytes[k] += size_of(cp) + size_of(dp);
    views[k] = std::move(v);
    return Status::OK();
  });
  HVDB_RETURN_IF_ERROR(loaded);
  for (size_t k = 0; k < views.size(); ++k) in.bytes_read += bytes[k], in.depth.push_back(std::move(views[k]));
  return in;
}

}  // namespace hvdb::ingest
