#include "python/common.h"

#include <cstring>

namespace hvdb::python {

py::object& PointDtype() {
  static py::object* dtype = nullptr;
  if (dtype == nullptr) {
    dtype = new py::object(py::module_::import("hvdb").attr("POINT_DTYPE"));
  }
  return *dtype;
}

// Takes ownership of the points: numpy frees them with the array.
py::array ToArray(std::vector<Point> points) {
  auto* owned = new std::vector<Point>(std::move(points));
  py::capsule free(owned, [](void* p) { delete static_cast<std::vector<Point>*>(p); });
  return py::array(py::dtype::from_args(PointDtype()),
                   {static_cast<py::ssize_t>(owned->size())},
                   {static_cast<py::ssize_t>(sizeof(Point))}, owned->data(), free);
}

// A structured array of POINT_DTYPE (checked in __init__.py) as Points.
std::vector<Point> FromArray(const py::array& a) {
  if (a.ndim() != 1 || a.itemsize() != static_cast<py::ssize_t>(sizeof(Point)) ||
      !(a.flags() & py::array::c_style)) {
    Throw(Status::InvalidArgument(
        "points: expected a 1-D C-contiguous array of hvdb.POINT_DTYPE (64-byte records)"));
  }
  std::vector<Point> out(static_cast<size_t>(a.shape(0)));
  if (!out.empty()) std::memcpy(static_cast<void*>(out.data()), a.data(), out.size() * sizeof(Point));
  for (Point& p : out) p.reserved = 0;
  return out;
}

}  // namespace hvdb::python
