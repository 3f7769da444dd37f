// What the files of the C++ half of the Python module share (module.cc, gaussians.cc): errors
// on their way to Python and points as numpy arrays of POINT_DTYPE. Internal to python/.
#ifndef HVDB_PYTHON_COMMON_H_
#define HVDB_PYTHON_COMMON_H_

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <exception>
#include <string>
#include <vector>

#include "storage/point.h"
#include "storage/status.h"

namespace hvdb::python {

namespace py = pybind11;

// A Status on its way to Python: __init__.py maps `code` to an exception class.
struct StatusError : std::exception {
  StatusCode code;
  std::string message;
  StatusError(StatusCode c, std::string m) : code(c), message(std::move(m)) {}
  const char* what() const noexcept override { return message.c_str(); }
};

[[noreturn]] inline void Throw(const Status& st) { throw StatusError(st.code(), st.message()); }
inline void Check(const Status& st) {
  if (!st.ok()) Throw(st);
}
template <typename T>
T Take(Result<T> r) {
  if (!r.ok()) Throw(r.status());
  return std::move(r).value();
}

// hvdb.POINT_DTYPE (imported from the package once).
py::object& PointDtype();
// Takes ownership of the points: numpy frees them with the array.
py::array ToArray(std::vector<Point> points);
// A structured array of POINT_DTYPE (checked in __init__.py) as Points.
std::vector<Point> FromArray(const py::array& a);

}  // namespace hvdb::python

#endif  // HVDB_PYTHON_COMMON_H_
