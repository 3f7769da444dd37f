#include "ingest/stereo.h"

#include <ceres/tiny_solver.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <string>
#include <thread>
#include <vector>

namespace hvdb::ingest {

namespace {

using Clock = std::chrono::steady_clock;

double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

constexpr int kMaxWindow = 101;     // horizontal box sums of W * 510 must fit in uint16
constexpr int kMaxFrames = 64;      // per-pixel cost summed over frames must fit in uint16
constexpr int kChunk = 16;          // disparity layers are padded to a multiple of this
constexpr int16_t kMaxPixelCost = 510;  // BT cost in half grey levels: at most 2 * 255
constexpr int16_t kOutside = -10000;    // right "intensity" beyond the image: cost saturates

// Runs fn(y0, y1) on `threads` contiguous row bands and waits for all of them.
void ParallelBands(int rows, int threads, const std::function<void(int, int)>& fn) {
  threads = std::max(1, std::min(threads, rows));
  if (threads == 1) {
    fn(0, rows);
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(threads);
  for (int t = 0; t < threads; ++t) {
    const int y0 = static_cast<int>(static_cast<int64_t>(rows) * t / threads);
    const int y1 = static_cast<int>(static_cast<int64_t>(rows) * (t + 1) / threads);
    pool.emplace_back(fn, y0, y1);
  }
  for (auto& th : pool) th.join();
}

// Runs fn(row) for every row, rows handed out one at a time: S5's cost per row varies with
// the number of valid pixels, so static bands would leave a core idle.
void ParallelRowsDynamic(int rows, int threads, const std::function<void(int)>& fn) {
  std::atomic<int> next{0};
  auto worker = [&](int, int) {
    for (int y = next++; y < rows; y = next++) fn(y);
  };
  ParallelBands(std::max(1, std::min(threads, rows)), threads,
                [&](int a, int b) { worker(a, b); });
}

Result<cv::Mat> ToGrey(const cv::Mat& m, const std::string& what) {
  if (m.empty()) return Status::InvalidArgument(what + " is empty");
  if (m.type() == CV_8UC1) return m;
  if (m.type() == CV_8UC3) {
    cv::Mat g;
    cv::cvtColor(m, g, cv::COLOR_BGR2GRAY);
    return g;
  }
  return Status::InvalidArgument(what + " must be 8-bit grey (CV_8UC1) or BGR (CV_8UC3), got type " +
                                 std::to_string(m.type()) + " with " +
                                 std::to_string(m.channels()) + " channel(s)");
}

// The signal S1 matches: the intensities minus their mean over the matching window (a
// zero-mean window, as in ZSAD), clipped to +-kPrefilterCap and offset into 8 bits. Plain
// intensities break down wherever the two cameras see different brightness — exposure
// (Middlebury's *E), lighting (*L, ArtL) or a different gain (Adirondack): the mean bad-2px
// rate over the 12 Middlebury 2014 Q scenes was 50.9 % on intensities and 24.0 % on this
// signal (stereo-bench, same parameters). A clipped x-derivative (OpenCV's prefilter) scored
// 20.8 % there but loses the subpixel structure of binary stripe patterns (thesis 3.4): only
// ~70 % of a synthetic stripe pair survived the cross-check, against 98 % here. The cost on
// the signal stays Birchfield-Tomasi; S5 refines on the plain intensities (eq. 3.28).
constexpr int kPrefilterCap = 127;

cv::Mat Prefilter(const cv::Mat& grey, int window) {
  cv::Mat mean, i16, m16, out;
  cv::blur(grey, mean, cv::Size(window, window), cv::Point(-1, -1), cv::BORDER_REFLECT_101);
  grey.convertTo(i16, CV_16S);
  mean.convertTo(m16, CV_16S);
  cv::Mat z = i16 - m16;
  z = cv::max(cv::min(z, kPrefilterCap), -kPrefilterCap);
  z.convertTo(out, CV_8U, 1.0, kPrefilterCap);
  return out;
}

// A disparity space image: rows x cols x dp uint16, the disparity index innermost so that
// every per-layer filter is a vectorisable loop over contiguous layers.
struct Volume {
  int rows = 0, cols = 0, dp = 0;
  std::vector<uint16_t> v;
  void Resize(int r, int c, int d) {
    rows = r, cols = c, dp = d;
    v.resize(static_cast<size_t>(r) * c * d);
  }
  uint16_t* Row(int y) { return v.data() + static_cast<size_t>(y) * cols * dp; }
  const uint16_t* Row(int y) const { return v.data() + static_cast<size_t>(y) * cols * dp; }
};

// S1: symmetric Birchfield-Tomasi cost of one row for all disparity layers, in half grey
// levels (the interpolated half-way intensities are exact in that unit). Layer k holds
// disparity dmin + k, i.e. the right pixel x - dmin - k. Right pixels outside the image get
// the maximum cost. When `accumulate`, the cost is added to `out` (spacetime frames).
struct CostRowWorkspace {
  std::vector<int16_t> lv, lmin, lmax, rv, rmin, rmax;
};

void CostRow(const uint8_t* left, const uint8_t* right, int w, int dmin, int dp,
             CostRowWorkspace& ws, uint16_t* out, bool accumulate) {
  auto extrema = [w](const uint8_t* I, int x, int16_t* v, int16_t* mn, int16_t* mx) {
    const int c = 2 * I[x];
    const int m = I[x] + I[std::max(x - 1, 0)];
    const int p = I[x] + I[std::min(x + 1, w - 1)];
    *v = static_cast<int16_t>(c);
    *mn = static_cast<int16_t>(std::min({c, m, p}));
    *mx = static_cast<int16_t>(std::max({c, m, p}));
  };
  ws.lv.resize(w), ws.lmin.resize(w), ws.lmax.resize(w);
  for (int x = 0; x < w; ++x) extrema(left, x, &ws.lv[x], &ws.lmin[x], &ws.lmax[x]);
  // The right row reversed (j = w - 1 - xr) so that layer k of left pixel x reads the
  // contiguous index j = w - 1 - x + dmin + k: the loop over k is a plain vector loop.
  const int jlo = std::min(dmin, 0);
  const int jhi = std::max(w - 1, w - 2 + dmin + dp);
  const int n = jhi - jlo + 1;
  ws.rv.assign(n, kOutside), ws.rmin.assign(n, kOutside), ws.rmax.assign(n, kOutside);
  for (int xr = 0; xr < w; ++xr) {
    const int e = (w - 1 - xr) - jlo;
    extrema(right, xr, &ws.rv[e], &ws.rmin[e], &ws.rmax[e]);
  }
  for (int x = 0; x < w; ++x) {
    const int16_t il = ws.lv[x], ilmin = ws.lmin[x], ilmax = ws.lmax[x];
    const int base = (w - 1 - x + dmin) - jlo;
    const int16_t* rv = ws.rv.data() + base;
    const int16_t* rmn = ws.rmin.data() + base;
    const int16_t* rmx = ws.rmax.data() + base;
    uint16_t* o = out + static_cast<size_t>(x) * dp;
    for (int k0 = 0; k0 < dp; k0 += kChunk) {
      for (int k = k0; k < k0 + kChunk; ++k) {
        const int16_t ir = rv[k];
        // Left intensity against the right pixel's interpolated range, and vice versa.
        int16_t a = std::max<int16_t>(std::max<int16_t>(il - rmx[k], rmn[k] - il), 0);
        int16_t b = std::max<int16_t>(std::max<int16_t>(ir - ilmax, ilmin - ir), 0);
        const uint16_t c = static_cast<uint16_t>(std::min<int16_t>(std::min(a, b), kMaxPixelCost));
        o[k] = accumulate ? static_cast<uint16_t>(o[k] + c) : c;
      }
    }
  }
}

// S2, horizontal half: out[x] = sum of in[x - r .. x + r] (indices clamped: replicated border,
// so every window sums the same number of terms). uint16 wrap-around is exact because every
// final sum is below 2^16 (W * 510 with W <= kMaxWindow).
void BoxRow(const uint16_t* in, int w, int dp, int r, uint16_t* out, std::vector<uint16_t>& acc) {
  acc.assign(dp, 0);
  for (int i = -r; i <= r; ++i) {
    const uint16_t* p = in + static_cast<size_t>(std::clamp(i, 0, w - 1)) * dp;
    for (int k = 0; k < dp; ++k) acc[k] = static_cast<uint16_t>(acc[k] + p[k]);
  }
  std::copy(acc.begin(), acc.end(), out);
  for (int x = 1; x < w; ++x) {
    const uint16_t* add = in + static_cast<size_t>(std::min(x + r, w - 1)) * dp;
    const uint16_t* sub = in + static_cast<size_t>(std::max(x - r - 1, 0)) * dp;
    uint16_t* o = out + static_cast<size_t>(x) * dp;
    uint16_t* a = acc.data();
    for (int k = 0; k < dp; ++k) {
      a[k] = static_cast<uint16_t>(a[k] + add[k] - sub[k]);
      o[k] = a[k];
    }
  }
}

// S3, horizontal half: out[x] = min of in[x - r .. x + r] within the row (a window hanging
// over the border holds the same values as the clamped one, so the range is just cut). By a
// sparse table: level q holds the minimum of 2^q consecutive columns, so any window is the
// minimum of two entries of one level: log2(2r + 1) passes over the row and one query each,
// instead of 2r passes (9 x 9 windows: 4 instead of 8; exact either way).
void MinRow(const uint16_t* in, int w, int dp, int r, uint16_t* out, std::vector<uint16_t>& table) {
  const size_t n = static_cast<size_t>(w) * dp;
  int levels = 0;
  while ((2 << levels) <= 2 * r + 1) ++levels;  // 2^levels <= 2r + 1 < 2^(levels + 1)
  table.resize(n * static_cast<size_t>(levels));
  auto level = [&](int q) -> const uint16_t* { return q == 0 ? in : table.data() + n * static_cast<size_t>(q - 1); };
  for (int q = 1; q <= levels; ++q) {
    const uint16_t* prev = level(q - 1);
    uint16_t* cur = table.data() + n * static_cast<size_t>(q - 1);
    const size_t half = static_cast<size_t>(1) << (q - 1);
    const size_t valid = static_cast<size_t>(w) >= 2 * half ? (static_cast<size_t>(w) - 2 * half + 1) * dp : 0;
    for (size_t i = 0; i < valid; ++i) cur[i] = std::min(prev[i], prev[i + half * dp]);
  }
  for (int x = 0; x < w; ++x) {
    const int a = std::max(x - r, 0), b = std::min(x + r, w - 1);
    int q = 0;
    while ((2 << q) <= b - a + 1) ++q;
    const uint16_t* p0 = level(q) + static_cast<size_t>(a) * dp;
    const uint16_t* p1 = level(q) + static_cast<size_t>(b + 1 - (1 << q)) * dp;
    uint16_t* o = out + static_cast<size_t>(x) * dp;
    for (int k = 0; k < dp; ++k) o[k] = std::min(p0[k], p1[k]);
  }
}

// S5: residuals of eq. 3.28/3.30 for one pixel, r_i = I_L(x, y, t) - I_R(x - d', y, t) with
// d' from eq. 3.29/3.31 and I_R linearly interpolated along the row; analytic Jacobian (the
// slope of the interpolant). Masked window pixels are simply not in `samples`; the residual
// vector keeps the full window size (zeros past `count`) so TinySolver never reallocates.
struct Sample {
  float il;           // left intensity
  const float* rrow;  // right row of the same frame
  float x, u, v, t;   // left x; offsets from the centre pixel in x, y, frames
};

template <int NP>
struct SubpixelResiduals {
  using Scalar = double;
  enum { NUM_RESIDUALS = Eigen::Dynamic, NUM_PARAMETERS = NP };
  const Sample* samples = nullptr;
  int count = 0;  // active samples
  int size = 0;   // residuals reported (window area x frames)
  int width = 0;  // right row length
  int NumResiduals() const { return size; }
  bool operator()(const double* p, double* res, double* jac) const {
    for (int i = 0; i < count; ++i) {
      const Sample& s = samples[i];
      double dprime = p[0] + p[1] * s.u + p[2] * s.v;
      if constexpr (NP == 4) dprime += p[3] * s.t;
      const double xs = s.x - dprime;
      double val = 0, slope = 0;
      const bool inside = width >= 2 && xs >= 0 && xs <= width - 1;
      if (inside) {
        const int i0 = std::min(static_cast<int>(xs), width - 2);
        const double a = xs - i0;
        const double r0 = s.rrow[i0], r1 = s.rrow[i0 + 1];
        val = r0 + a * (r1 - r0);
        slope = r1 - r0;
      }
      res[i] = inside ? s.il - val : 0.0;
      if (jac != nullptr) {
        // d r / d d = +slope, since x_right = x - d'.
        jac[i] = slope;
        jac[i + size] = slope * s.u;
        jac[i + 2 * size] = slope * s.v;
        if constexpr (NP == 4) jac[i + 3 * size] = slope * s.t;
      }
    }
    for (int i = count; i < size; ++i) {
      res[i] = 0;
      if (jac != nullptr) {
        for (int j = 0; j < NP; ++j) jac[i + j * size] = 0;
      }
    }
    return true;
  }
};

// Everything shared by MatchStereo and MatchSpacetime: frames [0, n) with the refined frame
// `centre`; `spacetime` adds dt to S5.
Result<DisparityMap> Match(const std::vector<cv::Mat>& lefts_in, const std::vector<cv::Mat>& rights_in,
                           size_t centre, const StereoParams& params, bool spacetime) {
  const auto t_start = Clock::now();
  if (lefts_in.empty()) return Status::InvalidArgument("stereo: no frames given");
  if (lefts_in.size() != rights_in.size()) {
    return Status::InvalidArgument("stereo: " + std::to_string(lefts_in.size()) +
                                   " left frames but " + std::to_string(rights_in.size()) +
                                   " right frames");
  }
  if (lefts_in.size() > static_cast<size_t>(kMaxFrames)) {
    return Status::InvalidArgument("stereo: at most " + std::to_string(kMaxFrames) +
                                   " frames, got " + std::to_string(lefts_in.size()));
  }
  if (centre >= lefts_in.size()) {
    return Status::InvalidArgument("stereo: centre frame " + std::to_string(centre) +
                                   " out of range (" + std::to_string(lefts_in.size()) +
                                   " frames)");
  }
  const int nframes = static_cast<int>(lefts_in.size());
  std::vector<cv::Mat> lefts(nframes), rights(nframes);
  for (int f = 0; f < nframes; ++f) {
    const std::string suffix = nframes > 1 ? " (frame " + std::to_string(f) + ")" : "";
    HVDB_ASSIGN_OR_RETURN(lefts[f], ToGrey(lefts_in[f], "left image" + suffix));
    HVDB_ASSIGN_OR_RETURN(rights[f], ToGrey(rights_in[f], "right image" + suffix));
    if (lefts[f].size() != rights[f].size() || lefts[f].size() != lefts[0].size()) {
      return Status::InvalidArgument(
          "stereo: image sizes differ" + suffix + ": left " + std::to_string(lefts[f].cols) + "x" +
          std::to_string(lefts[f].rows) + ", right " + std::to_string(rights[f].cols) + "x" +
          std::to_string(rights[f].rows) + ", first left " + std::to_string(lefts[0].cols) + "x" +
          std::to_string(lefts[0].rows));
    }
  }
  HVDB_RETURN_IF_ERROR(params.Validate(lefts[0].size()));
  // S5 works on the intensities, S1-S4 on the zero-mean signal (see Prefilter).
  std::vector<cv::Mat> lf(nframes), rf(nframes), zl(nframes), zr(nframes);
  for (int f = 0; f < nframes; ++f) {
    if (params.subpixel == Subpixel::kLevenbergMarquardt) {
      lefts[f].convertTo(lf[f], CV_32F);
      rights[f].convertTo(rf[f], CV_32F);
    }
    zl[f] = Prefilter(lefts[f], params.window);
    zr[f] = Prefilter(rights[f], params.window);
  }

  const auto t_bands = Clock::now();
  const int H = lefts[0].rows, W = lefts[0].cols;
  const int D = params.num_disparities, dmin = params.min_disparity;
  const int dp = (D + kChunk - 1) / kChunk * kChunk;
  const int r = params.window / 2;
  const int threads = params.threads > 0
                          ? params.threads
                          : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  DisparityMap out;
  StereoTiming& tm = out.timing;

  // S1-S4 and the cross-check, streamed in bands of rows: each band computes the cost rows it
  // needs (its rows plus 2r above and below, for the vertical box and minimum filters), so
  // a band's volumes (~(B + 4r) rows x W x dp) stay in cache and are reused band after band,
  // instead of two whole-image volumes (~115 MB at Middlebury 2014 Q) that were faulted in,
  // zeroed and freed on every call (a third of the time). Every stage is row-local after the
  // two vertical filters, so bands are independent; threads take them in turn. Stage times are
  // the threads' summed times divided by the thread count.
  int shift = 0;
  while ((static_cast<int64_t>(params.window) * params.window * kMaxPixelCost >> shift) > 65535) ++shift;
  const bool min_filter = params.multi_window && r > 0;
  const int band = 32;
  const int bands = (H + band - 1) / band;
  cv::Mat kl(H, W, CV_16S), dpar(H, W, CV_32F), valid(H, W, CV_8U);
  std::atomic<int> next_band{0};
  std::atomic<int64_t> ns[5] = {0, 0, 0, 0, 0};  // cost, aggregate, min, wta, check
  const int nthreads = std::max(1, std::min(threads, bands));
  ParallelBands(nthreads, nthreads, [&](int, int) {
    CostRowWorkspace ws;
    Volume cost, agg;  // this thread's band volumes, reused
    std::vector<uint16_t> acc16, tmp, min_table;
    std::vector<uint32_t> acc;
    std::vector<int> kr(W);
    const size_t n = static_cast<size_t>(W) * dp;
    auto lap = [](Clock::time_point& t, std::atomic<int64_t>& into) {
      const auto now = Clock::now();
      into += std::chrono::duration_cast<std::chrono::nanoseconds>(now - t).count();
      t = now;
    };
    for (int bi = next_band++; bi < bands; bi = next_band++) {
      const int y0 = bi * band, y1 = std::min(H, y0 + band);
      // Rows of the aggregated volume [a0, a1) and of the cost volume [c0, c1) this band needs.
      const int a0 = min_filter ? std::max(0, y0 - r) : y0;
      const int a1 = min_filter ? std::min(H, y1 + r) : y1;
      const int c0 = std::max(0, a0 - r), c1 = std::min(H, a1 + r);
      cost.Resize(c1 - c0, W, dp);
      agg.Resize(std::max(a1 - a0, y1 - y0), W, dp);
      auto t = Clock::now();
      // S1 (averaged over frames for spacetime: a constant-disparity spacetime window).
      for (int y = c0; y < c1; ++y) {
        uint16_t* row = cost.Row(y - c0);
        for (int f = 0; f < nframes; ++f) {
          CostRow(zl[f].ptr<uint8_t>(y), zr[f].ptr<uint8_t>(y), W, dmin, dp, ws, row, f > 0);
        }
        if (nframes > 1) {
          for (size_t i = 0; i < n; ++i) row[i] = static_cast<uint16_t>((row[i] + nframes / 2) / nframes);
        }
      }
      lap(t, ns[0]);
      // S2: box filter per layer: horizontal in place (through a row), then vertical running
      // sums (cost -> agg; kept in uint32 and shifted down, as the sum may pass 2^16).
      tmp.resize(n);
      for (int y = c0; y < c1; ++y) {
        BoxRow(cost.Row(y - c0), W, dp, r, tmp.data(), acc16);
        std::copy(tmp.begin(), tmp.end(), cost.Row(y - c0));
      }
      acc.assign(n, 0);
      auto crow = [&](int i) { return cost.Row(std::clamp(i, 0, H - 1) - c0); };
      for (int i = a0 - r; i <= a0 + r; ++i) {
        const uint16_t* p = crow(i);
        for (size_t k = 0; k < n; ++k) acc[k] += p[k];
      }
      for (int y = a0; y < a1; ++y) {
        if (y > a0) {
          const uint16_t* add = crow(y + r);
          const uint16_t* sub = crow(y - r - 1);
          for (size_t k = 0; k < n; ++k) acc[k] += static_cast<uint32_t>(add[k]) - sub[k];
        }
        uint16_t* o = agg.Row(y - a0);
        for (size_t k = 0; k < n; ++k) o[k] = static_cast<uint16_t>(acc[k] >> shift);
      }
      lap(t, ns[1]);
      // S3: eq. 3.32, the best of all windows containing the pixel = erosion of each layer
      // with the window; separable: horizontal min in place, vertical min (agg -> cost rows).
      auto final_row = [&](int y) -> const uint16_t* { return agg.Row(y - a0); };
      std::function<const uint16_t*(int)> fin = final_row;
      if (min_filter) {
        for (int y = a0; y < a1; ++y) {
          MinRow(agg.Row(y - a0), W, dp, r, tmp.data(), min_table);
          std::copy(tmp.begin(), tmp.end(), agg.Row(y - a0));
        }
        for (int y = y0; y < y1; ++y) {
          uint16_t* o = cost.Row(y - y0);  // the cost rows are spent: reused for the result
          const int lo = std::max(y - r, 0), hi = std::min(y + r, H - 1);
          std::copy(agg.Row(lo - a0), agg.Row(lo - a0) + n, o);
          for (int i = lo + 1; i <= hi; ++i) {
            const uint16_t* p = agg.Row(i - a0);
            for (size_t k = 0; k < n; ++k) o[k] = std::min(o[k], p[k]);
          }
        }
        fin = [&](int y) -> const uint16_t* { return cost.Row(y - y0); };
      }
      lap(t, ns[2]);
      // S4: winner-takes-all over the D real layers (padding layers ignored), plus the
      // parabola through the costs at k-1, k, k+1 (S5's starting point and fallback).
      for (int y = y0; y < y1; ++y) {
        const uint16_t* row = fin(y);
        int16_t* ko = kl.ptr<int16_t>(y);
        float* po = dpar.ptr<float>(y);
        for (int x = 0; x < W; ++x) {
          const uint16_t* c = row + static_cast<size_t>(x) * dp;
          int best = 0;
          uint16_t bc = c[0];
          for (int k = 1; k < D; ++k) {
            if (c[k] < bc) bc = c[k], best = k;
          }
          ko[x] = static_cast<int16_t>(best);
          float off = 0;
          if (best > 0 && best < D - 1) {
            const float cm = c[best - 1], c0v = c[best], cp = c[best + 1];
            const float den = cm - 2 * c0v + cp;
            if (den > 0) off = std::clamp(0.5f * (cm - cp) / den, -0.5f, 0.5f);
          }
          po[x] = static_cast<float>(dmin + best) + off;
        }
      }
      lap(t, ns[3]);
      // Left-right check (3.5.1): the right view's WTA from the same volume (right pixel xr
      // and layer k see left pixel xr + dmin + k). Matches outside the right image are invalid.
      for (int y = y0; y < y1; ++y) {
        const uint16_t* row = fin(y);
        const int16_t* kly = kl.ptr<int16_t>(y);
        uint8_t* vo = valid.ptr<uint8_t>(y);
        if (params.cross_check) {
          for (int xr = 0; xr < W; ++xr) {
            int best = -1;
            uint16_t bc = std::numeric_limits<uint16_t>::max();
            const int kmin = std::max(0, -(xr + dmin));
            const int kmax = std::min(D - 1, W - 1 - xr - dmin);
            for (int k = kmin; k <= kmax; ++k) {
              const uint16_t c = row[static_cast<size_t>(xr + dmin + k) * dp + k];
              if (c < bc) bc = c, best = k;
            }
            kr[xr] = best;
          }
        }
        for (int x = 0; x < W; ++x) {
          const int xr = x - dmin - kly[x];
          bool ok = xr >= 0 && xr < W;
          if (ok && params.cross_check) {
            ok = kr[xr] >= 0 && std::abs(kr[xr] - kly[x]) <= params.cross_check_tolerance;
          }
          vo[x] = ok ? 1 : 0;
        }
      }
      lap(t, ns[4]);
    }
  });
  auto t5 = Clock::now();
  tm.prepare_ms = Ms(t_start, t_bands);
  {
    const double wall = Ms(t_bands, t5);
    double sum = 0;
    for (const auto& v : ns) sum += static_cast<double>(v.load());
    auto share = [&](int i) { return sum > 0 ? wall * static_cast<double>(ns[i].load()) / sum : 0.0; };
    tm.cost_ms = share(0);
    tm.aggregate_ms = share(1);
    tm.min_filter_ms = share(2);
    tm.wta_ms = share(3);
    tm.cross_check_ms = share(4);
  }

  const float inf = std::numeric_limits<float>::infinity();
  out.d.create(H, W, CV_32F);
  out.dx = cv::Mat::zeros(H, W, CV_32F);
  out.dy = cv::Mat::zeros(H, W, CV_32F);
  if (spacetime) out.dt = cv::Mat::zeros(H, W, CV_32F);
  if (params.subpixel != Subpixel::kLevenbergMarquardt) {
    // Integer disparities, or S4's parabola fits.
    const bool parabola = params.subpixel == Subpixel::kParabola;
    for (int y = 0; y < H; ++y) {
      const uint8_t* v = valid.ptr<uint8_t>(y);
      const int16_t* k = kl.ptr<int16_t>(y);
      const float* pf = dpar.ptr<float>(y);
      float* o = out.d.ptr<float>(y);
      for (int x = 0; x < W; ++x) {
        o[x] = !v[x] ? inf : parabola ? pf[x] : static_cast<float>(dmin + k[x]);
      }
    }
  } else {
    // S5: Levenberg-Marquardt (Ceres' TinySolver: dense LM without per-problem overhead) on
    // (d, dx, dy[, dt]) per valid pixel, starting from the parabola fit.
    const float thr = static_cast<float>(params.discontinuity_threshold);
    const int area = params.window * params.window * nframes;
    auto refine = [&]<int NP>(std::integral_constant<int, NP>) {
      ParallelRowsDynamic(H, threads, [&](int y0) {
        std::vector<Sample> samples(area);
        SubpixelResiduals<NP> fn;
        fn.samples = samples.data();
        fn.size = area;
        fn.width = W;
        ceres::TinySolver<SubpixelResiduals<NP>> solver;
        solver.options.max_num_iterations = 10;
        solver.options.parameter_tolerance = 1e-4;
        solver.options.function_tolerance = 1e-6;
        solver.options.gradient_tolerance = 1e-8;
        float* dout = out.d.ptr<float>(y0);
        for (int x0 = 0; x0 < W; ++x0) {
          if (!valid.at<uint8_t>(y0, x0)) {
            dout[x0] = inf;
            continue;
          }
          const float dc = dpar.at<float>(y0, x0);
          const int dint = dmin + kl.at<int16_t>(y0, x0);
          // The window, without pixels across a depth discontinuity or without a valid
          // coarse disparity (occlusions).
          int m = 0;
          for (int y = std::max(y0 - r, 0); y <= std::min(y0 + r, H - 1); ++y) {
            const uint8_t* vrow = valid.ptr<uint8_t>(y);
            const float* prow = dpar.ptr<float>(y);
            for (int x = std::max(x0 - r, 0); x <= std::min(x0 + r, W - 1); ++x) {
              if (!vrow[x] || std::abs(prow[x] - dc) > thr) continue;
              for (int f = 0; f < nframes; ++f) {
                samples[m++] = {lf[f].ptr<float>(y)[x], rf[f].ptr<float>(y),
                                static_cast<float>(x), static_cast<float>(x - x0),
                                static_cast<float>(y - y0),
                                static_cast<float>(f - static_cast<int>(centre))};
              }
            }
          }
          fn.count = m;
          Eigen::Matrix<double, NP, 1> p = Eigen::Matrix<double, NP, 1>::Zero();
          p[0] = dc;
          bool accept = false;
          // Fewer samples than a quarter window: too little support for NP unknowns.
          if (m >= std::max(2 * NP, area / 4)) {
            solver.Solve(fn, &p);
            // Constrain d to the coarse value +-1 px: an LM result outside that (or NaN) has
            // slid into another match; reject it and keep the parabola fit with zero gradients.
            accept = p.allFinite() && std::abs(p[0] - dint) <= 1.0;
          }
          if (accept) {
            dout[x0] = static_cast<float>(p[0]);
            out.dx.at<float>(y0, x0) = static_cast<float>(p[1]);
            out.dy.at<float>(y0, x0) = static_cast<float>(p[2]);
            if constexpr (NP == 4) out.dt.at<float>(y0, x0) = static_cast<float>(p[3]);
          } else {
            dout[x0] = dc;
          }
        }
      });
    };
    if (spacetime) {
      refine(std::integral_constant<int, 4>{});
    } else {
      refine(std::integral_constant<int, 3>{});
    }
  }
  auto t6 = Clock::now();
  tm.subpixel_ms = Ms(t5, t6);
  tm.total_ms = Ms(t_start, t6);
  return out;
}

}  // namespace

bool ParseSubpixel(const std::string& name, Subpixel* out) {
  if (name == "none") *out = Subpixel::kNone;
  else if (name == "parabola") *out = Subpixel::kParabola;
  else if (name == "lm") *out = Subpixel::kLevenbergMarquardt;
  else return false;
  return true;
}

Status StereoParams::Validate(const cv::Size& image_size) const {
  if (image_size.width <= 0 || image_size.height <= 0) {
    return Status::InvalidArgument("stereo: empty image (" + std::to_string(image_size.width) +
                                   "x" + std::to_string(image_size.height) + ")");
  }
  const int w = image_size.width, h = image_size.height;
  if (num_disparities < 1) {
    return Status::InvalidArgument("stereo: num_disparities must be >= 1, got " +
                                   std::to_string(num_disparities));
  }
  if (num_disparities > w) {
    return Status::InvalidArgument("stereo: num_disparities " + std::to_string(num_disparities) +
                                   " is larger than the image width " + std::to_string(w));
  }
  // Every searched disparity must leave some overlap between the two views.
  if (min_disparity <= -w || min_disparity >= w ||
      static_cast<int64_t>(min_disparity) + num_disparities - 1 >= w) {
    return Status::InvalidArgument(
        "stereo: disparity range [" + std::to_string(min_disparity) + ", " +
        std::to_string(static_cast<int64_t>(min_disparity) + num_disparities) +
        ") does not fit the image width " + std::to_string(w));
  }
  if (num_disparities > 32767) return Status::InvalidArgument("stereo: num_disparities too large");
  if (window < 1 || window % 2 == 0 || window > kMaxWindow) {
    return Status::InvalidArgument("stereo: window must be odd and in [1, " +
                                   std::to_string(kMaxWindow) + "], got " + std::to_string(window));
  }
  if (window > w || window > h) {
    return Status::InvalidArgument("stereo: window " + std::to_string(window) +
                                   " is larger than the image (" + std::to_string(w) + "x" +
                                   std::to_string(h) + ")");
  }
  if (cross_check_tolerance < 0) {
    return Status::InvalidArgument("stereo: cross_check_tolerance must be >= 0, got " +
                                   std::to_string(cross_check_tolerance));
  }
  if (!(discontinuity_threshold > 0) || !std::isfinite(discontinuity_threshold)) {
    return Status::InvalidArgument("stereo: discontinuity_threshold must be a positive number, got " +
                                   std::to_string(discontinuity_threshold));
  }
  if (threads < 0 || threads > 1024) {
    return Status::InvalidArgument("stereo: threads must be in [0, 1024] (0 = all), got " +
                                   std::to_string(threads));
  }
  return Status::OK();
}

Result<DisparityMap> MatchStereo(const cv::Mat& left, const cv::Mat& right,
                                 const StereoParams& params) {
  return Match({left}, {right}, 0, params, /*spacetime=*/false);
}

Result<DisparityMap> MatchSpacetime(const std::vector<cv::Mat>& lefts,
                                    const std::vector<cv::Mat>& rights, size_t centre,
                                    const StereoParams& params) {
  return Match(lefts, rights, centre, params, /*spacetime=*/true);
}

}  // namespace hvdb::ingest
