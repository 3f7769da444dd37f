#include "bench/report.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "bench/util.h"

namespace hvdb::bench {

double Figure::median() const { return fixed ? fixed->median : Median(samples); }
double Figure::min() const {
  if (fixed) return fixed->min;
  return samples.empty() ? 0 : *std::min_element(samples.begin(), samples.end());
}
double Figure::max() const {
  if (fixed) return fixed->max;
  return samples.empty() ? 0 : *std::max_element(samples.begin(), samples.end());
}
size_t Figure::reps() const { return fixed ? fixed->reps : samples.size(); }

bool Figure::Met(const Target& t) const {
  double m = median();
  return t.op == "<=" ? m <= t.value : m >= t.value;
}

Figure& Report::Add(const std::string& name, const std::string& experiment,
                    const std::string& unit, std::vector<double> samples, nlohmann::json params,
                    const std::string& description) {
  if (Find(name) != nullptr) Die("figure " + name + " added twice");
  Figure f;
  f.name = name;
  f.experiment = experiment;
  f.unit = unit;
  f.samples = std::move(samples);
  f.params = params.is_null() ? nlohmann::json::object() : std::move(params);
  f.description = description;
  figures_.push_back(std::move(f));
  return figures_.back();
}

Figure* Report::Find(const std::string& name) {
  for (Figure& f : figures_) {
    if (f.name == name) return &f;
  }
  return nullptr;
}

Figure& Report::Get(const std::string& name) {
  Figure* f = Find(name);
  if (f == nullptr) Die("no figure " + name);
  return *f;
}

Figure& Report::Ratio(const std::string& name, const std::string& experiment,
                      const std::string& num, const std::string& den,
                      const std::string& description) {
  const Figure a = Get(num);
  const Figure b = Get(den);
  auto div = [](double x, double y) {
    return y > 0 ? x / y : std::numeric_limits<double>::infinity();
  };
  nlohmann::json params = {{"numerator", num},
                           {"denominator", den},
                           {"numerator_median", a.median()},
                           {"denominator_median", b.median()},
                           {"numerator_unit", a.unit},
                           {"denominator_unit", b.unit},
                           {"min_max", "bounds: numerator min / denominator max, max / min"}};
  Figure& f = Add(name, experiment, "ratio", {}, params, description);
  f.fixed = Figure::Stats{div(a.median(), b.median()), div(a.min(), b.max()),
                          div(a.max(), b.min()), std::min(a.reps(), b.reps())};
  return f;
}

void Report::AddTarget(const std::string& figure, const std::string& op, double value,
                       const std::string& source, const std::string& what) {
  Get(figure).targets.push_back(Target{op, value, source, what});
}

void Report::AttachLimit(const std::string& figure, Limits& limits, uint64_t bytes, bool cold) {
  Figure& f = Get(figure);
  nlohmann::json l = limits.Describe(bytes, cold);
  double lim = l["ms"].get<double>();
  double med = f.median();
  l["x_limit"] = lim > 0 ? med / lim : 0.0;
  l["fraction_of_limit"] = med > 0 ? lim / med : 0.0;
  f.limit = l;
}

Figure& Report::AddLimit(const std::string& name, const std::string& experiment,
                         Limits& limits, uint64_t bytes, bool cold) {
  nlohmann::json d = limits.Describe(bytes, cold);
  nlohmann::json params = {{"bytes", bytes}, {"kind", d["kind"]}};
  if (cold) {
    params["o_direct_ms"] = d["o_direct_ms"];
    params["buffered_ms"] = d["buffered_ms"];
  }
  return Add(name, experiment, "ms", limits.Samples(bytes, cold), params,
             cold ? "physical limit: sequential read of the same bytes from disk"
                  : "physical limit: memcpy of the same bytes");
}

Curve& Report::AddCurve(Curve c) {
  curves_.push_back(std::move(c));
  return curves_.back();
}

namespace {

nlohmann::json Num(double v) {
  if (!std::isfinite(v)) return nullptr;
  return v;
}

}  // namespace

nlohmann::json Report::ToJson() const {
  nlohmann::json figs = nlohmann::json::array();
  nlohmann::json targets = nlohmann::json::array();
  for (const Figure& f : figures_) {
    nlohmann::json j;
    j["name"] = f.name;
    j["experiment"] = f.experiment;
    j["unit"] = f.unit;
    j["median"] = Num(f.median());
    j["min"] = Num(f.min());
    j["max"] = Num(f.max());
    j["reps"] = f.reps();
    j["params"] = f.params;
    if (!f.description.empty()) j["description"] = f.description;
    if (!f.samples.empty() && f.samples.size() <= 200) j["samples"] = f.samples;
    if (!f.limit.is_null()) j["limit"] = f.limit;
    if (!f.targets.empty()) {
      nlohmann::json ts = nlohmann::json::array();
      for (const Target& t : f.targets) {
        nlohmann::json tj = {{"op", t.op},       {"value", t.value}, {"source", t.source},
                             {"what", t.what},   {"met", f.Met(t)}};
        ts.push_back(tj);
        nlohmann::json s = tj;
        s["figure"] = f.name;
        s["unit"] = f.unit;
        s["measured"] = Num(f.median());
        targets.push_back(s);
      }
      j["targets"] = ts;
    }
    figs.push_back(j);
  }
  nlohmann::json curves = nlohmann::json::array();
  for (const Curve& c : curves_) {
    nlohmann::json j = {{"name", c.name},     {"experiment", c.experiment}, {"title", c.title},
                        {"xlabel", c.xlabel}, {"ylabel", c.ylabel},         {"logx", c.logx},
                        {"logy", c.logy},     {"invertx", c.invertx},
                        {"png", c.name + ".png"}};
    nlohmann::json ss = nlohmann::json::array();
    for (const Series& s : c.series) {
      nlohmann::json x = nlohmann::json::array(), y = nlohmann::json::array();
      for (double v : s.x) x.push_back(Num(v));
      for (double v : s.y) y.push_back(Num(v));
      ss.push_back({{"label", s.label},
                    {"style", s.style.empty() ? "line" : s.style},
                    {"x", x},
                    {"y", y}});
    }
    j["series"] = ss;
    curves.push_back(j);
  }
  size_t missed = 0;
  for (const auto& t : targets) missed += t["met"].get<bool>() ? 0 : 1;
  return {{"figures", figs},
          {"curves", curves},
          {"targets", targets},
          {"targets_met", targets.size() - missed},
          {"targets_missed", missed}};
}

}  // namespace hvdb::bench
