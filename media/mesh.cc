// Mesh files (OBJ, PLY, glTF/GLB, STL, ... through assimp) sampled into surfels: area-uniform,
// deterministic, with the surface's normals and colours.
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <random>

#include <assimp/postprocess.h>

#include "media/assimp_lib.h"
#include "media/media.h"
#include "media/surfel.h"

#if defined(__SANITIZE_ADDRESS__)
#define HVDB_UNDER_ASAN 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define HVDB_UNDER_ASAN 1
#endif
#endif

namespace hvdb::media {
namespace {

// The seed of every mesh's sample: the same file and placement give the same points.
constexpr uint64_t kSeed = 0x68766462'6d657368ull;
constexpr double kMinSpacing = 0.002;      // metres
constexpr double kMaxMeshPoints = 200000;  // a frame, at the default spacing

// assimp's file access for a request's mesh (its C API's aiFileIO): the file itself is served
// from memory under a name beginning with kMemoryName (as Assimp::Importer's ReadFileFromMemory
// does), and every other name assimp asks for (a glTF's external buffer, an OBJ's mtllib, ...)
// is refused and remembered, so that no path on the server is ever opened on a client's behalf.
constexpr char kMemoryName[] = "$$$___magic___$$$";

struct RequestOnlyIO {
  aiFileIO io;
  std::string_view data;
  std::string refused;
};

struct MemoryFile {
  aiFile file;
  std::string_view data;
  size_t pos = 0;
};

MemoryFile* FileOf(aiFile* f) { return reinterpret_cast<MemoryFile*>(f->UserData); }

size_t MemoryRead(aiFile* f, char* buf, size_t size, size_t count) {
  MemoryFile* m = FileOf(f);
  if (size == 0 || count == 0) return 0;
  const size_t n = std::min(count, (m->data.size() - m->pos) / size);
  std::memcpy(buf, m->data.data() + m->pos, n * size);
  m->pos += n * size;
  return n;
}
size_t MemoryWrite(aiFile*, const char*, size_t, size_t) { return 0; }
size_t MemoryTell(aiFile* f) { return FileOf(f)->pos; }
size_t MemorySize(aiFile* f) { return FileOf(f)->data.size(); }
void MemoryFlush(aiFile*) {}
aiReturn MemorySeek(aiFile* f, size_t offset, aiOrigin origin) {
  MemoryFile* m = FileOf(f);
  const size_t base = origin == aiOrigin_CUR ? m->pos : origin == aiOrigin_END ? m->data.size() : 0;
  if (origin == aiOrigin_END ? offset > base : offset > m->data.size() - base) return aiReturn_FAILURE;
  m->pos = origin == aiOrigin_END ? base - offset : base + offset;
  return aiReturn_SUCCESS;
}

aiFile* RequestOpen(aiFileIO* io, const char* name, const char*) {
  auto* r = reinterpret_cast<RequestOnlyIO*>(io->UserData);
  if (name != nullptr && std::strncmp(name, kMemoryName, sizeof kMemoryName - 1) == 0) {
    auto* m = new MemoryFile{{MemoryRead, MemoryWrite, MemoryTell, MemorySize, MemorySeek,
                              MemoryFlush, nullptr},
                             r->data};
    m->file.UserData = reinterpret_cast<aiUserData>(m);
    return &m->file;
  }
  if (r->refused.empty()) r->refused = name != nullptr && *name != 0 ? name : "(no name)";
  return nullptr;
}
void RequestClose(aiFileIO*, aiFile* f) {
  if (f != nullptr) delete FileOf(f);
}

// A mesh's colour source: a texture (RGBA), vertex colours, or one colour.
struct Colours {
  Picture texture;
  int uv_channel = -1;
  bool vertex_colours = false;
  std::array<uint8_t, 3> flat{200, 200, 200};
};

uint8_t ToByte(double v) {
  return static_cast<uint8_t>(std::clamp(std::lround(v * 255.0), 0L, 255L));
}

// Embedded textures are decoded as images are (DecodeImage's bounds), at most this many texels
// a side: plenty for samples 2 mm apart.
constexpr uint32_t kMaxTextureSide = 4096;

Result<Colours> ColoursOf(const AssimpLib& ai, const aiScene* scene, const aiMesh* mesh,
                          const Budget& budget) {
  Colours c;
  if (mesh->HasVertexColors(0)) c.vertex_colours = true;
  if (mesh->mMaterialIndex >= scene->mNumMaterials) return c;
  const aiMaterial* mat = scene->mMaterials[mesh->mMaterialIndex];
  aiColor4D diffuse;
  if (ai.aiGetMaterialColor(mat, AI_MATKEY_BASE_COLOR, &diffuse) == AI_SUCCESS ||
      ai.aiGetMaterialColor(mat, AI_MATKEY_COLOR_DIFFUSE, &diffuse) == AI_SUCCESS) {
    c.flat = {ToByte(diffuse.r), ToByte(diffuse.g), ToByte(diffuse.b)};
  }
  for (aiTextureType type : {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}) {
    aiString path;
    unsigned uv = 0;
    if (ai.aiGetMaterialTexture(mat, type, 0, &path, nullptr, &uv, nullptr, nullptr, nullptr,
                                nullptr) != AI_SUCCESS) {
      continue;
    }
    // Only embedded textures travel with the bytes (GLB, data URIs); a file beside an OBJ does
    // not, and the mesh keeps its other colours.
    const aiTexture* tex = scene->GetEmbeddedTexture(path.C_Str());
    if (tex == nullptr || !mesh->HasTextureCoords(uv)) continue;
    if (tex->mHeight == 0) {
      // A compressed file (PNG, JPEG) of mWidth bytes.
      Result<Picture> pic =
          DecodeImage(std::string_view(reinterpret_cast<const char*>(tex->pcData), tex->mWidth),
                      tex->achFormatHint, kMaxTextureSide, budget);
      if (!pic.ok()) {
        return Status(pic.status().code(), "the mesh's embedded texture '" +
                                               std::string(path.C_Str()) + "': " +
                                               pic.status().message());
      }
      c.texture = std::move(pic).value();
    } else {
      // Raw BGRA texels, validated by assimp's ValidateDataStructure.
      const uint64_t n = uint64_t{tex->mWidth} * tex->mHeight;
      HVDB_RETURN_IF_ERROR(budget.Reserve(n * 4, "the mesh's raw texture"));
      c.texture.width = static_cast<int>(tex->mWidth);
      c.texture.height = static_cast<int>(tex->mHeight);
      c.texture.rgba.resize(n * 4);
      for (uint64_t i = 0; i < n; ++i) {
        const aiTexel& t = tex->pcData[i];
        c.texture.rgba[4 * i] = t.r;
        c.texture.rgba[4 * i + 1] = t.g;
        c.texture.rgba[4 * i + 2] = t.b;
        c.texture.rgba[4 * i + 3] = t.a;
      }
    }
    if (c.texture.width > 0 && c.texture.height > 0) {
      c.uv_channel = static_cast<int>(uv);
      break;
    }
  }
  return c;
}

Vec3 Sub(const aiVector3D& a, const aiVector3D& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
Vec3 Cross(const Vec3& a, const Vec3& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double Norm(const Vec3& a) { return std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]); }

struct Triangle {
  const aiMesh* mesh;
  const Colours* colours;
  unsigned v[3];
};

}  // namespace

double MeshSpacing(double area) {
  return std::max(kMinSpacing, std::sqrt(area / kMaxMeshPoints));
}

// What assimp's scene of a file may take, in bytes of the file: its arrays of vertices, faces
// and normals, a copy of the buffers, the post-processing's copies.
constexpr uint64_t kAssimpBytesPerFileByte = 12;

namespace {

// assimp's parse and our sampling of it, run in the child process of SampleMesh.
Result<std::vector<Point>> SampleHere(const AssimpLib& ai, std::string_view data,
                                      const std::string& format, const Placement& place,
                                      double spacing, uint32_t label, const Budget& budget,
                                      const std::string& what) {
  RequestOnlyIO io{{RequestOpen, RequestClose, nullptr}, data, {}};
  io.io.UserData = reinterpret_cast<aiUserData>(&io);
  // Node transforms baked in, points and lines dropped; the scene validated first (face indices
  // within the vertices, counts, references), before any step or our sampler reads it.
  // Polygons are split into triangles below, not by aiProcess_Triangulate: that step aborts the
  // process (an assertion) on some scenes that pass validation (found by media_import_fuzz).
  aiPropertyStore* props = ai.aiCreatePropertyStore();
  ai.aiSetImportPropertyInteger(props, AI_CONFIG_PP_SBP_REMOVE,
                                aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  // The name's extension is assimp's format hint; none: it tells the format from the bytes.
  const std::string hint = format.empty() && data.substr(0, 4) == "glTF" ? "glb" : format;
  const std::string name = std::string(kMemoryName) + "." + hint;
  std::unique_ptr<const aiScene, decltype(ai.aiReleaseImport)> scene(
      ai.aiImportFileExWithProperties(
          name.c_str(),
          aiProcess_ValidateDataStructure | aiProcess_PreTransformVertices | aiProcess_SortByPType,
          &io.io, props),
      ai.aiReleaseImport);
  ai.aiReleasePropertyStore(props);
  const std::string& refused = io.refused;
  if (!refused.empty()) {
    return Status::InvalidArgument(what + " refers to '" + refused +
                                   "', outside the bytes sent: only the file itself and data: "
                                   "URIs are read; embed it (GLB, or a data: URI) or leave it out");
  }
  if (scene == nullptr) {
    return Status::InvalidArgument(what + " could not be read: " + ai.aiGetErrorString());
  }
  HVDB_RETURN_IF_ERROR(budget.CheckTime(what));
  std::vector<Colours> colours(scene->mNumMeshes);
  std::vector<Triangle> tris;
  std::vector<double> cdf;  // cumulative area (model units^2)
  aiVector3D lo(INFINITY, INFINITY, INFINITY), hi(-INFINITY, -INFINITY, -INFINITY);
  double area = 0;
  for (unsigned m = 0; m < scene->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[m];
    if (!(mesh->mPrimitiveTypes & (aiPrimitiveType_TRIANGLE | aiPrimitiveType_POLYGON))) continue;
    HVDB_ASSIGN_OR_RETURN(colours[m], ColoursOf(ai, scene.get(), mesh, budget));
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices < 3 || face.mIndices == nullptr) continue;
      // ValidateDataStructure checked these; checked again where they are used, as the
      // sampler's own precondition.
      for (unsigned k = 0; k < face.mNumIndices; ++k) {
        if (face.mIndices[k] >= mesh->mNumVertices) {
          return Status::InvalidArgument(what + " has a face whose vertex does not exist");
        }
      }
      // A polygon as a fan of triangles around its first vertex (exact for convex ones).
      for (unsigned j = 1; j + 1 < face.mNumIndices; ++j) {
        Triangle t{mesh, &colours[m], {face.mIndices[0], face.mIndices[j], face.mIndices[j + 1]}};
        const aiVector3D* v = mesh->mVertices;
        for (unsigned k : t.v) {
          const aiVector3D& p = v[k];
          if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
            return Status::InvalidArgument(what + " has a vertex that is not finite");
          }
          lo = aiVector3D(std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z));
          hi = aiVector3D(std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z));
        }
        const double a = 0.5 * Norm(Cross(Sub(v[t.v[1]], v[t.v[0]]), Sub(v[t.v[2]], v[t.v[0]])));
        if (!(a > 0)) continue;  // degenerate: nothing to sample
        area += a;
        tris.push_back(t);
        cdf.push_back(area);
      }
    }
  }
  if (tris.empty()) {
    return Status::InvalidArgument(what + " has no triangles with an area (a point cloud? "
                                          "insert it with hvdb composite --ply)");
  }
  const double s2 = place.scale * place.scale;
  const double h = spacing > 0 ? spacing : MeshSpacing(area * s2);
  const double n_real = std::ceil(area * s2 / (h * h));
  if (n_real > static_cast<double>(kMaxImportPoints)) {
    return Status::InvalidArgument(
        "import_media.spacing: " + std::to_string(h) + " m over the mesh's " +
        std::to_string(area * s2) + " m^2 gives " + std::to_string(n_real) +
        " points, over the limit of " + std::to_string(kMaxImportPoints) + "; use a larger one");
  }
  const size_t n = static_cast<size_t>(std::max(1.0, n_real));
  HVDB_RETURN_IF_ERROR(budget.Reserve(n * sizeof(Point), what + ": its samples"));
  const std::array<double, 9> R = RotationMatrix(place.rotate_deg);
  const Vec3 c{(lo.x + hi.x) / 2.0, (lo.y + hi.y) / 2.0, (lo.z + hi.z) / 2.0};
  auto rotate = [&R](const Vec3& v) {
    return Vec3{R[0] * v[0] + R[1] * v[1] + R[2] * v[2], R[3] * v[0] + R[4] * v[1] + R[5] * v[2],
                R[6] * v[0] + R[7] * v[1] + R[8] * v[2]};
  };
  std::mt19937_64 rng(kSeed);
  // 53-bit uniforms in [0, 1): the same sequence on every standard library.
  auto uniform = [&rng]() { return static_cast<double>(rng() >> 11) * 0x1.0p-53; };
  std::vector<Point> out(n);
  for (size_t i = 0; i < n; ++i) {
    if (i % (1u << 16) == 0) HVDB_RETURN_IF_ERROR(budget.CheckTime(what));
    const size_t k = std::min<size_t>(
        std::upper_bound(cdf.begin(), cdf.end(), uniform() * area) - cdf.begin(), tris.size() - 1);
    const Triangle& t = tris[k];
    // Uniform barycentrics (Osada et al. 2002).
    const double r1 = std::sqrt(uniform()), r2 = uniform();
    const double w[3] = {1 - r1, r1 * (1 - r2), r1 * r2};
    const aiMesh* m = t.mesh;
    Vec3 pos{0, 0, 0};
    for (int j = 0; j < 3; ++j) {
      const aiVector3D& v = m->mVertices[t.v[j]];
      pos[0] += w[j] * v.x;
      pos[1] += w[j] * v.y;
      pos[2] += w[j] * v.z;
    }
    Vec3 nrm = Cross(Sub(m->mVertices[t.v[1]], m->mVertices[t.v[0]]),
                     Sub(m->mVertices[t.v[2]], m->mVertices[t.v[0]]));
    if (m->HasNormals()) {
      Vec3 sn{0, 0, 0};
      for (int j = 0; j < 3; ++j) {
        const aiVector3D& v = m->mNormals[t.v[j]];
        sn[0] += w[j] * v.x;
        sn[1] += w[j] * v.y;
        sn[2] += w[j] * v.z;
      }
      if (Norm(sn) > 1e-12) nrm = sn;
    }
    const double l = Norm(nrm);
    for (double& x : nrm) x /= l;
    nrm = rotate(nrm);  // a rotation and a uniform scale keep normals normal
    const Vec3 q = rotate({(pos[0] - c[0]) * place.scale, (pos[1] - c[1]) * place.scale,
                           (pos[2] - c[2]) * place.scale});
    Point& p = out[i];
    p.x = static_cast<float>(place.at[0] + q[0]);
    p.y = static_cast<float>(place.at[1] + q[1]);
    p.z = static_cast<float>(place.at[2] + q[2]);
    p.label = label;
    Vec3 t1, t2;
    Tangents(nrm, &t1, &t2);
    SetSurfel(p, nrm, t1, t2, kSigmaPerSpacing * h);
    const Colours& col = *t.colours;
    std::array<double, 3> rgb{col.flat[0] / 255.0, col.flat[1] / 255.0, col.flat[2] / 255.0};
    if (col.uv_channel >= 0) {
      double u = 0, v = 0;
      for (int j = 0; j < 3; ++j) {
        u += w[j] * m->mTextureCoords[col.uv_channel][t.v[j]].x;
        v += w[j] * m->mTextureCoords[col.uv_channel][t.v[j]].y;
      }
      // Repeat wrapping; v runs up the image.
      const int tw = col.texture.width, th = col.texture.height;
      const int x = std::isfinite(u) ? std::clamp(static_cast<int>((u - std::floor(u)) * tw), 0, tw - 1) : 0;
      const int y = std::isfinite(v) ? std::clamp(static_cast<int>((1 - (v - std::floor(v))) * th), 0, th - 1) : 0;
      const uint8_t* px = col.texture.rgba.data() + (static_cast<size_t>(y) * tw + x) * 4;
      rgb = {px[0] / 255.0, px[1] / 255.0, px[2] / 255.0};
    } else if (col.vertex_colours) {
      rgb = {0, 0, 0};
      for (int j = 0; j < 3; ++j) {
        const aiColor4D& vc = m->mColors[0][t.v[j]];
        rgb[0] += w[j] * vc.r;
        rgb[1] += w[j] * vc.g;
        rgb[2] += w[j] * vc.b;
      }
    }
    p.r = ToByte(rgb[0]);
    p.g = ToByte(rgb[1]);
    p.b = ToByte(rgb[2]);
  }
  return out;
}

}  // namespace

// assimp's importers trust their input: fuzzing found an abort (an assertion in a
// post-processing step), a crash (its binary PLY reader) and a loop without end (its PLY
// header parser) on files that pass every check we make first. So the parse runs in a child
// process: a crash or a hang there is the request's error, not the server's end. The child
// gets a CPU limit (the job's time left) and, outside the sanitizer builds, a data limit (what
// was reserved for it), and sends the samples back through a pipe.
Result<std::vector<Point>> SampleMesh(std::string_view data, const std::string& format,
                                      const Placement& place, double spacing, uint32_t label,
                                      const Budget& budget) {
  const std::string what = "import_media: the mesh (" + (format.empty() ? "?" : format) + ")";
  if (data.empty()) return Status::InvalidArgument(what + " is empty");
  HVDB_RETURN_IF_ERROR(CheckMeshFile(data, format, what));
  // Loaded here, not in the child: a fork of a threaded process should not run the loader.
  HVDB_ASSIGN_OR_RETURN(const AssimpLib* ai, LoadAssimp());
  const uint64_t parse_bytes = data.size() * kAssimpBytesPerFileByte;
  HVDB_RETURN_IF_ERROR(budget.Reserve(parse_bytes, what));
  // Seconds the parse may take: the job's time left, else kMaxParseSeconds.
  constexpr double kMaxParseSeconds = 120;
  double seconds = kMaxParseSeconds;
  if (budget.limits != nullptr && budget.limits->max_seconds != 0) {
    const std::chrono::duration<double> used = std::chrono::steady_clock::now() - budget.limits->start;
    seconds = std::max(0.0, budget.limits->max_seconds - used.count());
  }
  HVDB_RETURN_IF_ERROR(budget.CheckTime(what));
  int fds[2];
  if (::pipe2(fds, O_CLOEXEC) != 0) return Status::FromErrno(what + ": pipe", errno);
  const pid_t pid = ::fork();
  if (pid < 0) {
    const int err = errno;
    ::close(fds[0]);
    ::close(fds[1]);
    return Status::FromErrno(what + ": fork", err);
  }
  if (pid == 0) {
    ::close(fds[0]);
    const rlim_t cpu = static_cast<rlim_t>(std::ceil(seconds)) + 1;
    rlimit rl{cpu, cpu};
    ::setrlimit(RLIMIT_CPU, &rl);
#ifndef HVDB_UNDER_ASAN
    // The data segment as it is, plus what was reserved for the parse and the samples (ASan's
    // shadow memory would not fit such a limit).
    long pages = 0, data_pages = 0;
    if (FILE* f = std::fopen("/proc/self/statm", "r")) {
      long skip = 0;
      if (std::fscanf(f, "%ld %ld %ld %ld %ld %ld", &pages, &skip, &skip, &skip, &skip,
                      &data_pages) != 6) {
        data_pages = 0;
      }
      std::fclose(f);
    }
    if (data_pages > 0) {
      const rlim_t limit = static_cast<rlim_t>(data_pages) * ::sysconf(_SC_PAGESIZE) +
                           parse_bytes + (uint64_t{kMaxImportPoints} * sizeof(Point)) +
                           (rlim_t{256} << 20);
      rlimit dl{limit, limit};
      ::setrlimit(RLIMIT_DATA, &dl);
    }
#endif
    std::string out;
    Result<std::vector<Point>> r =
        SampleHere(*ai, data, format, place, spacing, label, Budget{}, what);
    if (r.ok()) {
      out.push_back('\1');
      out.append(reinterpret_cast<const char*>(r->data()), r->size() * sizeof(Point));
    } else {
      out.push_back('\0');
      out.push_back(static_cast<char>(r.status().code()));
      out.append(r.status().message());
    }
    for (size_t at = 0; at < out.size();) {
      const ssize_t n = ::write(fds[1], out.data() + at, out.size() - at);
      if (n <= 0) break;
      at += static_cast<size_t>(n);
    }
    ::_exit(0);
  }
  ::close(fds[1]);
  std::string got;
  char buf[1 << 16];
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000) + 2000);
  bool late = false;
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    if (left.count() <= 0) {
      late = true;
      break;
    }
    pollfd p{fds[0], POLLIN, 0};
    const int ready = ::poll(&p, 1, static_cast<int>(std::min<int64_t>(left.count(), 1000)));
    if (ready < 0 && errno != EINTR) break;
    if (ready <= 0) continue;
    const ssize_t n = ::read(fds[0], buf, sizeof buf);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    got.append(buf, static_cast<size_t>(n));
  }
  ::close(fds[0]);
  if (late) ::kill(pid, SIGKILL);
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (late || (WIFSIGNALED(status) && (WTERMSIG(status) == SIGXCPU || WTERMSIG(status) == SIGKILL))) {
    return Status::LimitExceeded(what + ": its parser ran past the time left to the job (" +
                                 std::to_string(static_cast<int>(seconds)) +
                                 " s; --max-job-seconds)");
  }
  if (WIFSIGNALED(status) || got.empty()) {
    return Status::InvalidArgument(
        what + " could not be read: its parser (assimp) " +
        (WIFSIGNALED(status) ? "failed with signal " + std::to_string(WTERMSIG(status))
                             : std::string("stopped without a result")) +
        ", on a malformed file or one over the memory reserved for it");
  }
  if (got[0] == '\0') {
    const auto code = static_cast<StatusCode>(got.size() > 1 ? got[1] : 8);
    return Status(code, got.size() > 2 ? got.substr(2) : what + ": failed");
  }
  const size_t n = (got.size() - 1) / sizeof(Point);
  if ((got.size() - 1) % sizeof(Point) != 0) {
    return Status::Internal(what + ": the parser's samples came back cut");
  }
  HVDB_RETURN_IF_ERROR(budget.Reserve(n * sizeof(Point), what + ": its samples"));
  budget.Release(parse_bytes);
  std::vector<Point> pts(n);
  std::memcpy(pts.data(), got.data() + 1, n * sizeof(Point));
  return pts;
}

}  // namespace hvdb::media
