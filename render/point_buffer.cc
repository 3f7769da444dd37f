#include "render/point_buffer.h"

#include <algorithm>
#include <new>
#include <type_traits>
#include <utility>

#include <sys/mman.h>

namespace hvdb::render {

namespace {

constexpr size_t kHugePage = size_t{2} << 20;

size_t RoundUp(size_t bytes) { return (bytes + kHugePage - 1) / kHugePage * kHugePage; }

}  // namespace

PointBuffer::~PointBuffer() {
  if (data_ != nullptr) munmap(data_, capacity_ * sizeof(Point));
}

PointBuffer::PointBuffer(PointBuffer&& o) noexcept
    : data_(std::exchange(o.data_, nullptr)),
      size_(std::exchange(o.size_, 0)),
      capacity_(std::exchange(o.capacity_, 0)) {}

PointBuffer& PointBuffer::operator=(PointBuffer&& o) noexcept {
  if (this != &o) {
    PointBuffer gone(std::move(*this));
    data_ = std::exchange(o.data_, nullptr);
    size_ = std::exchange(o.size_, 0);
    capacity_ = std::exchange(o.capacity_, 0);
  }
  return *this;
}

// Appended points are written by the query before they are read (and mapped memory is zeroed).
static_assert(std::is_trivially_copyable_v<Point>);

void PointBuffer::Reserve(size_t n) {
  if (n <= capacity_) return;
  // Whole huge pages (sizeof(Point) divides 2 MiB: the capacity is exact).
  static_assert(kHugePage % sizeof(Point) == 0);
  const size_t bytes = RoundUp(n * sizeof(Point));
  void* p = data_ == nullptr
                ? mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0)
                : mremap(data_, capacity_ * sizeof(Point), bytes, MREMAP_MAYMOVE);
  if (p == MAP_FAILED) throw std::bad_alloc();
  madvise(p, bytes, MADV_HUGEPAGE);  // advice only: on 4 KiB pages it still works
  data_ = static_cast<Point*>(p);
  capacity_ = bytes / sizeof(Point);
}

Point* PointBuffer::Append(size_t n) {
  if (size_ + n > capacity_) Reserve(std::max(size_ + n, 2 * capacity_));
  Point* at = data_ + size_;
  size_ += n;
  return at;
}

}  // namespace hvdb::render
