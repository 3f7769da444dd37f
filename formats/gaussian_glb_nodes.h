// Where a glTF file's node tree places its splat meshes (formats/gaussian_glb.cc's reader; internal
// to formats/). A node's local transform is its `matrix` (column-major) or T R S from
// `translation`, `rotation` (x y z w) and `scale`; a mesh's world transform is the product of
// those of its node and the node's ancestors. A Gaussian keeps its shape only under a similarity
// (rotation, uniform scale, translation): other transforms are refused, as is a mesh of splats
// that more than one node instantiates.
#ifndef HVDB_FORMATS_GAUSSIAN_GLB_NODES_H_
#define HVDB_FORMATS_GAUSSIAN_GLB_NODES_H_

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "formats/gaussian_transform.h"
#include "storage/status.h"

namespace hvdb::formats::glb {

// For each mesh of `root` with splat_mesh[m] set: the similarity its one instancing node's world
// transform is, in glTF's axes (the identity when no node instantiates it). Unsupported for a
// mirror, a non-uniform scale or shear, a projective row, or several instances; InvalidArgument
// for a malformed transform or a cycle. Errors start with `name`.
Result<std::vector<Similarity>> SplatMeshPlacements(const nlohmann::json& root,
                                                    const std::vector<bool>& splat_mesh,
                                                    const std::string& name);

// Moves splats [first, first + n) of `cloud` (decoded into the cloud's axes, x right y down)
// by `place`, a similarity in glTF's axes: conjugated by the axes' 180-degree turn about z.
Status PlaceSplats(GaussianCloud* cloud, size_t first, size_t n, const Similarity& place,
                   const std::string& where);

}  // namespace hvdb::formats::glb

#endif  // HVDB_FORMATS_GAUSSIAN_GLB_NODES_H_
