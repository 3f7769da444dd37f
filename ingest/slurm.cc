// hvdb-ingest submit / status: an sbatch array job of `hvdb-ingest run` over frame ranges.
#include "ingest/slurm.h"

#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

#include "ingest/pipeline.h"

namespace hvdb::ingest {
namespace {

namespace fs = std::filesystem;

// Options of `run` that submit sets for every task itself.
const std::set<std::string> kTaskOwned = {"--first", "--count", "--server", "--data",
                                          "--dataset", "--report", "--follow", "--frame-offset",
                                          "--token"};

// Slurm states of a task that has not ended.
const std::set<std::string> kActive = {"PENDING",  "RUNNING",   "CONFIGURING", "COMPLETING",
                                       "SUSPENDED", "REQUEUED", "RESIZING",    "SIGNALING",
                                       "STAGE_OUT", "REQUEUE_HOLD", "REQUEUE_FED"};

std::string ShellQuote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

struct ToolResult {
  int code = -1;
  std::string out;  // stdout (stderr with merge_stderr)
};

// Runs a command line through the shell; stderr goes along with stdout when asked.
ToolResult RunTool(const std::string& cmd, bool merge_stderr) {
  ToolResult r;
  FILE* p = ::popen((cmd + (merge_stderr ? " 2>&1" : " 2>/dev/null")).c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.out.append(buf.data(), n);
  const int st = ::pclose(p);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

std::string Trim(std::string s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.pop_back();
  size_t i = 0;
  while (i < s.size() && std::isspace(static_cast<unsigned char>(s[i]))) ++i;
  return s.substr(i);
}

// "0-3,5,7-8": the array indices of the tasks, consecutive ones as ranges.
std::string ArraySpec(const std::vector<TaskRange>& tasks) {
  std::string out;
  for (size_t i = 0; i < tasks.size();) {
    size_t j = i;
    while (j + 1 < tasks.size() && tasks[j + 1].id == tasks[j].id + 1) ++j;
    if (!out.empty()) out += ',';
    out += std::to_string(tasks[i].id);
    if (j > i) {  // appended apart: GCC 12 warns falsely (-Wrestrict) on "-" + to_string
      out += '-';
      out += std::to_string(tasks[j].id);
    }
    i = j + 1;
  }
  return out;
}

// The dataset's name as Slurm shows it: #SBATCH lines are not parsed by a shell.
std::string JobName(std::string s) {
  for (char& c : s)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_' && c != '.') c = '_';
  return s;
}

Status WriteFile(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::trunc);
  out << text;
  out.close();
  if (!out) return Status::IOError(path + ": cannot write");
  return Status::OK();
}

Result<nlohmann::json> ReadJson(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound(path + ": missing");
  try {
    return nlohmann::json::parse(in);
  } catch (const std::exception& e) {
    return Status::Corruption(path + ": not JSON: " + e.what());
  }
}

std::string DefaultJobDir(const SubmitOptions& o) {
  char stamp[32];
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  ::gmtime_r(&now, &tm);
  std::strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", &tm);
  const fs::path base = fs::absolute(o.recording) / "slurm" / (o.dataset + "-" + stamp);
  fs::path dir = base;
  for (int k = 2; fs::exists(dir); ++k) dir = base.string() + "-" + std::to_string(k);
  return dir.string();
}

Status CheckOptions(const SubmitOptions& o) {
  if (o.dataset.empty()) return Status::InvalidArgument("--dataset: give the dataset to ingest into");
  if (o.server.empty())
    return Status::InvalidArgument("--server: give HOST:PORT of the hvdb-server the tasks commit through");
  if (o.server.rfind("unix:", 0) == 0)
    return Status::InvalidArgument("--server: tasks run on other nodes; give a HOST:PORT they can reach, not " + o.server);
  if (o.frames_per_task < 1)
    return Status::InvalidArgument("--frames-per-task must be at least 1, got " + std::to_string(o.frames_per_task));
  if (o.cpus_per_task < 0)
    return Status::InvalidArgument("--cpus-per-task must be 0 (a node per task) or more");
  if (!fs::path(o.ingest_path).is_absolute() || ::access(o.ingest_path.c_str(), X_OK) != 0)
    return Status::InvalidArgument("hvdb-ingest to run in the tasks: " + o.ingest_path +
                                   " is not an executable absolute path");
  for (const std::string& a : o.run_options) {
    const std::string name = a.substr(0, a.find('='));
    if (kTaskOwned.count(name))
      return Status::InvalidArgument("run option " + name + ": submit sets it for each task; "
                                     "use submit's own --dataset/--server/--token/--frame-offset");
  }
  for (char c : o.partition + o.time_limit)
    if (std::isspace(static_cast<unsigned char>(c)))
      return Status::InvalidArgument("--partition and --time must not contain spaces");
  return Status::OK();
}

}  // namespace

std::vector<TaskRange> SplitFrames(int frames, int per_task) {
  std::vector<TaskRange> out;
  for (int first = 0, id = 0; first < frames; first += per_task, ++id)
    out.push_back({id, first, std::min(per_task, frames - first)});
  return out;
}

std::string SbatchScript(const SubmitOptions& o, const std::string& job_dir, int per_task,
                         const std::vector<TaskRange>& tasks) {
  std::ostringstream s;
  s << "#!/bin/bash\n"
    << "# Written by hvdb-ingest submit: task i ingests recording frames [i*" << per_task
    << ", (i+1)*" << per_task << ") through the server.\n"
    << "#SBATCH --job-name=hvdb-ingest-" << JobName(o.dataset) << "\n"
    << "#SBATCH --array=" << ArraySpec(tasks) << "\n"
    << "#SBATCH --output=" << job_dir << "/task-%a.log\n"
    << "#SBATCH --chdir=" << job_dir << "\n"
    << "#SBATCH --nodes=1\n"
    << "#SBATCH --ntasks=1\n";
  if (o.cpus_per_task > 0) {
    s << "#SBATCH --cpus-per-task=" << o.cpus_per_task << "\n";
  } else {
    s << "#SBATCH --exclusive\n";
  }
  if (!o.partition.empty()) s << "#SBATCH --partition=" << o.partition << "\n";
  if (!o.time_limit.empty()) s << "#SBATCH --time=" << o.time_limit << "\n";
  s << "set -u\n"
    << "id=$SLURM_ARRAY_TASK_ID\n"
    << "exec " << ShellQuote(o.ingest_path) << " run " << ShellQuote(fs::absolute(o.recording).string())
    << " --server " << ShellQuote(o.server) << " --dataset " << ShellQuote(o.dataset)
    << " --frame-offset " << o.frame_offset << " --first $((id * " << per_task << "))"
    << " --count " << per_task << " --report " << ShellQuote(job_dir) << "/task-$id.json --quiet";
  for (const std::string& a : o.run_options) s << " " << ShellQuote(a);
  s << "\n";
  return s.str();
}

Result<SubmitResult> SubmitIngest(const SubmitOptions& o, client::Backend& backend) {
  HVDB_RETURN_IF_ERROR(CheckOptions(o));
  HVDB_ASSIGN_OR_RETURN(Recording rec, OpenRecording(o.recording));
  // Created here, once, so that the tasks do not race to create it; a Gaussian-splat dataset
  // when the tasks fit Gaussians (each chunk's first frame from its points, the rest of the
  // chunk warm-started, as a local run of the same frames).
  const bool gaussians = std::find(o.run_options.begin(), o.run_options.end(), "--gaussians") !=
                         o.run_options.end();
  if (gaussians) HVDB_RETURN_IF_ERROR(CheckFitCameras(rec));
  HVDB_RETURN_IF_ERROR(EnsureDataset(backend, rec, o.dataset, gaussians));
  if (!o.run_options.empty()) {
    // The run options checked once here (no frames: --count 0) rather than failing every task.
    std::string cmd = ShellQuote(o.ingest_path) + " run " + ShellQuote(o.recording) +
                      " --server " + ShellQuote(o.server) + " --dataset " + ShellQuote(o.dataset) +
                      " --count 0 --quiet";
    for (const std::string& a : o.run_options) cmd += " " + ShellQuote(a);
    ToolResult r = RunTool(cmd, true);
    if (r.code != 0)
      return Status::InvalidArgument("the options for `hvdb-ingest run` were refused: " + Trim(r.out));
  }
  SubmitResult res;
  res.frames_total = rec.frames;
  // Resubmitting: only the ranges with a frame missing (the tasks skip the frames present).
  for (const TaskRange& t : SplitFrames(rec.frames, o.frames_per_task)) {
    bool missing = false;
    for (int i = t.first; i < t.first + t.count; ++i) {
      HVDB_ASSIGN_OR_RETURN(bool present, FramePresent(backend, o.dataset,
                                                       o.frame_offset + static_cast<uint32_t>(i), rec.fps));
      res.frames_present += present;
      missing |= !present;
    }
    if (missing) res.tasks.push_back(t);
  }
  if (res.tasks.empty()) return res;

  res.job_dir = o.job_dir.empty() ? DefaultJobDir(o) : fs::absolute(o.job_dir).string();
  std::error_code ec;
  fs::create_directories(res.job_dir, ec);
  if (ec) return Status::IOError(res.job_dir + ": cannot create the job directory: " + ec.message());
  const std::string script = res.job_dir + "/ingest.sbatch";
  HVDB_RETURN_IF_ERROR(WriteFile(script, SbatchScript(o, res.job_dir, o.frames_per_task, res.tasks)));
  ::chmod(script.c_str(), 0755);

  nlohmann::json job = {{"recording", fs::absolute(o.recording).string()},
                        {"dataset", o.dataset},
                        {"server", o.server},
                        {"frames", rec.frames},
                        {"fps", rec.fps},
                        {"frame_offset", o.frame_offset},
                        {"frames_per_task", o.frames_per_task},
                        {"ingest", o.ingest_path},
                        {"run_options", o.run_options},
                        {"tasks", nlohmann::json::array()}};
  for (const TaskRange& t : res.tasks)
    job["tasks"].push_back({{"id", t.id}, {"first", t.first}, {"count", t.count}});

  ToolResult r = RunTool(ShellQuote(o.sbatch) + " --parsable " + ShellQuote(script), true);
  if (r.code != 0) {
    if (r.code == 127)
      return Status::NotFound(o.sbatch + ": not found; submit from a Slurm submit host (Debian: "
                              "slurm-client; a dev cluster: scripts/slurm-dev.sh)");
    return Status::IOError("sbatch refused the job (" + script + "): " + Trim(r.out));
  }
  // --parsable: "JOBID" or "JOBID;CLUSTER" (sbatch may print warnings on lines before it).
  std::string last = Trim(r.out);
  if (const size_t nl = last.rfind('\n'); nl != std::string::npos) last = last.substr(nl + 1);
  res.job_id = last.substr(0, last.find(';'));
  if (res.job_id.empty() || res.job_id.find_first_not_of("0123456789") != std::string::npos)
    return Status::IOError("sbatch answered '" + Trim(r.out) + "', not a job id");
  job["job_id"] = res.job_id;
  HVDB_RETURN_IF_ERROR(WriteFile(res.job_dir + "/job.json", job.dump(2) + "\n"));
  return res;
}

Result<std::string> FindJobDir(const std::string& job) {
  if (fs::exists(fs::path(job) / "job.json")) return fs::absolute(job).string();
  if (job.empty() || job.find_first_not_of("0123456789") != std::string::npos)
    return Status::NotFound(job + ": neither a job id nor a job directory (with job.json)");
  // The job's script lies in its directory: scontrol names it while Slurm remembers the job.
  ToolResult r = RunTool("scontrol show job -o " + job, true);
  if (r.code == 0) {
    std::istringstream in(r.out);
    std::string field;
    while (in >> field) {
      if (field.rfind("Command=", 0) == 0) {
        const fs::path dir = fs::path(field.substr(8)).parent_path();
        if (fs::exists(dir / "job.json")) return dir.string();
      }
    }
  }
  return Status::NotFound("job " + job + ": Slurm does not know it (any more) or it was not "
                          "submitted by hvdb-ingest; give its job directory instead (" +
                          Trim(r.out) + ")");
}

nlohmann::json JobStatus::ToJson() const {
  nlohmann::json j = {{"job_id", job_id},
                      {"job_dir", job_dir},
                      {"dataset", job.value("dataset", "")},
                      {"server", job.value("server", "")},
                      {"frames_total", frames_total},
                      {"frames_committed", frames_committed},
                      {"frames_missing", frames_missing},
                      {"finished", finished},
                      {"stage_median_ms", stage_median_ms},
                      {"stage_frames", stage_frames},
                      {"tasks", nlohmann::json::array()}};
  for (const TaskStatus& t : tasks) {
    nlohmann::json e = {{"id", t.range.id},       {"first", t.range.first},
                        {"count", t.range.count}, {"state", t.state},
                        {"ingested", t.ingested}, {"present", t.present},
                        {"skipped", t.skipped},   {"has_report", t.has_report}};
    if (!t.error.empty()) e["error"] = t.error;
    j["tasks"].push_back(e);
  }
  return j;
}

Result<JobStatus> ReadJobStatus(const std::string& job_dir, client::Backend* backend) {
  JobStatus st;
  st.job_dir = job_dir;
  HVDB_ASSIGN_OR_RETURN(st.job, ReadJson(job_dir + "/job.json"));
  st.job_id = st.job.value("job_id", "");
  st.frames_total = st.job.value("frames", 0);

  // Slurm's view: one line per array task while it remembers the job (MinJobAge).
  std::map<int, std::string> states;
  if (!st.job_id.empty()) {
    ToolResult r = RunTool("squeue -h -r -t all -j " + st.job_id + " -o '%K|%T'", false);
    std::istringstream in(r.code == 0 ? r.out : "");
    std::string line;
    while (std::getline(in, line)) {
      const size_t bar = line.find('|');
      if (bar == std::string::npos) continue;
      try {
        states[std::stoi(line.substr(0, bar))] = Trim(line.substr(bar + 1));
      } catch (const std::exception&) {
      }
    }
  }

  std::map<std::string, std::vector<double>> stage_ms;
  st.finished = true;
  for (const nlohmann::json& jt : st.job.at("tasks")) {
    TaskStatus t;
    t.range = {jt.at("id").get<int>(), jt.at("first").get<int>(), jt.at("count").get<int>()};
    const std::string base = job_dir + "/task-" + std::to_string(t.range.id);
    Result<nlohmann::json> rep = ReadJson(base + ".json");
    if (rep.ok()) {
      t.has_report = true;
      if (rep->contains("error")) t.error = (*rep)["error"].get<std::string>();
      const nlohmann::json frames = rep->value("frames", nlohmann::json::array());
      for (const nlohmann::json& f : frames) {
        const std::string s = f.value("status", "");
        if (s == "ingested") {
          ++t.ingested;
          ++st.stage_frames;
          const nlohmann::json stages = f.value("stage_ms", nlohmann::json::object());
          for (const auto& [k, v] : stages.items()) stage_ms[k].push_back(v.get<double>());
        } else if (s == "present") {
          ++t.present;
        } else if (s == "skipped") {
          ++t.skipped;
          if (t.error.empty())
            t.error = "frame " + std::to_string(f.value("frame", 0)) + ": " + f.value("error", "");
        }
      }
    }
    auto s = states.find(t.range.id);
    if (s != states.end()) {
      t.state = s->second;
    } else {
      t.state = !t.has_report ? "UNKNOWN" : t.error.empty() ? "COMPLETED" : "FAILED";
    }
    if (kActive.count(t.state)) st.finished = false;
    if (t.error.empty() && !kActive.count(t.state) && t.state != "COMPLETED") {
      // Killed or failed before writing its report: the last line of its log says why.
      std::ifstream log(base + ".log");
      std::string line, last;
      while (std::getline(log, line))
        if (!Trim(line).empty()) last = Trim(line);
      t.error = last.empty() ? "no report and an empty log (" + base + ".log)" : last;
    }
    st.tasks.push_back(std::move(t));
  }
  for (auto& [k, v] : stage_ms) {
    std::sort(v.begin(), v.end());
    st.stage_median_ms[k] = v[v.size() / 2];
  }

  // The frames committed, from the server (the truth, whatever the reports say).
  std::unique_ptr<client::Backend> own;
  if (!backend) {
    const char* token = std::getenv("HVDB_TOKEN");
    client::RemoteOptions ro;
    ro.address = st.job.value("server", "");
    ro.token = token ? token : "";
    ro.follow_leader = true;
    HVDB_ASSIGN_OR_RETURN(own, client::MakeRemoteBackend(ro));
    backend = own.get();
  }
  const uint32_t offset = st.job.value("frame_offset", 0u);
  const double fps = st.job.value("fps", 30.0);
  const std::string ds = st.job.value("dataset", "");
  for (int i = 0; i < st.frames_total; ++i) {
    HVDB_ASSIGN_OR_RETURN(bool present, FramePresent(*backend, ds, offset + static_cast<uint32_t>(i), fps));
    if (present) {
      ++st.frames_committed;
    } else {
      st.frames_missing.push_back(i);
    }
  }
  return st;
}

}  // namespace hvdb::ingest
