// 3DGS's L1 + D-SSIM loss and its gradient (gaussian_loss.h).
//
// The SSIM map S = (2 mx my + C1)(2 sxy + C2) / ((mx^2 + my^2 + C1)(sxx + syy + C2)) with the
// local statistics as Gaussian blurs: mx = G*x, sxx = G*(x^2) - mx^2, sxy = G*(xy) - mx my.
// Its gradient with respect to the render x goes through the three blurs that involve x
// (G*x, G*x^2, G*xy): with dS/dmx, dS/dExx and dS/dExy per pixel (Exx = G*x^2, Exy = G*xy),
//   dL/dx = G*(g dS/dmx) + 2 x G*(g dS/dExx) + y G*(g dS/dExy),   g = dL/dS,
// since a zero-padded blur by a symmetric kernel is its own adjoint.
#include "ingest/gaussian_loss.h"

#include <cmath>

#include "render/splat.h"

namespace hvdb::ingest {

namespace {

constexpr int kRadius = 5;  // the 11-tap window
constexpr double kC1 = 0.01 * 0.01, kC2 = 0.03 * 0.03;

struct Window {
  float w[2 * kRadius + 1];
  Window() {
    double sum = 0, v[2 * kRadius + 1];
    for (int i = 0; i <= 2 * kRadius; ++i) {
      v[i] = std::exp(-(i - kRadius) * (i - kRadius) / (2.0 * 1.5 * 1.5));
      sum += v[i];
    }
    for (int i = 0; i <= 2 * kRadius; ++i) w[i] = static_cast<float>(v[i] / sum);
  }
};

// out = G * in, separable, zero outside the image. `tmp` holds one plane.
void Blur(const float* in, float* out, float* tmp, int width, int height) {
  static const Window window;
  const float* w = window.w;
  for (int y = 0; y < height; ++y) {
    const float* row = in + static_cast<size_t>(y) * width;
    float* to = tmp + static_cast<size_t>(y) * width;
    for (int x = 0; x < width; ++x) {
      float s = 0;
      const int a = std::max(0, x - kRadius), b = std::min(width - 1, x + kRadius);
      for (int k = a; k <= b; ++k) s += w[k - x + kRadius] * row[k];
      to[x] = s;
    }
  }
  for (int y = 0; y < height; ++y) {
    float* to = out + static_cast<size_t>(y) * width;
    for (int x = 0; x < width; ++x) to[x] = 0;
    const int a = std::max(0, y - kRadius), b = std::min(height - 1, y + kRadius);
    for (int k = a; k <= b; ++k) {
      const float wk = w[k - y + kRadius];
      const float* from = tmp + static_cast<size_t>(k) * width;
      for (int x = 0; x < width; ++x) to[x] += wk * from[x];
    }
  }
}

}  // namespace

PhotoLoss L1DssimLoss(const std::vector<float>& render, const std::vector<float>& target, int width,
                      int height, float lambda, unsigned threads, std::vector<float>* grad) {
  const size_t pixels = static_cast<size_t>(width) * height;
  const double n = 3.0 * static_cast<double>(pixels);
  if (grad != nullptr) grad->assign(3 * pixels, 0.0f);
  double l1 = 0;
  for (size_t i = 0; i < 3 * pixels; ++i) {
    const float d = render[i] - target[i];
    l1 += std::fabs(d);
    if (grad != nullptr) {
      (*grad)[i] = static_cast<float>((1.0 - lambda) * (d > 0 ? 1.0 : (d < 0 ? -1.0 : 0.0)) / n);
    }
  }
  double ssim_sum[3] = {0, 0, 0};
  // One channel per task: its planes, blurs and gradient.
  render::internal::ParallelFor(3, threads, [&](size_t ch) {
    std::vector<float> x(pixels), y(pixels), xx(pixels), yy(pixels), xy(pixels), tmp(pixels);
    for (size_t i = 0; i < pixels; ++i) {
      x[i] = render[3 * i + ch];
      y[i] = target[3 * i + ch];
      xx[i] = x[i] * x[i];
      yy[i] = y[i] * y[i];
      xy[i] = x[i] * y[i];
    }
    std::vector<float> mx(pixels), my(pixels), exx(pixels), eyy(pixels), exy(pixels);
    Blur(x.data(), mx.data(), tmp.data(), width, height);
    Blur(y.data(), my.data(), tmp.data(), width, height);
    Blur(xx.data(), exx.data(), tmp.data(), width, height);
    Blur(yy.data(), eyy.data(), tmp.data(), width, height);
    Blur(xy.data(), exy.data(), tmp.data(), width, height);
    double sum = 0;
    // Reuse xx, yy, xy as the three gradient planes g dS/dmx, g dS/dExx, g dS/dExy.
    const double g = -lambda / n;
    for (size_t i = 0; i < pixels; ++i) {
      const double ux = mx[i], uy = my[i];
      const double a1 = 2 * ux * uy + kC1, a2 = 2 * (exy[i] - ux * uy) + kC2;
      const double b1 = ux * ux + uy * uy + kC1;
      const double b2 = (exx[i] - ux * ux) + (eyy[i] - uy * uy) + kC2;
      const double s = a1 * a2 / (b1 * b2);
      sum += s;
      xx[i] = static_cast<float>(g * s * (2 * uy / a1 - 2 * uy / a2 - 2 * ux / b1 + 2 * ux / b2));
      yy[i] = static_cast<float>(g * -s / b2);
      xy[i] = static_cast<float>(g * 2 * s / a2);
    }
    ssim_sum[ch] = sum;
    if (grad == nullptr) return;
    Blur(xx.data(), mx.data(), tmp.data(), width, height);
    Blur(yy.data(), exx.data(), tmp.data(), width, height);
    Blur(xy.data(), exy.data(), tmp.data(), width, height);
    for (size_t i = 0; i < pixels; ++i) {
      (*grad)[3 * i + ch] += mx[i] + 2 * x[i] * exx[i] + y[i] * exy[i];
    }
  });
  PhotoLoss out;
  out.l1 = l1 / n;
  out.ssim = (ssim_sum[0] + ssim_sum[1] + ssim_sum[2]) / n;
  out.loss = (1.0 - lambda) * out.l1 + lambda * (1.0 - out.ssim);
  return out;
}

}  // namespace hvdb::ingest
