#include "render/splat.h"

// For HVDB_RENDER_CLONES only (no vector helper is used here; see cpu_renderer.cc on -Wpsabi).
#pragma GCC diagnostic ignored "-Wpsabi"
#include "render/simd.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <mutex>

namespace hvdb::render {

namespace {

using Vec3 = std::array<double, 3>;

Vec3 Sub(const Vec3& a, const Vec3& b) { return {a[0] - b[0], a[1] - b[1], a[2] - b[2]}; }
Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double Dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
double Norm(const Vec3& a) { return std::sqrt(Dot(a, a)); }

bool Finite(double v) { return std::isfinite(v); }

// The camera's viewing direction in the world: R * (0, 0, 1), the third column (eq. 5.15's r).
Vec3 ViewDirection(const std::array<double, 16>& m) { return {m[2], m[6], m[10]}; }

std::mutex g_log_mu;
std::function<void(const std::string&)> g_log_handler;

}  // namespace

Camera Camera::LookAt(const std::array<double, 3>& eye, const std::array<double, 3>& target,
                      const std::array<double, 3>& up, double fov_y_deg, uint32_t width,
                      uint32_t height) {
  Camera c;
  c.width = width;
  c.height = height;
  const double kPi = 3.14159265358979323846;
  double half = std::tan(fov_y_deg * kPi / 360.0);
  c.fy = c.fx = half > 0 ? 0.5 * height / half : 0;  // 0 fails Validate()
  c.cx = 0.5 * width - 0.5;  // pixel centres at integers: the image spans [-0.5, w - 0.5]
  c.cy = 0.5 * height - 0.5;
  Vec3 f = Sub(target, eye);
  double fn = Norm(f);
  Vec3 right = Cross(f, up);
  double rn = Norm(right);
  if (fn == 0 || rn == 0) {
    c.world_from_camera.fill(0);  // eye == target or up parallel to the view: fails Validate()
    return c;
  }
  for (auto& v : f) v /= fn;
  for (auto& v : right) v /= rn;
  Vec3 down = Cross(f, right);  // y points down in the image, so x (right) x y = z (forward)
  // Columns: the camera's x, y, z axes and its centre.
  c.world_from_camera = {right[0], down[0], f[0], eye[0],  //
                         right[1], down[1], f[1], eye[1],  //
                         right[2], down[2], f[2], eye[2],  //
                         0,        0,       0,    1};
  return c;
}

Camera Camera::Resized(uint32_t new_width, uint32_t new_height) const {
  Camera c = *this;
  if (width == 0 || height == 0) return c;
  double sx = static_cast<double>(new_width) / width;
  double sy = static_cast<double>(new_height) / height;
  c.width = new_width;
  c.height = new_height;
  c.fx = fx * sx;
  c.fy = fy * sy;
  // Pixel edges, not centres, scale: the image spans [-0.5, w - 0.5].
  c.cx = (cx + 0.5) * sx - 0.5;
  c.cy = (cy + 0.5) * sy - 0.5;
  return c;
}

Status Camera::Validate() const {
  auto size_ok = [](uint32_t s) { return s >= 1 && s <= kMaxImageSize; };
  if (!size_ok(width) || !size_ok(height)) {
    return Status::InvalidArgument("camera size: " + std::to_string(width) + "x" +
                                   std::to_string(height) + " is outside 1..4096 per side");
  }
  if (!(fx > 0) || !(fy > 0) || !Finite(fx) || !Finite(fy) || !Finite(cx) || !Finite(cy)) {
    return Status::InvalidArgument(
        "camera intrinsics: fx and fy must be positive and fx fy cx "
        "cy finite");
  }
  for (double d : distortion) {
    if (!Finite(d)) return Status::InvalidArgument("camera distortion: values must be finite");
  }
  const auto& m = world_from_camera;
  for (double v : m) {
    if (!Finite(v)) return Status::InvalidArgument("camera pose: values must be finite");
  }
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) {
    return Status::InvalidArgument(
        "camera pose: the last row of world_from_camera must be "
        "0 0 0 1");
  }
  // R^T R = I and det R = +1: a rotation, so that the inverse is the transpose.
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double d = m[i] * m[j] + m[4 + i] * m[4 + j] + m[8 + i] * m[8 + j];
      if (std::abs(d - (i == j ? 1.0 : 0.0)) > 1e-4) {
        return Status::InvalidArgument(
            "camera pose: the rotation part of world_from_camera is "
            "not orthonormal (or look-at had eye == target or up "
            "parallel to the view)");
      }
    }
  }
  Vec3 c0{m[0], m[4], m[8]}, c1{m[1], m[5], m[9]}, c2{m[2], m[6], m[10]};
  if (Dot(Cross(c0, c1), c2) < 0) {
    return Status::InvalidArgument("camera pose: world_from_camera is a reflection (det -1)");
  }
  return Status::OK();
}

const char* RendererKindName(RendererKind kind) {
  switch (kind) {
    case RendererKind::kEgl:
      return "egl";
    case RendererKind::kCpu:
      return "cpu";
    case RendererKind::kAuto:
      break;
  }
  return "auto";
}

Result<RendererKind> ParseRendererKind(const std::string& name) {
  if (name == "auto" || name.empty()) return RendererKind::kAuto;
  if (name == "egl") return RendererKind::kEgl;
  if (name == "cpu") return RendererKind::kCpu;
  return Status::InvalidArgument("renderer: '" + name + "' is not one of auto, egl, cpu");
}

void SetLogHandler(std::function<void(const std::string&)> handler) {
  std::lock_guard<std::mutex> l(g_log_mu);
  g_log_handler = std::move(handler);
}

Status Renderer::RenderInto(std::span<const Point> points, const Camera& camera,
                            const RenderOptions& options, Image* image) {
  HVDB_ASSIGN_OR_RETURN(*image, Render(points, camera, options));
  return Status::OK();
}

Status CheckRenderArguments(const Camera& camera, const RenderOptions& options) {
  return internal::PrepareView(camera, options).status();
}

namespace internal {

void LogWarning(const std::string& message) {
  std::lock_guard<std::mutex> l(g_log_mu);
  if (g_log_handler) {
    g_log_handler(message);
  } else {
    std::fprintf(stderr, "hvdb render: WARNING: %s\n", message.c_str());
  }
}

void LogNote(const std::string& message) {
  std::lock_guard<std::mutex> l(g_log_mu);
  if (g_log_handler) {
    g_log_handler("note: " + message);
  } else {
    std::fprintf(stderr, "hvdb render: %s\n", message.c_str());
  }
}

Result<View> PrepareView(const Camera& camera_in, const RenderOptions& o) {
  if ((o.width == 0) != (o.height == 0)) {
    return Status::InvalidArgument("render size: give both width and height, or neither");
  }
  Camera camera = o.width != 0 ? camera_in.Resized(o.width, o.height) : camera_in;
  HVDB_RETURN_IF_ERROR(camera.Validate());
  if (!(o.cutoff_radius > 0 && o.cutoff_radius <= 10)) {
    return Status::InvalidArgument("cutoff_radius: must be in (0, 10] standard deviations");
  }
  if (!(o.depth_threshold >= 0) || !std::isfinite(o.depth_threshold)) {
    return Status::InvalidArgument("depth_threshold: must be a finite value >= 0 (metres)");
  }
  if (!(o.filter_variance >= 0) || !std::isfinite(o.filter_variance)) {
    return Status::InvalidArgument("filter_variance: must be a finite value >= 0 (pixels^2)");
  }
  if (!(o.splat_scale > 0) || !std::isfinite(o.splat_scale)) {
    return Status::InvalidArgument("splat_scale: must be a finite value > 0");
  }
  if (!(o.default_sigma > 0) || !std::isfinite(o.default_sigma)) {
    return Status::InvalidArgument("default_sigma: must be a finite value > 0 (metres)");
  }
  if (!(o.near_plane > 0) || !std::isfinite(o.near_plane)) {
    return Status::InvalidArgument("near_plane: must be a finite value > 0 (metres)");
  }
  if (!(o.min_view_weight > 0 && o.min_view_weight <= 1)) {
    return Status::InvalidArgument("min_view_weight: must be in (0, 1]");
  }
  for (float b : o.background) {
    if (!std::isfinite(b)) return Status::InvalidArgument("background: values must be finite");
  }
  View v;
  v.width = camera.width;
  v.height = camera.height;
  const auto& m = camera.world_from_camera;
  // camera_from_world = [R^T | -R^T c] for world_from_camera = [R | c].
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) v.rot[i * 3 + j] = static_cast<float>(m[j * 4 + i]);
    v.trans[i] =
        static_cast<float>(-(m[0 * 4 + i] * m[3] + m[1 * 4 + i] * m[7] + m[2 * 4 + i] * m[11]));
  }
  v.fx = static_cast<float>(camera.fx);
  v.fy = static_cast<float>(camera.fy);
  v.cx = static_cast<float>(camera.cx);
  v.cy = static_cast<float>(camera.cy);
  for (int i = 0; i < 5; ++i) {
    v.k[i] = static_cast<float>(camera.distortion[i]);
    v.distorted = v.distorted || camera.distortion[i] != 0;
  }
  // Twice the radius of the farthest image corner: generous for real lenses, and it keeps
  // points far outside the view from folding back in through the polynomial.
  double r2 = 0;
  for (double px : {-0.5, camera.width - 0.5}) {
    for (double py : {-0.5, camera.height - 0.5}) {
      double a = (px - camera.cx) / camera.fx, b = (py - camera.cy) / camera.fy;
      r2 = std::max(r2, a * a + b * b);
    }
  }
  v.max_r2 = static_cast<float>(4 * r2);
  v.near_plane = o.near_plane;
  v.cutoff2 = o.cutoff_radius * o.cutoff_radius;
  v.filter = o.filter_variance;
  v.scale2 = o.splat_scale * o.splat_scale;
  v.default_var = o.default_sigma * o.default_sigma;
  v.depth_threshold = o.depth_threshold;
  return v;
}

std::vector<double> BlendingWeights(const Camera& virtual_camera,
                                    std::span<const SourceCamera> sources) {
  std::vector<double> w(sources.size(), 0.0);
  if (sources.empty()) return w;
  Vec3 r = ViewDirection(virtual_camera.world_from_camera);
  double rn = Norm(r);
  std::vector<double> angle(sources.size());
  double max_angle = 0;
  for (size_t i = 0; i < sources.size(); ++i) {
    Vec3 rv = ViewDirection(sources[i].world_from_camera);
    double n = rn * Norm(rv);
    double c = n > 0 ? std::clamp(Dot(r, rv) / n, -1.0, 1.0) : 1.0;
    angle[i] = std::acos(c);  // eq. 5.15
    max_angle = std::max(max_angle, angle[i]);
  }
  double sum = 0;
  for (size_t i = 0; i < sources.size(); ++i) {
    if (max_angle <= 0) {
      w[i] = 1;  // every camera looks along the virtual one: no preference
    } else if (angle[i] * kMaxPenaltyWeight <= 1) {
      w[i] = kMaxPenaltyWeight;  // eq. 5.16 tends to infinity: clamp to a large finite weight
    } else {
      w[i] = std::min(kMaxPenaltyWeight, (1 - angle[i] / max_angle) / angle[i]);  // eq. 5.16
    }
    sum += w[i];
  }
  for (double& x : w) x = sum > 0 ? x / sum : 1.0 / sources.size();  // eq. 5.17
  return w;
}

std::vector<float> ViewWeightTable(const Camera& virtual_camera, const RenderOptions& o) {
  if (!o.view_dependent) return {};
  std::vector<double> w = BlendingWeights(virtual_camera, o.source_cameras);
  uint16_t max_id = 0;
  for (const SourceCamera& s : o.source_cameras) max_id = std::max(max_id, s.id);
  std::vector<float> table(size_t{max_id} + 1, 1.0f);
  double best = w.empty() ? 0 : *std::max_element(w.begin(), w.end());
  for (size_t i = 0; i < w.size(); ++i) {
    double rel = best > 0 ? w[i] / best : 1.0;
    table[o.source_cameras[i].id] =
        static_cast<float>(std::clamp(rel, static_cast<double>(o.min_view_weight), 1.0));
  }
  return table;
}

const std::array<float, 256>& SrgbTable() {
  static const std::array<float, 256> table = [] {
    std::array<float, 256> t{};
    for (int i = 0; i < 256; ++i) t[i] = SrgbToLinear(static_cast<float>(i) / 255.0f);
    return t;
  }();
  return table;
}

// Built for AVX-512, AVX2+FMA and the baseline like the rasteriser (simd.h): a quarter of a
// 2 M-point render at 1080p is spent here, in chains of dependent multiplies and adds that
// FMA shortens (8 % less CPU per render measured; results differ from the baseline clone's by
// the roundings FMA saves, as the rasteriser's do).
HVDB_RENDER_CLONES
bool ProjectSplat(const Point& p, const View& view, std::span<const float> weights, Splat* out) {
  const float* R = view.rot;
  float xc = R[0] * p.x + R[1] * p.y + R[2] * p.z + view.trans[0];
  float yc = R[3] * p.x + R[4] * p.y + R[5] * p.z + view.trans[1];
  float zc = CameraDepth(view, p);
  if (!(zc >= view.near_plane)) return false;  // also drops NaN
  float inv_z = 1.0f / zc;
  float a = xc * inv_z, b = yc * inv_z;
  // Lens distortion (OpenCV model) and its Jacobian d(a', b') / d(a, b).
  float ad = a, bd = b, j00 = 1, j01 = 0, j10 = 0, j11 = 1;
  if (view.distorted) {
    const float* k = view.k;
    float r2 = a * a + b * b;
    if (!(r2 <= view.max_r2)) return false;
    float radial = 1.0f + r2 * (k[0] + r2 * (k[1] + r2 * k[4]));
    float drad = k[0] + r2 * (2.0f * k[1] + 3.0f * k[4] * r2);
    ad = a * radial + 2.0f * k[2] * a * b + k[3] * (r2 + 2.0f * a * a);
    bd = b * radial + k[2] * (r2 + 2.0f * b * b) + 2.0f * k[3] * a * b;
    j00 = radial + 2.0f * a * a * drad + 2.0f * k[2] * b + 6.0f * k[3] * a;
    j01 = 2.0f * a * b * drad + 2.0f * k[2] * a + 2.0f * k[3] * b;
    j10 = j01;
    j11 = radial + 2.0f * b * b * drad + 6.0f * k[2] * b + 2.0f * k[3] * a;
    if (!(j00 * j11 - j01 * j10 > 0)) return false;  // the polynomial folds here
  }
  float u = view.fx * ad + view.cx;
  float v = view.fy * bd + view.cy;
  // T = K J_dist J_persp W (2x3): the local affine approximation of the projection at the
  // point (Zwicker et al. 2001); J_persp W has rows (R_0 - a R_2) / z and (R_1 - b R_2) / z.
  float p0[3], p1[3], t0[3], t1[3];
  for (int i = 0; i < 3; ++i) {
    p0[i] = (R[i] - a * R[6 + i]) * inv_z;
    p1[i] = (R[3 + i] - b * R[6 + i]) * inv_z;
  }
  for (int i = 0; i < 3; ++i) {
    t0[i] = view.fx * (j00 * p0[i] + j01 * p1[i]);
    t1[i] = view.fy * (j10 * p0[i] + j11 * p1[i]);
  }
  // V: xx xy xz yy yz zz.
  float c[6];
  if (p.flags & kFlagHasCovariance) {
    for (int i = 0; i < 6; ++i) c[i] = p.cov[i];
  } else {
    c[0] = c[3] = c[5] = view.default_var;
    c[1] = c[2] = c[4] = 0;
  }
  float vt0[3] = {c[0] * t0[0] + c[1] * t0[1] + c[2] * t0[2],
                  c[1] * t0[0] + c[3] * t0[1] + c[4] * t0[2],
                  c[2] * t0[0] + c[4] * t0[1] + c[5] * t0[2]};
  float vt1[3] = {c[0] * t1[0] + c[1] * t1[1] + c[2] * t1[2],
                  c[1] * t1[0] + c[3] * t1[1] + c[4] * t1[2],
                  c[2] * t1[0] + c[4] * t1[1] + c[5] * t1[2]};
  // Screen covariance, grown by the level-of-detail scale (8.4), plus the antialiasing
  // filter (the EWA resampling filter's screen-space low-pass part).
  float s00 = (t0[0] * vt0[0] + t0[1] * vt0[1] + t0[2] * vt0[2]) * view.scale2 + view.filter;
  float s01 = (t0[0] * vt1[0] + t0[1] * vt1[1] + t0[2] * vt1[2]) * view.scale2;
  float s11 = (t1[0] * vt1[0] + t1[1] * vt1[1] + t1[2] * vt1[2]) * view.scale2 + view.filter;
  float det = s00 * s11 - s01 * s01;
  if (!(det > 0) || !std::isfinite(det)) return false;
  float ex = std::sqrt(view.cutoff2 * s00), ey = std::sqrt(view.cutoff2 * s11);
  // The ellipse's bounding box, clipped to the image (as the shader's quad is).
  float fx0 = std::max(std::ceil(u - ex), 0.0f);
  float fx1 = std::min(std::floor(u + ex), static_cast<float>(view.width) - 1.0f);
  float fy0 = std::max(std::ceil(v - ey), 0.0f);
  float fy1 = std::min(std::floor(v + ey), static_cast<float>(view.height) - 1.0f);
  if (!(fx0 <= fx1) || !(fy0 <= fy1)) return false;
  out->u = u;
  out->v = v;
  float inv_det = 1.0f / det;
  out->ca = s11 * inv_det;
  out->cb = -s01 * inv_det;
  out->cc = s00 * inv_det;
  out->z = zc;
  // Covariance of depth (row R_2 of the rotation) with the screen position; its regression on
  // the screen offset gives the depth slope: Sigma'^-1 (cov(u, z), cov(v, z)).
  float s02 = (R[6] * vt0[0] + R[7] * vt0[1] + R[8] * vt0[2]) * view.scale2;
  float s12 = (R[6] * vt1[0] + R[7] * vt1[1] + R[8] * vt1[2]) * view.scale2;
  out->dzdx = out->ca * s02 + out->cb * s12;
  out->dzdy = out->cb * s02 + out->cc * s12;
  const auto& srgb = SrgbTable();
  out->r = srgb[p.r];
  out->g = srgb[p.g];
  out->b = srgb[p.b];
  out->w = p.camera < weights.size() ? weights[p.camera] : 1.0f;
  out->x0 = static_cast<int16_t>(fx0);
  out->x1 = static_cast<int16_t>(fx1);
  out->y0 = static_cast<int16_t>(fy0);
  out->y1 = static_cast<int16_t>(fy1);
  return true;
}

std::vector<uint32_t> StableOrder(std::span<const float> keys) {
  const size_t n = keys.size();
  std::vector<uint32_t> order(n), tmp(n);
  std::vector<uint32_t> bits(n);
  for (size_t i = 0; i < n; ++i) {
    uint32_t b;
    std::memcpy(&b, &keys[i], 4);
    // Order-preserving map of IEEE floats to unsigned integers (negatives reversed).
    bits[i] = (b & 0x80000000u) ? ~b : (b | 0x80000000u);
    order[i] = static_cast<uint32_t>(i);
  }
  // LSD radix sort, 11 bits a pass: three passes, each stable.
  for (int shift = 0; shift < 32; shift += 11) {
    std::vector<uint32_t> count(2049, 0);
    for (size_t i = 0; i < n; ++i) ++count[((bits[order[i]] >> shift) & 2047u) + 1];
    for (size_t i = 1; i < count.size(); ++i) count[i] += count[i - 1];
    for (size_t i = 0; i < n; ++i) tmp[count[(bits[order[i]] >> shift) & 2047u]++] = order[i];
    order.swap(tmp);
  }
  return order;
}

}  // namespace internal
}  // namespace hvdb::render
