// The 3DGS forward rasteriser on the CPU (gaussian_raster.h).
//
// Why it is ours: no Debian package provides a CPU rasteriser of 3D Gaussian splats. The
// reference (graphdeco-inria/diff-gaussian-rasterization) and gsplat are CUDA extensions of
// PyTorch, and the viewers that draw 3DGS scenes do it in WebGL/Vulkan shaders with a global
// approximate sort and none of the reference's per-pixel early termination, so their images
// differ from the reference's. This file follows forward.cu's equations in float, organised
// for a few CPU cores instead of a GPU:
//
//  1. Preprocess, in parallel over chunks of splats: the view-space centre, the 2D covariance
//     and its conic, the opacity, the SH colour, the reference's tile rectangle, and the
//     ellipse where the splat's alpha can reach 1/255 (outside it every pixel skips the splat,
//     so leaving those pixels out changes nothing): its pixel box, and per row its span. The
//     visible splats of a chunk are packed into one 64-byte record each, in index order.
//  2. Bin: the records' depths radix-sorted (stable: ties keep index order, as the
//     reference's radix sort of tile|depth keys), then a counting sort by tile of the record
//     indices in that order, chunk after chunk, so that every tile's list comes out sorted
//     front to back. A splat goes to the tiles of the reference's rectangle that its box
//     reaches (in the others it would be skipped at every pixel).
//  3. Each band of tiles (a row of them), in parallel; in a band, tile after tile: its records
//     gathered a batch of 64 at a time. A tile row is two segments of 8 pixels, one vector
//     each (simd.h: AVX-512, AVX2 or SSE2 clone). Each record's row spans give the segments
//     its ellipse reaches, as a bit in each such segment's 64-bit mask of the batch; then
//     each segment blends its records in order with its pixels in registers, two segments
//     side by side. Pixels stop at the reference's transmittance threshold (their T negated);
//     a segment stops when all its pixels have, a tile when all its segments have. At the
//     band's end its pixels are written out row by row.
#include "render/gaussian_raster.h"

#include <sys/mman.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "render/gaussian_raster_kernels.h"
#include "render/splat.h"

namespace hvdb::render {

namespace {

using gaussian::BlendBatch;
using gaussian::Item;
using gaussian::kBatch;
using gaussian::kTile;
using gaussian::MakeView;
using gaussian::PrepareGroup;
using gaussian::Record;
using gaussian::TileState;
using gaussian::WriteRow;
using gaussian::ViewF;
using internal::ParallelFor;

constexpr size_t kMinChunk = 16384;  // splats per task of steps 1 and 2
constexpr size_t kMaxChunks = 64;    // preprocessing tasks at most
constexpr size_t kMaxListBytes = size_t{4} << 30;
constexpr size_t kKeepBytes = size_t{512} << 20;
constexpr size_t kPrefetch = 160; // records asked for ahead of the one blended

// Stable LSD radix sort of the `n` items at `a` by key bits [0, passes * 8) (keys: depth -
// lo), one thread, `b` n items of scratch; all the passes' histograms from one read.
void SortLowBits(Item* a, Item* b, size_t n, uint32_t lo, int passes) {
  uint32_t h[3][256] = {};
  for (size_t i = 0; i < n; ++i) {
    const uint32_t key = a[i].depth - lo;
    for (int p = 0; p < passes; ++p) ++h[p][(key >> (8 * p)) & 255];
  }
  Item *src = a, *dst = b;
  for (int p = 0; p < passes; ++p) {
    uint32_t sum = 0;
    for (uint32_t& c : h[p]) {
      const uint32_t k = c;
      c = sum;
      sum += k;
    }
    for (size_t i = 0; i < n; ++i) dst[h[p][((src[i].depth - lo) >> (8 * p)) & 255]++] = src[i];
    std::swap(src, dst);
  }
  if (src != a) std::memcpy(a, src, n * sizeof(Item));
}

// Sorts `n` items by depth, stably, on up to `threads` threads; `tmp` holds n items of
// scratch. The keys are the depths' bits less the smallest (a scene's depths span a few
// binary orders of magnitude: ~24 bits of keys). One pass over the whole array scatters the
// items by the keys' top 8 bits (histograms of slices, each slice scattered); then each of
// those 256 buckets, a few tens of kilobytes for a million splats, is sorted by the remaining
// bits on its own, in cache, by passes of 8 bits (256 write positions stay in L1). Three
// passes of the whole array cost twice as much: most of what a pass costs is memory.
void SortByDepth(Item* items, Item* tmp, size_t n, unsigned threads) {
  if (n < 2) return;
  uint32_t lo = items[0].depth, hi = items[0].depth;
  for (size_t i = 1; i < n; ++i) {
    lo = std::min(lo, items[i].depth);
    hi = std::max(hi, items[i].depth);
  }
  const int key_bits = 32 - __builtin_clz((hi - lo) | 1u);
  const int low_bits = std::max(0, key_bits - 8);  // sorted within the buckets
  const int low_passes = (low_bits + 7) / 8;
  constexpr size_t kBuckets = 256;
  const size_t parts = std::max<size_t>(1, std::min<size_t>(threads, n / 65536));
  std::vector<size_t> at(parts * kBuckets);
  auto slice = [&](size_t p) {
    return std::pair<size_t, size_t>(p * n / parts, (p + 1) * n / parts);
  };
  auto top = [&](const Item& item) { return ((item.depth - lo) >> low_bits) & 255u; };
  ParallelFor(parts, static_cast<unsigned>(parts), [&](size_t p) {
    size_t* h = at.data() + p * kBuckets;
    std::fill_n(h, kBuckets, 0);
    const auto [b, e] = slice(p);
    for (size_t i = b; i < e; ++i) ++h[top(items[i])];
  });
  std::vector<size_t> start(kBuckets + 1, 0);
  size_t sum = 0;
  for (size_t d = 0; d < kBuckets; ++d) {
    start[d] = sum;
    for (size_t p = 0; p < parts; ++p) {
      const size_t k = at[p * kBuckets + d];
      at[p * kBuckets + d] = sum;
      sum += k;
    }
  }
  start[kBuckets] = sum;
  ParallelFor(parts, static_cast<unsigned>(parts), [&](size_t p) {
    size_t* next = at.data() + p * kBuckets;
    const auto [b, e] = slice(p);
    for (size_t i = b; i < e; ++i) tmp[next[top(items[i])]++] = items[i];
  });
  // Each bucket sorted in tmp (items' same range its scratch), then copied back.
  ParallelFor(kBuckets, threads, [&](size_t d) {
    const size_t b = start[d], k = start[d + 1] - b;
    if (k == 0) return;
    if (k > 1) SortLowBits(tmp + b, items + b, k, lo, low_passes);
    std::memcpy(items + b, tmp + b, k * sizeof(Item));
  });
}

// Anonymous memory of its own on 2 MiB pages where the kernel has them (transparent huge pages
// are "madvise" on Debian): the arrays are large and written once a render.
class Mapped {
 public:
  Mapped() = default;
  Mapped(const Mapped&) = delete;
  Mapped& operator=(const Mapped&) = delete;
  ~Mapped() { Release(); }
  // At least `bytes`, contents unspecified; false when it cannot be mapped.
  bool Reserve(size_t bytes) {
    if (bytes <= bytes_) return true;
    Release();
    const size_t want = bytes + bytes / 4;
    void* p = mmap(nullptr, want, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) return false;
    madvise(p, want, MADV_HUGEPAGE);  // advice only
    data_ = p;
    bytes_ = want;
    return true;
  }
  void Release() {
    if (data_ != nullptr) munmap(data_, bytes_);
    data_ = nullptr;
    bytes_ = 0;
  }
  size_t bytes() const { return bytes_; }
  template <typename T>
  T* as() const {
    return static_cast<T*>(data_);
  }

 private:
  void* data_ = nullptr;
  size_t bytes_ = 0;
};

}  // namespace

Status CheckGaussianRender(const formats::GaussianCloud& g, const Camera& camera,
                           const GaussianRenderOptions& options) {
  for (double d : camera.distortion) {
    if (d != 0) {
      return Status::InvalidArgument(
          "gaussian mode renders pinhole cameras; this camera has lens distortion (k1 k2 p1 p2 "
          "k3 not all 0): render with the distortion set to 0, or undistort the images first");
    }
  }
  HVDB_RETURN_IF_ERROR(camera.Validate());
  if (options.threads < 0) {
    return Status::InvalidArgument("gaussian render: threads is " +
                                   std::to_string(options.threads) + " (0: every core)");
  }
  if (g.sh_degree < 0 || g.sh_degree > formats::kMaxShDegree) {
    return Status::InvalidArgument("gaussian render: sh_degree " + std::to_string(g.sh_degree) +
                                   " is outside 0..3");
  }
  const size_t n = g.size();
  auto wrong = [&](const char* name, size_t have, size_t want) {
    return Status::InvalidArgument("gaussian render: the cloud's " + std::string(name) + " holds " +
                                   std::to_string(have) + " values, " + std::to_string(n) +
                                   " splats need " + std::to_string(want));
  };
  if (g.position.size() != 3 * n) return wrong("position", g.position.size(), 3 * n);
  if (g.scale.size() != 3 * n) return wrong("scale", g.scale.size(), 3 * n);
  if (g.rotation.size() != 4 * n) return wrong("rotation", g.rotation.size(), 4 * n);
  if (g.sh_dc.size() != 3 * n) return wrong("sh_dc", g.sh_dc.size(), 3 * n);
  if (g.sh_rest.size() != n * g.sh_rest_per_splat()) {
    return wrong("sh_rest", g.sh_rest.size(), n * g.sh_rest_per_splat());
  }
  if (n >= (uint64_t{1} << 32)) {
    return Status::LimitExceeded("gaussian render: " + std::to_string(n) +
                                 " splats; at most 2^32 - 1 render at once");
  }
  return Status::OK();
}

std::vector<uint8_t> GaussianImage::ToRgba8() const {
  const size_t pixels = static_cast<size_t>(width) * height;
  std::vector<uint8_t> out(pixels * 4);
  auto to8 = [](float v) {
    return static_cast<uint8_t>(std::round(std::min(std::max(v, 0.0f), 1.0f) * 255.0f));
  };
  for (size_t i = 0; i < pixels && 3 * i + 2 < rgb.size() && i < alpha.size(); ++i) {
    for (int c = 0; c < 3; ++c) out[4 * i + c] = to8(rgb[3 * i + c]);
    out[4 * i + 3] = to8(alpha[i]);
  }
  return out;
}

struct GaussianRasterizer::Buffers {
  Mapped records;  // a Record per visible splat, packed per chunk
  Mapped items;    // an Item per visible splat, packed per chunk, then sorted
  Mapped scratch;  // the sort's
  Mapped lists;    // uint32 record indices, tile after tile
  std::vector<uint32_t> counts;
  std::vector<uint64_t> tile_start;
};

GaussianRasterizer::GaussianRasterizer() : buffers_(std::make_unique<Buffers>()) {}
GaussianRasterizer::~GaussianRasterizer() = default;

Status GaussianRasterizer::Render(const formats::GaussianCloud& cloud, const Camera& camera,
                                  const GaussianRenderOptions& options, GaussianImage* out,
                                  GaussianRenderStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  HVDB_RETURN_IF_ERROR(CheckGaussianRender(cloud, camera, options));
  const ViewF view = MakeView(camera);
  const unsigned threads = options.threads > 0 ? static_cast<unsigned>(options.threads)
                                               : std::max(1u, std::thread::hardware_concurrency());
  const size_t n = cloud.size();
  const size_t tiles = static_cast<size_t>(view.tiles_x) * view.tiles_y;
  const size_t chunk = std::max(kMinChunk, (n + kMaxChunks - 1) / kMaxChunks);
  const size_t chunks = (n + chunk - 1) / chunk;
  Buffers& buf = *buffers_;
  auto out_of_memory = [](size_t bytes) {
    return Status::LimitExceeded("gaussian render: cannot map " + std::to_string(bytes >> 20) +
                                 " MiB of working memory");
  };
  auto reserve = [&](Mapped& m, size_t bytes) {
    return m.Reserve(bytes) ? Status::OK() : out_of_memory(bytes);
  };
  HVDB_RETURN_IF_ERROR(reserve(buf.records, n * sizeof(Record)));
  HVDB_RETURN_IF_ERROR(reserve(buf.items, n * sizeof(Item)));
  HVDB_RETURN_IF_ERROR(reserve(buf.scratch, n * sizeof(Item)));
  Record* records = buf.records.as<Record>();
  Item* items = buf.items.as<Item>();

  // 1. Preprocess: chunk c's visible splats at records[c * chunk ...], their items likewise.
  std::vector<size_t> visible(chunks + 1, 0);
  ParallelFor(chunks, threads, [&](size_t c) {
    uint32_t k = 0;
    const size_t end = std::min(n, (c + 1) * chunk);
    for (size_t i = c * chunk; i < end; i += 8) {
      PrepareGroup(cloud, i, static_cast<int>(std::min<size_t>(8, end - i)), view,
                   records + c * chunk, items + c * chunk, &k);
    }
    for (uint32_t j = 0; j < k; ++j)
      items[c * chunk + j].index = static_cast<uint32_t>(c * chunk + j);
    visible[c] = k;
  });
  const auto preprocessed = std::chrono::steady_clock::now();

  // 2. Bin. The items packed, sorted front to back; then counted and scattered by tile in
  // that order, in chunks of the sorted items: counts[c * tiles + t] is chunk c's entries in
  // tile t, then where chunk c writes next in tile t's list.
  size_t m = 0;
  for (size_t c = 0; c < chunks; ++c) {
    std::memmove(items + m, items + c * chunk, visible[c] * sizeof(Item));
    m += visible[c];
  }
  SortByDepth(items, buf.scratch.as<Item>(), m, threads);
  // A few chunks a thread balance the load; more would only lengthen the counters.
  const size_t sorted_chunk = std::max(kMinChunk, (m + 4 * threads - 1) / (4 * threads));
  const size_t sorted_chunks = (m + sorted_chunk - 1) / sorted_chunk;
  buf.counts.assign(sorted_chunks * tiles, 0);
  auto for_tiles = [&](size_t c, auto&& fn) {
    for (size_t i = c * sorted_chunk, end = std::min(m, i + sorted_chunk); i < end; ++i) {
      const Item& item = items[i];
      for (int ty = item.ty0; ty <= item.ty0 + item.tiles_h; ++ty) {
        for (int tx = item.tx0; tx <= item.tx0 + item.tiles_w; ++tx) {
          fn(static_cast<size_t>(ty) * view.tiles_x + tx, item.index);
        }
      }
    }
  };
  ParallelFor(sorted_chunks, threads, [&](size_t c) {
    uint32_t* count = buf.counts.data() + c * tiles;
    for_tiles(c, [&](size_t t, uint32_t) { ++count[t]; });
  });
  buf.tile_start.assign(tiles + 1, 0);
  uint64_t* total = buf.tile_start.data() + 1;  // entries of tile t so far, chunk after chunk
  for (size_t c = 0; c < sorted_chunks; ++c) {
    uint32_t* count = buf.counts.data() + c * tiles;
    for (size_t t = 0; t < tiles; ++t) {
      const uint32_t k = count[t];
      count[t] = static_cast<uint32_t>(total[t]);
      total[t] += k;
    }
  }
  for (size_t t = 0; t < tiles; ++t) buf.tile_start[t + 1] += buf.tile_start[t];
  const uint64_t entries = buf.tile_start[tiles];
  if (entries > kMaxListBytes / sizeof(uint32_t)) {
    return Status::LimitExceeded("gaussian render: the splats cover " + std::to_string(entries) +
                                 " screen tiles in all, more than the rasteriser holds (" +
                                 std::to_string(kMaxListBytes >> 20) +
                                 " MiB of tile lists); move the camera back");
  }
  HVDB_RETURN_IF_ERROR(reserve(buf.lists, entries * sizeof(uint32_t)));
  uint32_t* lists = buf.lists.as<uint32_t>();
  ParallelFor(sorted_chunks, threads, [&](size_t c) {
    uint32_t* next = buf.counts.data() + c * tiles;
    for_tiles(c, [&](size_t t, uint32_t index) { lists[buf.tile_start[t] + next[t]++] = index; });
  });
  const auto binned = std::chrono::steady_clock::now();

  // 3. Blend the tiles.
  out->width = camera.width;
  out->height = camera.height;
  const size_t pixels = static_cast<size_t>(camera.width) * camera.height;
  out->rgb.resize(3 * pixels);
  out->alpha.resize(pixels);
  const auto bg = options.background;
  // A band (a row of tiles) a task: the tiles of a band share many splats (their records stay
  // in cache from tile to tile), and the band's pixels are written out row after row at the
  // end, in long runs, instead of 16 short rows a tile far apart in the image.
  // The bands with the most tile entries first: the last band a thread takes is then a light
  // one, and the threads end together.
  std::vector<uint32_t> bands(view.tiles_y);
  for (int b = 0; b < view.tiles_y; ++b) bands[b] = static_cast<uint32_t>(b);
  auto weight = [&](uint32_t b) {
    return buf.tile_start[(b + 1) * size_t(view.tiles_x)] - buf.tile_start[b * size_t(view.tiles_x)];
  };
  std::stable_sort(bands.begin(), bands.end(),
                   [&](uint32_t x, uint32_t y) { return weight(x) > weight(y); });
  ParallelFor(bands.size(), threads, [&](size_t task) {
    const size_t band = bands[task];
    const int ty0 = static_cast<int>(band) * kTile;
    const int rows = std::min(kTile, view.height - ty0);
    std::unique_ptr<TileState[]> states(new TileState[view.tiles_x]);
    const uint64_t band_end = buf.tile_start[(band + 1) * view.tiles_x];
    for (uint64_t i = buf.tile_start[band * view.tiles_x], e = std::min(band_end, i + kPrefetch);
         i < e; ++i) {
      __builtin_prefetch(&records[lists[i]]);
    }
    alignas(64) Record batch[kBatch];
    for (int tx = 0; tx < view.tiles_x; ++tx) {
      const size_t t = band * view.tiles_x + tx;
      const int tx0 = tx * kTile, cols = std::min(kTile, view.width - tx0);
      TileState& st = states[tx];
      st.live = 0;
      for (int y = 0; y < kTile; ++y) {
        for (int x = 0; x < kTile; ++x) {
          st.T[y][x] = y < rows && x < cols ? 1.0f : -1.0f;  // negative: no pixel there
          st.r[y][x] = st.g[y][x] = st.b[y][x] = 0;
        }
        if (y < rows) st.live |= (cols > 8 ? 3u : 1u) << (2 * y);
      }
      const uint32_t* list = lists + buf.tile_start[t];
      const size_t k_all = buf.tile_start[t + 1] - buf.tile_start[t];
      for (size_t at = 0; at < k_all; at += kBatch) {
        const size_t k = std::min(kBatch, k_all - at);
        // The records are scattered over the whole array: each copy asks for the one
        // kPrefetch entries on in the band's lists (the band's tiles' lists follow each other),
        // so that the next batch's, and the next tile's first, are on their way meanwhile.
        const size_t pos = buf.tile_start[t] + at;
        for (size_t j = 0; j < k; ++j) {
          batch[j] = records[list[at + j]];
          if (pos + j + kPrefetch < band_end) __builtin_prefetch(&records[lists[pos + j + kPrefetch]]);
        }
        if (BlendBatch(batch, k, tx0, ty0, &st)) break;
      }
    }
    for (int y = 0; y < rows; ++y) {
      const size_t row = static_cast<size_t>(ty0 + y) * camera.width;
      WriteRow(states.get(), view.tiles_x, y, view.width, bg.data(), &out->rgb[3 * row],
               &out->alpha[row]);
    }
  });

  for (Mapped* mapped : {&buf.records, &buf.items, &buf.scratch, &buf.lists}) {
    if (mapped->bytes() > kKeepBytes) mapped->Release();
  }
  if (stats != nullptr) {
    const auto end = std::chrono::steady_clock::now();
    auto ms = [](auto from, auto to) {
      return std::chrono::duration<double, std::milli>(to - from).count();
    };
    stats->splats_in = n;
    stats->splats_visible = m;
    stats->tile_entries = entries;
    stats->milliseconds = ms(start, end);
    stats->preprocess_ms = ms(start, preprocessed);
    stats->bin_ms = ms(preprocessed, binned);
    stats->blend_ms = ms(binned, end);
  }
  return Status::OK();
}

Status RenderGaussians(const formats::GaussianCloud& cloud, const Camera& camera,
                       const GaussianRenderOptions& options, GaussianImage* out,
                       GaussianRenderStats* stats) {
  GaussianRasterizer rasterizer;
  return rasterizer.Render(cloud, camera, options, out, stats);
}

}  // namespace hvdb::render
