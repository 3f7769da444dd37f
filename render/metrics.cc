#include "render/metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace hvdb::render {

namespace {

bool SameShape(const Srgb8Image& a, const Srgb8Image& b) {
  return a.width == b.width && a.height == b.height && a.width > 0 &&
         a.data.size() == size_t{a.width} * a.height * a.channels &&
         b.data.size() == size_t{b.width} * b.height * b.channels;
}

std::vector<double> Luma(const Srgb8Image& im) {
  std::vector<double> y(size_t{im.width} * im.height);
  for (size_t i = 0; i < y.size(); ++i) {
    const uint8_t* p = &im.data[i * im.channels];
    y[i] = im.channels >= 3 ? 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2] : p[0];
  }
  return y;
}

// Separable Gaussian blur (11 taps, sigma 1.5), the image edge repeated.
std::vector<double> Blur(const std::vector<double>& in, int w, int h) {
  static const std::vector<double> kernel = [] {
    std::vector<double> k(11);
    double sum = 0;
    for (int i = 0; i < 11; ++i) sum += k[i] = std::exp(-(i - 5) * (i - 5) / (2 * 1.5 * 1.5));
    for (double& v : k) v /= sum;
    return k;
  }();
  std::vector<double> tmp(in.size()), out(in.size());
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      double s = 0;
      for (int i = 0; i < 11; ++i)
        s += kernel[i] * in[size_t(y) * w + std::clamp(x + i - 5, 0, w - 1)];
      tmp[size_t(y) * w + x] = s;
    }
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      double s = 0;
      for (int i = 0; i < 11; ++i)
        s += kernel[i] * tmp[size_t(std::clamp(y + i - 5, 0, h - 1)) * w + x];
      out[size_t(y) * w + x] = s;
    }
  }
  return out;
}

}  // namespace

double Psnr(const Srgb8Image& a, const Srgb8Image& b, const std::vector<uint8_t>* mask) {
  if (!SameShape(a, b)) return std::numeric_limits<double>::quiet_NaN();
  const size_t n = size_t{a.width} * a.height;
  if (mask && mask->size() != n) return std::numeric_limits<double>::quiet_NaN();
  const uint32_t ch = std::min({a.channels, b.channels, 3u});
  double se = 0;
  size_t count = 0;
  for (size_t i = 0; i < n; ++i) {
    if (mask && !(*mask)[i]) continue;
    for (uint32_t c = 0; c < ch; ++c) {
      double d = double(a.data[i * a.channels + c]) - double(b.data[i * b.channels + c]);
      se += d * d;
    }
    count += ch;
  }
  if (count == 0) return std::numeric_limits<double>::quiet_NaN();
  if (se == 0) return std::numeric_limits<double>::infinity();
  return 10.0 * std::log10(255.0 * 255.0 / (se / static_cast<double>(count)));
}

double Ssim(const Srgb8Image& a, const Srgb8Image& b, const std::vector<uint8_t>* mask) {
  if (!SameShape(a, b)) return std::numeric_limits<double>::quiet_NaN();
  const int w = static_cast<int>(a.width), h = static_cast<int>(a.height);
  const size_t n = size_t(w) * h;
  if (mask && mask->size() != n) return std::numeric_limits<double>::quiet_NaN();
  std::vector<double> x = Luma(a), y = Luma(b), xx(n), yy(n), xy(n);
  for (size_t i = 0; i < n; ++i) {
    xx[i] = x[i] * x[i];
    yy[i] = y[i] * y[i];
    xy[i] = x[i] * y[i];
  }
  std::vector<double> mx = Blur(x, w, h), my = Blur(y, w, h);
  std::vector<double> sxx = Blur(xx, w, h), syy = Blur(yy, w, h), sxy = Blur(xy, w, h);
  const double c1 = (0.01 * 255) * (0.01 * 255), c2 = (0.03 * 255) * (0.03 * 255);
  double sum = 0;
  size_t count = 0;
  for (size_t i = 0; i < n; ++i) {
    if (mask && !(*mask)[i]) continue;
    double vx = sxx[i] - mx[i] * mx[i], vy = syy[i] - my[i] * my[i], cxy = sxy[i] - mx[i] * my[i];
    sum += ((2 * mx[i] * my[i] + c1) * (2 * cxy + c2)) /
           ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
    ++count;
  }
  return count ? sum / static_cast<double>(count) : std::numeric_limits<double>::quiet_NaN();
}

Srgb8Image AbsDiff(const Srgb8Image& a, const Srgb8Image& b, int gain) {
  Srgb8Image d;
  if (!SameShape(a, b)) return d;
  d.width = a.width;
  d.height = a.height;
  d.channels = 3;
  const size_t n = size_t{a.width} * a.height;
  d.data.resize(n * 3);
  for (size_t i = 0; i < n; ++i) {
    for (uint32_t c = 0; c < 3; ++c) {
      int va = a.data[i * a.channels + std::min(c, a.channels - 1)];
      int vb = b.data[i * b.channels + std::min(c, b.channels - 1)];
      d.data[i * 3 + c] = static_cast<uint8_t>(std::min(255, std::abs(va - vb) * gain));
    }
  }
  return d;
}

}  // namespace hvdb::render
