#include "formats/gaussian_points.h"

#include <algorithm>
#include <cmath>

namespace hvdb::formats {

void CloudToPoints(const GaussianCloud& cloud, uint32_t frame, std::vector<Point>* points,
                   GaussianColumns* records) {
  const size_t n = cloud.size();
  const size_t rest = cloud.sh_rest_per_splat();
  records->sh_degree = cloud.sh_degree;
  records->antialiased = cloud.antialiased;
  records->values.resize(n * records->stride());
  points->resize(n);
  for (size_t i = 0; i < n; ++i) {
    float* rec = records->record(i);
    rec[kGsOpacity] = cloud.opacity[i];
    std::copy_n(&cloud.scale[3 * i], 3, rec + kGsScale);
    std::copy_n(&cloud.rotation[4 * i], 4, rec + kGsRotation);
    std::copy_n(&cloud.sh_dc[3 * i], 3, rec + kGsDc);
    std::copy_n(cloud.sh_rest.data() + i * rest, rest, rec + kGsRest);
    Point& p = (*points)[i];
    p = Point{};
    p.x = cloud.position[3 * i];
    p.y = cloud.position[3 * i + 1];
    p.z = cloud.position[3 * i + 2];
    p.frame = frame;
    p.cov = cloud.Covariance(i);
    p.flags = kFlagHasCovariance;
    uint8_t* rgb[3] = {&p.r, &p.g, &p.b};
    for (int c = 0; c < 3; ++c) {
      const double v = std::clamp(0.5 + kShC0 * cloud.sh_dc[3 * i + c], 0.0, 1.0);
      *rgb[c] = static_cast<uint8_t>(std::lround(v * 255));
    }
  }
}

GaussianCloud PointsToCloud(std::span<const Point> points, const GaussianColumns& records) {
  GaussianCloud cloud;
  cloud.sh_degree = records.sh_degree;
  cloud.antialiased = records.antialiased;
  cloud.Resize(points.size());
  const size_t rest = cloud.sh_rest_per_splat();
  for (size_t i = 0; i < points.size(); ++i) {
    const float* rec = records.record(i);
    cloud.position[3 * i] = points[i].x;
    cloud.position[3 * i + 1] = points[i].y;
    cloud.position[3 * i + 2] = points[i].z;
    cloud.opacity[i] = rec[kGsOpacity];
    std::copy_n(rec + kGsScale, 3, &cloud.scale[3 * i]);
    std::copy_n(rec + kGsRotation, 4, &cloud.rotation[4 * i]);
    std::copy_n(rec + kGsDc, 3, &cloud.sh_dc[3 * i]);
    std::copy_n(rec + kGsRest, rest, cloud.sh_rest.data() + i * rest);
  }
  return cloud;
}

}  // namespace hvdb::formats
