// Headless EGL contexts (render/egl_context.h).
#include "render/egl_context.h"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#define GL_GLEXT_PROTOTYPES 1
#include <GL/glcorearb.h>

#include <cstdio>
#include <cstring>
#include <map>
#include <mutex>
#include <vector>

#include "render/renderer.h"

namespace hvdb::render::internal {

struct EglContext::Handles {
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
  EGLSurface surface = EGL_NO_SURFACE;
};

namespace {

bool HasExtension(const char* list, const char* name) {
  if (list == nullptr) return false;
  size_t n = std::strlen(name);
  for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n) {
    if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
  }
  return false;
}

std::string EglErrorName(EGLint e) {
  switch (e) {
    case EGL_SUCCESS:
      return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED:
      return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS:
      return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC:
      return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE:
      return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG:
      return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT:
      return "EGL_BAD_CONTEXT";
    case EGL_BAD_DISPLAY:
      return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH:
      return "EGL_BAD_MATCH";
    case EGL_BAD_PARAMETER:
      return "EGL_BAD_PARAMETER";
    default: {
      char buf[32];
      std::snprintf(buf, sizeof(buf), "EGL error 0x%04x", static_cast<unsigned>(e));
      return buf;
    }
  }
}

// EGL displays are per-process singletons and eglTerminate ends them for every user, so
// renderers share each initialised display and the last one out terminates it.
std::mutex g_display_mu;
std::map<EGLDisplay, int> g_display_refs;

void ReleaseDisplay(EGLDisplay d) {
  std::lock_guard<std::mutex> l(g_display_mu);
  if (--g_display_refs[d] == 0) {
    g_display_refs.erase(d);
    eglTerminate(d);
  }
}

struct Candidate {
  EGLDisplay display;
  std::string label;
};

std::vector<Candidate> CandidateDisplays(std::string* notes) {
  std::vector<Candidate> out;
  const char* client_ext = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
  auto get_platform_display = reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(
      eglGetProcAddress("eglGetPlatformDisplayEXT"));
  if (get_platform_display != nullptr && HasExtension(client_ext, "EGL_EXT_platform_device")) {
    auto query_devices =
        reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
    auto query_device_string = reinterpret_cast<PFNEGLQUERYDEVICESTRINGEXTPROC>(
        eglGetProcAddress("eglQueryDeviceStringEXT"));
    EGLDeviceEXT devices[16];
    EGLint n = 0;
    if (query_devices != nullptr && query_devices(16, devices, &n)) {
      std::vector<Candidate> software;
      for (EGLint i = 0; i < n; ++i) {
        const char* ext =
            query_device_string ? query_device_string(devices[i], EGL_EXTENSIONS) : nullptr;
        bool sw = HasExtension(ext, "EGL_MESA_device_software");
        EGLDisplay d = get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr);
        if (d == EGL_NO_DISPLAY) continue;
        Candidate c{d, "device " + std::to_string(i) + (sw ? " (software)" : "")};
        (sw ? software : out).push_back(c);
      }
      out.insert(out.end(), software.begin(), software.end());
    }
  } else {
    *notes += "no EGL_EXT_platform_device; ";
  }
  if (get_platform_display != nullptr &&
      HasExtension(client_ext, "EGL_MESA_platform_surfaceless")) {
    EGLDisplay d =
        get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
    if (d != EGL_NO_DISPLAY) out.push_back({d, "surfaceless"});
  }
  EGLDisplay d = eglGetDisplay(EGL_DEFAULT_DISPLAY);
  if (d != EGL_NO_DISPLAY) out.push_back({d, "default display"});
  return out;
}

}  // namespace

EglContext::~EglContext() {
  if (!h_ || h_->display == EGL_NO_DISPLAY) return;
  if (h_->context != EGL_NO_CONTEXT) eglDestroyContext(h_->display, h_->context);
  if (h_->surface != EGL_NO_SURFACE) eglDestroySurface(h_->display, h_->surface);
  ReleaseDisplay(h_->display);
}

bool EglContext::MakeCurrent() {
  eglBindAPI(EGL_OPENGL_API);  // per-thread state: renders may come from any thread
  return eglMakeCurrent(h_->display, h_->surface, h_->surface, h_->context) == EGL_TRUE;
}

void EglContext::ReleaseCurrent() {
  eglMakeCurrent(h_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
}

bool EglContext::Hardware(const std::string& gl_renderer) const {
  return label_.find("(software)") == std::string::npos && !IsSoftwareRasteriser(gl_renderer);
}

std::string EglContext::LastError() { return EglErrorName(eglGetError()); }

Result<std::unique_ptr<EglContext>> EglContext::Create(const std::function<Status()>& init) {
  std::string notes;
  std::vector<Candidate> candidates = CandidateDisplays(&notes);
  if (candidates.empty()) {
    return Status::Unsupported("EGL renderer: no EGL display (" + notes +
                               "is libEGL with Mesa or a GPU vendor's EGL installed?)");
  }
  for (const Candidate& c : candidates) {
    std::unique_ptr<EglContext> ctx(new EglContext());
    ctx->h_ = std::make_unique<Handles>();
    Handles& h = *ctx->h_;
    EGLint major = 0, minor = 0;
    if (!eglInitialize(c.display, &major, &minor)) {
      notes += c.label + ": eglInitialize: " + EglErrorName(eglGetError()) + "; ";
      continue;
    }
    {
      std::lock_guard<std::mutex> l(g_display_mu);
      ++g_display_refs[c.display];
    }
    h.display = c.display;  // from here the destructor releases what was made
    ctx->label_ = c.label;
    auto fail = [&](const std::string& msg) { notes += c.label + ": " + msg + "; "; };
    if (!eglBindAPI(EGL_OPENGL_API)) {
      fail("desktop OpenGL is not supported");
      continue;
    }
    const char* ext = eglQueryString(h.display, EGL_EXTENSIONS);
    const bool surfaceless = HasExtension(ext, "EGL_KHR_surfaceless_context");
    EGLConfig config = nullptr;
    EGLint n = 0;
    const EGLint config_attribs[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_SURFACE_TYPE,
                                     EGL_PBUFFER_BIT, EGL_NONE};
    if (!eglChooseConfig(h.display, config_attribs, &config, 1, &n) || n == 0) {
      if (!HasExtension(ext, "EGL_KHR_no_config_context") || !surfaceless) {
        fail("no OpenGL-renderable config");
        continue;
      }
      config = EGL_NO_CONFIG_KHR;
    }
    for (EGLint minor_version : {5, 3}) {
      const EGLint ctx_attribs[] = {EGL_CONTEXT_MAJOR_VERSION,
                                    4,
                                    EGL_CONTEXT_MINOR_VERSION,
                                    minor_version,
                                    EGL_CONTEXT_OPENGL_PROFILE_MASK,
                                    EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                    EGL_NONE};
      h.context = eglCreateContext(h.display, config, EGL_NO_CONTEXT, ctx_attribs);
      if (h.context != EGL_NO_CONTEXT) break;
    }
    if (h.context == EGL_NO_CONTEXT) {
      fail("eglCreateContext (OpenGL 4.3 core): " + EglErrorName(eglGetError()));
      continue;
    }
    if (!surfaceless) {
      const EGLint pb[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
      h.surface = eglCreatePbufferSurface(h.display, config, pb);
      if (h.surface == EGL_NO_SURFACE) {
        fail("no surfaceless contexts and no pbuffer");
        continue;
      }
    }
    if (!ctx->MakeCurrent()) {
      fail("eglMakeCurrent: " + EglErrorName(eglGetError()));
      continue;
    }
    Status st = init();
    ctx->ReleaseCurrent();
    if (!st.ok()) {
      fail(st.message());
      continue;
    }
    return ctx;
  }
  return Status::Unsupported("EGL renderer: no OpenGL 4.3 core context could be made (" +
                             notes.substr(0, notes.size() - 2) + ")");
}

namespace {

Result<GLuint> Compile(GLenum type, const char* src, const std::string& who) {
  GLuint s = glCreateShader(type);
  glShaderSource(s, 1, &src, nullptr);
  glCompileShader(s);
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    char log[4096];
    glGetShaderInfoLog(s, sizeof(log), nullptr, log);
    glDeleteShader(s);
    return Status::Internal(who + ": shader does not compile: " + log);
  }
  return s;
}

}  // namespace

Result<unsigned> LinkProgram(const char* vs_src, const char* fs_src, const std::string& who) {
  HVDB_ASSIGN_OR_RETURN(GLuint vs, Compile(GL_VERTEX_SHADER, vs_src, who));
  auto fs = Compile(GL_FRAGMENT_SHADER, fs_src, who);
  if (!fs.ok()) {
    glDeleteShader(vs);
    return fs.status();
  }
  GLuint p = glCreateProgram();
  glAttachShader(p, vs);
  glAttachShader(p, *fs);
  glLinkProgram(p);
  glDeleteShader(vs);
  glDeleteShader(*fs);
  GLint ok = 0;
  glGetProgramiv(p, GL_LINK_STATUS, &ok);
  if (!ok) {
    char log[4096];
    glGetProgramInfoLog(p, sizeof(log), nullptr, log);
    glDeleteProgram(p);
    return Status::Internal(who + ": program does not link: " + log);
  }
  return p;
}

}  // namespace hvdb::render::internal
