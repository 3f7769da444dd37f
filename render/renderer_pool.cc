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

Result<std::unique_ptr<Renderer>> RendererPool::Take(RendererKind kind, bool* fallback) {
  *fallback = false;
  if (kind != RendererKind::kCpu) {
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
    if (!known_error) {
      // Made outside the lock: creating a context takes tens of milliseconds or more.
      auto r = MakeEglRenderer();
      if (r.ok()) return r;
      std::lock_guard<std::mutex> l(mu_);
      if (!egl_error_) {
        egl_error_ = r.status();
        if (kind == RendererKind::kAuto) {
          internal::LogWarning("render service: using the CPU renderer: " + r.status().message());
        }
      }
      known_error = egl_error_;
    }
    if (kind == RendererKind::kEgl) return *known_error;
    *fallback = true;
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
  if (r) (r->kind() == RendererKind::kEgl ? idle_egl_ : idle_cpu_).push_back(std::move(r));
  --in_use_;
}

RendererPool::Lease::Lease(Lease&& other) noexcept
    : pool_(other.pool_),
      kind_(other.kind_),
      renderer_(std::move(other.renderer_)),
      fallback_(other.fallback_) {
  other.pool_ = nullptr;
}

RendererPool::Lease& RendererPool::Lease::operator=(Lease&& other) noexcept {
  if (this != &other) {
    Release();
    pool_ = other.pool_;
    kind_ = other.kind_;
    renderer_ = std::move(other.renderer_);
    fallback_ = other.fallback_;
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
    HVDB_ASSIGN_OR_RETURN(renderer_, pool_->Take(kind_, &fallback_));
  }
  return renderer_.get();
}

}  // namespace hvdb::render
