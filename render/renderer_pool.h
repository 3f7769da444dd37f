// Renderers shared by concurrent requests (the server's render service).
//
// At most `capacity` renders run at once: a request takes a slot with TryAcquire, which
// refuses at once (Overloaded) when all are taken, rather than queueing behind minutes of
// work. Renderers, with their EGL contexts, compiled shaders and buffers, are made on first use
// and kept for later requests; an EGL renderer may be used from any thread, one at a time.
#ifndef HVDB_RENDER_RENDERER_POOL_H_
#define HVDB_RENDER_RENDERER_POOL_H_

#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "render/renderer.h"

namespace hvdb::render {

class RendererPool {
 public:
  explicit RendererPool(size_t capacity);
  ~RendererPool();
  RendererPool(const RendererPool&) = delete;
  RendererPool& operator=(const RendererPool&) = delete;

  // One slot of the pool; gives its renderer back when destroyed.
  class Lease {
   public:
    Lease(Lease&& other) noexcept;
    Lease& operator=(Lease&& other) noexcept;
    ~Lease();
    // The renderer (made on the first call, which may take a while: call it on a worker).
    // kAuto chooses as MakeRenderer does, once per pool: EGL on a GPU, else the CPU renderer
    // (a missing EGL context is warned about once per pool).
    Result<Renderer*> Get();
    // True when kAuto found no EGL context and used the CPU renderer.
    bool fallback() const { return fallback_; }
    // After Get(): which renderer and why (kAuto's reason, or "asked for ...").
    const std::string& why() const { return why_; }

   private:
    friend class RendererPool;
    Lease(RendererPool* pool, RendererKind kind) : pool_(pool), kind_(kind) {}
    void Release();
    RendererPool* pool_;
    RendererKind kind_;
    std::unique_ptr<Renderer> renderer_;
    bool fallback_ = false;
    std::string why_;
  };

  // A slot for a render of `kind`, or Overloaded when `capacity` renders are in flight.
  Result<Lease> TryAcquire(RendererKind kind);
  size_t capacity() const { return capacity_; }
  size_t in_use() const;

 private:
  Result<std::unique_ptr<Renderer>> Take(RendererKind kind, bool* fallback, std::string* why);
  void Give(std::unique_ptr<Renderer> r);

  const size_t capacity_;
  mutable std::mutex mu_;
  size_t in_use_ = 0;
  std::vector<std::unique_ptr<Renderer>> idle_egl_, idle_cpu_;
  // Why no EGL renderer could be made, once that has happened (not retried: each attempt
  // costs a driver initialisation).
  std::optional<Status> egl_error_;
  bool egl_worked_ = false;  // an EGL renderer has been made (and given back) here
  // kAuto's choice once made: EGL (a GPU) or not, and why.
  std::optional<bool> auto_egl_;
  std::string auto_reason_;
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_RENDERER_POOL_H_
