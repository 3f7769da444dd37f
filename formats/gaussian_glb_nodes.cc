// The node tree of a glTF file, for its splat meshes (formats/gaussian_glb_nodes.h).
#include "formats/gaussian_glb_nodes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>

namespace hvdb::formats::glb {
namespace {

using json = nlohmann::json;
using Mat4 = std::array<double, 16>;  // row-major

constexpr Mat4 kIdentity = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};

std::string S(uint64_t v) { return std::to_string(v); }

Mat4 Mul(const Mat4& a, const Mat4& b) {
  Mat4 c{};
  for (int i = 0; i < 4; ++i) {
    for (int j = 0; j < 4; ++j) {
      for (int k = 0; k < 4; ++k) c[4 * i + j] += a[4 * i + k] * b[4 * k + j];
    }
  }
  return c;
}

// `n` finite numbers of member `key`, or `fallback` when absent.
Status Numbers(const json& node, const char* key, size_t n, const std::vector<double>& fallback,
               const std::string& where, std::vector<double>* out) {
  auto it = node.find(key);
  if (it == node.end()) {
    *out = fallback;
    return Status::OK();
  }
  if (!it->is_array() || it->size() != n) {
    return Status::InvalidArgument(where + ": " + key + " must be an array of " + S(n) +
                                   " numbers");
  }
  out->assign(n, 0.0);
  for (size_t k = 0; k < n; ++k) {
    const json& e = (*it)[k];
    if (!e.is_number() || !std::isfinite(e.get<double>())) {
      return Status::InvalidArgument(where + ": " + key + "[" + S(k) + "] is not a finite number");
    }
    (*out)[k] = e.get<double>();
  }
  return Status::OK();
}

// The node's local transform: its matrix, else T R S (glTF 2.0, 5.25).
Status Local(const json& node, const std::string& where, Mat4* m) {
  std::vector<double> v;
  if (node.contains("matrix")) {
    HVDB_RETURN_IF_ERROR(Numbers(node, "matrix", 16, {}, where, &v));
    for (int i = 0; i < 4; ++i) {
      for (int j = 0; j < 4; ++j) (*m)[4 * i + j] = v[4 * j + i];  // column-major in the file
    }
    return Status::OK();
  }
  std::vector<double> t, q, s;
  HVDB_RETURN_IF_ERROR(Numbers(node, "translation", 3, {0, 0, 0}, where, &t));
  HVDB_RETURN_IF_ERROR(Numbers(node, "rotation", 4, {0, 0, 0, 1}, where, &q));
  HVDB_RETURN_IF_ERROR(Numbers(node, "scale", 3, {1, 1, 1}, where, &s));
  const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (std::abs(norm - 1) > 1e-3) {
    return Status::InvalidArgument(where + ": rotation is not a unit quaternion (norm " +
                                   std::to_string(norm) + ")");
  }
  const double x = q[0] / norm, y = q[1] / norm, z = q[2] / norm, w = q[3] / norm;
  const double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - z * w),     2 * (x * z + y * w),
                       2 * (x * y + z * w),     1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                       2 * (x * z - y * w),     2 * (y * z + x * w),     1 - 2 * (x * x + y * y)};
  *m = kIdentity;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) (*m)[4 * i + j] = r[3 * i + j] * s[j];
    (*m)[4 * i + 3] = t[i];
  }
  return Status::OK();
}

// `m` as a similarity s R p + t, or Unsupported naming what else it does.
Status ToSimilarity(const Mat4& m, const std::string& where, Similarity* out) {
  if (m[12] != 0 || m[13] != 0 || m[14] != 0 || m[15] != 1) {
    return Status::Unsupported(where + ": a projective transform (last row not 0 0 0 1)");
  }
  const double det = m[0] * (m[5] * m[10] - m[6] * m[9]) - m[1] * (m[4] * m[10] - m[6] * m[8]) +
                     m[2] * (m[4] * m[9] - m[5] * m[8]);
  if (!(det > 0)) {
    return Status::Unsupported(where + (det < 0 ? ": a mirroring transform" : ": a flat transform") +
                               " (determinant " + std::to_string(det) +
                               "): a splat's rotation cannot hold it");
  }
  const double s = std::cbrt(det);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) out->rotation[3 * i + j] = m[4 * i + j] / s;
    out->translation[i] = m[4 * i + 3];
  }
  // R^T R = I within 1e-6: a uniform scale times a rotation.
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      double d = 0;
      for (int k = 0; k < 3; ++k) d += out->rotation[3 * k + i] * out->rotation[3 * k + j];
      if (std::abs(d - (i == j ? 1.0 : 0.0)) > 1e-6) {
        return Status::Unsupported(where + ": a non-uniform scale or shear; Gaussians are read "
                                           "under rotations, uniform scales and translations only");
      }
    }
  }
  out->scale = s;
  return Status::OK();
}

}  // namespace

Result<std::vector<Similarity>> SplatMeshPlacements(const json& root,
                                                    const std::vector<bool>& splat_mesh,
                                                    const std::string& name) {
  std::vector<Similarity> out(splat_mesh.size());
  auto nodes_it = root.find("nodes");
  if (nodes_it == root.end() || !nodes_it->is_array()) return out;
  const json& nodes = *nodes_it;
  const size_t count = nodes.size();
  std::vector<size_t> parent(count, count);
  for (size_t i = 0; i < count; ++i) {
    if (!nodes[i].is_object()) continue;
    auto children = nodes[i].find("children");
    if (children == nodes[i].end() || !children->is_array()) continue;
    for (const json& c : *children) {
      if (c.is_number_unsigned() && c.get<uint64_t>() < count) parent[c.get<uint64_t>()] = i;
    }
  }
  std::vector<size_t> instanced_by(splat_mesh.size(), count);
  for (size_t i = 0; i < count; ++i) {
    if (!nodes[i].is_object()) continue;
    auto mesh = nodes[i].find("mesh");
    if (mesh == nodes[i].end() || !mesh->is_number_unsigned()) continue;
    const uint64_t m = mesh->get<uint64_t>();
    if (m >= splat_mesh.size() || !splat_mesh[m]) continue;
    if (instanced_by[m] != count) {
      return Status::Unsupported(name + ": the splats of mesh " + S(m) + " are instanced by nodes " +
                                 S(instanced_by[m]) + " and " + S(i) +
                                 "; one instance of each is read: flatten the scene first");
    }
    instanced_by[m] = i;
    // Up to the root; a cycle (more steps than nodes) is an error.
    Mat4 world = kIdentity;
    size_t steps = 0;
    for (size_t j = i; j < count; j = parent[j]) {
      if (++steps > count) {
        return Status::InvalidArgument(name + ": the nodes above node " + S(i) + " form a cycle");
      }
      Mat4 local;
      HVDB_RETURN_IF_ERROR(Local(nodes[j], name + ": node " + S(j), &local));
      world = Mul(local, world);
    }
    HVDB_RETURN_IF_ERROR(ToSimilarity(
        world, name + ": node " + S(i) + " (over the splats of mesh " + S(m) + ")", &out[m]));
  }
  return out;
}

Status PlaceSplats(GaussianCloud* cloud, size_t first, size_t n, const Similarity& place,
                   const std::string& where) {
  // C = diag(-1, -1, 1) (gaussian_glb.cc): C M C is M in the cloud's axes.
  const double c[3] = {-1, -1, 1};
  Similarity m = place;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) m.rotation[3 * i + j] *= c[i] * c[j];
    m.translation[i] *= c[i];
  }
  GaussianCloud part;
  part.sh_degree = cloud->sh_degree;
  part.Resize(n);
  const size_t rest = cloud->sh_rest_per_splat();
  auto slice = [&](std::vector<float>& from, std::vector<float>& to, size_t per, bool in) {
    float* whole = from.data() + first * per;
    if (in) {
      std::copy(whole, whole + n * per, to.begin());
    } else {
      std::copy(to.begin(), to.begin() + static_cast<std::ptrdiff_t>(n * per), whole);
    }
  };
  for (bool in : {true, false}) {
    if (!in) HVDB_RETURN_IF_ERROR(TransformCloud(&part, m, where));
    slice(cloud->position, part.position, 3, in);
    slice(cloud->scale, part.scale, 3, in);
    slice(cloud->rotation, part.rotation, 4, in);
    slice(cloud->opacity, part.opacity, 1, in);
    slice(cloud->sh_dc, part.sh_dc, 3, in);
    slice(cloud->sh_rest, part.sh_rest, rest, in);
  }
  return Status::OK();
}

}  // namespace hvdb::formats::glb
