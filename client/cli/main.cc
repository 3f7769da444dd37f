// hvdb: the command line of the 3D-video database, embedded on a data directory like sqlite3,
// or talking to an hvdb-server like psql:
//
//   hvdb --data DIR create walk --fps 29.97
//   hvdb --data DIR import walk --frame 0 --units-scale 0.01 f380.ply f381.ply
//   hvdb --data DIR window walk --box -2 2 -2 2 -2 2 0 1 --out all.ply
//   hvdb --server 127.0.0.1:7878 slice walk --normal 0 0 0 1 --offset 0.0334 --thickness 0.01
//   hvdb --data DIR select walk --bit 1 --box -2 2 -2 2 -2 2 0 0.1 --rect 290 100 350 200
//       --look-at -0.3 -0.9 -3 -0.3 -0.9 0 --fov 50 --size 640 480     (one line)
//   hvdb --data DIR cut walk --bit 0 --clipboard man
//   hvdb --data DIR paste walk --clipboard man --translate 1 0 0 0
//   hvdb --server 127.0.0.1:7878 render walk --box -2 2 -2 2 -2 2 0.16 0.17
//       --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 --size 640 480 --out walk.png  (one line)
//
// Every subcommand runs the same code in both modes, through client::Backend (client/backend.h);
// only `check` (the data directory's files) is embedded-only and `ping` server-only.
//
// Positions are metres, times seconds (frame / fps). Exit status: 0 success, 1 an error from
// the database, the server or a file (printed as "hvdb: <status>"), 2 a usage error.
//
// This file holds the global options, the choice of backend and the dispatch; the subcommands
// are registered by their families (client/cli/commands.h).
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include <CLI/CLI.hpp>

#include "client/backend.h"
#include "client/cli/commands.h"
#include "client/cli/common.h"
#include "storage/status.h"

namespace hvdb::cli {
namespace {

// The options that pick the database, the help's footer and the usage message of CLI11's
// errors.
void AddGlobalOptions(CLI::App& app, GlobalArgs& g) {
  // At most one; none is reported by Run(), so that an unknown word is named as such.
  app.require_subcommand(0, 1);
  app.footer(
      "Positions are metres, times seconds (t = frame / fps). Each command has --help.\n"
      "Editing: select and graphcut mark points in label bits; copy, cut and paste move them\n"
      "through named clipboards; composite inserts an object, import-media an image, video or\n"
      "mesh; every change prints an lsn for undo (and redo). render draws a region through a\n"
      "camera into PNG or EXR images.\n"
      "With --server HOST:PORT every command but check runs on an hvdb-server instead of --data;\n"
      "a server that needs a token gets it from --token or the environment variable HVDB_TOKEN.\n"
      "Exit status: 0 success, 1 error (printed as 'hvdb: <status>'), 2 usage error.\n"
      "Example: hvdb create walk --fps 30 && hvdb import walk --frame 0 --units-scale 0.01 *.ply");
  app.fallthrough();  // global options may also follow the subcommand
  g.data_opt = app.add_option("--data", g.data, "Data directory")->capture_default_str();
  g.cache_opt = app.add_option("--cache-mb", g.cache_mb, "Block cache size in MiB (>= 8)")
                    ->capture_default_str()
                    ->check(CLI::Range(size_t{8}, size_t{1} << 30));
  app.add_option("--server", g.server,
                 "HOST:PORT or unix:PATH of an hvdb-server to work on, instead of a data "
                 "directory (a server on this machine is reached through its Unix socket and "
                 "shared memory by itself)");
  app.add_option("--wire", g.wire,
                 "With --server: how query results travel: records (default; shared memory on "
                 "this machine), columns, draco or hvdb7 (compressed, docs/CODEC.md)")
      ->capture_default_str()
      ->check(CLI::IsMember({"records", "columns", "draco", "hvdb7"}));
  g.token_opt = app.add_option(
      "--token", g.token,
      "Access token for --server (default: $HVDB_TOKEN; the environment keeps it out of ps)");
  app.failure_message([](const CLI::App* a, const CLI::Error& e) {
    auto subs = a->get_subcommands();
    std::string cmd = subs.empty() ? "hvdb" : "hvdb " + subs.front()->get_name();
    return "hvdb: " + std::string(e.what()) + "\nRun '" + cmd + " --help' for usage.\n";
  });
}

// Picks the data directory or the server; nothing is opened or connected before the first
// request, so usage errors are reported before touching a file or the network. Returns the
// exit status of a usage error, or nullopt.
std::optional<int> MakeBackend(Context& ctx) {
  const GlobalArgs& g = ctx.global;
  if (g.server.empty()) {
    if (g.token_opt->count() > 0) return Usage("", "--token is for --server HOST:PORT");
    if (g.wire != "records") return Usage("", "--wire is for --server HOST:PORT");
    ctx.backend = client::MakeEmbeddedBackend(g.data, g.cache_mb << 20);
    return std::nullopt;
  }
  if (g.data_opt->count() > 0) {
    return Usage("", "give --data DIR or --server HOST:PORT, not both");
  }
  if (g.cache_opt->count() > 0) {
    return Usage("",
                 "--cache-mb sizes the cache of a data directory; with --server the "
                 "server's own applies (hvdb-server --cache-mb)");
  }
  client::RemoteOptions ro;
  ro.address = g.server;
  ro.token = g.token;
  ro.wire = g.wire;
  if (ro.token.empty()) {
    if (const char* env = std::getenv("HVDB_TOKEN")) ro.token = env;
  }
  Result<std::unique_ptr<client::Backend>> b = client::MakeRemoteBackend(ro);
  if (!b.ok()) return Usage("", b.status().message());
  ctx.backend = std::move(b).value();
  return std::nullopt;
}

// The whole command line: global options, then every family's subcommands in the order the
// help lists them.
void AddCommands(CLI::App& app, Context& ctx) {
  AddGlobalOptions(app, ctx.global);
  AddDataCommands(app, ctx);
  AddEditCommands(app, ctx);
  AddSelectCommands(app, ctx);
  AddClipboardCommands(app, ctx);
  AddMediaCommands(app, ctx);
  AddRenderCommands(app, ctx);
  AddWatchCommands(app, ctx);
  AddAdminCommands(app, ctx);
}

int Run(const CLI::App& app, Context& ctx) {
  if (app.get_subcommands().empty()) {
    return Usage(
        "",
        "a command is required: datasets, create, describe, import, export, window, slice, "
        "edit, undo, redo, select, graphcut, copy, cut, paste, composite, import-media, render, "
        "stats, check, drop or ping");
  }
  if (std::optional<int> rc = MakeBackend(ctx)) return *rc;
  if (std::optional<int> rc = ctx.RunParsed()) return *rc;
  return Usage("", "unknown command");
}

}  // namespace
}  // namespace hvdb::cli

int main(int argc, char** argv) {
  // Declared out here because the catch blocks still use them.
  std::optional<CLI::App> app;
  std::optional<hvdb::cli::Context> ctx;
  // The only try/catch: CLI11 reports usage errors by exception; nothing below throws on
  // purpose (the storage and client APIs return Status), so anything else is a bug or out of
  // memory.
  try {
    app.emplace(
        "hvdb: a database for 3D video (point clouds over time), on a data directory or an "
        "hvdb-server",
        "hvdb");
    ctx.emplace();
    hvdb::cli::AddCommands(*app, *ctx);
    app->parse(argc, argv);
    return hvdb::cli::Run(*app, *ctx);
  } catch (const CLI::ParseError& e) {
    int rc = app->exit(e);  // prints the help, or the message and a pointer to --help
    return rc == 0 ? hvdb::cli::kExitOk : hvdb::cli::kExitUsage;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hvdb: internal error: %s\n", e.what());
    return hvdb::cli::kExitError;
  }
}
