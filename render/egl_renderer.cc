// The GPU renderer: OpenGL 4.3+ core through headless EGL (no window system; the display and
// context: egl_context.h). Render targets are framebuffer objects; nothing is ever shown.
//
// Splats are drawn as one instanced quad each; the vertex shader pulls the 64-byte Point
// records straight from a shader storage buffer and does the EWA set-up of splat.cc's
// ProjectSplat(), the fragment shader evaluates the kernel. Modes:
//   visibility     the two-pass method of Ren et al. 2002 / thesis 5.1.2: pass 1 renders
//                  depth only (the nearest, by GL_MIN blending of float depth, which needs no
//                  depth range); pass 2 blends additively, in float, the fragments within dz of
//                  it (the fuzzy depth test, done in the shader against pass 1's result rather
//                  than by a depth buffer shifted by dz: the same test, exact in metres); a
//                  full-screen pass normalises.
//   probabilistic  splats presorted front to back on the CPU, blended with
//                  GL_SRC_ALPHA_SATURATE into a 16-bit normalised target, whose clamping at
//                  one makes accumulation stop at saturation (5.4.1).
#define GL_GLEXT_PROTOTYPES 1
#include <GL/glcorearb.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <mutex>
#include <optional>

#include "render/egl_context.h"
#include "render/egl_shaders.h"
#include "render/renderer.h"
#include "render/splat.h"

namespace hvdb::render {

namespace {

using internal::View;

// ---- GL helpers ----

// Programs: egl_context.h's LinkProgram.
Result<GLuint> Link(const char* vs_src, const char* fs_src) {
  return internal::LinkProgram(vs_src, fs_src, "EGL renderer");
}

GLuint MakeTexture(GLenum format, uint32_t w, uint32_t h) {
  GLuint t;
  glGenTextures(1, &t);
  glBindTexture(GL_TEXTURE_2D, t);
  glTexStorage2D(GL_TEXTURE_2D, 1, format, static_cast<GLsizei>(w), static_cast<GLsizei>(h));
  // No mipmaps: the default minification filter would make the texture incomplete.
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
  glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
  return t;
}

class EglRenderer final : public Renderer {
 public:
  static Result<std::unique_ptr<Renderer>> Create() {
    std::unique_ptr<EglRenderer> r(new EglRenderer());
    HVDB_RETURN_IF_ERROR(r->Init());
    return std::unique_ptr<Renderer>(std::move(r));
  }

  ~EglRenderer() override {
    if (ctx_ == nullptr) return;
    if (MakeCurrent()) {
      FreeTargets();
      if (!point_buffers_.empty()) {
        glDeleteBuffers(static_cast<GLsizei>(point_buffers_.size()), point_buffers_.data());
      }
      if (table_buffer_) glDeleteBuffers(1, &table_buffer_);
      if (vao_) glDeleteVertexArrays(1, &vao_);
      if (splat_program_) glDeleteProgram(splat_program_);
      if (resolve_program_) glDeleteProgram(resolve_program_);
      ReleaseCurrent();
    }
  }

  RendererKind kind() const override { return RendererKind::kEgl; }
  std::string name() const override { return name_; }
  bool hardware() const override { return hardware_; }
  RenderStats last_stats() const override {
    std::lock_guard<std::mutex> l(mu_);
    return stats_;
  }

  Result<Image> Render(std::span<const Point> points, const Camera& camera,
                       const RenderOptions& options) override {
    std::lock_guard<std::mutex> l(mu_);
    auto start = std::chrono::steady_clock::now();
    HVDB_ASSIGN_OR_RETURN(View view, internal::PrepareView(camera, options));
    Camera cam = options.width != 0 ? camera.Resized(options.width, options.height) : camera;
    std::vector<float> weights = internal::ViewWeightTable(cam, options);
    if (!MakeCurrent()) {
      return Status::Internal("EGL renderer: eglMakeCurrent failed: " +
                              internal::EglContext::LastError());
    }
    Result<Image> img = RenderCurrent(points, view, weights, options);
    glFinish();
    ReleaseCurrent();
    if (img.ok()) {
      stats_.points = points.size();
      stats_.milliseconds =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
    }
    return img;
  }

 private:
  EglRenderer() = default;

  bool MakeCurrent() { return ctx_->MakeCurrent(); }
  void ReleaseCurrent() { ctx_->ReleaseCurrent(); }

  Status Init() {
    HVDB_ASSIGN_OR_RETURN(ctx_, internal::EglContext::Create([this] { return InitGl(); }));
    name_ = "egl: " + gl_renderer_ + ", OpenGL " + gl_version_ + " (" + ctx_->label() + ")";
    hardware_ = ctx_->Hardware(gl_renderer_);
    return Status::OK();
  }

  Status InitGl() {
    const char* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    const char* v = reinterpret_cast<const char*>(glGetString(GL_VERSION));
    gl_renderer_ = r ? r : "?";
    gl_version_ = v ? v : "?";
    GLint major = 0, minor = 0;
    glGetIntegerv(GL_MAJOR_VERSION, &major);
    glGetIntegerv(GL_MINOR_VERSION, &minor);
    if (major < 4 || (major == 4 && minor < 3)) {
      return Status::Unsupported("OpenGL " + gl_version_ + " is older than 4.3");
    }
    GLint max_ssbo = 0, max_size = 0;
    glGetIntegerv(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &max_ssbo);
    glGetIntegerv(GL_MAX_TEXTURE_SIZE, &max_size);
    if (max_size < static_cast<GLint>(kMaxImageSize)) {
      return Status::Unsupported("the largest texture (" + std::to_string(max_size) +
                                 ") is smaller than 4096");
    }
    // Points go to the GPU in chunks that fit one storage buffer binding.
    chunk_points_ = std::min<size_t>(size_t{1} << 20, static_cast<size_t>(max_ssbo) / 64);
    if (chunk_points_ == 0) return Status::Unsupported("no shader storage buffers");
    HVDB_ASSIGN_OR_RETURN(splat_program_,
                          Link(shaders::kSplatVertexShader, shaders::kSplatFragmentShader));
    HVDB_ASSIGN_OR_RETURN(resolve_program_,
                          Link(shaders::kResolveVertexShader, shaders::kResolveFragmentShader));
    glGenVertexArrays(1, &vao_);  // core profile draws need one, even without attributes
    glGenBuffers(1, &table_buffer_);
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) return Status::Internal("OpenGL error " + std::to_string(e));
    return Status::OK();
  }

  void FreeTargets() {
    GLuint fbos[] = {fbo_depth_, fbo_vis_, fbo_prob_, fbo_out_};
    glDeleteFramebuffers(4, fbos);
    GLuint texs[] = {tex_zmin_,   tex_vis_acc_,  tex_vis_cov_, tex_prob_acc_,
                     tex_prob_z_, tex_out_rgba_, tex_out_cd_};
    glDeleteTextures(7, texs);
    fbo_depth_ = fbo_vis_ = fbo_prob_ = fbo_out_ = 0;
    tex_zmin_ = tex_vis_acc_ = tex_vis_cov_ = tex_prob_acc_ = tex_prob_z_ = 0;
    tex_out_rgba_ = tex_out_cd_ = 0;
    target_w_ = target_h_ = 0;
  }

  Status EnsureTargets(uint32_t w, uint32_t h) {
    if (w == target_w_ && h == target_h_) return Status::OK();
    FreeTargets();
    tex_zmin_ = MakeTexture(GL_R32F, w, h);        // nearest depth (GL_MIN blending)
    tex_vis_acc_ = MakeTexture(GL_RGBA32F, w, h);  // sum w a c, sum w a
    tex_vis_cov_ = MakeTexture(GL_R32F, w, h);     // sum a
    tex_prob_acc_ = MakeTexture(GL_RGBA16, w, h);  // C, A: clamps at one (saturation)
    tex_prob_z_ = MakeTexture(GL_R32F, w, h);      // nearest depth (GL_MIN blending)
    tex_out_rgba_ = MakeTexture(GL_RGBA32F, w, h);
    tex_out_cd_ = MakeTexture(GL_RG32F, w, h);  // coverage, depth
    auto make_fbo = [](GLuint c0, GLuint c1) {
      GLuint f;
      glGenFramebuffers(1, &f);
      glBindFramebuffer(GL_FRAMEBUFFER, f);
      glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, c0, 0);
      if (c1) glFramebufferTexture2D(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT1, GL_TEXTURE_2D, c1, 0);
      const GLenum bufs[] = {GL_COLOR_ATTACHMENT0, GL_COLOR_ATTACHMENT1};
      glDrawBuffers(c1 ? 2 : 1, bufs);
      return f;
    };
    fbo_depth_ = make_fbo(tex_zmin_, 0);
    fbo_vis_ = make_fbo(tex_vis_acc_, tex_vis_cov_);
    fbo_prob_ = make_fbo(tex_prob_acc_, tex_prob_z_);
    fbo_out_ = make_fbo(tex_out_rgba_, tex_out_cd_);
    for (GLuint f : {fbo_depth_, fbo_vis_, fbo_prob_, fbo_out_}) {
      glBindFramebuffer(GL_FRAMEBUFFER, f);
      GLenum st = glCheckFramebufferStatus(GL_FRAMEBUFFER);
      if (st != GL_FRAMEBUFFER_COMPLETE) {
        FreeTargets();
        return Status::Internal("EGL renderer: framebuffer incomplete (status " +
                                std::to_string(st) + ")");
      }
    }
    target_w_ = w;
    target_h_ = h;
    return Status::OK();
  }

  // Uploads the points chunk by chunk, in `order` when given; returns the points per chunk.
  std::vector<size_t> Upload(std::span<const Point> points, const std::vector<uint32_t>* order) {
    size_t n = order ? order->size() : points.size();
    size_t chunks = (n + chunk_points_ - 1) / chunk_points_;
    if (point_buffers_.size() < chunks) {
      size_t old = point_buffers_.size();
      point_buffers_.resize(chunks);
      glGenBuffers(static_cast<GLsizei>(chunks - old), point_buffers_.data() + old);
    }
    std::vector<size_t> counts;
    std::vector<Point> staging;
    for (size_t c = 0; c < chunks; ++c) {
      size_t lo = c * chunk_points_, cnt = std::min(chunk_points_, n - lo);
      const Point* data = points.data() + lo;
      if (order) {
        staging.resize(cnt);
        for (size_t i = 0; i < cnt; ++i) staging[i] = points[(*order)[lo + i]];
        data = staging.data();
      }
      glBindBuffer(GL_SHADER_STORAGE_BUFFER, point_buffers_[c]);
      // A fresh data store each time: the driver need not wait for the last frame's draws.
      glBufferData(GL_SHADER_STORAGE_BUFFER, static_cast<GLsizeiptr>(cnt * sizeof(Point)), data,
                   GL_STREAM_DRAW);
      counts.push_back(cnt);
    }
    return counts;
  }

  void DrawChunks(const std::vector<size_t>& counts) {
    for (size_t c = 0; c < counts.size(); ++c) {
      glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 0, point_buffers_[c]);
      glDrawArraysInstanced(GL_TRIANGLE_STRIP, 0, 4, static_cast<GLsizei>(counts[c]));
    }
  }

  void SetUniforms(const View& view, int num_weights) {
    GLuint p = splat_program_;
    auto loc = [p](const char* n) { return glGetUniformLocation(p, n); };
    glUseProgram(p);
    glUniform3f(loc("u_rot0"), view.rot[0], view.rot[1], view.rot[2]);
    glUniform3f(loc("u_rot1"), view.rot[3], view.rot[4], view.rot[5]);
    glUniform3f(loc("u_rot2"), view.rot[6], view.rot[7], view.rot[8]);
    glUniform3f(loc("u_trans"), view.trans[0], view.trans[1], view.trans[2]);
    glUniform4f(loc("u_intr"), view.fx, view.fy, view.cx, view.cy);
    glUniform1fv(loc("u_k"), 5, view.k);
    glUniform1i(loc("u_distorted"), view.distorted ? 1 : 0);
    glUniform1f(loc("u_max_r2"), view.max_r2);
    glUniform1f(loc("u_near"), view.near_plane);
    glUniform1f(loc("u_cutoff2"), view.cutoff2);
    glUniform1f(loc("u_filter"), view.filter);
    glUniform1f(loc("u_scale2"), view.scale2);
    glUniform1f(loc("u_default_var"), view.default_var);
    glUniform2f(loc("u_size"), static_cast<float>(view.width), static_cast<float>(view.height));
    glUniform1i(loc("u_num_weights"), num_weights);
    glUniform1f(loc("u_dz"), view.depth_threshold);
  }

  Result<Image> RenderCurrent(std::span<const Point> points, const View& view,
                              const std::vector<float>& weights, const RenderOptions& o) {
    while (glGetError() != GL_NO_ERROR) {
    }
    HVDB_RETURN_IF_ERROR(EnsureTargets(view.width, view.height));
    // The lookup table: sRGB decoding, then the view weights by camera id.
    std::vector<float> table(internal::SrgbTable().begin(), internal::SrgbTable().end());
    table.insert(table.end(), weights.begin(), weights.end());
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, table_buffer_);
    glBufferData(GL_SHADER_STORAGE_BUFFER, static_cast<GLsizeiptr>(table.size() * sizeof(float)),
                 table.data(), GL_STREAM_DRAW);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, table_buffer_);

    // Depth only: either mode's nearest depth is pass 1's (no sort, no blending pass).
    const bool probabilistic = o.mode == Mode::kProbabilistic && !o.depth_only;
    std::vector<size_t> counts;
    if (probabilistic) {
      // 5.4.1: "the Gaussians have to be presorted by the CPU according to their depths".
      // Points behind the near plane are culled anyway and left out of the sort.
      std::vector<float> keys;
      std::vector<uint32_t> index;
      keys.reserve(points.size());
      index.reserve(points.size());
      for (size_t i = 0; i < points.size(); ++i) {
        float z = internal::CameraDepth(view, points[i]);
        if (z >= view.near_plane) {
          keys.push_back(z);
          index.push_back(static_cast<uint32_t>(i));
        }
      }
      std::vector<uint32_t> order = internal::StableOrder(keys);
      for (uint32_t& i : order) i = index[i];
      counts = Upload(points, &order);
    } else {
      counts = Upload(points, nullptr);
    }

    SetUniforms(view, static_cast<int>(weights.size()));
    GLint pass_loc = glGetUniformLocation(splat_program_, "u_pass");
    glBindVertexArray(vao_);
    glViewport(0, 0, static_cast<GLsizei>(view.width), static_cast<GLsizei>(view.height));
    glDisable(GL_CULL_FACE);
    glDisable(GL_SCISSOR_TEST);
    const float zero[4] = {0, 0, 0, 0};
    const float inf[4] = {std::numeric_limits<float>::infinity(), 0, 0, 0};
    glDisable(GL_DEPTH_TEST);
    glColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    glEnable(GL_BLEND);
    // The splat program samples unit 0 (t_zmin): nothing it renders into may be bound there.
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, 0);
    if (!probabilistic) {
      // Pass 1: the nearest depth at each pixel.
      glBindFramebuffer(GL_FRAMEBUFFER, fbo_depth_);
      glClearBufferfv(GL_COLOR, 0, inf);
      glBlendEquation(GL_MIN);
      glUniform1i(pass_loc, 0);
      DrawChunks(counts);
      if (o.depth_only) return ReadDepth(view, points.size());
      // Pass 2: additive blending of the fragments that pass the fuzzy depth test.
      glBindFramebuffer(GL_FRAMEBUFFER, fbo_vis_);
      glClearBufferfv(GL_COLOR, 0, zero);
      glClearBufferfv(GL_COLOR, 1, zero);
      glBindTexture(GL_TEXTURE_2D, tex_zmin_);
      glBlendEquation(GL_FUNC_ADD);
      glBlendFunc(GL_ONE, GL_ONE);
      glUniform1i(pass_loc, 1);
      DrawChunks(counts);
    } else {
      glBindFramebuffer(GL_FRAMEBUFFER, fbo_prob_);
      glClearBufferfv(GL_COLOR, 0, zero);
      glClearBufferfv(GL_COLOR, 1, inf);
      // C += c min(a, 1 - A); A = min(1, A + a): the 16-bit normalised target clamps.
      glBlendEquationi(0, GL_FUNC_ADD);
      glBlendFunci(0, GL_SRC_ALPHA_SATURATE, GL_ONE);
      glBlendEquationi(1, GL_MIN);
      glBlendFunci(1, GL_ONE, GL_ONE);
      glUniform1i(pass_loc, 2);
      DrawChunks(counts);
    }
    // Normalisation and compositing over the background, one full-screen pass.
    glDisable(GL_BLEND);
    glDisable(GL_DEPTH_TEST);
    glBindFramebuffer(GL_FRAMEBUFFER, fbo_out_);
    glUseProgram(resolve_program_);
    glUniform1i(glGetUniformLocation(resolve_program_, "u_probabilistic"), probabilistic ? 1 : 0);
    glUniform4f(glGetUniformLocation(resolve_program_, "u_bg"), o.background[0], o.background[1],
                o.background[2], o.background[3]);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_2D, probabilistic ? tex_prob_acc_ : tex_vis_acc_);
    glActiveTexture(GL_TEXTURE1);
    glBindTexture(GL_TEXTURE_2D, probabilistic ? tex_prob_z_ : tex_vis_cov_);
    glActiveTexture(GL_TEXTURE2);
    glBindTexture(GL_TEXTURE_2D, tex_zmin_);
    glDrawArrays(GL_TRIANGLES, 0, 3);

    Image img;
    img.width = view.width;
    img.height = view.height;
    img.rgba.resize(img.pixels() * 4);
    std::vector<float> cd(img.pixels() * 2);
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glReadPixels(0, 0, static_cast<GLsizei>(view.width), static_cast<GLsizei>(view.height), GL_RGBA,
                 GL_FLOAT, img.rgba.data());
    glReadBuffer(GL_COLOR_ATTACHMENT1);
    glReadPixels(0, 0, static_cast<GLsizei>(view.width), static_cast<GLsizei>(view.height), GL_RG,
                 GL_FLOAT, cd.data());
    img.coverage.resize(img.pixels());
    img.depth.resize(img.pixels());
    for (size_t i = 0; i < img.pixels(); ++i) {
      img.coverage[i] = cd[2 * i];
      img.depth[i] = cd[2 * i + 1];
    }
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) {
      return Status::Internal("EGL renderer: OpenGL error 0x" + std::to_string(e) +
                              " while rendering " + std::to_string(points.size()) + " points");
    }
    return img;
  }

  // Pass 1's nearest depth (fbo_depth_, bound) as the image's depth, nothing else.
  Result<Image> ReadDepth(const View& view, size_t points) {
    Image img;
    img.width = view.width;
    img.height = view.height;
    img.depth.resize(img.pixels());
    glPixelStorei(GL_PACK_ALIGNMENT, 4);
    glReadBuffer(GL_COLOR_ATTACHMENT0);
    glReadPixels(0, 0, static_cast<GLsizei>(view.width), static_cast<GLsizei>(view.height), GL_RED,
                 GL_FLOAT, img.depth.data());
    GLenum e = glGetError();
    if (e != GL_NO_ERROR) {
      return Status::Internal("EGL renderer: OpenGL error 0x" + std::to_string(e) +
                              " while rendering the depth of " + std::to_string(points) +
                              " points");
    }
    return img;
  }

  mutable std::mutex mu_;
  RenderStats stats_;
  std::unique_ptr<internal::EglContext> ctx_;
  std::string name_, gl_renderer_, gl_version_;
  bool hardware_ = false;
  size_t chunk_points_ = 0;
  GLuint splat_program_ = 0, resolve_program_ = 0, vao_ = 0, table_buffer_ = 0;
  std::vector<GLuint> point_buffers_;
  uint32_t target_w_ = 0, target_h_ = 0;
  GLuint fbo_depth_ = 0, fbo_vis_ = 0, fbo_prob_ = 0, fbo_out_ = 0;
  GLuint tex_zmin_ = 0, tex_vis_acc_ = 0, tex_vis_cov_ = 0, tex_prob_acc_ = 0, tex_prob_z_ = 0;
  GLuint tex_out_rgba_ = 0, tex_out_cd_ = 0;
};

}  // namespace

bool IsSoftwareRasteriser(const std::string& gl_renderer) {
  // Mesa's CPU drivers name themselves so in GL_RENDERER ("llvmpipe (LLVM 15.0.6, 256 bits)",
  // "softpipe", "Software Rasterizer" for swrast, "SWR" for OpenSWR).
  for (const char* sw : {"llvmpipe", "softpipe", "Software Rasterizer", "swrast", "SWR "}) {
    if (gl_renderer.find(sw) != std::string::npos) return true;
  }
  return false;
}

namespace {

// An operator's (and the tests') switch for the CPU path on machines whose EGL misbehaves.
bool EglDisabled() {
  const char* off = std::getenv("HVDB_RENDER_NO_EGL");
  return off != nullptr && *off != '\0' && std::strcmp(off, "0") != 0;
}

// MakeRenderer(kAuto)'s finding that EGL is a software rasteriser here, with its reason; the
// machine's devices do not change while the process runs.
std::mutex g_auto_mu;
std::optional<std::string> g_auto_software;

}  // namespace

Result<std::unique_ptr<Renderer>> MakeEglRenderer() {
  if (EglDisabled()) {
    return Status::Unsupported("EGL renderer: disabled by HVDB_RENDER_NO_EGL");
  }
  return EglRenderer::Create();
}

Result<std::unique_ptr<Renderer>> MakeRenderer(RendererKind kind, std::string* why) {
  std::string reason;
  if (why == nullptr) why = &reason;
  if (kind == RendererKind::kCpu) {
    *why = "asked for the CPU renderer";
    return MakeCpuRenderer();
  }
  if (kind == RendererKind::kAuto && !EglDisabled()) {
    // Known already: EGL here is a software rasteriser (probing again would make and destroy
    // a context per render).
    std::lock_guard<std::mutex> l(g_auto_mu);
    if (g_auto_software) {
      *why = *g_auto_software;
      return MakeCpuRenderer();
    }
  }
  auto egl = MakeEglRenderer();
  if (kind == RendererKind::kEgl) {
    *why = "asked for the EGL renderer";
    return egl;
  }
  if (!egl.ok()) {
    *why = "no EGL context (" + egl.status().message() + "): the CPU renderer";
    internal::LogWarning("falling back to the CPU renderer: " + egl.status().message());
    return MakeCpuRenderer();
  }
  std::unique_ptr<Renderer> chosen = ChooseAuto(std::move(egl).value(), why);
  if (chosen->kind() == RendererKind::kCpu) {
    std::lock_guard<std::mutex> l(g_auto_mu);
    g_auto_software = *why;
  }
  return chosen;
}

std::unique_ptr<Renderer> ChooseAuto(std::unique_ptr<Renderer> egl, std::string* why) {
  if (egl->hardware()) {
    *why = "a GPU (" + egl->name() + "): the EGL renderer";
    return egl;
  }
  // On the same cores the tiled CPU splatter is faster than any software OpenGL driver
  // (render-bench, 2 cores: 6-25x llvmpipe's splats/s at 1080p).
  *why = "EGL runs on a software rasteriser (" + egl->name() +
         "); the CPU renderer is faster on the same cores";
  std::unique_ptr<Renderer> cpu = MakeCpuRenderer();
  internal::LogNote("renderer auto: " + *why);
  return cpu;
}

}  // namespace hvdb::render
