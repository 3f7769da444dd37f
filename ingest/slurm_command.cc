// hvdb-ingest submit / status (ingest/slurm.h).
#include <unistd.h>

#include <climits>
#include <cstdio>
#include <iostream>

#include "client/backend.h"
#include "ingest/commands.h"
#include "ingest/slurm.h"

namespace hvdb::ingest {
namespace {

int Fail(const Status& st) {
  std::cerr << "hvdb-ingest: " << st.ToString() << "\n";
  return st.IsInvalidArgument() || st.IsNotFound() ? 2 : 1;
}

std::string SelfPath() {
  char buf[PATH_MAX];
  const ssize_t n = ::readlink("/proc/self/exe", buf, sizeof buf - 1);
  return n > 0 ? std::string(buf, static_cast<size_t>(n)) : std::string();
}

std::string Range(const TaskRange& t) {
  return t.count == 1 ? std::to_string(t.first)
                      : std::to_string(t.first) + "-" + std::to_string(t.first + t.count - 1);
}

void PrintStatus(const JobStatus& st) {
  std::printf("job %s (%s into '%s' through %s), %s\n", st.job_id.c_str(),
              st.job.value("recording", "").c_str(), st.job.value("dataset", "").c_str(),
              st.job.value("server", "").c_str(), st.finished ? "finished" : "running");
  std::printf("frames: %d of %d committed", st.frames_committed, st.frames_total);
  if (!st.frames_missing.empty()) {
    std::printf("; missing:");
    for (size_t i = 0; i < st.frames_missing.size() && i < 20; ++i)
      std::printf(" %d", st.frames_missing[i]);
    if (st.frames_missing.size() > 20) std::printf(" ...");
  }
  std::printf("\n");
  std::map<std::string, int> by_state;
  for (const TaskStatus& t : st.tasks) ++by_state[t.state];
  std::printf("tasks:");
  for (const auto& [s, n] : by_state) std::printf(" %d %s", n, s.c_str());
  std::printf("\n");
  for (const TaskStatus& t : st.tasks) {
    std::printf("  task %d (frames %s): %s", t.range.id, Range(t.range).c_str(), t.state.c_str());
    if (t.has_report)
      std::printf(", %d ingested, %d already present, %d skipped", t.ingested, t.present, t.skipped);
    if (!t.error.empty()) std::printf("\n    error: %s", t.error.c_str());
    std::printf("\n");
  }
  if (st.stage_frames > 0) {
    std::printf("median per frame over %d ingested frames (ms):", st.stage_frames);
    for (const auto& [k, v] : st.stage_median_ms) std::printf(" %s %.1f", k.c_str(), v);
    std::printf("\n");
  }
  if (st.finished && st.frames_committed < st.frames_total)
    std::printf("to finish the missing frames, submit again with the same options\n");
}

}  // namespace

void RegisterSlurmCommands(CLI::App& app, int* rc) {
  auto* sub = app.add_subcommand(
      "submit",
      "Ingest a recording on a Slurm cluster: an sbatch array job whose tasks each run `run` on "
      "a range of frames and commit through --server (docs/RECORDING.md, \"On a Slurm "
      "cluster\"). Submitting again only sends the ranges with frames missing");
  auto o = std::make_shared<SubmitOptions>();
  sub->add_option("recording", o->recording, "recording directory, on a file system every node sees")->required();
  sub->add_option("--dataset", o->dataset, "dataset to ingest into (created now if missing)")->required();
  sub->add_option("--server", o->server,
                  "HOST:PORT of the hvdb-server the tasks commit through (reachable from the "
                  "nodes; given a reading server, they commit to the writer it names)")->required();
  sub->add_option("--token", o->token, "access token (read-write role); the tasks get it from the environment")
      ->envname("HVDB_TOKEN");
  sub->add_option("--partition", o->partition, "Slurm partition (default: the cluster's default)");
  sub->add_option("--frames-per-task", o->frames_per_task,
                  "frames each array task ingests (a killed task loses at most the frames in hand)")
      ->capture_default_str();
  sub->add_option("--cpus-per-task", o->cpus_per_task,
                  "CPUs Slurm gives each task (0: a whole node each, --exclusive)")->capture_default_str();
  sub->add_option("--time", o->time_limit, "time limit of each task (sbatch --time, e.g. 2:00:00)");
  sub->add_option("--frame-offset", o->frame_offset, "dataset frame of recording frame 0")->capture_default_str();
  sub->add_option("--job-dir", o->job_dir,
                  "where the sbatch script, the tasks' logs and reports go (every node must see "
                  "it; default: RECORDING/slurm/DATASET-TIME)");
  sub->add_option("--sbatch", o->sbatch, "the sbatch command")->capture_default_str();
  sub->add_option("run-options", o->run_options,
                  "after --: options for each task's `hvdb-ingest run` (e.g. -- --num-disparities 64 --no-photos)");
  sub->callback([o, rc] {
    o->ingest_path = SelfPath();
    client::RemoteOptions ro;
    ro.address = o->server;
    ro.token = o->token;
    ro.follow_leader = true;
    auto backend = client::MakeRemoteBackend(ro);
    if (!backend.ok()) {
      *rc = Fail(backend.status());
      return;
    }
    if (!o->token.empty()) ::setenv("HVDB_TOKEN", o->token.c_str(), 1);  // sbatch passes it on
    auto r = SubmitIngest(*o, **backend);
    if (!r.ok()) {
      *rc = Fail(r.status());
      return;
    }
    if (r->job_id.empty()) {
      std::printf("all %d frames of %s are in '%s' already: nothing to submit\n", r->frames_total,
                  o->recording.c_str(), o->dataset.c_str());
      *rc = 0;
      return;
    }
    std::fprintf(stderr, "submitted %zu tasks for %d of %d frames (%d present); job directory %s\n",
                 r->tasks.size(), r->frames_total - r->frames_present, r->frames_total,
                 r->frames_present, r->job_dir.c_str());
    std::printf("%s\n", r->job_id.c_str());  // alone on stdout, for scripts
    *rc = 0;
  });

  auto* stat = app.add_subcommand(
      "status", "Progress of a submitted ingest: the tasks' states, the frames committed, the "
                "per-stage median times and the failed tasks' errors");
  struct StatusArgs {
    std::string job;
    bool json = false;
  };
  auto a = std::make_shared<StatusArgs>();
  stat->add_option("job", a->job, "job id (while Slurm remembers it) or job directory")->required();
  stat->add_flag("--json", a->json, "print the status as JSON");
  stat->callback([a, rc] {
    auto dir = FindJobDir(a->job);
    if (!dir.ok()) {
      *rc = Fail(dir.status());
      return;
    }
    auto st = ReadJobStatus(*dir, nullptr);
    if (!st.ok()) {
      *rc = Fail(st.status());
      return;
    }
    if (a->json) {
      std::printf("%s\n", st->ToJson().dump(2).c_str());
    } else {
      PrintStatus(*st);
    }
    bool failed = false;
    for (const TaskStatus& t : st->tasks) failed |= !t.error.empty();
    *rc = failed ? 3 : 0;
  });
}

}  // namespace hvdb::ingest
