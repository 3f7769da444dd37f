// The families of `hvdb` subcommands. Each registers its own subcommands and options on the
// app and what they run on the context; main.cc calls them in the order `hvdb --help` lists
// the subcommands.
#ifndef HVDB_CLIENT_CLI_COMMANDS_H_
#define HVDB_CLIENT_CLI_COMMANDS_H_

#include <CLI/CLI.hpp>

#include "client/cli/common.h"

namespace hvdb::cli {

// data_commands.cc: datasets, create, describe, import, export, window, slice.
void AddDataCommands(CLI::App& app, Context& ctx);
// edit_commands.cc: edit, undo, redo.
void AddEditCommands(CLI::App& app, Context& ctx);
// select_commands.cc: select, graphcut.
void AddSelectCommands(CLI::App& app, Context& ctx);
// edit_commands.cc: copy, cut, paste, composite.
void AddClipboardCommands(CLI::App& app, Context& ctx);
// media_commands.cc: import-media.
void AddMediaCommands(CLI::App& app, Context& ctx);
// render_commands.cc: render.
void AddRenderCommands(CLI::App& app, Context& ctx);
// admin_commands.cc: stats, check, drop, ping.
void AddAdminCommands(CLI::App& app, Context& ctx);
// watch_commands.cc: watch.
void AddWatchCommands(CLI::App& app, Context& ctx);

}  // namespace hvdb::cli

#endif  // HVDB_CLIENT_CLI_COMMANDS_H_
