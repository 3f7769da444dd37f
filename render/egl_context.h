// A headless OpenGL 4.3+ core context through EGL, for the renderers of render/ (internal): the
// EWA splat renderer (egl_renderer.cc) and the 3DGS rasteriser (egl_gaussian.cc).
//
// Display: the EGL device platform first (the vendor's driver on a GPU machine; hardware
// devices before software ones), then Mesa's surfaceless platform (llvmpipe), then the default
// display. A context is current on one thread at a time (MakeCurrent per call).
#ifndef HVDB_RENDER_EGL_CONTEXT_H_
#define HVDB_RENDER_EGL_CONTEXT_H_

#include <functional>
#include <memory>
#include <string>

#include "storage/status.h"

namespace hvdb::render::internal {

class EglContext {
 public:
  // The first display whose OpenGL 4.3 (4.5 where offered) core context can be made and on
  // which `init` (run with the context current) succeeds; Unsupported with every display's
  // reason otherwise.
  static Result<std::unique_ptr<EglContext>> Create(const std::function<Status()>& init);
  ~EglContext();
  EglContext(const EglContext&) = delete;
  EglContext& operator=(const EglContext&) = delete;

  bool MakeCurrent();  // binds the OpenGL API and the context to the calling thread
  void ReleaseCurrent();
  // "device 0", "device 1 (software)", "surfaceless", "default display".
  const std::string& label() const { return label_; }
  // Whether the display is a hardware device whose driver is no software rasteriser.
  bool Hardware(const std::string& gl_renderer) const;
  // The calling thread's last EGL error, by name.
  static std::string LastError();

 private:
  EglContext() = default;
  struct Handles;
  std::unique_ptr<Handles> h_;
  std::string label_;
};

// Compiles and links a vertex and a fragment shader in the current context: the program's name,
// or Internal with the driver's log (`who` opens the message).
Result<unsigned> LinkProgram(const char* vs_src, const char* fs_src, const std::string& who);

}  // namespace hvdb::render::internal

#endif  // HVDB_RENDER_EGL_CONTEXT_H_
