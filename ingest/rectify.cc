#include "ingest/rectify.h"

#include <cmath>
#include <limits>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace hvdb::ingest {

Result<Rectification> PrepareRectification(const CameraModel& left, const CameraModel& right) {
  if (left.size != right.size)
    return Status::InvalidArgument("cameras '" + left.name + "' and '" + right.name +
                                   "' have different image sizes; a stereo pair needs equal ones");
  // Pose of the right camera relative to the left: X_r = R X_l + T.
  const cv::Matx33d R = right.R * left.R.t();
  const cv::Vec3d T = right.T - R * left.T;
  if (cv::norm(T) < 1e-9)
    return Status::InvalidArgument("cameras '" + left.name + "' and '" + right.name +
                                   "' have the same centre: no baseline to triangulate with");
  cv::Mat R1, R2, P1, P2, Q;
  const cv::Mat K1(left.K), K2(right.K), D1(left.dist), D2(right.dist);
  cv::stereoRectify(K1, D1.empty() ? cv::Mat() : D1.reshape(1, 1), K2,
                    D2.empty() ? cv::Mat() : D2.reshape(1, 1), left.size, cv::Mat(R), cv::Mat(T),
                    R1, R2, P1, P2, Q, cv::CALIB_ZERO_DISPARITY, 0);
  // Horizontal rectification puts Tx*f into P2(0,3); a vertical pair puts it into P2(1,3).
  if (std::abs(P2.at<double>(1, 3)) > std::abs(P2.at<double>(0, 3)))
    return Status::InvalidArgument("cameras '" + left.name + "' and '" + right.name +
                                   "' are above each other; hvdb's matcher needs a horizontal pair");
  Rectification r;
  r.size = left.size;
  r.baseline = -P2.at<double>(0, 3) / P2.at<double>(0, 0);
  if (r.baseline <= 0)
    return Status::InvalidArgument("camera '" + right.name + "' is to the LEFT of '" + left.name +
                                   "': left and right are swapped in the calibration");
  r.doffs = P2.at<double>(0, 2) - P1.at<double>(0, 2);
  cv::initUndistortRectifyMap(K1, D1.empty() ? cv::Mat() : D1.reshape(1, 1), R1, P1, left.size,
                              CV_32FC1, r.map_lx, r.map_ly);
  cv::initUndistortRectifyMap(K2, D2.empty() ? cv::Mat() : D2.reshape(1, 1), R2, P2, right.size,
                              CV_32FC1, r.map_rx, r.map_ry);
  r.left.name = left.name + "_rect";
  r.left.size = left.size;
  r.left.K = cv::Matx33d(P1.colRange(0, 3));
  const cv::Matx33d r1(R1);
  r.left.R = r1 * left.R;
  r.left.T = r1 * left.T;
  r.left.reprojection_error = left.reprojection_error;
  return r;
}

void Rectify(const Rectification& rect, const cv::Mat& left, const cv::Mat& right,
             cv::Mat* left_out, cv::Mat* right_out) {
  cv::remap(left, *left_out, rect.map_lx, rect.map_ly, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  cv::remap(right, *right_out, rect.map_rx, rect.map_ry, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
}

cv::Mat DepthFromDisparity(const cv::Mat& disparity, double baseline, double fx, double doffs) {
  cv::Mat z(disparity.size(), CV_32F, cv::Scalar(0));
  for (int y = 0; y < disparity.rows; ++y) {
    const float* d = disparity.ptr<float>(y);
    float* out = z.ptr<float>(y);
    for (int x = 0; x < disparity.cols; ++x) {
      const double dd = d[x] + doffs;
      if (std::isfinite(d[x]) && dd > 1e-3) out[x] = static_cast<float>(baseline * fx / dd);
    }
  }
  return z;
}

CameraModel Pinhole(const CameraModel& camera) {
  CameraModel c = camera;
  c.dist.clear();
  return c;
}

cv::Mat Undistort(const CameraModel& camera, const cv::Mat& image, bool nearest) {
  if (camera.dist.empty()) return image;
  bool any = false;
  for (double d : camera.dist) any |= d != 0;
  if (!any) return image;
  cv::Mat mx, my;
  cv::initUndistortRectifyMap(cv::Mat(camera.K), cv::Mat(camera.dist).reshape(1, 1), cv::Mat(),
                              cv::Mat(camera.K), camera.size, CV_32FC1, mx, my);
  cv::Mat out;
  cv::remap(image, out, mx, my, nearest ? cv::INTER_NEAREST : cv::INTER_LINEAR,
            cv::BORDER_CONSTANT);
  return out;
}

WarpedDepth WarpDepth(const CameraModel& src, const cv::Mat& depth, const cv::Mat& carried,
                      const CameraModel& dst, double max_relative_jump) {
  WarpedDepth out;
  out.depth = cv::Mat(dst.size, CV_32F, cv::Scalar(0));
  if (!carried.empty()) out.carried = cv::Mat(dst.size, CV_32F, cv::Scalar(0));
  const cv::Matx33d Kinv = src.K.inv();
  // src camera -> dst camera: X_d = Rd (Rs^T (X_s - Ts)) + Td
  const cv::Matx33d Rsd = dst.R * src.R.t();
  const cv::Vec3d Tsd = dst.T - Rsd * src.T;
  const cv::Matx33d Kd = dst.K, Kdinv = dst.K.inv();
  const int W = depth.cols, H = depth.rows;
  auto point = [&](int x, int y) {  // source pixel -> 3D in dst camera coordinates
    const double z = depth.at<float>(y, x);
    return Rsd * (Kinv * cv::Vec3d(x * z, y * z, z)) + Tsd;
  };
  auto usable = [&](int x, int y, double z0) {
    if (x < 0 || y < 0 || x >= W || y >= H) return false;
    const double z = depth.at<float>(y, x);
    return z > 0 && std::abs(z - z0) <= max_relative_jump * z0;
  };
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const double z = depth.at<float>(y, x);
      if (!(z > 0)) continue;
      const cv::Vec3d P = point(x, y);
      if (P[2] <= 1e-6) continue;
      // Local plane normal from the neighbours (central or one-sided differences).
      cv::Vec3d n(0, 0, 0);
      const int xa = usable(x + 1, y, z) ? x + 1 : x, xb = usable(x - 1, y, z) ? x - 1 : x;
      const int ya = usable(x, y + 1, z) ? y + 1 : y, yb = usable(x, y - 1, z) ? y - 1 : y;
      if (xa != xb && ya != yb) {
        n = (point(xa, y) - point(xb, y)).cross(point(x, ya) - point(x, yb));
      }
      const cv::Vec3d p = Kd * P;
      const double u = p[0] / p[2], v = p[1] / p[2];
      // The 2x2 destination pixels around the projection (the source and destination samplings
      // are similar in density for a brick's cameras; a 2x2 splat closes the gaps between them).
      // Pixels at a depth edge (no plane) go to the nearest pixel only, so silhouettes are not
      // dilated onto the background behind them.
      const bool edge = cv::norm(n) == 0;
      const int u0 = edge ? static_cast<int>(std::lround(u)) : static_cast<int>(std::floor(u));
      const int v0 = edge ? static_cast<int>(std::lround(v)) : static_cast<int>(std::floor(v));
      for (int dv = 0; dv <= (edge ? 0 : 1); ++dv) {
        for (int du = 0; du <= (edge ? 0 : 1); ++du) {
          const int uu = u0 + du, vv = v0 + dv;
          if (uu < 0 || vv < 0 || uu >= dst.size.width || vv >= dst.size.height) continue;
          double zd = P[2];
          if (cv::norm(n) > 0) {  // intersect the pixel's ray with the plane through P
            const cv::Vec3d ray = Kdinv * cv::Vec3d(uu, vv, 1);
            const double denom = n.dot(ray);
            if (std::abs(denom) > 1e-9) {
              const double t = n.dot(P) / denom;  // ray(t) = t * ray, ray z = 1
              // Keep the plane estimate only near P (grazing planes extrapolate badly).
              if (t > 0 && std::abs(t - P[2]) < 0.02 * P[2]) zd = t;
            }
          }
          float& cur = out.depth.at<float>(vv, uu);
          if (cur == 0 || zd < cur) {
            cur = static_cast<float>(zd);
            if (!carried.empty()) out.carried.at<float>(vv, uu) = carried.at<float>(y, x);
          }
        }
      }
    }
  }
  return out;
}

}  // namespace hvdb::ingest
