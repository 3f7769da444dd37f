// `hvdb watch`: a dataset's changes as they happen, one line per event (storage/watch.h).
#include <cstdint>
#include <cstdio>
#include <optional>
#include <string>

#include "client/cli/commands.h"
#include "client/cli/common.h"

namespace hvdb::cli {
namespace {

struct WatchArgs {
  std::string name;
  uint64_t from_lsn = 0;
  CLI::Option* from_opt = nullptr;
  uint64_t count = 0;
  double seconds = 0;
  bool json = false;
} watch_args;

// The line a script reads: names fixed by docs/PROTOCOL.md ("Watching"), in that order.
nlohmann::ordered_json WatchEventJson(const ChangeEvent& ev) {
  nlohmann::ordered_json j = {{"lsn", ev.lsn}, {"kind", ChangeKindName(ev.kind)}};
  if (ev.kind == ChangeEvent::Kind::kLive || ev.kind == ChangeEvent::Kind::kLagged ||
      ev.kind == ChangeEvent::Kind::kDropped) {
    return j;
  }
  j["frames"] = ev.frames;
  j["points"] = ev.points;
  j["removed"] = ev.removed;
  if (ev.kind == ChangeEvent::Kind::kRevert) j["reverts"] = ev.reverts;
  return j;
}

std::string WatchEventText(const ChangeEvent& ev) {
  const std::string lsn = "lsn " + std::to_string(ev.lsn);
  switch (ev.kind) {
    case ChangeEvent::Kind::kLive: return lsn + ": live (what follows happens now)";
    case ChangeEvent::Kind::kLagged:
      return lsn + ": fell behind; the watch ended (resume with --from-lsn " +
             std::to_string(ev.lsn) + ")";
    case ChangeEvent::Kind::kDropped: return lsn + ": the dataset was dropped";
    default: break;
  }
  std::string frames;
  for (size_t i = 0; i < ev.frames.size() && i < 8; ++i) {
    frames += (i ? "," : "") + std::to_string(ev.frames[i]);
  }
  if (ev.frames.size() > 8) frames += ",... (" + std::to_string(ev.frames.size()) + " frames)";
  std::string s = lsn + ": " + ChangeKindName(ev.kind);
  if (ev.kind == ChangeEvent::Kind::kRevert) s += " of " + std::to_string(ev.reverts);
  return s + " frames " + frames + ", +" + std::to_string(ev.points) + " -" +
         std::to_string(ev.removed) + " points";
}

int CmdWatch(Context& ctx, const WatchArgs& a) {
  std::optional<uint64_t> from;
  if (a.from_opt && a.from_opt->count() > 0) from = a.from_lsn;
  auto w = ctx.db().Watch(a.name, from);
  if (!w.ok()) return Fail(w.status());
  const auto end = a.seconds > 0 ? Clock::now() + std::chrono::microseconds(
                                                      static_cast<int64_t>(a.seconds * 1e6))
                                 : Clock::time_point::max();
  uint64_t changes = 0;
  ChangeEvent ev;
  while (a.count == 0 || changes < a.count) {
    auto left = std::chrono::duration_cast<std::chrono::milliseconds>(end - Clock::now());
    if (left.count() <= 0) break;
    auto got = (*w)->Next(&ev, std::min(left, std::chrono::milliseconds(1000)));
    if (!got.ok()) return Fail(got.status());
    if (!*got) continue;
    std::printf("%s\n", a.json ? WatchEventJson(ev).dump().c_str() : WatchEventText(ev).c_str());
    std::fflush(stdout);  // a line per event, as it happens (pipes included)
    if (ev.kind == ChangeEvent::Kind::kLagged) {
      std::fprintf(stderr, "hvdb: watch of '%s' fell behind; resume with --from-lsn %llu\n",
                   a.name.c_str(), static_cast<unsigned long long>(ev.lsn));
      return kExitError;
    }
    if (ev.kind == ChangeEvent::Kind::kDropped) break;
    if (ev.kind != ChangeEvent::Kind::kLive) ++changes;
  }
  return kExitOk;
}

}  // namespace

void AddWatchCommands(CLI::App& app, Context& ctx) {
  WatchArgs& w = watch_args;
  CLI::App* cmd = app.add_subcommand(
      "watch",
      "Print a dataset's changes as they are committed (commits, reverts, bulk loads), one line "
      "each; with --from-lsn, the changes after that LSN first (from the log), then a 'live' "
      "line, then the new ones. Runs until Ctrl-C, --count or --seconds, or the dataset is "
      "dropped. Use --server: with --data this process holds the directory, so only the log's "
      "past changes (--from-lsn) can come");
  cmd->add_option("name", w.name, "Dataset")->required();
  w.from_opt = cmd->add_option("--from-lsn", w.from_lsn,
                               "Replay the changes after this LSN first (resume where you were)");
  cmd->add_option("--count", w.count, "Stop after this many changes (0: no limit)")
      ->capture_default_str();
  cmd->add_option("--seconds", w.seconds, "Stop after this long (0: no limit)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_flag("--json", w.json,
                "One JSON object per line: {\"lsn\", \"kind\", \"frames\", \"points\", "
                "\"removed\"} (kind: commit, revert, bulk, live, lagged, dropped)");
  ctx.Add(cmd, [](Context& c) { return CmdWatch(c, watch_args); });
}

}  // namespace hvdb::cli
