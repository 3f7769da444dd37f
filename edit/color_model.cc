#include "edit/color_model.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>

namespace hvdb::edit {

namespace {

// Added to every covariance: keeps a model of a single-colour stroke (zero scatter) invertible.
constexpr double kRegularisation = 1e-6;

double Dist2(const Rgb& a, const Rgb& b) {
  double d = 0;
  for (int i = 0; i < 3; ++i) d += (a[i] - b[i]) * (a[i] - b[i]);
  return d;
}

// SplitMix64: a fixed, portable sequence (std::uniform_*_distribution is not portable across
// standard libraries, and the same strokes must give the same models everywhere).
struct SplitMix64 {
  uint64_t s;
  uint64_t Next() {
    uint64_t z = (s += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  double Uniform() { return static_cast<double>(Next() >> 11) * 0x1.0p-53; }  // [0, 1)
};

}  // namespace

double ColorModel::weight(size_t j) const {
  // log_norm = log w - (3 log 2pi + log det) / 2, and det = 1 / det(inv).
  const auto& m = comps_[j].inv;
  const double det_inv = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                         m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                         m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
  return std::exp(comps_[j].log_norm + 0.5 * (3 * std::log(2 * std::numbers::pi) - std::log(det_inv)));
}

Status ColorModel::Train(const std::vector<Rgb>& samples, int components, int iterations) {
  if (samples.empty()) return Status::InvalidArgument("graph cut: a colour model has no samples");
  if (components < 1 || iterations < 1) {
    return Status::InvalidArgument("graph cut: a colour model needs components and iterations >= 1");
  }
  // At most kMaxSamples, evenly strided: a thousand colours fit five Gaussians in 3D as well as
  // all of them (issue 15's real scene: same precision and recall) in a fraction of the time.
  constexpr size_t kMaxSamples = 1000;
  std::vector<Rgb> strided;
  if (samples.size() > kMaxSamples) {
    const size_t stride = (samples.size() + kMaxSamples - 1) / kMaxSamples;
    for (size_t i = 0; i < samples.size(); i += stride) strided.push_back(samples[i]);
    return Train(strided, components, iterations);
  }
  const size_t m = samples.size();
  const size_t kmax = static_cast<size_t>(
      std::clamp<int64_t>(std::min<int64_t>(components, static_cast<int64_t>(m / 4)), 1, 16));

  // k-means++ centres (Arthur & Vassilvitskii 2007), then a few Lloyd steps.
  SplitMix64 rng{0x5eed5eed5eed5eedULL};
  std::vector<Rgb> centre{samples[rng.Next() % m]};
  std::vector<double> d2(m);
  for (size_t i = 0; i < m; ++i) d2[i] = Dist2(samples[i], centre[0]);
  while (centre.size() < kmax) {
    double total = 0;
    for (double d : d2) total += d;
    if (total <= 0) break;  // every sample is on a centre already: fewer components
    double r = rng.Uniform() * total;
    size_t pick = m - 1;
    for (size_t i = 0; i < m; ++i) {
      if ((r -= d2[i]) < 0) {
        pick = i;
        break;
      }
    }
    centre.push_back(samples[pick]);
    for (size_t i = 0; i < m; ++i) d2[i] = std::min(d2[i], Dist2(samples[i], centre.back()));
  }
  const size_t k = centre.size();
  std::vector<uint32_t> label(m, 0);
  for (int step = 0; step < 10; ++step) {
    bool moved = false;
    for (size_t i = 0; i < m; ++i) {
      uint32_t best = 0;
      for (uint32_t j = 1; j < k; ++j) {
        if (Dist2(samples[i], centre[j]) < Dist2(samples[i], centre[best])) best = j;
      }
      moved |= best != label[i];
      label[i] = best;
    }
    if (!moved && step > 0) break;
    std::vector<Rgb> sum(k, Rgb{0, 0, 0});
    std::vector<size_t> count(k, 0);
    for (size_t i = 0; i < m; ++i) {
      for (int a = 0; a < 3; ++a) sum[label[i]][a] += samples[i][a];
      ++count[label[i]];
    }
    for (size_t j = 0; j < k; ++j) {
      if (count[j] == 0) continue;  // an empty cluster keeps its centre
      for (int a = 0; a < 3; ++a) centre[j][a] = sum[j][a] / static_cast<double>(count[j]);
    }
  }

  // Expectation-maximisation from the clusters: responsibilities start hard (the k-means
  // labels), then each step refits weights, means and full covariances to them.
  std::vector<double> resp(m * k, 0.0);
  for (size_t i = 0; i < m; ++i) resp[i * k + label[i]] = 1;
  double last = -std::numeric_limits<double>::infinity();
  for (int it = 0;; ++it) {
    // M-step.
    comps_.clear();
    std::vector<size_t> kept;
    for (size_t j = 0; j < k; ++j) {
      double nj = 0;
      Rgb mu{0, 0, 0};
      for (size_t i = 0; i < m; ++i) {
        const double r = resp[i * k + j];
        nj += r;
        for (int a = 0; a < 3; ++a) mu[a] += r * samples[i][a];
      }
      if (nj < 1e-9) continue;  // a component nothing belongs to is dropped
      for (int a = 0; a < 3; ++a) mu[a] /= nj;
      double c[3][3] = {};
      for (size_t i = 0; i < m; ++i) {
        const double r = resp[i * k + j];
        if (r == 0) continue;
        const double d[3] = {samples[i][0] - mu[0], samples[i][1] - mu[1], samples[i][2] - mu[2]};
        for (int a = 0; a < 3; ++a) {
          for (int b = a; b < 3; ++b) c[a][b] += r * d[a] * d[b];
        }
      }
      for (int a = 0; a < 3; ++a) {
        for (int b = a; b < 3; ++b) c[b][a] = c[a][b] = c[a][b] / nj + (a == b ? kRegularisation : 0);
      }
      // Inverse and determinant by cofactors (symmetric positive definite 3x3).
      const double c00 = c[1][1] * c[2][2] - c[1][2] * c[2][1];
      const double c01 = c[1][2] * c[2][0] - c[1][0] * c[2][2];
      const double c02 = c[1][0] * c[2][1] - c[1][1] * c[2][0];
      double det = c[0][0] * c00 + c[0][1] * c01 + c[0][2] * c02;
      if (!(det > 0)) continue;  // degenerate beyond the regularisation: dropped
      Component comp;
      comp.mean = mu;
      const double inv[3][3] = {
          {c00, c[0][2] * c[2][1] - c[0][1] * c[2][2], c[0][1] * c[1][2] - c[0][2] * c[1][1]},
          {c01, c[0][0] * c[2][2] - c[0][2] * c[2][0], c[0][2] * c[1][0] - c[0][0] * c[1][2]},
          {c02, c[0][1] * c[2][0] - c[0][0] * c[2][1], c[0][0] * c[1][1] - c[0][1] * c[1][0]}};
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) comp.inv[a][b] = inv[a][b] / det;
      }
      comp.log_norm = std::log(nj / static_cast<double>(m)) -
                      0.5 * (3 * std::log(2 * std::numbers::pi) + std::log(det));
      comps_.push_back(comp);
      kept.push_back(j);
    }
    if (comps_.empty()) return Status::Internal("graph cut: colour model fit failed");
    if (it + 1 >= iterations) break;
    // E-step; stop when the mean log-likelihood per sample moves less than 1e-4.
    double ll = 0;
    std::fill(resp.begin(), resp.end(), 0.0);
    double terms[16];
    for (size_t i = 0; i < m; ++i) {
      double best = -std::numeric_limits<double>::infinity();
      for (size_t c = 0; c < comps_.size(); ++c) {
        const Component& comp = comps_[c];
        const double d[3] = {samples[i][0] - comp.mean[0], samples[i][1] - comp.mean[1],
                             samples[i][2] - comp.mean[2]};
        double q = 0;
        for (int a = 0; a < 3; ++a) {
          for (int b = 0; b < 3; ++b) q += d[a] * comp.inv[a][b] * d[b];
        }
        terms[c] = comp.log_norm - 0.5 * q;
        best = std::max(best, terms[c]);
      }
      double sum = 0;
      for (size_t c = 0; c < comps_.size(); ++c) sum += std::exp(terms[c] - best);
      ll += best + std::log(sum);
      for (size_t c = 0; c < comps_.size(); ++c) resp[i * k + kept[c]] = std::exp(terms[c] - best) / sum;
    }
    if (ll - last < 1e-4 * static_cast<double>(m)) break;
    last = ll;
  }
  return Status::OK();
}

double ColorModel::LogLikelihood(const Rgb& x) const {
  double best = -std::numeric_limits<double>::infinity(), terms[16];
  size_t n = 0;
  for (const Component& c : comps_) {
    const double d[3] = {x[0] - c.mean[0], x[1] - c.mean[1], x[2] - c.mean[2]};
    double q = 0;
    for (int a = 0; a < 3; ++a) {
      for (int b = 0; b < 3; ++b) q += d[a] * c.inv[a][b] * d[b];
    }
    terms[n] = c.log_norm - 0.5 * q;
    best = std::max(best, terms[n++]);
  }
  double sum = 0;
  for (size_t i = 0; i < n; ++i) sum += std::exp(terms[i] - best);
  return best + std::log(sum);
}

}  // namespace hvdb::edit
