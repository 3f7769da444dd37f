// graphcut-e2e: the 4D graph cut as a user runs it — whole `hvdb graphcut` processes on a data
// directory, and through an hvdb-server (a cut, then a re-cut after one more stroke) — on the
// real scene of tests/edit/panoptic_scene.h (the Panoptic person against a touching floor and
// wall textured by real photographs; strokes in the first frame as label bits, as `hvdb select`
// leaves them). Each run's wall time is the process's, start to exit; the steps are what the
// command reports (--json). Medians of --repetitions runs; every cut is undone (`hvdb undo`,
// not timed) so that each run relabels the person again. Writes JSON (bench/README.md).
#include <CLI/CLI.hpp>
#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>
#include <vector>

#include "storage/database.h"
#include "tests/edit/panoptic_scene.h"
#include "tests/run_command.h"

using nlohmann::json;
namespace fs = std::filesystem;

namespace {

[[noreturn]] void Die(const std::string& what) {
  std::fprintf(stderr, "graphcut-e2e: %s\n", what.c_str());
  std::exit(1);
}

json RunJson(const std::string& cmd, double* wall_ms) {
  auto t0 = std::chrono::steady_clock::now();
  auto r = hvdb::testing::RunCommand(cmd);
  *wall_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (r.code != 0) Die(cmd + " failed: " + r.out);
  try {
    return json::parse(r.out.substr(r.out.find('{')));
  } catch (const std::exception& e) {
    Die(cmd + " printed no JSON: " + r.out);
  }
}

struct Series {
  std::vector<double> wall, load, cut, commit;
  void Add(double w, const json& j) {
    wall.push_back(w);
    const json& t = j.at("timings_ms");
    load.push_back(t.at("load").get<double>());
    cut.push_back(t.at("neighbours").get<double>() + t.at("gmm").get<double>() +
                  t.at("graph").get<double>() + t.at("maxflow").get<double>());
    commit.push_back(t.at("commit").get<double>());
  }
};

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0 : v[v.size() / 2];
}

json Report(const Series& s, double target_ms) {
  json j = {{"wall_ms_median", Median(s.wall)}, {"wall_ms_all", s.wall},
            {"load_ms_median", Median(s.load)}, {"cut_ms_median", Median(s.cut)},
            {"commit_ms_median", Median(s.commit)}, {"target_ms", target_ms}};
  j["overhead_ms_median"] = Median(s.wall) - Median(s.load) - Median(s.cut) - Median(s.commit);
  j["ratio_to_target"] = Median(s.wall) / target_ms;
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"graphcut-e2e: whole `hvdb graphcut` commands on the real scene, embedded and "
               "through hvdb-server (JSON)"};
  std::string shared = "../shared/data", out, work = "/tmp/hvdb-graphcut-e2e";
  int frames = 5, reps = 5;
  bool keep = false;
  double plane_spacing = 0.006;
  app.add_option("--shared-data", shared, "the shared data folder")->capture_default_str();
  app.add_option("--frames", frames, "frames of the scene")->capture_default_str();
  app.add_option("--plane-spacing", plane_spacing, "floor and wall spacing (m)")->capture_default_str();
  app.add_option("--repetitions", reps, "runs of each command")->capture_default_str();
  app.add_option("--work", work, "scratch directory (replaced)")->capture_default_str();
  app.add_option("--out", out, "JSON output file");
  app.add_flag("--keep", keep, "keep the scratch directory (its data/ holds the scene)");
  CLI11_PARSE(app, argc, argv);

  auto scene = hvdb::testing::PanopticScene(shared, static_cast<uint32_t>(frames), plane_spacing);
  if (!scene.ok()) Die(scene.status().ToString());
  std::error_code ec;
  fs::remove_all(work, ec);
  fs::create_directories(work);
  const std::string data = work + "/data";
  const double fps = 30;
  float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
  {
    auto db = hvdb::Database::Open(data);
    if (!db.ok()) Die(db.status().ToString());
    hvdb::DatasetInfo info;
    info.name = "scene";
    info.fps = fps;
    auto ds = (*db)->CreateDataset(info);
    if (!ds.ok()) Die(ds.status().ToString());
    std::vector<std::vector<hvdb::Point>> by_frame(frames);
    for (size_t i = 0; i < scene->points.size(); ++i) {
      hvdb::Point p = scene->points[i];
      p.label = scene->seeds[i] == hvdb::edit::Seed::kForeground   ? 1u
                : scene->seeds[i] == hvdb::edit::Seed::kBackground ? 2u
                                                                    : 0u;
      const float v[3] = {p.x, p.y, p.z};
      for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], v[a]), hi[a] = std::max(hi[a], v[a]);
      by_frame[p.frame].push_back(p);
    }
    for (int f = 0; f < frames; ++f) {
      auto n = (*ds)->BulkLoad(static_cast<uint32_t>(f), std::move(by_frame[f]));
      if (!n.ok()) Die(n.status().ToString());
    }
  }
  char box[256];
  std::snprintf(box, sizeof box, "--box %g %g %g %g %g %g %g %g", lo[0] - 0.01, hi[0] + 0.01,
                lo[1] - 0.01, hi[1] + 0.01, lo[2] - 0.01, hi[2] + 0.01, -0.001,
                (frames - 0.5) / fps);
  const std::string cut_args = std::string(" graphcut scene --fg-bit 0 --bg-bit 1 --out-bit 2 ") +
                               box + " --json";
  const std::string cli = HVDB_CLI_PATH;
  std::printf("scene: %zu points over %d frames\n", scene->points.size(), frames);

  // Embedded: `hvdb --data DIR graphcut ...`, then `hvdb undo LSN` (not timed).
  Series embedded;
  for (int r = 0; r < reps; ++r) {
    double ms;
    json j = RunJson(cli + " --data " + data + cut_args, &ms);
    embedded.Add(ms, j);
    std::printf("embedded cut: %.0f ms (%s)\n", ms, j["timings_ms"].dump().c_str());
    hvdb::testing::RunCommand(cli + " --data " + data + " undo scene " +
                              std::to_string(j.at("lsn").get<uint64_t>()));
  }

  // Served: a cut, one more foreground stroke (a brush-sized ball on the person in the last
  // frame, as a label edit), the re-cut; both undone, the server restarted for a cold cut.
  Series served, recut;
  const std::string sock = work + "/server.sock";
  for (int r = 0; r < reps; ++r) {
    pid_t pid = ::fork();
    if (pid == 0) {
      int fd = ::open((work + "/server.log").c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      ::dup2(fd, 1);
      ::dup2(fd, 2);
      ::execl(HVDB_SERVER_PATH, HVDB_SERVER_PATH, "--data", data.c_str(), "--listen",
              ("unix:" + sock).c_str(), "--log-level", "warn", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    for (int i = 0; i < 500 && !fs::exists(sock); ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    const std::string remote = cli + " --server unix:" + sock;
    double ms;
    json j = RunJson(remote + cut_args, &ms);
    served.Add(ms, j);
    // The stroke: person points of the last frame within 5 cm of their centre, into bit 0.
    double c[3] = {0, 0, 0};
    size_t n = 0;
    const uint32_t last = static_cast<uint32_t>(frames - 1);
    for (size_t i = 0; i < scene->points.size(); ++i) {
      const auto& p = scene->points[i];
      if (p.frame == last && scene->person[i]) c[0] += p.x, c[1] += p.y, c[2] += p.z, ++n;
    }
    char stroke[256];
    std::snprintf(stroke, sizeof stroke,
                  " select scene --bit 0 --mode add --box %g %g %g %g %g %g %g %g --json",
                  c[0] / n - 0.05, c[0] / n + 0.05, c[1] / n - 0.05, c[1] / n + 0.05,
                  c[2] / n - 0.05, c[2] / n + 0.05, (last - 0.5) / fps, (last + 0.5) / fps);
    double stroke_ms;
    json s = RunJson(remote + stroke, &stroke_ms);
    json j2 = RunJson(remote + cut_args, &ms);
    recut.Add(ms, j2);
    std::printf("served cut %.0f ms, re-cut %.0f ms (recut=%s, labels only=%s)\n",
                served.wall.back(), ms, j2.value("recut", false) ? "yes" : "no",
                j2.value("labels_only", false) ? "yes" : "no");
    for (const json* k : {&j2, &s, &j}) {
      if (k->at("lsn").get<uint64_t>() != 0) {
        hvdb::testing::RunCommand(remote + " undo scene " + std::to_string(k->at("lsn").get<uint64_t>()));
      }
    }
    ::kill(pid, SIGTERM);
    ::waitpid(pid, nullptr, 0);
  }
  json result = {{"benchmark", "graphcut-e2e"},
                 {"scene", {{"points", scene->points.size()}, {"frames", frames}}},
                 {"repetitions", reps},
                 {"embedded_cut", Report(embedded, 2000)},
                 {"served_cut", Report(served, 2000)},
                 {"served_recut", Report(recut, 500)}};
  std::printf("%s\n", result.dump(2).c_str());
  if (!out.empty()) std::ofstream(out) << result.dump(2) << "\n";
  if (!keep) fs::remove_all(work, ec);
  return 0;
}
