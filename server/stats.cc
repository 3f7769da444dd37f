#include "server/stats.h"

#include <algorithm>

namespace hvdb::server {

void ServerStats::Record(const std::string& kind, double ms) {
  std::lock_guard<std::mutex> l(mu_);
  Kind& k = kinds_[kind];
  if (k.recent.size() < kWindow) {
    k.recent.push_back(ms);
  } else {
    k.recent[k.count % kWindow] = ms;
  }
  ++k.count;
}

std::vector<ServerStats::Summary> ServerStats::Summaries() const {
  std::lock_guard<std::mutex> l(mu_);
  std::vector<Summary> out;
  for (const auto& [name, k] : kinds_) {
    std::vector<double> v = k.recent;
    std::sort(v.begin(), v.end());
    auto pct = [&](double p) {
      return v.empty() ? 0.0 : v[std::min(v.size() - 1, static_cast<size_t>(p * v.size()))];
    };
    out.push_back({name, k.count, pct(0.5), pct(0.95), pct(0.99)});
  }
  return out;
}

}  // namespace hvdb::server
