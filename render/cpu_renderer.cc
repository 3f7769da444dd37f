// The CPU renderer: the same algorithm as the EGL renderer, evaluated with the same float
// operations up to rounding, tiled for the caches and for every core.
//
//  1. Project, in parallel over chunks of points: one Splat per point (culled ones marked
//     empty); each chunk counts the screen tiles (kTile x kTile pixels) its splats touch.
//  2. Bin: a counting sort of splat indices by tile, chunk by chunk, so that every tile lists
//     its splats in input order (the GPU's primitive order) whatever the thread count.
//  3. Rasterise the tiles in parallel, each in buffers of its own (30 KB: they stay in L1/L2),
//     the kernel evaluated 8 pixels at a time (simd.h). Visibility: the depth pass, then
//     the blend pass over the tile's list; probabilistic: the tile's list sorted front to back
//     (depth, then index: a global stable sort's order restricted to the tile), one pass.
//  4. Resolve each tile straight into the image; tiles no splat touches get the background.
// The former band renderer, scalar and one std::exp per fragment, is kept as the reference
// this one is tested against (tests/render/reference_renderer.h).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <new>
#include <thread>

#include <sys/mman.h>

#include "render/renderer.h"
// simd.h's helpers pass 32-byte vectors by value; they are always inlined, so the ABI note
// GCC gives for them in the non-AVX clone does not apply. (Before the include: GCC judges a
// template's diagnostics by where it is defined.)
#pragma GCC diagnostic ignored "-Wpsabi"
#include "render/simd.h"
#include "render/splat.h"

namespace hvdb::render {

namespace {

using internal::F8;
using internal::ParallelFor;
using internal::Splat;
using internal::View;

constexpr int kTile = 32;
// Row stride of the tile buffers: an 8-lane run that starts in a tile's last column stays
// inside its row (lanes past the tile are masked off or land in the padding).
constexpr int kStride = kTile + 8;
constexpr int kTileFloats = kTile * kStride;
constexpr size_t kMinChunk = 32768;  // points per projection task
constexpr size_t kMaxChunks = 64;    // bounds the per-chunk tile counters
// Bounds the per-tile copies of the splats (a splat is copied into every tile it touches).
constexpr size_t kMaxBinBytes = size_t{4} << 30;
// Buffers kept between renders above this are given back after the render (a pooled renderer
// should not keep one huge frame's memory).
constexpr size_t kKeepBytes = size_t{512} << 20;

// An array of splats in memory of its own, on 2 MiB pages where the kernel has them
// (MADV_HUGEPAGE: transparent huge pages are "madvise" on Debian). The binning pass scatters
// each splat into the lists of ~2000 tiles at 1080p: on 4 KiB pages every stream is a TLB
// miss, and a grown buffer is tens of thousands of page faults on its first render. The
// entries are left uninitialised: every one read is written first.
struct SplatArray {
  struct Unmap {
    size_t bytes = 0;
    void operator()(Splat* p) const { munmap(p, bytes); }
  };
  static std::unique_ptr<Splat[], Unmap> Make(size_t n) {
    const size_t bytes = std::max<size_t>(n, 1) * sizeof(Splat);
    void* p = mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    madvise(p, bytes, MADV_HUGEPAGE);  // advice only: without huge pages it still works
    return std::unique_ptr<Splat[], Unmap>(static_cast<Splat*>(p), Unmap{bytes});
  }
};
using SplatBuffer = std::unique_ptr<Splat[], SplatArray::Unmap>;

struct alignas(64) TileBuffers {
  float zmin[kTileFloats];
  float r[kTileFloats], g[kTileFloats], b[kTileFloats];
  float w[kTileFloats];  // visibility: sum of w*a over fragments that pass; probabilistic: A
  float a[kTileFloats];  // visibility: sum of a over all fragments
  // Probabilistic: the tile's splat indices front to back, and SortByDepth's scratch.
  std::vector<uint32_t> order, keys, tmp_order, tmp_keys;
};

// The pixels of splat s in row y of the tile at column tx0, as a column range [xa, xb]; false
// when the row misses the cutoff ellipse. Splats wider than two runs get the row's span of the
// ellipse, ca dx^2 + 2 cb dy dx + cc dy^2 = r_C^2, widened by a pixel against rounding (the
// per-pixel test still decides, as the shader's does); narrower ones just their box (the span
// rarely saves a whole run there, and costs a sqrt and two divisions a row).
template <int kRun>
HVDB_SIMD_INLINE bool RowRange(const Splat& s, float dy, float cutoff2, int tx0, int* xa,
                               int* xb) {
  int lo = std::max<int>(s.x0, tx0), hi = std::min<int>(s.x1, tx0 + kTile - 1);
  if (hi - lo >= 2 * kRun) {
    float b = s.cb * dy, c = s.cc * dy * dy - cutoff2;
    float disc = b * b - s.ca * c;
    if (!(disc >= 0)) return false;
    float root = std::sqrt(disc);
    lo = std::max(lo, static_cast<int>(std::floor(s.u + (-b - root) / s.ca)) - 1);
    hi = std::min(hi, static_cast<int>(std::ceil(s.u + (-b + root) / s.ca)) + 1);
  }
  *xa = lo;
  *xb = hi;
  return lo <= hi;
}

// The per-lane quantities of one run of a splat's row starting at column x.
template <typename F>
struct Lanes {
  using I = typename internal::VecTraits<F>::I;
  F q;     // kernel exponent, d^T Sigma'^-1 d
  F z;     // fragment depth
  I mask;  // inside the cutoff and within [x, xb]
};
template <typename F>
HVDB_SIMD_INLINE Lanes<F> Evaluate(const Splat& s, int x, int xa, int xb, float dy,
                                   float cutoff2) {
  F px = internal::Broadcast<F>(static_cast<float>(x)) + internal::VecTraits<F>::kIota;
  F dx = px - s.u;
  Lanes<F> l;
  l.q = s.ca * dx * dx + (2.0f * s.cb * dy) * dx + s.cc * dy * dy;
  l.z = internal::Max(s.z + s.dzdx * dx + s.dzdy * dy, internal::Broadcast<F>(0.0f));
  l.mask = (l.q <= cutoff2) & (px >= static_cast<float>(xa)) & (px <= static_cast<float>(xb));
  return l;
}

// Calls body(offset of the run in the tile buffers, lanes) for every 8-pixel run of splat s
// inside the tile at (tx0, ty0). (Measured on Panoptic frames at 1080p, where splats are ~10
// pixels wide: 16-lane runs for wide splats, and runs aligned to the buffers, were slower.)
template <typename Body>
HVDB_SIMD_INLINE void ForEachRun(const Splat& s, int tx0, int ty0, float cutoff2, Body&& body) {
  constexpr int kRun = internal::VecTraits<F8>::kLanes;
  int y0 = std::max<int>(s.y0, ty0), y1 = std::min<int>(s.y1, ty0 + kTile - 1);
  for (int y = y0; y <= y1; ++y) {
    float dy = static_cast<float>(y) - s.v;
    int xa, xb;
    if (!RowRange<kRun>(s, dy, cutoff2, tx0, &xa, &xb)) continue;
    int row = (y - ty0) * kStride - tx0;
    for (int x = xa; x <= xb; x += kRun) body(row + x, Evaluate<F8>(s, x, xa, xb, dy, cutoff2));
  }
}

// The nearest fragment depth at each pixel of the tile, into t->zmin (which starts at +inf).
HVDB_RENDER_CLONES void DepthPass(const Splat* list, size_t n, const View& view, int tx0,
                                  int ty0, TileBuffers* t) {
  using internal::Load;
  using internal::Store;
  for (size_t k = 0; k < n; ++k) {
    ForEachRun(list[k], tx0, ty0, view.cutoff2, [&](int at, const auto& l) HVDB_SIMD_LAMBDA {
      using F = decltype(l.q);
      F zmin = Load<F>(t->zmin + at);
      Store(t->zmin + at, internal::Select(l.mask, internal::Min(zmin, l.z), zmin));
    });
  }
}

// Fig. 5.2 as the two-pass GPU method: pass 1 finds the nearest depth at each pixel, pass 2
// blends every fragment within dz of it (the fuzzy depth test) additively; the resolve
// normalises by the accumulated weight. Coverage is the sum of all kernels at the pixel
// (occluded ones too), clamped to one: silhouettes against the background stay antialiased.
HVDB_RENDER_CLONES void RasteriseVisibility(const Splat* list, size_t n, const View& view,
                                            int tx0, int ty0, TileBuffers* t) {
  using internal::Load;
  using internal::Store;
  const float c2 = view.cutoff2, dz = view.depth_threshold;
  DepthPass(list, n, view, tx0, ty0, t);
  for (size_t k = 0; k < n; ++k) {
    const Splat& s = list[k];
    ForEachRun(s, tx0, ty0, c2, [&](int at, const auto& l) HVDB_SIMD_LAMBDA {
      using F = decltype(l.q);
      const F zero = internal::Broadcast<F>(0.0f);
      auto pass = l.mask & (l.z - dz <= Load<F>(t->zmin + at));  // the fuzzy depth test
      // An occluded fragment only adds to the coverage, which is clamped to one: once that
      // is reached, it adds nothing (most fragments at a deep pixel).
      F cover = Load<F>(t->a + at);
      if (!internal::Any(pass | (l.mask & (cover < 1.0f)))) return;
      F a = internal::Select(l.mask, internal::Exp(-0.5f * l.q), zero);
      Store(t->a + at, cover + a);
      F wa = internal::Select(pass, s.w * a, zero);
      Store(t->r + at, Load<F>(t->r + at) + s.r * wa);
      Store(t->g + at, Load<F>(t->g + at) + s.g * wa);
      Store(t->b + at, Load<F>(t->b + at) + s.b * wa);
      Store(t->w + at, Load<F>(t->w + at) + wa);
    });
  }
}

// 5.4.1: front to back, each fragment adds min(a, 1 - A) of its colour (GL_SRC_ALPHA_SATURATE)
// until the accumulated alpha A reaches one.
// `order` holds the indices into `list` in that order.
HVDB_RENDER_CLONES void RasteriseProbabilistic(const Splat* list, const uint32_t* order,
                                               size_t n, const View& view, int tx0, int ty0,
                                               TileBuffers* t) {
  using internal::Load;
  using internal::Store;
  const float c2 = view.cutoff2;
  for (size_t k = 0; k < n; ++k) {
    const Splat& s = list[order[k]];
    ForEachRun(s, tx0, ty0, c2, [&](int at, const auto& l) HVDB_SIMD_LAMBDA {
      using F = decltype(l.q);
      const F one = internal::Broadcast<F>(1.0f), zero = internal::Broadcast<F>(0.0f);
      F zmin = Load<F>(t->zmin + at);
      Store(t->zmin + at, internal::Select(l.mask, internal::Min(zmin, l.z), zmin));
      F acc = Load<F>(t->w + at);
      auto live = l.mask & (acc < one);  // saturated rays have stopped
      if (!internal::Any(live)) return;
      F a = internal::Min(one, s.w * internal::Exp(-0.5f * l.q));
      F f = internal::Select(live, internal::Min(a, one - acc), zero);
      Store(t->r + at, Load<F>(t->r + at) + s.r * f);
      Store(t->g + at, Load<F>(t->g + at) + s.g * f);
      Store(t->b + at, Load<F>(t->b + at) + s.b * f);
      Store(t->w + at, internal::Select(live, internal::Min(one, acc + a), acc));
    });
  }
}

// The indices of list[0, n) in the order of a stable sort by depth, into t->order: an LSD radix
// sort on the depths' bits (z > 0, so they order as the floats do), 8 bits a pass, skipping
// bytes all depths share (usually the top one: a tile sees a narrow range of depths).
void SortByDepth(const Splat* list, size_t n, TileBuffers* t) {
  t->order.resize(n);
  t->keys.resize(n);
  t->tmp_order.resize(n);
  t->tmp_keys.resize(n);
  uint32_t all_and = ~0u, all_or = 0;
  for (size_t k = 0; k < n; ++k) {
    uint32_t bits;
    std::memcpy(&bits, &list[k].z, 4);
    t->keys[k] = bits;
    t->order[k] = static_cast<uint32_t>(k);
    all_and &= bits;
    all_or |= bits;
  }
  for (int shift = 0; shift < 32; shift += 8) {
    if ((((all_and ^ all_or) >> shift) & 0xffu) == 0) continue;  // the same byte everywhere
    uint32_t count[257] = {};
    for (size_t k = 0; k < n; ++k) ++count[((t->keys[k] >> shift) & 0xffu) + 1];
    for (int i = 0; i < 256; ++i) count[i + 1] += count[i];
    for (size_t k = 0; k < n; ++k) {
      uint32_t at = count[(t->keys[k] >> shift) & 0xffu]++;
      t->tmp_keys[at] = t->keys[k];
      t->tmp_order[at] = t->order[k];
    }
    t->keys.swap(t->tmp_keys);
    t->order.swap(t->tmp_order);
  }
}

class CpuRenderer final : public Renderer {
 public:
  explicit CpuRenderer(unsigned threads)
      : threads_(threads != 0 ? threads : std::max(1u, std::thread::hardware_concurrency())) {}

  RendererKind kind() const override { return RendererKind::kCpu; }
  std::string name() const override {
    return "cpu (" + std::to_string(threads_) + " thread" + (threads_ == 1 ? "" : "s") + ")";
  }
  RenderStats last_stats() const override {
    std::lock_guard<std::mutex> l(mu_);
    return stats_;
  }

  Result<Image> Render(std::span<const Point> points, const Camera& camera,
                       const RenderOptions& options) override {
    Image img;
    HVDB_RETURN_IF_ERROR(RenderInto(points, camera, options, &img));
    return img;
  }

  Status RenderInto(std::span<const Point> points, const Camera& camera,
                    const RenderOptions& options, Image* img) override {
    std::lock_guard<std::mutex> l(mu_);
    auto start = std::chrono::steady_clock::now();
    HVDB_ASSIGN_OR_RETURN(View view, internal::PrepareView(camera, options));
    Camera cam = options.width != 0 ? camera.Resized(options.width, options.height) : camera;
    std::vector<float> weights = internal::ViewWeightTable(cam, options);
    tiles_x_ = (view.width + kTile - 1) / kTile;
    tiles_y_ = (view.height + kTile - 1) / kTile;
    HVDB_RETURN_IF_ERROR(ProjectAndBin(points, view, weights));
    // Every pixel is written below: buffers of the right size are kept as they are.
    img->width = view.width;
    img->height = view.height;
    img->rgba.resize(options.depth_only ? 0 : img->pixels() * 4);
    img->coverage.resize(options.depth_only ? 0 : img->pixels());
    img->depth.resize(img->pixels());
    const bool probabilistic = options.mode == Mode::kProbabilistic;
    ParallelFor(size_t{tiles_x_} * tiles_y_, threads_, [&](size_t tile) {
      RenderTile(tile, view, options, probabilistic, img);
    });
    if (bin_capacity_ * sizeof(Splat) > kKeepBytes) {
      bin_.reset();
      bin_capacity_ = 0;
    }
    if (splat_capacity_ * sizeof(Splat) > kKeepBytes) {
      splats_.reset();
      splat_capacity_ = 0;
    }
    stats_.points = points.size();
    stats_.milliseconds =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    return Status::OK();
  }

 private:
  // Steps 1 and 2: fills splats_ (one per point; culled ones have x1 < x0) and the tile lists
  // bin_start_ / bin_.
  // LimitExceeded when the splats would need more than kMaxBinBytes of tile lists (huge
  // splats: a camera inside the cloud, or a very coarse level).
  Status ProjectAndBin(std::span<const Point> points, const View& view,
                       const std::vector<float>& weights) {
    const size_t n = points.size();
    const size_t tiles = size_t{tiles_x_} * tiles_y_;
    if (n > splat_capacity_) {
      splats_ = SplatArray::Make(n);  // uninitialised: every entry is written below
      splat_capacity_ = n;
    }
    const size_t chunk = std::max(kMinChunk, (n + kMaxChunks - 1) / kMaxChunks);
    const size_t chunks = (n + chunk - 1) / chunk;
    // counts[c * tiles + t]: splats of chunk c in tile t, then where chunk c writes in tile t.
    std::vector<uint32_t> counts(chunks * tiles, 0);
    Splat* splats = splats_.get();
    ParallelFor(chunks, threads_, [&](size_t c) {
      uint32_t* count = counts.data() + c * tiles;
      for (size_t i = c * chunk, end = std::min(n, i + chunk); i < end; ++i) {
        Splat& s = splats[i];
        if (!internal::ProjectSplat(points[i], view, weights, &s)) {
          s.x0 = 1;
          s.x1 = 0;
          continue;
        }
        for (int ty = s.y0 / kTile; ty <= s.y1 / kTile; ++ty) {
          for (int tx = s.x0 / kTile; tx <= s.x1 / kTile; ++tx) ++count[ty * tiles_x_ + tx];
        }
      }
    });
    // From here counts[c * tiles + t] is where chunk c writes next in tile t's list, relative
    // to the list's start.
    bin_start_.assign(tiles + 1, 0);
    for (size_t t = 0; t < tiles; ++t) {
      uint32_t at = 0;
      for (size_t c = 0; c < chunks; ++c) {
        uint32_t k = counts[c * tiles + t];
        counts[c * tiles + t] = at;
        at += k;
      }
      bin_start_[t + 1] = bin_start_[t] + at;
    }
    if (bin_start_[tiles] > kMaxBinBytes / sizeof(Splat)) {
      return Status::LimitExceeded(
          "render: the splats cover " + std::to_string(bin_start_[tiles]) +
          " screen tiles in all, more than the renderer holds (" +
          std::to_string(kMaxBinBytes >> 20) +
          " MiB of tile lists); move the camera back from the points or use a finer level");
    }
    if (bin_start_[tiles] > bin_capacity_) {
      bin_capacity_ = bin_start_[tiles] + bin_start_[tiles] / 4;
      bin_.reset();  // the old lists first: both at once may not fit
      bin_ = SplatArray::Make(bin_capacity_);
    }
    ParallelFor(chunks, threads_, [&](size_t c) {
      uint32_t* next = counts.data() + c * tiles;
      for (size_t i = c * chunk, end = std::min(n, i + chunk); i < end; ++i) {
        const Splat& s = splats[i];
        if (s.x1 < s.x0) continue;
        for (int ty = s.y0 / kTile; ty <= s.y1 / kTile; ++ty) {
          for (int tx = s.x0 / kTile; tx <= s.x1 / kTile; ++tx) {
            size_t t = static_cast<size_t>(ty) * tiles_x_ + static_cast<size_t>(tx);
            bin_[bin_start_[t] + next[t]++] = s;
          }
        }
      }
    });
    return Status::OK();
  }

  // Steps 3 and 4 for one tile.
  void RenderTile(size_t tile, const View& view, const RenderOptions& o, bool probabilistic,
                  Image* img) const {
    const int tx0 = static_cast<int>(tile % tiles_x_) * kTile;
    const int ty0 = static_cast<int>(tile / tiles_x_) * kTile;
    const int cols = std::min<int>(kTile, static_cast<int>(view.width) - tx0);
    const int rows = std::min<int>(kTile, static_cast<int>(view.height) - ty0);
    const Splat* list = bin_.get() + bin_start_[tile];
    const size_t n = bin_start_[tile + 1] - bin_start_[tile];
    const internal::Resolved empty = internal::Composite(0, 0, 0, 0, o.background);
    if (n == 0) {  // the background, a row at a time
      float pattern[kTile * 4];
      for (int x = 0; x < kTile; ++x) std::memcpy(pattern + 4 * x, empty.rgba, 16);
      for (int y = 0; y < rows; ++y) {
        size_t at = (static_cast<size_t>(ty0 + y)) * view.width + static_cast<size_t>(tx0);
        std::fill_n(&img->depth[at], cols, std::numeric_limits<float>::infinity());
        if (o.depth_only) continue;
        std::memcpy(&img->rgba[at * 4], pattern, sizeof(float) * 4 * static_cast<size_t>(cols));
        std::memset(&img->coverage[at], 0, sizeof(float) * static_cast<size_t>(cols));
      }
      return;
    }
    thread_local std::unique_ptr<TileBuffers> buffers;
    if (!buffers) buffers = std::make_unique<TileBuffers>();
    TileBuffers* t = buffers.get();
    std::fill_n(t->zmin, kTileFloats, std::numeric_limits<float>::infinity());
    if (o.depth_only) {  // the nearest depth: either mode's first pass alone
      DepthPass(list, n, view, tx0, ty0, t);
      for (int y = 0; y < rows; ++y) {
        size_t at = (static_cast<size_t>(ty0 + y)) * view.width + static_cast<size_t>(tx0);
        std::memcpy(&img->depth[at], t->zmin + y * kStride,
                    sizeof(float) * static_cast<size_t>(cols));
      }
      return;
    }
    for (float* f : {t->r, t->g, t->b, t->w, t->a}) std::fill_n(f, kTileFloats, 0.0f);
    if (probabilistic) {
      SortByDepth(list, n, t);
      RasteriseProbabilistic(list, t->order.data(), n, view, tx0, ty0, t);
    } else {
      RasteriseVisibility(list, n, view, tx0, ty0, t);
    }
    for (int y = 0; y < rows; ++y) {
      size_t at = (static_cast<size_t>(ty0 + y)) * view.width + static_cast<size_t>(tx0);
      for (int x = 0; x < cols; ++x) {
        int i = y * kStride + x;
        internal::Resolved r = empty;
        if (probabilistic) {
          float acc = t->w[i];
          if (acc > 0) {
            r = internal::Composite(t->r[i] / acc, t->g[i] / acc, t->b[i] / acc, acc,
                                    o.background);
          }
        } else if (t->a[i] > 0) {
          // The nearest fragment always passes, so the weight is > 0 wherever a is.
          float wsum = t->w[i];
          r = internal::Composite(t->r[i] / wsum, t->g[i] / wsum, t->b[i] / wsum,
                                  std::min(1.0f, t->a[i]), o.background);
        }
        std::memcpy(&img->rgba[(at + x) * 4], r.rgba, 16);
        img->coverage[at + x] = r.coverage;
        img->depth[at + x] = t->zmin[i];
      }
    }
  }

  unsigned threads_;
  mutable std::mutex mu_;
  RenderStats stats_;
  // Kept between renders (a sequence reuses them): splats, one per point, and the tile lists.
  SplatBuffer splats_;
  size_t splat_capacity_ = 0;
  uint32_t tiles_x_ = 0, tiles_y_ = 0;
  std::vector<size_t> bin_start_;
  // The splats of each tile, copied in: the rasteriser then reads one contiguous run per tile
  // instead of chasing indices across all splats (which made it wait on memory).
  SplatBuffer bin_;
  size_t bin_capacity_ = 0;
};

}  // namespace

std::unique_ptr<Renderer> MakeCpuRenderer(unsigned threads) {
  return std::make_unique<CpuRenderer>(threads);
}

}  // namespace hvdb::render
