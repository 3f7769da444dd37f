// The result of a run: figures (a named, unit-carrying sample with its statistics, parameters,
// targets, and the physical limit or peer it is compared with) and curves (for the plots).
// bench/README.md documents the JSON this writes.
#ifndef HVDB_BENCH_REPORT_H_
#define HVDB_BENCH_REPORT_H_

#include <deque>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace hvdb::bench {

class Limits;

struct Target {
  std::string op;  // "<=" or ">="
  double value = 0;
  std::string source;  // "thesis 2008, Table 8.2" or "issue 7 goal"
  std::string what;    // one line: what is being compared
};

struct Figure {
  std::string name, experiment, unit, description;
  std::vector<double> samples;
  nlohmann::json params = nlohmann::json::object();
  std::vector<Target> targets;
  nlohmann::json limit;  // null, or the physical limit for the same bytes (Limits::Describe)
  // Derived figures (ratios) carry their statistics instead of samples.
  struct Stats {
    double median, min, max;
    size_t reps;
  };
  std::optional<Stats> fixed;

  double median() const;
  double min() const;
  double max() const;
  size_t reps() const;
  bool Met(const Target& t) const;
};

struct Series {
  std::string label;
  std::vector<double> x, y;
  std::string style;  // "line" (default), "dashed" or "points"
};

struct Curve {
  std::string name, experiment, title, xlabel, ylabel;
  bool logx = false, logy = false;
  std::vector<Series> series;
  bool invertx = false;
};

class Report {
 public:
  Figure& Add(const std::string& name, const std::string& experiment, const std::string& unit,
              std::vector<double> samples, nlohmann::json params = nlohmann::json::object(),
              const std::string& description = "");
  Figure* Find(const std::string& name);
  Figure& Get(const std::string& name);  // dies when missing
  // name = num / den (ratio of medians; min and max are the bounds from the extremes).
  Figure& Ratio(const std::string& name, const std::string& experiment, const std::string& num,
                const std::string& den, const std::string& description);
  void AddTarget(const std::string& figure, const std::string& op, double value,
                 const std::string& source, const std::string& what);
  // Attaches the physical limit for `bytes` to a time figure (ms): limit ms, x_limit
  // (figure / limit) and fraction_of_limit (limit / figure).
  void AttachLimit(const std::string& figure, Limits& limits, uint64_t bytes, bool cold);
  // A figure of the physical limit itself (ms per rep) for `bytes`.
  Figure& AddLimit(const std::string& name, const std::string& experiment, Limits& limits,
                   uint64_t bytes, bool cold);
  Curve& AddCurve(Curve c);

  nlohmann::json ToJson() const;
  const std::deque<Figure>& figures() const { return figures_; }
  const std::deque<Curve>& curves() const { return curves_; }

 private:
  // Deques: the references Add() returns stay valid as more figures are added.
  std::deque<Figure> figures_;
  std::deque<Curve> curves_;
};

}  // namespace hvdb::bench

#endif  // HVDB_BENCH_REPORT_H_
