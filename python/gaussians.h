// Gaussian splats from Python (python/gaussians.cc): a Gaussian-splat dataset's records
// (storage/gaussian_column.h) as a dict of numpy arrays, and splat files (formats/gaussians.h)
// read and written as points with that dict. Internal to python/.
//
// The dict: sh_degree (int), antialiased (bool), opacity (n, sigmoid of the stored logit),
// opacity_logit (n), log_scale (n, 3), rotation (n, 4: w x y z as stored), sh (n, 3,
// (d+1)^2: per channel R G B, coefficient 0 the DC term f_dc, then f_rest's), all float32; from
// Database.gaussians also derived (how many were derived from their points).
#ifndef HVDB_PYTHON_GAUSSIANS_H_
#define HVDB_PYTHON_GAUSSIANS_H_

#include <string>

#include "python/common.h"
#include "storage/gaussian_column.h"

namespace hvdb::python {

py::dict GaussiansToDict(const GaussianColumns& g);
// The dict's records for n points (opacity_logit, log_scale, rotation, sh; the degree from
// sh's shape); InvalidArgument naming a key that is missing or of the wrong shape.
GaussianColumns GaussiansFromDict(const py::dict& d, size_t n);
// hvdb.read_splats: (points of frame 0, gaussians dict, ignored properties) of a 3DGS PLY, SPZ,
// GLB or .splat file.
py::tuple ReadSplats(const std::string& path);
// hvdb.write_splats: format "3dgs", "spz" or "splat".
void WriteSplats(const std::string& path, const py::array& points, const py::dict& gaussians,
                 const std::string& format);

}  // namespace hvdb::python

#endif  // HVDB_PYTHON_GAUSSIANS_H_
