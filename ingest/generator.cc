#include "ingest/generator.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <limits>
#include <numbers>
#include <system_error>
#include <thread>
#include <utility>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>

namespace hvdb::ingest {

namespace {

namespace fs = std::filesystem;

// ---- Counter-based randomness: a value is a pure function of (seed, purpose, indices), so the
// output does not depend on thread scheduling or on the order things are generated in.

uint64_t SplitMix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

uint64_t Hash(uint64_t a, uint64_t b, uint64_t c = 0, uint64_t d = 0, uint64_t e = 0) {
  uint64_t h = SplitMix(a);
  h = SplitMix(h ^ b);
  h = SplitMix(h ^ c);
  h = SplitMix(h ^ d);
  return SplitMix(h ^ e);
}

double U01(uint64_t h) { return (static_cast<double>(h >> 11) + 0.5) * 0x1.0p-53; }  // (0, 1)
double Uniform(uint64_t h, double lo, double hi) { return lo + (hi - lo) * U01(h); }

double Gauss(uint64_t h) {  // Box-Muller on the two 32-bit halves of h
  const double u1 = (static_cast<double>(h >> 32) + 0.5) * 0x1.0p-32;
  const double u2 = (static_cast<double>(h & 0xffffffffULL) + 0.5) * 0x1.0p-32;
  return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * std::numbers::pi * u2);
}

// Purposes, so that different uses of the seed never share a stream.
enum Purpose : uint64_t {
  kRig = 1,
  kSceneLayout = 2,
  kTexture = 3,
  kPattern = 4,
  kNoise = 5,
};

// A cheap lattice hash for textures (one mixing round; textures need no stream quality).
uint64_t LatticeHash(uint64_t key, int64_t x, int64_t y, int64_t z = 0) {
  return SplitMix(key ^ (static_cast<uint64_t>(x) * 0x9e3779b97f4a7c15ULL) ^
                  (static_cast<uint64_t>(y) * 0xc2b2ae3d27d4eb4fULL) ^
                  (static_cast<uint64_t>(z) * 0x165667b19e3779f9ULL));
}

// Smooth 3D value noise in [0, 1] (trilinear over a hashed lattice, smoothstep weights).
double ValueNoise(const cv::Vec3d& p, uint64_t key) {
  const double fx = std::floor(p[0]), fy = std::floor(p[1]), fz = std::floor(p[2]);
  const auto ix = static_cast<int64_t>(fx), iy = static_cast<int64_t>(fy),
             iz = static_cast<int64_t>(fz);
  auto s = [](double t) { return t * t * (3 - 2 * t); };
  const double tx = s(p[0] - fx), ty = s(p[1] - fy), tz = s(p[2] - fz);
  auto lat = [&](int64_t dx, int64_t dy, int64_t dz) {
    return U01(LatticeHash(key, ix + dx, iy + dy, iz + dz));
  };
  auto lerp = [](double a, double b, double t) { return a + (b - a) * t; };
  const double x00 = lerp(lat(0, 0, 0), lat(1, 0, 0), tx), x10 = lerp(lat(0, 1, 0), lat(1, 1, 0), tx);
  const double x01 = lerp(lat(0, 0, 1), lat(1, 0, 1), tx), x11 = lerp(lat(0, 1, 1), lat(1, 1, 1), tx);
  return lerp(lerp(x00, x10, ty), lerp(x01, x11, ty), tz);
}

double Fbm(const cv::Vec3d& p, uint64_t key) {
  return (2.0 * ValueNoise(p, key) + ValueNoise(p * 2.7, key + 1)) / 3.0;
}

// The same on a plane (floor, wall): half the lattice look-ups.
double ValueNoise2(double px, double py, uint64_t key) {
  const double fx = std::floor(px), fy = std::floor(py);
  const auto ix = static_cast<int64_t>(fx), iy = static_cast<int64_t>(fy);
  auto s = [](double t) { return t * t * (3 - 2 * t); };
  const double tx = s(px - fx), ty = s(py - fy);
  auto lat = [&](int64_t dx, int64_t dy) { return U01(LatticeHash(key, ix + dx, iy + dy)); };
  const double a = lat(0, 0) + (lat(1, 0) - lat(0, 0)) * tx;
  const double b = lat(0, 1) + (lat(1, 1) - lat(0, 1)) * tx;
  return a + (b - a) * ty;
}

double Fbm2(double px, double py, uint64_t key) {
  return (2.0 * ValueNoise2(px, py, key) + ValueNoise2(px * 2.7, py * 2.7, key + 1)) / 3.0;
}

cv::Vec3d Rgb(double r, double g, double b) { return {b, g, r}; }  // albedos are stored BGR

cv::Vec3d Mix(const cv::Vec3d& a, const cv::Vec3d& b, double t) { return a + (b - a) * t; }

double Luminance(const cv::Vec3d& bgr) { return 0.114 * bgr[0] + 0.587 * bgr[1] + 0.299 * bgr[2]; }

int64_t FloorDiv(double v, double cell) { return static_cast<int64_t>(std::floor(v / cell)); }

// ---- Scene layout (metres, y up). The floor and wall are finite rectangles so that cameras
// on the outer bricks see past their edges (background pixels, depth +inf).
constexpr double kHalfWidth = 2.0;   // floor and wall span x in [-2, 2]
constexpr double kFloorFront = 1.5;  // floor spans z in [kWallZ, 1.5]
constexpr double kWallTop = 1.0;     // wall spans y in [kFloorY, 1.0]
constexpr double kBoxSpeed = 0.4;    // m/s along x
constexpr double kBoxMinX = -0.75, kBoxMaxX = 0.75;

// ---- Rig (thesis 4.1: two grey cameras, a colour camera and a projector per brick).
constexpr double kArcRadius = 2.7, kRigHeight = 0.4;
const cv::Vec3d kLookAt{0, -0.2, 0};
constexpr double kHalfFovDeg = 25;        // horizontal half field of view of the cameras
constexpr double kColourAbove = 0.07;     // colour camera above the brick centre (m)
constexpr double kProjectorBelow = 0.09;  // projector below it: its shadows are visible
// Lighting of the grey images (thesis 3.4: overlapping projections add).
constexpr double kAmbient = 0.12, kProjectorGain = 0.45;
constexpr double kColourLight = 0.9;  // uniform light of the colour images

double Deg(double d) { return d * std::numbers::pi / 180.0; }

cv::Matx33d SmallRotation(uint64_t key, double max_deg) {
  cv::Vec3d rvec(Deg(Uniform(Hash(key, 1), -max_deg, max_deg)),
                 Deg(Uniform(Hash(key, 2), -max_deg, max_deg)),
                 Deg(Uniform(Hash(key, 3), -max_deg, max_deg)));
  cv::Matx33d r;
  cv::Rodrigues(rvec, r);
  return r;
}

// World -> camera rotation looking from `eye` to `target`, OpenCV axes, world +y up.
cv::Matx33d LookAt(const cv::Vec3d& eye, const cv::Vec3d& target) {
  const cv::Vec3d forward = cv::normalize(target - eye);
  const cv::Vec3d right = cv::normalize(forward.cross(cv::Vec3d(0, 1, 0)));
  const cv::Vec3d down = forward.cross(right);
  return {right[0], right[1], right[2], down[0], down[1], down[2], forward[0], forward[1], forward[2]};
}

struct BrickPose {
  cv::Vec3d centre;
  cv::Matx33d R;  // world -> brick
};

BrickPose BrickAt(int k, int bricks) {
  const double span = std::min(30.0 * (bricks - 1), 140.0);
  const double angle = bricks == 1 ? 0.0 : -span / 2 + span * k / (bricks - 1);
  BrickPose p;
  p.centre = {kArcRadius * std::sin(Deg(angle)), kRigHeight, kArcRadius * std::cos(Deg(angle))};
  p.R = LookAt(p.centre, kLookAt);
  return p;
}

CameraModel MakeCamera(const GeneratorOptions& o, std::string name, const cv::Vec3d& centre,
                       const cv::Matx33d& R, uint64_t key) {
  CameraModel c;
  c.name = std::move(name);
  c.size = {o.width, o.height};
  // Every camera slightly different, as real ones are after calibration.
  const double fx = 0.5 * o.width / std::tan(Deg(kHalfFovDeg)) * (1 + Uniform(Hash(key, 10), -0.01, 0.01));
  const double fy = fx * (1 + Uniform(Hash(key, 11), -0.002, 0.002));
  const double cx = (o.width - 1) / 2.0 + Uniform(Hash(key, 12), -0.01, 0.01) * o.width;
  const double cy = (o.height - 1) / 2.0 + Uniform(Hash(key, 13), -0.01, 0.01) * o.height;
  c.K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
  // k1 k2 p1 p2 k3. Without distortion all zeros rather than none: the same camera, and
  // SaveCalibration writes an explicit dist row either way.
  c.dist.assign(5, 0.0);
  if (o.distortion) {
    c.dist = {-0.06 + Uniform(Hash(key, 20), -0.02, 0.02), 0.02 + Uniform(Hash(key, 21), -0.01, 0.01),
              Uniform(Hash(key, 22), -0.0008, 0.0008), Uniform(Hash(key, 23), -0.0008, 0.0008), 0.0};
  }
  c.R = R;
  c.T = -(R * centre);
  c.reprojection_error = kGeneratorReprojectionError;
  return c;
}

// A projector: a distortion-free pinhole at the brick throwing a binary vertical stripe pattern
// (one value per projector column).
struct Projector {
  cv::Vec3d centre;
  cv::Matx33d R;
  double f = 0, cx = 0, cy = 0;
  int width = 0, height = 0;
  std::vector<uint8_t> pattern;
};

Projector MakeProjector(const GeneratorOptions& o, int brick, int frame) {
  const BrickPose pose = BrickAt(brick, o.bricks);
  Projector p;
  p.R = pose.R;
  p.centre = pose.centre + cv::Vec3d(pose.R(1, 0), pose.R(1, 1), pose.R(1, 2)) * kProjectorBelow;
  // One projector pixel covers about two camera pixels: stripes of 1-4 projector pixels are
  // 2-8 camera pixels wide, fine enough for matching windows, coarse enough to resolve.
  p.f = 0.5 * (0.5 * o.width / std::tan(Deg(kHalfFovDeg)));
  p.width = static_cast<int>(std::ceil(2 * p.f * std::tan(Deg(34))));
  p.height = static_cast<int>(std::ceil(2 * p.f * std::tan(Deg(28))));
  p.cx = p.width / 2.0;
  p.cy = p.height / 2.0;
  // Random stripe widths 1-4, alternating black and white, new for every brick and frame
  // (thesis 3.4: random, non-periodic patterns; temporally changing ones help spacetime stereo).
  p.pattern.resize(static_cast<size_t>(p.width));
  const uint64_t key = Hash(o.seed, kPattern, static_cast<uint64_t>(brick), static_cast<uint64_t>(frame));
  uint8_t value = static_cast<uint8_t>(Hash(key, 0) & 1);
  size_t i = 0;
  for (uint64_t k = 1; i < p.pattern.size(); ++k, value ^= 1) {
    const size_t w = 1 + Hash(key, k) % 4;
    for (size_t j = 0; j < w && i < p.pattern.size(); ++j) p.pattern[i++] = value;
  }
  return p;
}

bool AllZero(const std::vector<double>& v) {
  return std::all_of(v.begin(), v.end(), [](double x) { return x == 0; });
}

// Inverse of the Brown-Conrady distortion of CameraModel::Project (k1 k2 p1 p2 k3) by Newton,
// starting from `guess` (a neighbouring sample's solution converges in one or two steps).
cv::Vec2d Undistort(const std::vector<double>& dist, double xd, double yd, cv::Vec2d guess,
                    double tolerance) {
  if (dist.empty()) return {xd, yd};
  const double k1 = dist[0], k2 = dist.size() > 1 ? dist[1] : 0;
  const double p1 = dist.size() > 2 ? dist[2] : 0, p2 = dist.size() > 3 ? dist[3] : 0;
  const double k3 = dist.size() > 4 ? dist[4] : 0;
  double x = guess[0], y = guess[1];
  tolerance *= 1 + std::abs(xd) + std::abs(yd);  // relative: rounding grows with the coordinates
  for (int it = 0; it < 30; ++it) {
    const double r2 = x * x + y * y;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double fx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd;
    const double fy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd;
    if (std::abs(fx) + std::abs(fy) < tolerance) break;
    const double dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2);  // d radial / d r2
    const double a = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x;
    const double b = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y;
    const double d = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x;
    const double det = a * d - b * b;
    if (!(std::abs(det) > 1e-12)) break;
    x -= (d * fx - b * fy) / det;
    y -= (a * fy - b * fx) / det;
  }
  return {x, y};
}

// Per-camera constants for casting many rays.
struct RayCaster {
  explicit RayCaster(const CameraModel& c)
      : dist(AllZero(c.dist) ? std::vector<double>{} : c.dist), Rt(c.R.t()), origin(c.Centre()),
        fx(c.K(0, 0)), fy(c.K(1, 1)), skew(c.K(0, 1)), cx(c.K(0, 2)), cy(c.K(1, 2)) {}
  // The normalised (undistorted) image coordinates of pixel (u, v); `guess` is a nearby solution.
  // Tolerance in normalised units: 1e-15 is ~1e-12 pixels (ground truth); image samples
  // need far less.
  cv::Vec2d Normalised(double u, double v, const cv::Vec2d* guess = nullptr,
                       double tolerance = 1e-15) const {
    const double yd = (v - cy) / fy, xd = (u - cx - skew * yd) / fx;
    return Undistort(dist, xd, yd, guess ? *guess : cv::Vec2d(xd, yd), tolerance);
  }
  // Not unit length (the renderer needs only hit points): camera z = 1 along it.
  Ray FromNormalised(const cv::Vec2d& n) const { return {origin, Rt * cv::Vec3d(n[0], n[1], 1.0)}; }
  Ray At(double u, double v) const {
    const Ray r = FromNormalised(Normalised(u, v));
    return {r.origin, cv::normalize(r.dir)};
  }
  std::vector<double> dist;
  cv::Matx33d Rt;
  cv::Vec3d origin;
  double fx, fy, skew, cx, cy;
};

template <typename Fn>
void ParallelRows(int rows, Fn&& fn) {
  const int threads = std::clamp(static_cast<int>(std::thread::hardware_concurrency()), 1, 16);
  std::atomic<int> next{0};
  auto work = [&] {
    for (int r; (r = next.fetch_add(1)) < rows;) fn(r);
  };
  std::vector<std::thread> pool;
  for (int i = 1; i < threads; ++i) pool.emplace_back(work);
  work();
  for (auto& t : pool) t.join();
}

uint8_t ToByte(double v) { return static_cast<uint8_t>(std::clamp(v, 0.0, 255.0) + 0.5); }

struct CameraImages {
  cv::Mat image;   // CV_8U grey or CV_8UC3 BGR
  cv::Mat depth;   // CV_32F camera z at the pixel centre, +inf for none
  cv::Mat object;  // CV_8U object id at the pixel centre
};

// Ray-casts one camera with supersample^2 rays per pixel. Grey cameras see the projectors'
// stripes; colour cameras see the albedo under uniform light.
CameraImages RenderCamera(const SyntheticScene& scene, const CameraModel& cam, bool grey,
                          const std::vector<Projector>& projectors, const GeneratorOptions& o,
                          int frame, int camera_index) {
  const int w = cam.size.width, h = cam.size.height, ss = o.supersample;
  CameraImages out;
  out.image = cv::Mat(h, w, grey ? CV_8UC1 : CV_8UC3);
  out.depth = cv::Mat(h, w, CV_32FC1);
  out.object = cv::Mat(h, w, CV_8UC1);
  const RayCaster caster(cam);
  std::vector<double> offsets(static_cast<size_t>(ss));
  for (int i = 0; i < ss; ++i) offsets[static_cast<size_t>(i)] = (i + 0.5) / ss - 0.5;
  const uint64_t noise_key = Hash(o.seed, kNoise, static_cast<uint64_t>(frame), static_cast<uint64_t>(camera_index));
  const double inv = 1.0 / (ss * ss);

  // Light reaching a surface point from the projectors (thesis 3.4: overlapping projections add).
  auto irradiance = [&](const cv::Vec3d& p, const cv::Vec3d& n) {
    double e = kAmbient;
    for (const Projector& pr : projectors) {
      // Cheap rejections first: facing, frustum, dark stripe; the shadow ray last.
      const cv::Vec3d to = pr.centre - p;
      const double facing = n.dot(to);
      if (facing <= 0) continue;
      const cv::Vec3d pc = pr.R * (p - pr.centre);
      if (pc[2] <= 0) continue;
      const double iz = 1.0 / pc[2];
      const double u = pr.f * pc[0] * iz + pr.cx, v = pr.f * pc[1] * iz + pr.cy;
      if (!(u >= 0 && u < pr.width && v >= 0 && v < pr.height)) continue;
      if (!pr.pattern[static_cast<size_t>(u)]) continue;
      // Shadow ray from just off the surface towards the projector.
      if (scene.Occluded({p + n * 1e-6, to}, 1e-6, 1.0 - 1e-6)) continue;
      e += kProjectorGain * facing / std::sqrt(to.dot(to));  // Lambertian n.l
    }
    return e;
  };

  ParallelRows(h, [&](int v) {
    float* depth_row = out.depth.ptr<float>(v);
    uint8_t* object_row = out.object.ptr<uint8_t>(v);
    uint8_t* image_row = out.image.ptr<uint8_t>(v);
    // Each sample's undistorted position at the previous two pixels: the next pixel's Newton
    // starts from their linear extrapolation and usually needs a single step.
    const size_t nsamples = static_cast<size_t>(ss) * static_cast<size_t>(ss);
    std::vector<cv::Vec2d> guess(nsamples), previous(nsamples);
    for (int sy = 0; sy < ss; ++sy)
      for (int sx = 0; sx < ss; ++sx) {
        const size_t i = static_cast<size_t>(sy * ss + sx);
        // Pixel -1's solution, twice: the first pixel starts from it without extrapolating.
        guess[i] = previous[i] = caster.Normalised(offsets[static_cast<size_t>(sx)] - 1, v + offsets[static_cast<size_t>(sy)]);
      }
    for (int u = 0; u < w; ++u) {
      cv::Vec3d acc(0, 0, 0);
      float centre_depth = std::numeric_limits<float>::infinity();
      int centre_object = kObjectNone;
      auto record_centre = [&](const std::optional<SceneHit>& hit) {
        if (!hit) return;
        centre_depth = static_cast<float>((cam.R * hit->position + cam.T)[2]);
        centre_object = hit->object;
      };
      for (int sy = 0; sy < ss; ++sy) {
        for (int sx = 0; sx < ss; ++sx) {
          const size_t i = static_cast<size_t>(sy * ss + sx);
          const cv::Vec2d start = 2.0 * guess[i] - previous[i];
          previous[i] = guess[i];
          const bool is_centre = ss % 2 == 1 && sx == ss / 2 && sy == ss / 2;
          guess[i] = caster.Normalised(u + offsets[static_cast<size_t>(sx)], v + offsets[static_cast<size_t>(sy)],
                                       &start, is_centre ? 1e-15 : 1e-11);
          const Ray ray = caster.FromNormalised(guess[i]);
          const std::optional<SceneHit> hit = scene.Intersect(ray);
          // For odd ss the middle sample's offset is exactly 0: the pixel centre.
          if (is_centre) record_centre(hit);
          if (!hit) continue;  // the void beyond the scene is black
          const cv::Vec3d albedo = cv::Vec3d(hit->colour_bgr) * (1.0 / 255.0);
          if (grey) {
            acc[0] += Luminance(albedo) * irradiance(hit->position, hit->normal);
          } else {
            acc += albedo * kColourLight;
          }
        }
      }
      // Ground truth at the exact pixel centre.
      if (ss % 2 == 0) {
        const cv::Vec2d near = guess[0];
        record_centre(scene.Intersect(caster.FromNormalised(caster.Normalised(u, v, &near))));
      }
      depth_row[u] = centre_depth;
      object_row[u] = static_cast<uint8_t>(centre_object);
      const uint64_t pixel = static_cast<uint64_t>(v) * static_cast<uint64_t>(w) + static_cast<uint64_t>(u);
      const int channels = grey ? 1 : 3;
      for (int c = 0; c < channels; ++c) {
        const double noise = o.noise_sigma > 0 ? o.noise_sigma * Gauss(LatticeHash(noise_key, static_cast<int64_t>(pixel), c)) : 0.0;
        image_row[u * channels + c] = ToByte(255.0 * acc[c] * inv + noise);
      }
    }
  });
  return out;
}

Status WritePng(const std::string& path, const cv::Mat& image) {
  try {
    if (cv::imwrite(path, image)) return Status::OK();
  } catch (const cv::Exception& e) {
    return Status::IOError(path + ": cannot write PNG: " + e.what());
  }
  return Status::IOError(path + ": cannot write PNG");
}

// "b<k>_<role>" (appended piecewise: GCC 12 warns falsely on chained string operator+).
std::string CameraName(int brick, const char* role) {
  std::string name = "b";
  name += std::to_string(brick);
  name += '_';
  name += role;
  return name;
}

std::string FrameDir(int frame) {
  char buf[16];
  std::snprintf(buf, sizeof(buf), "%06d", frame);
  return buf;
}

// recording.yml (docs/RECORDING.md). The seed is written as a decimal string: FileStorage
// integers are 32-bit and seeds are 64-bit.
Status WriteRecordingYaml(const GeneratorOptions& o, const std::string& path) {
  try {
    cv::FileStorage fs(path, cv::FileStorage::WRITE | cv::FileStorage::FORMAT_YAML);
    if (!fs.isOpened()) return Status::IOError(path + ": cannot open for writing");
    fs << "format" << "hvdb-recording";
    fs << "version" << 1;
    fs << "kind" << "stereo";
    fs << "frames" << o.frames;
    fs << "fps" << o.fps;
    fs << "first_frame" << 0;
    // Its stripe patterns change every frame: a spacetime window of one frame on either side.
    if (o.frames > 1) fs << "spacetime" << 1;
    fs << "generator" << "{";
    fs << "name" << "hvdb-ingest generate";
    fs << "seed" << std::to_string(o.seed);
    fs << "bricks" << o.bricks;
    fs << "width" << o.width;
    fs << "height" << o.height;
    fs << "distortion" << static_cast<int>(o.distortion);
    fs << "supersample" << o.supersample;
    fs << "noise_sigma" << o.noise_sigma;
    fs << "baseline" << o.baseline;
    fs << "ground_truth" << "groundtruth";
    fs << "}";
    fs.release();
  } catch (const cv::Exception& e) {
    return Status::IOError(path + ": " + e.what());
  }
  return Status::OK();
}

Status MakeDir(const std::string& path) {
  std::error_code ec;
  fs::create_directories(path, ec);
  if (ec) return Status::IOError(path + ": cannot create directory: " + ec.message());
  return Status::OK();
}

}  // namespace

// ---------------------------------------------------------------- options

Status GeneratorOptions::Validate() const {
  auto range = [](const char* name, const std::string& allowed) {
    return Status::InvalidArgument(std::string("generator option ") + name + " must be " + allowed);
  };
  if (bricks < 1 || bricks > 16) return range("bricks", "1..16");
  if (width < 16 || width > 4096) return range("width", "16..4096 pixels");
  if (height < 16 || height > 4096) return range("height", "16..4096 pixels");
  if (frames < 1 || frames > 100000) return range("frames", "1..100000");
  if (!(fps > 0 && fps <= 1000)) return range("fps", "in (0, 1000]");
  if (supersample < 1 || supersample > 8) return range("supersample", "1..8 rays per pixel and axis");
  if (!(noise_sigma >= 0 && noise_sigma <= 64)) return range("noise_sigma", "in [0, 64] grey levels");
  if (!(baseline >= 0.01 && baseline <= 1)) return range("baseline", "in [0.01, 1] metres");
  if (!(realtime_fps >= 0 && realtime_fps <= 1000)) return range("realtime", "in [0, 1000] fps");
  return Status::OK();
}

// ---------------------------------------------------------------- scene

SyntheticScene::SyntheticScene(uint64_t seed, int frame, double fps)
    : texture_key_(Hash(seed, kTexture)) {
  const uint64_t key = Hash(seed, kSceneLayout);
  auto jitter = [&](uint64_t i, double a) { return Uniform(Hash(key, i), -a, a); };
  // Three spheres resting on the floor, placed with a little seeded jitter.
  spheres_ = {
      {{-0.55 + jitter(1, 0.05), kFloorY + 0.30, -0.35 + jitter(2, 0.05)}, 0.30,
       Rgb(0.85, 0.25, 0.15), Rgb(0.95, 0.70, 0.20)},
      {{0.55 + jitter(3, 0.05), kFloorY + 0.25, -0.45 + jitter(4, 0.05)}, 0.25,
       Rgb(0.15, 0.30, 0.85), Rgb(0.30, 0.80, 0.90)},
      {{0.50 + jitter(5, 0.05), kFloorY + 0.18, 0.45 + jitter(6, 0.05)}, 0.18,
       Rgb(0.20, 0.70, 0.20), Rgb(0.90, 0.90, 0.30)},
  };
  // The moving box floats above the floor and moves along x at kBoxSpeed, bouncing between
  // kBoxMinX and kBoxMaxX (linear within any short stretch of frames).
  const double t = frame / fps;
  const double span = kBoxMaxX - kBoxMinX;
  const double start = -0.6 + Uniform(Hash(key, 7), 0, 0.2);
  const double s = std::fmod(start - kBoxMinX + kBoxSpeed * t, 2 * span);
  box_centre_ = {kBoxMinX + (s < span ? s : 2 * span - s), -0.35, 0.25 + jitter(8, 0.05)};
  box_half_ = {0.14, 0.14, 0.14};
  box_colour_ = Rgb(0.80, 0.30, 0.70);
}

cv::Vec3d SyntheticScene::Albedo(int object, const cv::Vec3d& p) const {
  const uint64_t key = texture_key_ + static_cast<uint64_t>(object) * 0x9e3779b97f4a7c15ULL;
  cv::Vec3d c;
  switch (object) {
    case kObjectFloor: {  // checker of 0.2 m tiles, each tile's colour a little different
      const int64_t ix = FloorDiv(p[0], 0.2), iz = FloorDiv(p[2], 0.2);
      const cv::Vec3d base = ((ix + iz) & 1) ? Rgb(0.85, 0.78, 0.60) : Rgb(0.20, 0.55, 0.55);
      const uint64_t tile = LatticeHash(key, ix, iz);
      for (int k = 0; k < 3; ++k) c[k] = base[k] * (0.8 + 0.35 * static_cast<double>((tile >> (16 * k)) & 0xffff) / 65535.0);
      c *= 0.75 + 0.4 * Fbm2(p[0] * 6.0, p[2] * 6.0, key);
      break;
    }
    case kObjectWall: {  // 0.3 m tiles from a palette, with cloudy noise
      static const cv::Vec3d kPalette[] = {Rgb(0.75, 0.35, 0.30), Rgb(0.35, 0.55, 0.75),
                                           Rgb(0.70, 0.65, 0.35), Rgb(0.40, 0.65, 0.40),
                                           Rgb(0.60, 0.45, 0.70), Rgb(0.65, 0.65, 0.65)};
      const int64_t ix = FloorDiv(p[0], 0.3), iy = FloorDiv(p[1], 0.3);
      const uint64_t tile = LatticeHash(key, ix, iy);
      const cv::Vec3d a = kPalette[tile % 6], b = kPalette[(tile >> 32) % 6];
      c = Mix(a, b, Fbm2(p[0] * 5.0, p[1] * 5.0, key)) * (0.7 + 0.5 * ValueNoise2(p[0] * 11.0, p[1] * 11.0, key + 7));
      break;
    }
    case kObjectMoving: {  // fine 5 cm 3D checker
      const int64_t parity = FloorDiv(p[0], 0.05) + FloorDiv(p[1], 0.05) + FloorDiv(p[2], 0.05);
      c = (parity & 1) ? box_colour_ : Rgb(0.92, 0.90, 0.85);
      break;
    }
    default: {
      const size_t i = static_cast<size_t>(object - kObjectFirstSphere);
      if (i < spheres_.size()) {
        c = Mix(spheres_[i].colour_a, spheres_[i].colour_b, Fbm(p * 7.0, key));
      } else {
        c = {0, 0, 0};
      }
    }
  }
  for (int k = 0; k < 3; ++k) c[k] = std::clamp(c[k], 0.04, 0.96);
  return c;
}

std::optional<SceneHit> SyntheticScene::Nearest(const Ray& ray, double t_min, double t_max,
                                                bool any) const {
  const cv::Vec3d& o = ray.origin;
  const cv::Vec3d& d = ray.dir;
  double best = t_max;
  int object = kObjectNone;
  cv::Vec3d normal;
  // Floor rectangle y = kFloorY.
  if (d[1] != 0) {
    const double t = (kFloorY - o[1]) / d[1];
    if (t > t_min && t < best) {
      const double x = o[0] + t * d[0], z = o[2] + t * d[2];
      if (std::abs(x) <= kHalfWidth && z >= kWallZ && z <= kFloorFront) {
        best = t;
        object = kObjectFloor;
        normal = {0, 1, 0};
        if (any) return SceneHit{t, {}, {}, {}, object};
      }
    }
  }
  // Back wall rectangle z = kWallZ.
  if (d[2] != 0) {
    const double t = (kWallZ - o[2]) / d[2];
    if (t > t_min && t < best) {
      const double x = o[0] + t * d[0], y = o[1] + t * d[1];
      if (std::abs(x) <= kHalfWidth && y >= kFloorY && y <= kWallTop) {
        best = t;
        object = kObjectWall;
        normal = {0, 0, 1};
        if (any) return SceneHit{t, {}, {}, {}, object};
      }
    }
  }
  const double dd = d.dot(d);
  for (size_t i = 0; i < spheres_.size(); ++i) {
    const cv::Vec3d oc = o - spheres_[i].centre;
    const double b = oc.dot(d), c = oc.dot(oc) - spheres_[i].radius * spheres_[i].radius;
    const double disc = b * b - dd * c;
    if (disc < 0) continue;
    const double sq = std::sqrt(disc);
    double t = (-b - sq) / dd;
    if (t <= t_min) t = (-b + sq) / dd;  // origin inside or on the sphere
    if (t > t_min && t < best) {
      best = t;
      object = kObjectFirstSphere + static_cast<int>(i);
      normal = cv::normalize(o + d * t - spheres_[i].centre);
      if (any) return SceneHit{t, {}, {}, {}, object};
    }
  }
  {  // The moving box (slabs).
    double t0 = t_min, t1 = best;
    int axis0 = -1, axis1 = -1;
    bool miss = false;
    for (int a = 0; a < 3 && !miss; ++a) {
      const double lo = box_centre_[a] - box_half_[a], hi = box_centre_[a] + box_half_[a];
      if (d[a] == 0) {
        miss = o[a] < lo || o[a] > hi;
        continue;
      }
      double ta = (lo - o[a]) / d[a], tb = (hi - o[a]) / d[a];
      if (ta > tb) std::swap(ta, tb);
      if (ta > t0) {
        t0 = ta;
        axis0 = a;
      }
      if (tb < t1) {
        t1 = tb;
        axis1 = a;
      }
      miss = t0 > t1;
    }
    if (!miss) {
      // Entering face if the origin is outside, else the exit face.
      const bool outside = axis0 >= 0;
      const double t = outside ? t0 : t1;
      const int axis = outside ? axis0 : axis1;
      if (axis >= 0 && t > t_min && t < best) {
        best = t;
        object = kObjectMoving;
        normal = {0, 0, 0};
        normal[axis] = 1;
        if (any) return SceneHit{t, {}, {}, {}, object};
      }
    }
  }
  if (object == kObjectNone) return std::nullopt;
  SceneHit hit;
  hit.t = best;
  hit.position = o + d * best;
  hit.normal = normal.dot(d) > 0 ? -normal : normal;  // face the viewer
  hit.object = object;
  const cv::Vec3d albedo = Albedo(object, hit.position);
  for (int k = 0; k < 3; ++k) hit.colour_bgr[k] = ToByte(255.0 * albedo[k]);
  return hit;
}

std::optional<SceneHit> SyntheticScene::Intersect(const Ray& ray) const {
  return Nearest(ray, 1e-9, std::numeric_limits<double>::infinity(), false);
}

bool SyntheticScene::Occluded(const Ray& ray, double t_min, double t_max) const {
  return Nearest(ray, t_min, t_max, true).has_value();
}

void SyntheticScene::Bounds(cv::Vec3d* lo, cv::Vec3d* hi) const {
  cv::Vec3d l(-kHalfWidth, kFloorY, kWallZ), h(kHalfWidth, kWallTop, kFloorFront);
  auto grow = [&](const cv::Vec3d& c, const cv::Vec3d& r) {
    for (int k = 0; k < 3; ++k) {
      l[k] = std::min(l[k], c[k] - r[k]);
      h[k] = std::max(h[k], c[k] + r[k]);
    }
  };
  for (const Sphere& s : spheres_) grow(s.centre, {s.radius, s.radius, s.radius});
  grow(box_centre_, box_half_);
  if (lo) *lo = l;
  if (hi) *hi = h;
}

// ---------------------------------------------------------------- rig and rays

Ray CameraRay(const CameraModel& camera, cv::Point2d pixel) { return RayCaster(camera).At(pixel.x, pixel.y); }

Calibration GeneratorCalibration(const GeneratorOptions& o) {
  Calibration cal;
  for (int k = 0; k < o.bricks; ++k) {
    const BrickPose pose = BrickAt(k, o.bricks);
    const cv::Vec3d right(pose.R(0, 0), pose.R(0, 1), pose.R(0, 2));
    const cv::Vec3d down(pose.R(1, 0), pose.R(1, 1), pose.R(1, 2));
    auto key = [&](uint64_t camera) { return Hash(o.seed, kRig, static_cast<uint64_t>(k), camera); };
    // Roughly parallel grey cameras, each turned by a fraction of a degree, so that the pair
    // really needs rectification (a few pixels of vertical disparity).
    Brick b;
    b.id = k;
    b.left = static_cast<int>(cal.cameras.size());
    cal.cameras.push_back(MakeCamera(o, CameraName(k, "left"), pose.centre - right * (o.baseline / 2),
                                     SmallRotation(key(0), 0.4) * pose.R, key(0)));
    b.right = static_cast<int>(cal.cameras.size());
    cal.cameras.push_back(MakeCamera(o, CameraName(k, "right"), pose.centre + right * (o.baseline / 2),
                                     SmallRotation(key(1), 0.4) * pose.R, key(1)));
    b.colour = static_cast<int>(cal.cameras.size());
    cal.cameras.push_back(MakeCamera(o, CameraName(k, "colour"), pose.centre - down * kColourAbove,
                                     SmallRotation(key(2), 0.4) * pose.R, key(2)));
    cal.bricks.push_back(b);
  }
  return cal;
}

// ---------------------------------------------------------------- recording

Result<GeneratedRecording> GenerateRecording(const GeneratorOptions& options,
                                             const std::string& out_dir,
                                             const std::function<void(int, int)>& progress) {
  HVDB_RETURN_IF_ERROR(options.Validate());
  if (out_dir.empty()) return Status::InvalidArgument("the output directory is empty");
  {
    std::error_code ec;
    const auto st = fs::status(out_dir, ec);
    if (fs::exists(st)) {
      if (!fs::is_directory(st))
        return Status::AlreadyExists(out_dir + ": exists and is not a directory");
      if (!fs::is_empty(out_dir, ec) || ec)
        return Status::AlreadyExists(out_dir +
                                     ": directory is not empty; generate writes a new recording "
                                     "into an empty or absent directory");
    }
  }
  HVDB_RETURN_IF_ERROR(MakeDir(out_dir));

  GeneratedRecording rec;
  rec.calibration = GeneratorCalibration(options);
  rec.frames = options.frames;
  rec.fps = options.fps;
  HVDB_RETURN_IF_ERROR(rec.calibration.Validate());
  const fs::path root(out_dir);
  // realtime: every file a reader may be waiting for is written under a temporary name and
  // renamed into place whole; a frame's images at start + f / realtime_fps (or when rendered).
  const bool live = options.realtime_fps > 0;
  auto publish = [&](const std::string& path, auto&& write) -> Status {
    if (!live) return write(path);
    const fs::path p(path);
    std::string name = ".";  // appended piecewise: GCC 12 warns falsely on chained operator+
    name += p.stem().string();
    name += ".tmp";
    name += p.extension().string();
    const std::string tmp = (p.parent_path() / name).string();
    HVDB_RETURN_IF_ERROR(write(tmp));
    std::error_code ec;
    fs::rename(tmp, path, ec);
    return ec ? Status::IOError(path + ": cannot rename into place: " + ec.message()) : Status::OK();
  };
  HVDB_RETURN_IF_ERROR(publish((root / "recording.yml").string(),
                               [&](const std::string& p) { return WriteRecordingYaml(options, p); }));
  HVDB_RETURN_IF_ERROR(publish((root / "calibration.yml").string(),
                               [&](const std::string& p) { return SaveCalibration(rec.calibration, p); }));
  const auto start = std::chrono::steady_clock::now();

  for (int f = 0; f < options.frames; ++f) {
    const std::string frame_dir = (root / "frames" / FrameDir(f)).string();
    const std::string gt_dir = (root / "groundtruth" / FrameDir(f)).string();
    HVDB_RETURN_IF_ERROR(MakeDir(frame_dir));
    HVDB_RETURN_IF_ERROR(MakeDir(gt_dir));
    const SyntheticScene scene(options.seed, f, options.fps);
    std::vector<Projector> projectors;
    for (int k = 0; k < options.bricks; ++k) projectors.push_back(MakeProjector(options, k, f));
    std::vector<std::pair<std::string, cv::Mat>> images;  // written together at the frame's time
    for (const Brick& b : rec.calibration.bricks) {
      for (int idx : {b.left, b.right, b.colour}) {
        const CameraModel& cam = rec.calibration.cameras[static_cast<size_t>(idx)];
        const CameraImages img =
            RenderCamera(scene, cam, idx != b.colour, projectors, options, f, idx);
        images.emplace_back(frame_dir + "/" + cam.name + ".png", img.image);
        HVDB_RETURN_IF_ERROR(WriteDepthExr(gt_dir + "/" + cam.name + ".depth.exr", img.depth));
        HVDB_RETURN_IF_ERROR(WritePng(gt_dir + "/" + cam.name + ".object.png", img.object));
      }
    }
    if (live) {
      std::this_thread::sleep_until(start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                std::chrono::duration<double>(f / options.realtime_fps)));
    }
    for (const auto& [path, image] : images)
      HVDB_RETURN_IF_ERROR(publish(path, [&](const std::string& p) { return WritePng(p, image); }));
    if (progress) progress(f + 1, options.frames);
  }
  return rec;
}

}  // namespace hvdb::ingest
