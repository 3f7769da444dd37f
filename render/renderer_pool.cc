#include "render/renderer_pool.h"

#include "render/splat.h"

namespace hvdb::render {

RendererPool::RendererPool(size_t capacity) : capacity_(std::max<size_t>(1, capacity)) {}

RendererPool::~RendererPool() = default;

size_t RendererPool::in_use() const {
  std::lock_guard<std::mutex> l(mu_);
  return in_use_;
}

Result<RendererPool::Lease> RendererPool::TryAcquire(RendererKind kind) {
  std::lock_guard<std::mutex> l(mu_);
  if (in_use_ >= capacity_) {
    return Status::Overloaded("render: " + std::to_string(capacity_) +
                              " renders are in progress, the server's limit; retry later");
  }
  ++in_use_;
  return Lease(this, kind);
}

Result<std::unique_ptr<Renderer>> RendererPool::Take(RendererKind kind, bool* fallback,
                                                     std::string* why) {
  *fallback = false;
  if (kind == RendererKind::kAuto) {
    // Decided once per pool, with the first EGL renderer: on a GPU auto means EGL; on a
    // software rasteriser or without a context, the CPU renderer.
    std::optional<bool> use_egl;
    {
      std::lock_guard<std::mutex> l(mu_);
      use_egl = auto_egl_;
    }
    if (!use_egl) {
      auto egl = Take(RendererKind::kEgl, fallback, why);
      std::lock_guard<std::mutex> l(mu_);
      if (!auto_egl_) {
        if (!egl.ok()) {
          auto_egl_ = false;
          auto_reason_ =
              "render service: no EGL context (" + egl.status().message() + "): the CPU renderer";
          internal::LogWarning("render service: using the CPU renderer: " +
                               egl.status().message());
        } else {
          std::string reason;
          bool hardware = (*egl)->hardware();
          std::unique_ptr<Renderer> chosen = ChooseAuto(std::move(egl).value(), &reason);
          auto_egl_ = hardware;
          auto_reason_ = "render service: " + reason;
          if (hardware) {
            *why = auto_reason_;
            return chosen;
          }
          idle_cpu_.push_back(std::move(chosen));
          // The EGL renderer ChooseAuto passed over is not kept: its context would hold
          // memory for requests that name egl, which make their own.
        }
      }
      use_egl = auto_egl_;
    }
    {
      std::lock_guard<std::mutex> l(mu_);
      *why = auto_reason_;
      *fallback = !*use_egl && egl_error_.has_value();
    }
    if (*use_egl) {
      bool unused;
      std::string ignored;
      auto egl = Take(RendererKind::kEgl, &unused, &ignored);
      if (egl.ok()) return egl;
      // A GPU that cannot give one more context now (memory, driver limits): this request
      // falls back rather than fails, as auto promises.
      internal::LogWarning("render service: using the CPU renderer for this request: " +
                           egl.status().message());
      *fallback = true;
      *why = "render service: the GPU gave no EGL context (" + egl.status().message() +
             "): the CPU renderer";
    }
    kind = RendererKind::kCpu;
  } else {
    *why = kind == RendererKind::kEgl ? "asked for the EGL renderer" : "asked for the CPU renderer";
  }
  if (kind == RendererKind::kEgl) {
    std::optional<Status> known_error;
    {
      std::lock_guard<std::mutex> l(mu_);
      if (!idle_egl_.empty()) {
        auto r = std::move(idle_egl_.back());
        idle_egl_.pop_back();
        return r;
      }
      known_error = egl_error_;
    }
    if (known_error) return *known_error;
    // Made outside the lock: creating a context takes tens of milliseconds or more.
    auto r = MakeEglRenderer();
    if (r.ok()) return r;
    std::lock_guard<std::mutex> l(mu_);
    // Remembered (not retried: each attempt costs a driver initialisation) unless EGL has
    // worked here before: then the failure is taken as passing (a GPU out of contexts).
    if (!egl_error_ && !egl_worked_) egl_error_ = r.status();
    return r.status();
  }
  {
    std::lock_guard<std::mutex> l(mu_);
    if (!idle_cpu_.empty()) {
      auto r = std::move(idle_cpu_.back());
      idle_cpu_.pop_back();
      return r;
    }
  }
  return MakeCpuRenderer();
}

void RendererPool::Give(std::unique_ptr<Renderer> r) {
  std::lock_guard<std::mutex> l(mu_);
  if (r && r->kind() == RendererKind::kEgl) egl_worked_ = true;
  if (r) (r->kind() == RendererKind::kEgl ? idle_egl_ : idle_cpu_).push_back(std::move(r));
  --in_use_;
}

RendererPool::Lease::Lease(Lease&& other) noexcept
    : pool_(other.pool_),
      kind_(other.kind_),
      renderer_(std::move(other.renderer_)),
      fallback_(other.fallback_),
      why_(std::move(other.why_)) {
  other.pool_ = nullptr;
}

RendererPool::Lease& RendererPool::Lease::operator=(Lease&& other) noexcept {
  if (this != &other) {
    Release();
    pool_ = other.pool_;
    kind_ = other.kind_;
    renderer_ = std::move(other.renderer_);
    fallback_ = other.fallback_;
    why_ = std::move(other.why_);
    other.pool_ = nullptr;
  }
  return *this;
}

RendererPool::Lease::~Lease() { Release(); }

void RendererPool::Lease::Release() {
  if (pool_ == nullptr) return;
  pool_->Give(std::move(renderer_));
  pool_ = nullptr;
}

Result<Renderer*> RendererPool::Lease::Get() {
  if (pool_ == nullptr) return Status::Internal("render: the lease was given back");
  if (!renderer_) {
    HVDB_ASSIGN_OR_RETURN(renderer_, pool_->Take(kind_, &fallback_, &why_));
  }
  return renderer_.get();
}

}  // namespace hvdb::render
