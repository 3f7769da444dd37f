// The points a render job gathers from a query: one contiguous array (the renderers take a
// span) in anonymous memory of its own, advised onto 2 MiB pages and grown by mremap.
//
// Why not std::vector: a frame of the SJTU stage is 2.6 M points (170 MB). Growing a vector
// to it copies the points several times over into fresh memory, and every 4 KiB of fresh
// memory is a page fault, which costs microseconds on a virtual machine: gathering took 2.3 s
// of a 4 s `hvdb render` against 0.46 s for the query itself (bench/README.md, issue 48).
// mremap moves the pages instead of copying them, and huge pages take 512 times fewer faults.
#ifndef HVDB_RENDER_POINT_BUFFER_H_
#define HVDB_RENDER_POINT_BUFFER_H_

#include <cstddef>
#include <span>

#include "storage/point.h"

namespace hvdb::render {

class PointBuffer {
 public:
  PointBuffer() = default;
  ~PointBuffer();
  PointBuffer(PointBuffer&& o) noexcept;
  PointBuffer& operator=(PointBuffer&& o) noexcept;
  PointBuffer(const PointBuffer&) = delete;
  PointBuffer& operator=(const PointBuffer&) = delete;

  // Room for `n` points in all (kept contents); throws std::bad_alloc when the kernel refuses.
  void Reserve(size_t n);
  // Appends n uninitialised points and returns them (Reserve first to bound the growth).
  Point* Append(size_t n);
  // Drops the last n points (what a short read left unused).
  void Shrink(size_t n) { size_ -= n; }
  void clear() { size_ = 0; }

  size_t size() const { return size_; }
  size_t capacity() const { return capacity_; }
  bool empty() const { return size_ == 0; }
  Point* data() { return data_; }
  const Point* data() const { return data_; }
  const Point& front() const { return data_[0]; }
  const Point& operator[](size_t i) const { return data_[i]; }
  const Point* begin() const { return data_; }
  const Point* end() const { return data_ + size_; }
  operator std::span<const Point>() const { return {data_, size_}; }

 private:
  Point* data_ = nullptr;
  size_t size_ = 0, capacity_ = 0;  // in points; capacity_ * sizeof(Point) bytes are mapped
};

}  // namespace hvdb::render

#endif  // HVDB_RENDER_POINT_BUFFER_H_
