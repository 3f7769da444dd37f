// The administrative commands of `hvdb`: stats, check, drop, compact and ping.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <iostream>
#include <string>
#include <utility>
#include <vector>

#include "client/cli/commands.h"
#include "client/cli/common.h"

namespace hvdb::cli {
namespace {

struct PingArgs {
  unsigned count = 1;
  bool json = false;
};

// What CLI11 fills in for these subcommands: static, so that registering them allocates
// nothing but what CLI11 does (see Context in common.h).
struct CompactArgs {
  std::string name;
  std::vector<uint32_t> frames;  // first, last (none: every frame)
  bool photos = false;
  bool json = false;
};

struct AdminArgs {
  NameArgs stats, check, drop;
  CompactArgs compact;
  PingArgs ping;
} admin_args;

int CmdStats(Context& ctx, const NameArgs& a) {
  Result<client::StatsReport> report = ctx.db().Stats(a.name);
  if (!report.ok()) return Fail(report.status());
  json list = json::array();
  for (const client::StatsReport::Entry& e : report->datasets) {
    const DatasetStats& s = e.stats;
    if (a.json) {
      list.push_back({{"name", e.name},
                      {"frames_with_data", s.frames_with_data},
                      {"points", s.points},
                      {"tombstones", s.tombstones},
                      {"buffered_points", s.buffered_points},
                      {"trees", s.trees},
                      {"tree_bytes", s.tree_bytes},
                      {"wal_bytes", s.wal_bytes},
                      {"leaf_utilisation", s.leaf_utilisation},
                      {"hot_tree_bytes", s.tree_bytes - s.cold_tree_bytes},
                      {"cold_frames", s.cold_frames},
                      {"cold_trees", s.cold_trees},
                      {"cold_tree_bytes", s.cold_tree_bytes},
                      {"cold_points", s.cold_points},
                      {"last_lsn", e.last_lsn}});
    } else {
      std::printf(
          "%s: %u frames with data, %llu points (%llu buffered, %llu tombstones), %llu trees "
          "(%.1f MiB, leaves %.0f%% full), log %.1f MiB, last lsn %llu\n",
          e.name.c_str(), s.frames_with_data, static_cast<unsigned long long>(s.points),
          static_cast<unsigned long long>(s.buffered_points),
          static_cast<unsigned long long>(s.tombstones), static_cast<unsigned long long>(s.trees),
          static_cast<double>(s.tree_bytes) / (1 << 20), 100 * s.leaf_utilisation,
          static_cast<double>(s.wal_bytes) / (1 << 20),
          static_cast<unsigned long long>(e.last_lsn));
      std::printf("  hot tier: %llu points in %.1f MiB; cold tier: %u frames, %llu points in "
                  "%.1f MiB (%.1f bytes/point)\n",
                  static_cast<unsigned long long>(s.points - s.cold_points),
                  static_cast<double>(s.tree_bytes - s.cold_tree_bytes) / (1 << 20),
                  s.cold_frames, static_cast<unsigned long long>(s.cold_points),
                  static_cast<double>(s.cold_tree_bytes) / (1 << 20),
                  s.cold_points ? static_cast<double>(s.cold_tree_bytes) /
                                      static_cast<double>(s.cold_points)
                                : 0.0);
    }
  }
  json out = {{"datasets", list}};
  if (report->cache) {
    const CacheStats& c = *report->cache;
    uint64_t lookups = c.hits + c.misses;
    double hit_rate = lookups ? static_cast<double>(c.hits) / static_cast<double>(lookups) : 0;
    if (a.json) {
      out["cache"] = {{"capacity_bytes", c.capacity_bytes},
                      {"block_size", c.block_size},
                      {"hits", c.hits},
                      {"misses", c.misses},
                      {"hit_rate", hit_rate},
                      {"evictions", c.evictions},
                      {"resident_blocks", c.resident_blocks},
                      {"pinned_blocks", c.pinned_blocks}};
    } else {
      std::printf(
          "cache: %.0f MiB in %llu KiB blocks, %llu resident, %llu pinned; %llu hits, %llu "
          "misses, %llu evictions\n",
          static_cast<double>(c.capacity_bytes) / (1 << 20),
          static_cast<unsigned long long>(c.block_size >> 10),
          static_cast<unsigned long long>(c.resident_blocks),
          static_cast<unsigned long long>(c.pinned_blocks), static_cast<unsigned long long>(c.hits),
          static_cast<unsigned long long>(c.misses), static_cast<unsigned long long>(c.evictions));
    }
  }
  if (report->server) {
    const client::ServerCounters& v = *report->server;
    if (a.json) {
      out["cache"] = {{"capacity_bytes", v.cache_capacity_bytes}, {"hit_rate", v.cache_hit_rate}};
      json requests = json::array();
      for (const client::RequestLatency& l : v.requests) {
        requests.push_back({{"kind", l.kind},
                            {"count", l.count},
                            {"p50_ms", l.p50_ms},
                            {"p95_ms", l.p95_ms},
                            {"p99_ms", l.p99_ms}});
      }
      out["server"] = {{"address", ctx.db().where()},
                       {"role", v.role},
                       {"leader", v.leader},
                       {"connections_open", v.connections_open},
                       {"connections_total", v.connections_total},
                       {"bytes_in", v.bytes_in},
                       {"bytes_out", v.bytes_out},
                       {"requests", requests}};
    } else {
      std::printf("server %s: %llu connection%s open, %llu in all; %s in, %s out\n",
                  ctx.db().where().c_str(), static_cast<unsigned long long>(v.connections_open),
                  v.connections_open == 1 ? "" : "s",
                  static_cast<unsigned long long>(v.connections_total), Bytes(v.bytes_in).c_str(),
                  Bytes(v.bytes_out).c_str());
      if (!v.role.empty()) {
        std::printf("role: %s%s%s\n", v.role.c_str(), v.leader.empty() ? "" : "; the writer is at ",
                    v.leader.c_str());
      }
      std::printf("cache: %.0f MiB, hit rate %.1f%%\n",
                  static_cast<double>(v.cache_capacity_bytes) / (1 << 20), 100 * v.cache_hit_rate);
      if (!v.requests.empty()) {
        std::printf("  %-10s %10s %10s %10s %10s\n", "request", "count", "p50 ms", "p95 ms",
                    "p99 ms");
      }
      for (const client::RequestLatency& l : v.requests) {
        std::printf("  %-10s %10llu %10.3f %10.3f %10.3f\n", l.kind.c_str(),
                    static_cast<unsigned long long>(l.count), l.p50_ms, l.p95_ms, l.p99_ms);
      }
    }
  }
  if (a.json) PrintJson(out);
  return kExitOk;
}

int CmdCheck(Context& ctx, const NameArgs& a) {
  if (ctx.db().remote()) {
    return Usage("check",
                 "check reads the data directory's files and cannot run through --server; run "
                 "'hvdb --data DIR check' on the server's machine, with hvdb-server stopped");
  }
  std::vector<std::string> names;
  if (!a.name.empty()) {
    names.push_back(a.name);
  } else {
    Result<std::vector<std::string>> all = ctx.db().ListDatasets();
    if (!all.ok()) return Fail(all.status());
    names = std::move(all).value();
  }
  json problems = json::array();
  for (const std::string& name : names) {
    Result<std::vector<std::string>> found = ctx.db().Check(name);
    if (!found.ok()) return Fail(found.status());
    for (const std::string& p : *found) {
      problems.push_back({{"dataset", name}, {"problem", p}});
      if (!a.json) std::printf("%s: %s\n", name.c_str(), p.c_str());
    }
  }
  if (a.json) {
    PrintJson({{"ok", problems.empty()}, {"datasets", names.size()}, {"problems", problems}});
  } else if (problems.empty()) {
    std::printf("ok\n");
  }
  return problems.empty() ? kExitOk : kExitError;
}

int CmdDrop(Context& ctx, const NameArgs& a) {
  Status s = ctx.db().DropDataset(a.name);
  if (!s.ok()) return Fail(s);
  std::cout << "dropped dataset '" << a.name << "'\n";
  return kExitOk;
}

int PrintPhotoCompact(const CompactArgs& a, const CompactInfo& r) {
  const double ratio = r.photo_bytes_before ? static_cast<double>(r.photo_bytes_after) /
                                                  static_cast<double>(r.photo_bytes_before)
                                            : 0.0;
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"photo_runs", r.photo_runs},
               {"photo_pictures", r.photo_pictures},
               {"photo_already", r.photo_already},
               {"photo_bytes_before", r.photo_bytes_before},
               {"photo_bytes_after", r.photo_bytes_after},
               {"photo_min_psnr", r.photo_min_psnr},
               {"ratio", ratio}});
  } else {
    std::printf("coded %u photos of '%s' as %u videos: %.2f MiB -> %.2f MiB (%.3f), lowest "
                "PSNR (Y, Cb, Cr) %.1f dB%s\n",
                r.photo_pictures, a.name.c_str(), r.photo_runs,
                static_cast<double>(r.photo_bytes_before) / (1 << 20),
                static_cast<double>(r.photo_bytes_after) / (1 << 20), ratio, r.photo_min_psnr,
                r.photo_already ? (", " + std::to_string(r.photo_already) +
                                   " cameras one video already").c_str()
                                : "");
  }
  return kExitOk;
}

int CmdCompact(Context& ctx, const CompactArgs& a) {
  uint32_t first = 0, last = UINT32_MAX;
  if (!a.frames.empty()) {
    first = a.frames[0];
    last = a.frames[1];
    if (first > last) {
      return Usage("compact", "--frames A B needs A <= B (got " + std::to_string(first) + " " +
                                  std::to_string(last) + ")");
    }
  }
  Result<CompactInfo> r = ctx.db().Compact(a.name, first, last, a.photos);
  if (!r.ok()) return Fail(r.status());
  if (a.photos) return PrintPhotoCompact(a, *r);
  const double ratio = r->bytes_before ? static_cast<double>(r->bytes_after) /
                                             static_cast<double>(r->bytes_before)
                                       : 0.0;
  if (a.json) {
    PrintJson({{"dataset", a.name},
               {"frames", r->frames},
               {"already", r->already},
               {"points", r->points},
               {"bytes_before", r->bytes_before},
               {"bytes_after", r->bytes_after},
               {"ratio", ratio}});
  } else {
    std::printf("compacted %u frames of '%s' (%llu points): %.1f MiB -> %.1f MiB (%.3f)%s\n",
                r->frames, a.name.c_str(), static_cast<unsigned long long>(r->points),
                static_cast<double>(r->bytes_before) / (1 << 20),
                static_cast<double>(r->bytes_after) / (1 << 20), ratio,
                r->already ? (", " + std::to_string(r->already) + " compressed already").c_str()
                           : "");
  }
  return kExitOk;
}

int CmdPing(Context& ctx, const PingArgs& a) {
  if (!ctx.db().remote()) {
    return Usage("ping", "ping needs --server HOST:PORT (there is no server on a data directory)");
  }
  std::vector<double> rtts;
  for (unsigned i = 0; i < a.count; ++i) {
    Result<double> ms = ctx.db().Ping();
    if (!ms.ok()) return Fail(ms.status());
    rtts.push_back(*ms);
    if (!a.json) {
      std::printf("pong from %s (%s) in %.3f ms\n", ctx.db().where().c_str(),
                  ctx.db().transport().c_str(), *ms);
    }
  }
  double lo = *std::min_element(rtts.begin(), rtts.end());
  double hi = *std::max_element(rtts.begin(), rtts.end());
  double sum = 0;
  for (double v : rtts) sum += v;
  double avg = sum / static_cast<double>(rtts.size());
  if (a.json) {
    PrintJson({{"server", ctx.db().where()},
               {"transport", ctx.db().transport()},
               {"count", rtts.size()},
               {"rtt_ms", rtts},
               {"min_ms", lo},
               {"avg_ms", avg},
               {"max_ms", hi}});
  } else if (rtts.size() > 1) {
    std::printf("%zu pings: min %.3f, avg %.3f, max %.3f ms\n", rtts.size(), lo, avg, hi);
  }
  return kExitOk;
}

}  // namespace

void AddAdminCommands(CLI::App& app, Context& ctx) {
  NameArgs& stats = admin_args.stats;
  CLI::App* stats_cmd = app.add_subcommand("stats", "Storage and cache statistics");
  stats_cmd->add_option("name", stats.name, "Dataset (default: all)");
  stats_cmd->add_flag("--json", stats.json, "Print JSON");
  ctx.Add(stats_cmd, [](Context& c) { return CmdStats(c, admin_args.stats); });

  CompactArgs& compact = admin_args.compact;
  CLI::App* compact_cmd = app.add_subcommand(
      "compact",
      "Rewrite frames into the cold tier now: one compressed tree per frame, lossless, about a "
      "fifth of the bytes (the server does it by itself to frames idle for --cold-after seconds)");
  compact_cmd->add_option("name", compact.name, "Dataset")->required();
  compact_cmd->add_option("--frames", compact.frames, "First and last frame (default: all)")
      ->expected(2);
  compact_cmd->add_flag("--photos", compact.photos,
                        "Instead, code each camera's photos of those frames as one AV1 video "
                        "per camera (lossy: every picture >= 40 dB PSNR in Y, Cb and Cr)");
  compact_cmd->add_flag("--json", compact.json, "Print JSON");
  ctx.Add(compact_cmd, [](Context& c) { return CmdCompact(c, admin_args.compact); });

  NameArgs& check = admin_args.check;
  CLI::App* check_cmd =
      app.add_subcommand("check",
                         "Verify checksums and tree invariants; exit status 1 if a "
                         "problem is found (data directory only, not --server)");
  check_cmd->add_option("name", check.name, "Dataset (default: all)");
  check_cmd->add_flag("--json", check.json, "Print JSON");
  ctx.Add(check_cmd, [](Context& c) { return CmdCheck(c, admin_args.check); });

  NameArgs& drop = admin_args.drop;
  CLI::App* drop_cmd = app.add_subcommand("drop", "Delete a dataset and all its data");
  drop_cmd->add_option("name", drop.name, "Dataset")->required();
  ctx.Add(drop_cmd, [](Context& c) { return CmdDrop(c, admin_args.drop); });

  PingArgs& ping = admin_args.ping;
  CLI::App* ping_cmd = app.add_subcommand("ping", "Measure the round trip to the --server");
  ping_cmd->add_option("--count", ping.count, "Number of pings")
      ->capture_default_str()
      ->check(CLI::Range(1u, 100000u));
  ping_cmd->add_flag("--json", ping.json, "Print JSON");
  ctx.Add(ping_cmd, [](Context& c) { return CmdPing(c, admin_args.ping); });
}

}  // namespace hvdb::cli
