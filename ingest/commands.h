// The subcommands of hvdb-ingest; each registers itself on the CLI11 app (ingest/main.cc).
#ifndef HVDB_INGEST_COMMANDS_H_
#define HVDB_INGEST_COMMANDS_H_

#include <CLI/CLI.hpp>

namespace hvdb::ingest {

void RegisterStereoCommand(CLI::App& app);     // stereo_command.cc: the matcher on one pair
void RegisterGenerateCommand(CLI::App& app);   // generate_command.cc: synthetic recordings
void RegisterReplayCommand(CLI::App& app);     // generate_command.cc: a recording at its rate
// slurm_command.cc: submit (an sbatch array job of `run`) and status.
void RegisterSlurmCommands(CLI::App& app, int* rc);

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_COMMANDS_H_
