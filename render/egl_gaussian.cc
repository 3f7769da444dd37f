// The 3DGS rasteriser through EGL (render/egl_gaussian.h). The shaders follow
// gaussian_raster_kernels.h's PrepareGroup (the set-up) and BlendBatch (the per-pixel step),
// in float as the reference, but for the early stop (see the header).
#define GL_GLEXT_PROTOTYPES 1
#include "render/egl_gaussian.h"

#include <GL/glcorearb.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <mutex>
#include <vector>

#include "render/egl_context.h"
#include "render/gaussian_view.h"

namespace hvdb::render {
namespace {

constexpr const char* kVertexShader = R"(#version 430 core
layout(std430, binding = 0) readonly buffer Position { float pos[]; };
layout(std430, binding = 1) readonly buffer Scale { float scl[]; };
layout(std430, binding = 2) readonly buffer Rotation { float rot[]; };
layout(std430, binding = 3) readonly buffer Opacity { float opa[]; };
layout(std430, binding = 4) readonly buffer Dc { float dc[]; };
layout(std430, binding = 5) readonly buffer Rest { float rest[]; };
layout(std430, binding = 6) readonly buffer Order { uint order[]; };
uniform float uRot[9];   // camera-from-world, row-major
uniform vec3 uTrans;     // camera-from-world translation
uniform vec3 uCentre;    // camera centre
uniform vec4 uK;         // fx fy cx cy
uniform vec2 uLim;       // 1.3 tan(half fov)
uniform ivec2 uSize;     // width, height
uniform ivec2 uTiles;    // tiles_x, tiles_y
uniform int uDegree;
uniform bool uAntialiased;
flat out vec3 vConic;
flat out vec2 vCentre;
flat out vec3 vColour;
flat out float vOpacity;
const float kC0 = 0.28209479177387814;
const float kC1 = 0.4886025119029199;
const float kC2[5] = float[](1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
                             -1.0925484305920792, 0.5462742152960396);
const float kC3[7] = float[](-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
                             0.3731763325901154, -0.4570457994644658, 1.445305721320277,
                             -0.5900435899266435);
void cull() { gl_Position = vec4(2.0, 2.0, 2.0, 1.0); }
void main() {
  uint i = order[gl_InstanceID];
  vec3 p = vec3(pos[3u * i], pos[3u * i + 1u], pos[3u * i + 2u]);
  float tx = uRot[0] * p.x + uRot[1] * p.y + uRot[2] * p.z + uTrans.x;
  float ty = uRot[3] * p.x + uRot[4] * p.y + uRot[5] * p.z + uTrans.y;
  float tz = uRot[6] * p.x + uRot[7] * p.y + uRot[8] * p.z + uTrans.z;
  if (!(tz > 0.2)) { cull(); return; }
  vec4 q = vec4(rot[4u * i], rot[4u * i + 1u], rot[4u * i + 2u], rot[4u * i + 3u]);  // w x y z
  float qn = length(q);
  q = qn > 0.0 ? q / qn : vec4(1.0, 0.0, 0.0, 0.0);
  float s0 = exp(min(scl[3u * i], 80.0)), s1 = exp(min(scl[3u * i + 1u], 80.0));
  float s2 = exp(min(scl[3u * i + 2u], 80.0));
  float qw = q.x, qx = q.y, qy = q.z, qz = q.w;
  float M[9] = float[]((1.0 - 2.0 * (qy * qy + qz * qz)) * s0, 2.0 * (qx * qy - qw * qz) * s1,
                       2.0 * (qx * qz + qw * qy) * s2, 2.0 * (qx * qy + qw * qz) * s0,
                       (1.0 - 2.0 * (qx * qx + qz * qz)) * s1, 2.0 * (qy * qz - qw * qx) * s2,
                       2.0 * (qx * qz - qw * qy) * s0, 2.0 * (qy * qz + qw * qx) * s1,
                       (1.0 - 2.0 * (qx * qx + qy * qy)) * s2);
  float S00 = M[0] * M[0] + M[1] * M[1] + M[2] * M[2];
  float S01 = M[0] * M[3] + M[1] * M[4] + M[2] * M[5];
  float S02 = M[0] * M[6] + M[1] * M[7] + M[2] * M[8];
  float S11 = M[3] * M[3] + M[4] * M[4] + M[5] * M[5];
  float S12 = M[3] * M[6] + M[4] * M[7] + M[5] * M[8];
  float S22 = M[6] * M[6] + M[7] * M[7] + M[8] * M[8];
  float invZ = 1.0 / tz;
  float xc = min(uLim.x, max(-uLim.x, tx * invZ)) * tz;
  float yc = min(uLim.y, max(-uLim.y, ty * invZ)) * tz;
  float j00 = uK.x * invZ, j02 = -(uK.x * xc) * (invZ * invZ);
  float j11 = uK.y * invZ, j12 = -(uK.y * yc) * (invZ * invZ);
  vec3 t0 = vec3(j00 * uRot[0] + j02 * uRot[6], j00 * uRot[1] + j02 * uRot[7],
                 j00 * uRot[2] + j02 * uRot[8]);
  vec3 t1 = vec3(j11 * uRot[3] + j12 * uRot[6], j11 * uRot[4] + j12 * uRot[7],
                 j11 * uRot[5] + j12 * uRot[8]);
  vec3 st0 = vec3(S00 * t0.x + S01 * t0.y + S02 * t0.z, S01 * t0.x + S11 * t0.y + S12 * t0.z,
                  S02 * t0.x + S12 * t0.y + S22 * t0.z);
  vec3 st1 = vec3(S00 * t1.x + S01 * t1.y + S02 * t1.z, S01 * t1.x + S11 * t1.y + S12 * t1.z,
                  S02 * t1.x + S12 * t1.y + S22 * t1.z);
  float cxx = dot(t0, st0), cxy = dot(t1, st0), cyy = dot(t1, st1);
  float det0 = cxx * cyy - cxy * cxy;
  cxx += 0.3;
  cyy += 0.3;
  float det = cxx * cyy - cxy * cxy;
  if (det == 0.0 || isnan(det) || isinf(det)) { cull(); return; }
  float detInv = 1.0 / det;
  float opacity = 1.0 / (1.0 + exp(min(-opa[i], 80.0)));
  if (uAntialiased) opacity *= sqrt(max(0.0, det0 / det));
  float mid = 0.5 * (cxx + cyy);
  float root3 = 3.0 * sqrt(mid + sqrt(max(0.1, mid * mid - det)));
  float u = uK.x * tx * invZ + uK.z, v = uK.y * ty * invZ + uK.w;
  vec3 conic = vec3(cyy * detInv, -cxy * detInv, cxx * detInv);
  if (isnan(u) || isinf(u) || isnan(v) || isinf(v) || isnan(root3) || isinf(root3) ||
      isnan(conic.x + conic.y + conic.z) || isinf(conic.x + conic.y + conic.z) ||
      !(opacity >= 1.0 / 255.0)) {
    cull();
    return;
  }
  // The reference's tiles (getRect), then the box of the ellipse where alpha can reach 1/255.
  float radius = ceil(min(root3, 1e9));
  float rx0 = trunc(clamp((u - radius) / 16.0, 0.0, float(uTiles.x)));
  float ry0 = trunc(clamp((v - radius) / 16.0, 0.0, float(uTiles.y)));
  float rx1 = trunc(clamp((u + radius + 15.0) / 16.0, 0.0, float(uTiles.x)));
  float ry1 = trunc(clamp((v + radius + 15.0) / 16.0, 0.0, float(uTiles.y)));
  if ((rx1 - rx0) * (ry1 - ry0) == 0.0) { cull(); return; }
  float kq = 2.0 * log(max(255.0 * opacity, 1.0)) * 1.001 + 0.01;
  float ex = sqrt(kq * max(cxx, 0.0)) * 1.001 + 0.01;
  float ey = sqrt(kq * max(cyy, 0.0)) * 1.001 + 0.01;
  float w = float(uSize.x), h = float(uSize.y);
  float x0 = max(ceil(clamp(u - ex, -1.0, w)), rx0 * 16.0);
  float x1 = min(min(floor(clamp(u + ex, -1.0, w)), rx1 * 16.0 - 1.0), w - 1.0);
  float y0 = max(ceil(clamp(v - ey, -1.0, h)), ry0 * 16.0);
  float y1 = min(min(floor(clamp(v + ey, -1.0, h)), ry1 * 16.0 - 1.0), h - 1.0);
  if (!(x0 <= x1) || !(y0 <= y1)) { cull(); return; }
  // Colour: the SH for the direction from the camera centre, + 0.5, clamped below at 0.
  vec3 d = normalize(p - uCentre);
  float basis[15];
  basis[0] = -kC1 * d.y; basis[1] = kC1 * d.z; basis[2] = -kC1 * d.x;
  float xx = d.x * d.x, yy = d.y * d.y, zz = d.z * d.z;
  basis[3] = kC2[0] * d.x * d.y; basis[4] = kC2[1] * d.y * d.z;
  basis[5] = kC2[2] * (2.0 * zz - xx - yy); basis[6] = kC2[3] * d.x * d.z;
  basis[7] = kC2[4] * (xx - yy);
  basis[8] = kC3[0] * d.y * (3.0 * xx - yy); basis[9] = kC3[1] * d.x * d.y * d.z;
  basis[10] = kC3[2] * d.y * (4.0 * zz - xx - yy);
  basis[11] = kC3[3] * d.z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
  basis[12] = kC3[4] * d.x * (4.0 * zz - xx - yy); basis[13] = kC3[5] * d.z * (xx - yy);
  basis[14] = kC3[6] * d.x * (xx - 3.0 * yy);
  int per = (uDegree + 1) * (uDegree + 1) - 1;
  vec3 colour;
  for (int ch = 0; ch < 3; ++ch) {
    float c = kC0 * dc[3u * i + uint(ch)];
    uint base = (3u * i + uint(ch)) * uint(per);
    for (int j = 0; j < per; ++j) c += basis[j] * rest[base + uint(j)];
    colour[ch] = c + 0.5;
  }
  if (any(isnan(colour)) || any(isinf(colour))) { cull(); return; }
  vConic = conic;
  vCentre = vec2(u, v);
  vColour = max(colour, vec3(0.0));
  vOpacity = opacity;
  // The pixel box [x0, x1] x [y0, y1]: pixel centres at integers, row 0 at the top.
  vec2 corner = vec2(float(gl_VertexID & 1), float(gl_VertexID >> 1));
  float px = mix(x0 - 0.5, x1 + 0.5, corner.x), py = mix(y0 - 0.5, y1 + 0.5, corner.y);
  gl_Position = vec4((px + 0.5) / w * 2.0 - 1.0, 1.0 - (py + 0.5) / h * 2.0, 0.0, 1.0);
}
)";

constexpr const char* kFragmentShader = R"(#version 430 core
flat in vec3 vConic;
flat in vec2 vCentre;
flat in vec3 vColour;
flat in float vOpacity;
uniform int uHeight;
out vec4 o;
void main() {
  vec2 pixel = vec2(gl_FragCoord.x - 0.5, float(uHeight) - gl_FragCoord.y - 0.5);
  vec2 d = vCentre - pixel;
  float power = -0.5 * (vConic.x * d.x * d.x + vConic.z * d.y * d.y) - vConic.y * d.x * d.y;
  if (power > 0.0) discard;
  float alpha = min(0.99, vOpacity * exp(power));
  if (alpha < 1.0 / 255.0) discard;
  o = vec4(vColour * alpha, alpha);  // front to back "under" blending: T = 1 - destination a
}
)";

bool EglDisabled() {
  const char* off = std::getenv("HVDB_RENDER_NO_EGL");
  return off != nullptr && *off != '\0' && std::strcmp(off, "0") != 0;
}

}  // namespace

struct EglGaussianRasterizer::Impl {
  std::unique_ptr<internal::EglContext> ctx;
  std::string name;
  bool hardware = false;
  GLuint program = 0, vao = 0, fbo = 0, target = 0;
  GLuint buffers[7] = {};
  GLint max_block = 0;
  uint32_t w = 0, h = 0;
  std::vector<uint64_t> keys;
  std::vector<uint32_t> order;
  std::vector<float> pixels;

  Status InitGl() {
    const char* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    const char* v = reinterpret_cast<const char*>(glGetString(GL_VERSION));
    GLint major = 0, minor = 0;
    glGetIntegerv(GL_MAJOR_VERSION, &major);
    glGetIntegerv(GL_MINOR_VERSION, &minor);
    if (major < 4 || (major == 4 && minor < 3)) {
      return Status::Unsupported(std::string("OpenGL ") + (v ? v : "?") + " is older than 4.3");
    }
    glGetIntegerv(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_block);
    HVDB_ASSIGN_OR_RETURN(program, internal::LinkProgram(kVertexShader, kFragmentShader,
                                                         "EGL gaussian"));
    glGenVertexArrays(1, &vao);
    glGenBuffers(7, buffers);
    name = std::string("egl: ") + (r ? r : "?") + ", OpenGL " + (v ? v : "?");
    hardware_renderer = r ? r : "";
    return glGetError() == GL_NO_ERROR ? Status::OK()
                                       : Status::Internal("EGL gaussian: OpenGL error at set-up");
  }
  std::string hardware_renderer;

  Status EnsureTarget(uint32_t width, uint32_t height) {
    if (width == w && height == h) return Status::OK();
    w = h = 0;  // known good only once complete
    if (fbo) glDeleteFramebuffers(1, &fbo);
    if (target) glDeleteTextures(1, &target);
    glGenTextures(1, &target);
    glBindTexture(GL_TEXTURE_2D, target);
    glTexStorage2D(GL_TEXTURE_2D, 1, GL_RGBA32F, static_cast<GLsizei>(width),
                   static_cast<GLsizei>(height));
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glGenFramebuffers(1, &fbo);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, target, 0);
    const GLenum complete = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    const GLenum err = glGetError();
    if (complete != GL_FRAMEBUFFER_COMPLETE || err != GL_NO_ERROR) {
      return Status::LimitExceeded("EGL gaussian: no " + std::to_string(width) + "x" +
                                   std::to_string(height) + " float target (framebuffer status " +
                                   std::to_string(complete) + ", GL error " +
                                   std::to_string(err) + ")");
    }
    w = width;
    h = height;
    return Status::OK();
  }

  void Free() {
    if (fbo) glDeleteFramebuffers(1, &fbo);
    if (target) glDeleteTextures(1, &target);
    glDeleteBuffers(7, buffers);
    if (vao) glDeleteVertexArrays(1, &vao);
    if (program) glDeleteProgram(program);
  }
};

EglGaussianRasterizer::EglGaussianRasterizer() : impl_(std::make_unique<Impl>()) {}

EglGaussianRasterizer::~EglGaussianRasterizer() {
  if (impl_->ctx && impl_->ctx->MakeCurrent()) {
    impl_->Free();
    impl_->ctx->ReleaseCurrent();
  }
}

Result<std::unique_ptr<EglGaussianRasterizer>> EglGaussianRasterizer::Create() {
  if (EglDisabled()) return Status::Unsupported("EGL renderer: disabled by HVDB_RENDER_NO_EGL");
  std::unique_ptr<EglGaussianRasterizer> r(new EglGaussianRasterizer());
  Impl* impl = r->impl_.get();
  HVDB_ASSIGN_OR_RETURN(impl->ctx, internal::EglContext::Create([impl] { return impl->InitGl(); }));
  impl->name += " (" + impl->ctx->label() + ")";
  impl->hardware = impl->ctx->Hardware(impl->hardware_renderer);
  return r;
}

namespace {
std::mutex g_idle_mu;
std::vector<std::unique_ptr<EglGaussianRasterizer>> g_idle;
}  // namespace

Result<std::unique_ptr<EglGaussianRasterizer>> EglGaussianRasterizer::Take() {
  {
    std::lock_guard<std::mutex> l(g_idle_mu);
    if (!g_idle.empty()) {
      std::unique_ptr<EglGaussianRasterizer> r = std::move(g_idle.back());
      g_idle.pop_back();
      return r;
    }
  }
  return Create();
}

void EglGaussianRasterizer::Recycle(std::unique_ptr<EglGaussianRasterizer> r) {
  if (r == nullptr) return;
  std::lock_guard<std::mutex> l(g_idle_mu);
  if (g_idle.size() < 4) g_idle.push_back(std::move(r));
}

const std::string& EglGaussianRasterizer::name() const { return impl_->name; }
bool EglGaussianRasterizer::hardware() const { return impl_->hardware; }

Status EglGaussianRasterizer::Render(const formats::GaussianCloud& cloud, const Camera& camera,
                                     const GaussianRenderOptions& options, GaussianImage* out,
                                     GaussianRenderStats* stats) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  HVDB_RETURN_IF_ERROR(CheckGaussianRender(cloud, camera, options));
  Impl& m = *impl_;
  const gaussian::ViewF view = gaussian::MakeView(camera);
  const size_t n = cloud.size();
  // Every array must fit one storage buffer binding.
  const size_t largest = std::max({cloud.sh_rest.size(), cloud.position.size(),
                                   cloud.rotation.size()}) * sizeof(float);
  if (largest > static_cast<size_t>(m.max_block)) {
    return Status::LimitExceeded("EGL gaussian: " + std::to_string(n) + " splats need " +
                                 std::to_string(largest >> 20) + " MiB storage buffers; this "
                                 "driver binds at most " + std::to_string(m.max_block >> 20) +
                                 " MiB (the CPU rasteriser has no such bound)");
  }
  // Front to back: the view depths, sorted with the splat index breaking ties (the
  // reference's order within a tile). Positive floats order as their bits.
  m.keys.clear();
  m.keys.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    const float* p = &cloud.position[3 * i];
    const float z = view.rot[6] * p[0] + view.rot[7] * p[1] + view.rot[8] * p[2] + view.trans[2];
    if (!(z > 0.2f)) continue;
    uint32_t bits;
    std::memcpy(&bits, &z, 4);
    m.keys.push_back((uint64_t{bits} << 32) | i);
  }
  std::sort(m.keys.begin(), m.keys.end());
  m.order.resize(m.keys.size());
  for (size_t k = 0; k < m.keys.size(); ++k) m.order[k] = static_cast<uint32_t>(m.keys[k]);
  const auto sorted = Clock::now();

  if (!m.ctx->MakeCurrent()) {
    return Status::Internal("EGL gaussian: eglMakeCurrent failed: " +
                            internal::EglContext::LastError());
  }
  const uint32_t width = camera.width, height = camera.height;
  Status target = m.EnsureTarget(width, height);
  if (!target.ok()) {
    m.ctx->ReleaseCurrent();
    return target;
  }
  auto upload = [&](int binding, const void* data, size_t bytes) {
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, m.buffers[binding]);
    // At least 4 bytes: a buffer of none cannot be bound.
    glBufferData(GL_SHADER_STORAGE_BUFFER, static_cast<GLsizeiptr>(std::max<size_t>(bytes, 4)),
                 nullptr, GL_STREAM_DRAW);
    if (bytes) glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, static_cast<GLsizeiptr>(bytes), data);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, static_cast<GLuint>(binding), m.buffers[binding]);
  };
  upload(0, cloud.position.data(), cloud.position.size() * 4);
  upload(1, cloud.scale.data(), cloud.scale.size() * 4);
  upload(2, cloud.rotation.data(), cloud.rotation.size() * 4);
  upload(3, cloud.opacity.data(), cloud.opacity.size() * 4);
  upload(4, cloud.sh_dc.data(), cloud.sh_dc.size() * 4);
  upload(5, cloud.sh_rest.data(), cloud.sh_rest.size() * 4);
  upload(6, m.order.data(), m.order.size() * 4);

  glBindFramebuffer(GL_FRAMEBUFFER, m.fbo);
  glViewport(0, 0, static_cast<GLsizei>(width), static_cast<GLsizei>(height));
  glDisable(GL_DEPTH_TEST);
  glClearColor(0, 0, 0, 0);
  glClear(GL_COLOR_BUFFER_BIT);
  glEnable(GL_BLEND);
  glBlendFuncSeparate(GL_ONE_MINUS_DST_ALPHA, GL_ONE, GL_ONE_MINUS_DST_ALPHA, GL_ONE);
  glUseProgram(m.program);
  auto loc = [&](const char* u) { return glGetUniformLocation(m.program, u); };
  glUniform1fv(loc("uRot"), 9, view.rot);
  glUniform3fv(loc("uTrans"), 1, view.trans);
  glUniform3fv(loc("uCentre"), 1, view.centre);
  glUniform4f(loc("uK"), view.fx, view.fy, view.cx, view.cy);
  glUniform2f(loc("uLim"), view.lim_x, view.lim_y);
  glUniform2i(loc("uSize"), view.width, view.height);
  glUniform2i(loc("uTiles"), view.tiles_x, view.tiles_y);
  glUniform1i(loc("uDegree"), cloud.sh_degree);
  glUniform1i(loc("uAntialiased"), cloud.antialiased ? 1 : 0);
  glUniform1i(loc("uHeight"), view.height);
  glBindVertexArray(m.vao);
  if (!m.order.empty()) {
    glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, static_cast<GLsizei>(m.order.size()));
  }
  glDisable(GL_BLEND);
  m.pixels.resize(size_t{width} * height * 4);
  glPixelStorei(GL_PACK_ALIGNMENT, 4);
  glReadPixels(0, 0, static_cast<GLsizei>(width), static_cast<GLsizei>(height), GL_RGBA, GL_FLOAT,
               m.pixels.data());
  const GLenum err = glGetError();
  m.ctx->ReleaseCurrent();
  if (err == GL_OUT_OF_MEMORY) {
    return Status::LimitExceeded("EGL gaussian: the GPU ran out of memory for " +
                                 std::to_string(n) + " splats");
  }
  if (err != GL_NO_ERROR) {
    return Status::Internal("EGL gaussian: OpenGL error " + std::to_string(err));
  }
  const auto drawn = Clock::now();
  // GL's rows run bottom up; C + T * background, alpha 1 - T.
  out->width = width;
  out->height = height;
  out->rgb.resize(size_t{width} * height * 3);
  out->alpha.resize(size_t{width} * height);
  for (uint32_t y = 0; y < height; ++y) {
    const float* src = &m.pixels[size_t{height - 1 - y} * width * 4];
    for (uint32_t x = 0; x < width; ++x) {
      const size_t o = size_t{y} * width + x;
      const float t = 1.0f - src[4 * x + 3];
      for (int c = 0; c < 3; ++c) out->rgb[3 * o + c] = src[4 * x + c] + t * options.background[c];
      out->alpha[o] = src[4 * x + 3];
    }
  }
  if (stats != nullptr) {
    using Ms = std::chrono::duration<double, std::milli>;
    *stats = {};
    stats->splats_in = n;
    stats->splats_visible = m.order.size();  // in front of the near plane (the GPU culls more)
    stats->preprocess_ms = 0;
    stats->bin_ms = Ms(sorted - start).count();
    stats->blend_ms = Ms(drawn - sorted).count();
    stats->milliseconds = Ms(Clock::now() - start).count();
  }
  return Status::OK();
}

}  // namespace hvdb::render
