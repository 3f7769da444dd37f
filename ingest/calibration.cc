#include "ingest/calibration.h"

#include <cmath>
#include <filesystem>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::ingest {

cv::Point2d CameraModel::Project(const cv::Vec3d& world, double* z_cam) const {
  const cv::Vec3d c = R * world + T;
  if (z_cam) *z_cam = c[2];
  double x = c[0] / c[2], y = c[1] / c[2];
  if (!dist.empty()) {  // Brown-Conrady, eqs. 3.10-3.11 (OpenCV's order k1 k2 p1 p2 k3)
    const double k1 = dist[0], k2 = dist.size() > 1 ? dist[1] : 0;
    const double p1 = dist.size() > 2 ? dist[2] : 0, p2 = dist.size() > 3 ? dist[3] : 0;
    const double k3 = dist.size() > 4 ? dist[4] : 0;
    const double r2 = x * x + y * y;
    const double radial = 1 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    const double xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
    const double yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
    x = xd;
    y = yd;
  }
  return {K(0, 0) * x + K(0, 1) * y + K(0, 2), K(1, 1) * y + K(1, 2)};
}

render::Camera CameraModel::ToRenderCamera() const {
  render::Camera cam;
  cam.width = static_cast<uint32_t>(size.width);
  cam.height = static_cast<uint32_t>(size.height);
  cam.fx = K(0, 0);
  cam.fy = K(1, 1);
  cam.cx = K(0, 2);
  cam.cy = K(1, 2);
  for (size_t i = 0; i < dist.size() && i < 5; ++i) cam.distortion[i] = dist[i];
  const cv::Matx33d Rt = R.t();  // camera -> world rotation: columns are the camera axes
  const cv::Vec3d o = Centre();
  cam.world_from_camera = {Rt(0, 0), Rt(0, 1), Rt(0, 2), o[0],  //
                           Rt(1, 0), Rt(1, 1), Rt(1, 2), o[1],  //
                           Rt(2, 0), Rt(2, 1), Rt(2, 2), o[2],  //
                           0,        0,        0,        1};
  return cam;
}

Status CameraModel::Validate() const {
  const std::string where = "camera '" + name + "': ";
  if (name.empty()) return Status::InvalidArgument("camera without a name");
  if (size.width <= 0 || size.height <= 0 || size.width > 16384 || size.height > 16384)
    return Status::InvalidArgument(where + "image size must be 1..16384 pixels per side");
  if (!(K(0, 0) > 0) || !(K(1, 1) > 0) || !std::isfinite(K(0, 2)) || !std::isfinite(K(1, 2)) ||
      K(2, 0) != 0 || K(2, 1) != 0 || K(2, 2) != 1)
    return Status::InvalidArgument(where + "K must be [fx s cx; 0 fy cy; 0 0 1] with fx, fy > 0");
  if (!dist.empty() && dist.size() != 4 && dist.size() != 5 && dist.size() != 8)
    return Status::InvalidArgument(where + "distortion needs 4, 5 or 8 coefficients (k1 k2 p1 p2 [k3])");
  for (double d : dist)
    if (!std::isfinite(d)) return Status::InvalidArgument(where + "distortion is not finite");
  const cv::Matx33d should_be_eye = R * R.t();
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      // 1e-4: rotations printed with 6-7 significant digits (most tools) are off by ~1e-6..1e-5.
      if (std::abs(should_be_eye(i, j) - (i == j ? 1.0 : 0.0)) > 1e-4)
        return Status::InvalidArgument(where + "R is not a rotation (R R^T != I)");
  if (cv::determinant(R) < 0) return Status::InvalidArgument(where + "R is a reflection");
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(T[i])) return Status::InvalidArgument(where + "T is not finite");
  if (!(reprojection_error >= 0) || !std::isfinite(reprojection_error))
    return Status::InvalidArgument(where + "reprojection_error must be >= 0");
  return Status::OK();
}

double Calibration::SigmaC() const {
  if (cameras.empty()) return 0;
  double s = 0;
  for (const auto& c : cameras) s += c.reprojection_error;
  return s / static_cast<double>(cameras.size());
}

int Calibration::Find(const std::string& name) const {
  for (size_t i = 0; i < cameras.size(); ++i)
    if (cameras[i].name == name) return static_cast<int>(i);
  return -1;
}

Status Calibration::Validate() const {
  if (cameras.empty()) return Status::InvalidArgument("calibration has no cameras");
  for (size_t i = 0; i < cameras.size(); ++i) {
    HVDB_RETURN_IF_ERROR(cameras[i].Validate());
    for (size_t j = 0; j < i; ++j)
      if (cameras[j].name == cameras[i].name)
        return Status::InvalidArgument("two cameras are named '" + cameras[i].name + "'");
  }
  const int n = static_cast<int>(cameras.size());
  for (const auto& b : bricks) {
    for (int idx : {b.left, b.right, b.colour})
      if (idx < 0 || idx >= n)
        return Status::InvalidArgument("brick " + std::to_string(b.id) +
                                       ": camera index out of range 0.." + std::to_string(n - 1));
    if (b.left == b.right)
      return Status::InvalidArgument("brick " + std::to_string(b.id) +
                                     ": left and right grey cameras are the same");
    if (cameras[b.left].size != cameras[b.right].size)
      return Status::InvalidArgument("brick " + std::to_string(b.id) +
                                     ": the two grey cameras have different image sizes");
  }
  return Status::OK();
}

Result<Calibration> LoadCalibration(const std::string& path) {
  if (!std::filesystem::exists(path)) return Status::NotFound(path + ": no such calibration file");
  Calibration cal;
  try {
    cv::FileStorage fs(path, cv::FileStorage::READ);
    if (!fs.isOpened()) return Status::Corruption(path + ": not an OpenCV FileStorage YAML file");
    const cv::FileNode cams = fs["cameras"];
    if (!cams.isSeq() || cams.size() == 0)
      return Status::Corruption(path + ": 'cameras' must be a non-empty sequence");
    for (const auto& node : cams) {
      CameraModel c;
      node["name"] >> c.name;
      cv::Mat K, dist, R, T;
      node["K"] >> K;
      node["dist"] >> dist;
      node["R"] >> R;
      node["T"] >> T;
      int w = 0, h = 0;
      node["width"] >> w;
      node["height"] >> h;
      c.size = {w, h};
      if (!node["reprojection_error"].empty()) node["reprojection_error"] >> c.reprojection_error;
      if (K.total() != 9 || R.total() != 9 || T.total() != 3)
        return Status::Corruption(path + ": camera '" + c.name +
                                  "' needs K (3x3), R (3x3) and T (3x1) matrices");
      K.convertTo(K, CV_64F);
      R.convertTo(R, CV_64F);
      T.convertTo(T, CV_64F);
      c.K = cv::Matx33d(K.reshape(1, 3));
      c.R = cv::Matx33d(R.reshape(1, 3));
      c.T = cv::Vec3d(T.reshape(1, 3));
      if (!dist.empty()) {
        dist.convertTo(dist, CV_64F);
        dist = dist.reshape(1, 1);
        c.dist.assign(dist.ptr<double>(), dist.ptr<double>() + dist.total());
      }
      cal.cameras.push_back(std::move(c));
    }
    const cv::FileNode bricks = fs["bricks"];
    if (!bricks.empty()) {
      if (!bricks.isSeq()) return Status::Corruption(path + ": 'bricks' must be a sequence");
      for (const auto& node : bricks) {
        Brick b;
        std::string l, r, c;
        node["id"] >> b.id;
        node["left"] >> l;
        node["right"] >> r;
        node["colour"] >> c;
        b.left = cal.Find(l);
        b.right = cal.Find(r);
        b.colour = cal.Find(c);
        if (b.left < 0 || b.right < 0 || b.colour < 0)
          return Status::Corruption(path + ": brick " + std::to_string(b.id) +
                                    " names a camera that is not in 'cameras'");
        cal.bricks.push_back(b);
      }
    }
  } catch (const cv::Exception& e) {
    return Status::Corruption(path + ": cannot parse calibration: " + e.what());
  }
  Status st = cal.Validate();
  if (!st.ok()) return Status::InvalidArgument(path + ": " + st.message());
  return cal;
}

Status SaveCalibration(const Calibration& cal, const std::string& path) {
  HVDB_RETURN_IF_ERROR(cal.Validate());
  try {
    const std::string tmp = path + ".tmp.yml";
    {
      cv::FileStorage fs(tmp, cv::FileStorage::WRITE);
      if (!fs.isOpened()) return Status::IOError(path + ": cannot write");
      fs << "cameras" << "[";
      for (const auto& c : cal.cameras) {
        fs << "{" << "name" << c.name << "width" << c.size.width << "height" << c.size.height
           << "K" << cv::Mat(c.K);
        if (!c.dist.empty()) fs << "dist" << cv::Mat(c.dist, true).reshape(1, 1);
        fs << "R" << cv::Mat(c.R) << "T" << cv::Mat(c.T) << "reprojection_error"
           << c.reprojection_error << "}";
      }
      fs << "]";
      if (!cal.bricks.empty()) {
        fs << "bricks" << "[";
        for (const auto& b : cal.bricks)
          fs << "{" << "id" << b.id << "left" << cal.cameras[b.left].name << "right"
             << cal.cameras[b.right].name << "colour" << cal.cameras[b.colour].name << "}";
        fs << "]";
      }
    }
    std::error_code ec;
    std::filesystem::rename(tmp, path, ec);
    if (ec) return Status::IOError(path + ": " + ec.message());
  } catch (const cv::Exception& e) {
    return Status::IOError(path + ": " + e.what());
  }
  return Status::OK();
}

}  // namespace hvdb::ingest

namespace hvdb::ingest {

Result<CheckerboardResult> CalibrateCheckerboard(const std::vector<std::string>& left,
                                                 const std::vector<std::string>& right,
                                                 const CheckerboardOptions& opt) {
  const bool stereo = !right.empty();
  if (stereo && right.size() != left.size())
    return Status::InvalidArgument("calibrate: " + std::to_string(left.size()) + " left but " +
                                   std::to_string(right.size()) + " right images; give pairs");
  if (opt.pattern.width < 2 || opt.pattern.height < 2 || !(opt.square > 0))
    return Status::InvalidArgument("calibrate: the pattern needs >= 2x2 inner corners and a square > 0");
  std::vector<cv::Point3f> board;
  for (int y = 0; y < opt.pattern.height; ++y)
    for (int x = 0; x < opt.pattern.width; ++x)
      board.emplace_back(static_cast<float>(x * opt.square), static_cast<float>(y * opt.square), 0.f);
  std::vector<std::vector<cv::Point3f>> object;
  std::vector<std::vector<cv::Point2f>> pl, pr;
  cv::Size size;
  CheckerboardResult res;
  auto detect = [&](const std::string& path, std::vector<cv::Point2f>* corners) -> Result<bool> {
    cv::Mat img = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (img.empty()) return Status::NotFound(path + ": cannot read the image");
    if (size.area() == 0) size = img.size();
    if (img.size() != size)
      return Status::InvalidArgument(path + ": image size differs from the first image's");
    if (!cv::findChessboardCorners(img, opt.pattern, *corners,
                                   cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE))
      return false;
    cv::cornerSubPix(img, *corners, {11, 11}, {-1, -1},
                     {cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30, 0.01});
    return true;
  };
  for (size_t i = 0; i < left.size(); ++i) {
    std::vector<cv::Point2f> cl, cr;
    HVDB_ASSIGN_OR_RETURN(bool okl, detect(left[i], &cl));
    bool okr = true;
    if (stereo) {
      HVDB_ASSIGN_OR_RETURN(okr, detect(right[i], &cr));
    }
    if (!okl || !okr) {
      res.skipped.push_back(left[i] + (stereo ? " + " + right[i] : "") + ": board not found");
      continue;
    }
    object.push_back(board);
    pl.push_back(cl);
    if (stereo) pr.push_back(cr);
    res.used.push_back(left[i]);
  }
  if (object.size() < 3)
    return Status::InvalidArgument("calibrate: the " + std::to_string(opt.pattern.width) + "x" +
                                   std::to_string(opt.pattern.height) +
                                   " board was found in only " + std::to_string(object.size()) +
                                   " views; need at least 3 (right --pattern?)");
  auto mono = [&](const std::vector<std::vector<cv::Point2f>>& pts, const std::string& name,
                  double* rms) {
    cv::Mat K, D;
    std::vector<cv::Mat> rv, tv;
    *rms = cv::calibrateCamera(object, pts, size, K, D, rv, tv);
    CameraModel c;
    c.name = name;
    c.size = size;
    c.K = cv::Matx33d(K);
    D = D.reshape(1, 1);
    c.dist.assign(D.ptr<double>(), D.ptr<double>() + std::min<int>(5, static_cast<int>(D.total())));
    c.reprojection_error = *rms;
    return c;
  };
  CameraModel l = mono(pl, opt.left_name, &res.left_rms);
  res.calibration.cameras.push_back(l);
  if (stereo) {
    CameraModel r = mono(pr, opt.right_name, &res.right_rms);
    cv::Mat K1(l.K), D1(l.dist), K2(r.K), D2(r.dist), R, T, E, F;
    D1 = D1.reshape(1, 1);
    D2 = D2.reshape(1, 1);
    res.stereo_rms = cv::stereoCalibrate(object, pl, pr, K1, D1, K2, D2, size, R, T, E, F,
                                         cv::CALIB_FIX_INTRINSIC);
    r.R = cv::Matx33d(R);
    r.T = cv::Vec3d(T.reshape(1, 3));
    r.reprojection_error = res.stereo_rms;
    res.calibration.cameras.push_back(r);
  }
  HVDB_RETURN_IF_ERROR(res.calibration.Validate());
  return res;
}

}  // namespace hvdb::ingest
