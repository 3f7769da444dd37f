#include "python/gaussians.h"

#include <pybind11/stl.h>

#include <cmath>
#include <fstream>
#include <sstream>

#include "formats/gaussian_points.h"
#include "formats/gaussians.h"

namespace hvdb::python {
namespace {

using F32 = py::array_t<float, py::array::c_style | py::array::forcecast>;

F32 Array(std::vector<py::ssize_t> shape) { return F32(shape); }

F32 Field(const py::dict& d, const char* key, std::vector<py::ssize_t> shape) {
  if (!d.contains(key)) Throw(Status::InvalidArgument(std::string("gaussians: no '") + key + "'"));
  F32 a = py::cast<F32>(d[key]);
  bool ok = static_cast<size_t>(a.ndim()) == shape.size();
  for (size_t k = 0; ok && k < shape.size(); ++k) ok = a.shape(static_cast<py::ssize_t>(k)) == shape[k];
  if (!ok) {
    std::string want;
    for (py::ssize_t v : shape) want += (want.empty() ? "" : ", ") + std::to_string(v);
    Throw(Status::InvalidArgument(std::string("gaussians['") + key + "']: expected shape (" +
                                  want + ")"));
  }
  return a;
}

Result<std::string> ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return Status::NotFound(path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

}  // namespace

py::dict GaussiansToDict(const GaussianColumns& g) {
  const auto n = static_cast<py::ssize_t>(g.size());
  const py::ssize_t coeffs = (g.sh_degree + 1) * (g.sh_degree + 1);
  const size_t rest = static_cast<size_t>(coeffs - 1);
  F32 opacity = Array({n}), logit = Array({n}), scale = Array({n, 3}), rot = Array({n, 4}),
      sh = Array({n, 3, coeffs});
  float* o = opacity.mutable_data();
  float* l = logit.mutable_data();
  float* s = scale.mutable_data();
  float* r = rot.mutable_data();
  float* h = sh.mutable_data();
  for (py::ssize_t i = 0; i < n; ++i) {
    const float* rec = g.record(static_cast<size_t>(i));
    l[i] = rec[kGsOpacity];
    o[i] = formats::Sigmoid(rec[kGsOpacity]);
    for (int k = 0; k < 3; ++k) s[3 * i + k] = rec[kGsScale + k];
    for (int k = 0; k < 4; ++k) r[4 * i + k] = rec[kGsRotation + k];
    for (size_t c = 0; c < 3; ++c) {
      float* out = h + (static_cast<size_t>(i) * 3 + c) * static_cast<size_t>(coeffs);
      out[0] = rec[kGsDc + c];
      for (size_t j = 0; j < rest; ++j) out[1 + j] = rec[kGsRest + c * rest + j];
    }
  }
  return py::dict(py::arg("sh_degree") = g.sh_degree, py::arg("antialiased") = g.antialiased,
                  py::arg("opacity") = opacity, py::arg("opacity_logit") = logit,
                  py::arg("log_scale") = scale, py::arg("rotation") = rot, py::arg("sh") = sh);
}

GaussianColumns GaussiansFromDict(const py::dict& d, size_t n) {
  const auto pn = static_cast<py::ssize_t>(n);
  if (!d.contains("sh")) Throw(Status::InvalidArgument("gaussians: no 'sh'"));
  F32 sh = py::cast<F32>(d["sh"]);
  py::ssize_t coeffs = sh.ndim() == 3 ? sh.shape(2) : 0;
  int degree = -1;
  for (int k = 0; k <= kMaxGaussianShDegree; ++k) {
    if ((k + 1) * (k + 1) == coeffs) degree = k;
  }
  if (degree < 0) {
    Throw(Status::InvalidArgument("gaussians['sh']: expected shape (n, 3, 1|4|9|16): SH degree "
                                  "0 to 3"));
  }
  sh = Field(d, "sh", {pn, 3, coeffs});
  F32 logit = Field(d, "opacity_logit", {pn});
  F32 scale = Field(d, "log_scale", {pn, 3});
  F32 rot = Field(d, "rotation", {pn, 4});
  GaussianColumns g;
  g.sh_degree = degree;
  g.antialiased = d.contains("antialiased") && py::cast<bool>(d["antialiased"]);
  g.values.resize(n * g.stride());
  const size_t rest = static_cast<size_t>(coeffs - 1);
  for (size_t i = 0; i < n; ++i) {
    float* rec = g.record(i);
    rec[kGsOpacity] = logit.data()[i];
    for (size_t k = 0; k < 3; ++k) rec[kGsScale + k] = scale.data()[3 * i + k];
    for (size_t k = 0; k < 4; ++k) rec[kGsRotation + k] = rot.data()[4 * i + k];
    for (size_t c = 0; c < 3; ++c) {
      const float* in = sh.data() + (i * 3 + c) * static_cast<size_t>(coeffs);
      rec[kGsDc + c] = in[0];
      for (size_t j = 0; j < rest; ++j) rec[kGsRest + c * rest + j] = in[1 + j];
    }
  }
  Check(ValidateGaussianColumns(g));
  return g;
}

py::tuple ReadSplats(const std::string& path) {
  std::vector<Point> points;
  GaussianColumns records;
  std::vector<std::string> ignored;
  {
    py::gil_scoped_release release;
    Result<std::string> bytes = ReadFile(path);
    Result<formats::GaussianCloud> cloud =
        bytes.ok() ? formats::ReadGaussians(*bytes, path) : Result<formats::GaussianCloud>(bytes.status());
    if (!cloud.ok()) {
      py::gil_scoped_acquire acquire;
      Throw(cloud.status());
    }
    ignored = cloud->ignored;
    formats::CloudToPoints(*cloud, 0, &points, &records);
  }
  return py::make_tuple(ToArray(std::move(points)), GaussiansToDict(records), ignored);
}

void WriteSplats(const std::string& path, const py::array& points, const py::dict& gaussians,
                 const std::string& format) {
  std::vector<Point> pts = FromArray(points);
  GaussianColumns records = GaussiansFromDict(gaussians, pts.size());
  if (format != "3dgs" && format != "spz" && format != "splat" && format != "glb") {
    Throw(Status::InvalidArgument("format: '" + format + "' is not 3dgs, spz, splat or glb"));
  }
  py::gil_scoped_release release;
  const formats::GaussianCloud cloud = formats::PointsToCloud(pts, records);
  Result<std::string> bytes = format == "spz"     ? formats::WriteSpz(cloud, path)
                              : format == "splat" ? formats::WriteSplat(cloud, path)
                              : format == "glb"   ? formats::WriteGlb(cloud, path)
                                                  : formats::WriteGaussianPly(cloud, path);
  Status st = bytes.status();
  if (st.ok()) {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(bytes->data(), static_cast<std::streamsize>(bytes->size()));
    if (!out) st = Status::IOError(path + ": write failed");
  }
  py::gil_scoped_acquire acquire;
  Check(st);
}

}  // namespace hvdb::python
