// Bulk ingest on a Slurm cluster (docs/RECORDING.md, "On a Slurm cluster"): `hvdb-ingest
// submit` cuts a recording into frame ranges and submits one sbatch array job whose tasks each
// run `hvdb-ingest run --first A --count N --server ADDR` on whatever node Slurm gives them;
// `hvdb-ingest status` reads the tasks' states from Slurm, their JSON reports from the job
// directory and the frames committed from the server.
//
// Nothing here needs to be undone after a failure: every frame is one atomic bulk load, `run`
// skips frames already present, so a task killed at any moment, submitted again, finishes
// exactly the frames that are missing.
#ifndef HVDB_INGEST_SLURM_H_
#define HVDB_INGEST_SLURM_H_

#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "ingest/recording.h"
#include "storage/status.h"

namespace hvdb::ingest {

struct SubmitOptions {
  std::string recording, dataset, server, token;
  std::string partition;         // "" : the cluster's default
  std::string job_dir;           // "" : RECORDING/slurm/DATASET-<time>
  std::string time_limit;        // sbatch --time, "" : the partition's
  int frames_per_task = 25;
  int cpus_per_task = 0;         // 0: each task has a node to itself (--exclusive)
  uint32_t frame_offset = 0;
  std::vector<std::string> run_options;  // passed to every task's `hvdb-ingest run`
  std::string ingest_path;       // the hvdb-ingest the tasks run (absolute)
  std::string sbatch = "sbatch"; // the sbatch to call
};

// One array task: recording frames [first, first + count).
struct TaskRange {
  int id = 0, first = 0, count = 0;
};

// Frames 0..frames-1 in tasks of `per_task` frames (the last may have fewer).
std::vector<TaskRange> SplitFrames(int frames, int per_task);

// The sbatch script for the given tasks (array indices: their ids).
std::string SbatchScript(const SubmitOptions& o, const std::string& job_dir, int per_task,
                         const std::vector<TaskRange>& tasks);

struct SubmitResult {
  std::string job_id;            // "" when nothing was missing
  std::string job_dir;
  std::vector<TaskRange> tasks;  // the ones submitted
  int frames_total = 0, frames_present = 0;
};

// Checks the options and the recording, creates the dataset, leaves out the tasks whose frames
// are all present, writes the job directory (ingest.sbatch, job.json) and calls sbatch.
Result<SubmitResult> SubmitIngest(const SubmitOptions& o, client::Backend& backend);

// What `hvdb-ingest status` shows.
struct TaskStatus {
  TaskRange range;
  std::string state;  // Slurm's (PENDING, RUNNING, COMPLETED, FAILED, ...) or from the report
  std::string error;  // a failed task's error: its report's, else its log's last line
  int ingested = 0, present = 0, skipped = 0;
  bool has_report = false;
};

struct JobStatus {
  std::string job_id, job_dir;
  nlohmann::json job;  // job.json
  std::vector<TaskStatus> tasks;
  int frames_total = 0, frames_committed = 0;
  std::vector<int> frames_missing;  // recording frames not committed
  std::map<std::string, double> stage_median_ms;  // over the frames the reports show ingested
  int stage_frames = 0;
  bool finished = false;  // no task pending or running
  nlohmann::json ToJson() const;
};

// JOB: a job id (its directory found through scontrol) or a job directory.
Result<std::string> FindJobDir(const std::string& job);

// Reads the job directory, asks Slurm for its tasks' states and the server (`backend`, null:
// the server job.json names) for the frames committed.
Result<JobStatus> ReadJobStatus(const std::string& job_dir, client::Backend* backend);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_SLURM_H_
