// hvdb-server: flags, the optional config file, and the server's lifetime. The only
// try/catch of the server is here.
#include <CLI/CLI.hpp>
#include <malloc.h>

#include <cstdio>

#include "server/server.h"

int main(int argc, char** argv) {
  // Keep freed memory for the next request instead of returning it to the kernel: a request's
  // vectors of points (a 57 k-point select allocates ~20 MB) otherwise come from fresh mmaps
  // each time, and faulting their pages in was most of a select's time (bench/README.md,
  // "Label summaries": 102 -> 40 ms). glibc's defaults return blocks over 128 KiB at once and
  // trim the heap above 128 KiB free.
  mallopt(M_MMAP_THRESHOLD, 64 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
  using hvdb::server::Config;
  Config c;
  std::string log_level = "info";
  bool no_sync = false;
  CLI::App app{"hvdb-server: serves hvdb datasets over the hvdb wire protocol (docs/PROTOCOL.md)"};
  app.set_config("--config", "", "read options from an INI/TOML file (keys = long option names)");
  app.add_option("--data", c.data_dir, "data directory (with --store rados:...: its name prefix in the pool)")
      ->capture_default_str();
  app.add_option("--store", c.store,
                 "where the data lives: files under --data (default), or rados:POOL?conf=FILE "
                 "for a Ceph RADOS pool (created if missing; docs/FORMAT.md)");
  bool follow = false;
  app.add_flag("--follow", follow,
               "when another server writes the data: serve reads, follow its commits and take "
               "over when it is gone (its lease ends), instead of refusing to start; always on "
               "with --store rados:...");
  app.add_option("--follow-interval-ms", c.follow_interval_ms,
                 "how often a reading server looks for the writer's new commits without being told "
                 "(it also watches the writer and follows each commit at once)")
      ->capture_default_str()->check(CLI::Range(10u, 60000u));
  bool no_follow_events = false;
  app.add_flag("--no-follow-events", no_follow_events,
               "with --follow: look for the writer's changes every --follow-interval-ms only, "
               "without watching the writer for them");
  app.add_option("--advertise", c.advertise,
                 "HOST:PORT that clients should send writes to while this server is the writer "
                 "(default: the TCP --listen address)");
  app.add_option("--listen", c.listen,
                 "address to listen on, repeatable: HOST:PORT (port 0: any free port; a "
                 "non-loopback address needs --token-file) or unix:PATH (the local fast path; "
                 "'unix:' alone is DATA/hvdb.sock). Default: 127.0.0.1:7878 and unix:")
      ->capture_default_str();
  app.add_option("--http", c.http_listen,
                 "also serve HTTP on HOST:PORT: the web viewer and its WebSocket at /ws (a "
                 "non-loopback address needs --token-file)");
  app.add_option("--web-root", c.web_root,
                 "folder of the web viewer's files (default: the source tree's web/ when built "
                 "from one, else the installed share/hvdb/web)");
  app.add_option("--http-origin", c.http_origins,
                 "another origin (http://HOST:PORT) whose pages may open the WebSocket; "
                 "repeatable (default: only the server's own pages)");
  app.add_option("--token-file", c.token_file, "access tokens, one 'TOKEN ro|rw' per line");
  app.add_option("--port-file", c.port_file, "write the bound port to this file");
  app.add_option("--io-threads", c.io_threads, "network threads (sockets, and query batches in bounded tasks)")->capture_default_str()
      ->check(CLI::Range(1u, 256u));
  app.add_option("--workers", c.worker_threads, "worker threads for commits, edits, ingest and renders")
      ->capture_default_str()->check(CLI::Range(1u, 256u));
  app.add_option("--cache-mb", c.cache_mb, "block cache size in MiB (>= 8)")->capture_default_str()
      ->check(CLI::Range(size_t{8}, size_t{1} << 20));
  app.add_option("--cold-after", c.cold_after_s,
                 "seconds without writes after which a frame is compressed into the cold tier "
                 "(lossless, ~1/5 of the bytes; 0: only `hvdb compact` does it)")
      ->capture_default_str();
  app.add_option("--max-frame-bytes", c.max_frame_bytes, "largest request frame accepted")
      ->capture_default_str()->check(CLI::Range(1024u, 1u << 30));
  app.add_option("--max-connections", c.max_connections,
                 "authenticated connections at once (more are refused as OVERLOADED)")
      ->capture_default_str()->check(CLI::Range(1u, 65536u));
  app.add_option("--max-preauth", c.max_preauth,
                 "connections waiting to say Hello; when full, a new one closes the one there "
                 "longest")
      ->capture_default_str()->check(CLI::Range(1u, 65536u));
  app.add_option("--handshake-timeout", c.handshake_timeout_s,
                 "seconds a new connection has to send its Hello")
      ->capture_default_str()->check(CLI::Range(1u, 3600u));
  size_t connection_buffer_kib = c.outbound_high_water >> 10;
  app.add_option("--connection-buffer-kib", connection_buffer_kib,
                 "results buffered for one connection before its queries pause and its "
                 "requests are no longer read (back-pressure)")
      ->capture_default_str()->check(CLI::Range(size_t{256}, size_t{1} << 20));
  size_t memory_budget_mb = 0;
  app.add_option("--memory-budget", memory_budget_mb,
                 "MiB of results buffered for all connections together; past it a connection "
                 "holding results gets no more until it reads them. The same number bounds the "
                 "memory that import-media and render jobs hold together (default: 1/8 of RAM, " +
                     std::to_string(hvdb::server::DefaultMemoryBudget() >> 20) + " MiB here)")
      ->check(CLI::Range(size_t{16}, size_t{1} << 24));
  app.add_option("--max-job-seconds", c.max_job_seconds,
                 "seconds one import-media or render job may run before it is stopped with an "
                 "error naming this limit (0: no bound)")
      ->capture_default_str()->check(CLI::Range(0u, 86400u));
  app.add_option("--max-inflight", c.max_inflight, "requests in flight per connection")
      ->capture_default_str()->check(CLI::Range(1u, 4096u));
  app.add_option("--idle-timeout", c.idle_timeout_s, "seconds before an idle connection closes")
      ->capture_default_str()->check(CLI::Range(1u, 86400u));
  app.add_option("--max-slice-frames", c.max_slice_frames,
                 "default bound on frames a hyperslice may read")->capture_default_str();
  app.add_option("--max-renders", c.max_renders,
                 "render requests running at once, server-wide (more are refused as OVERLOADED)")
      ->capture_default_str()->check(CLI::Range(1u, 256u));
  app.add_option("--max-render-points", c.max_render_points,
                 "points one rendered image may draw (held in memory while rendering)")
      ->capture_default_str();
  app.add_option("--shm-slots", c.shm_slots,
                 "1 MiB slots of each local client's shared-memory ring (0: none)")
      ->capture_default_str()->check(CLI::Range(0u, 1024u));
  app.add_flag("--no-sync", no_sync, "do not fsync commits (faster, loses the last commits on a "
                                     "power failure)");
  app.add_option("--log-level", log_level, "error, warn, info or debug")->capture_default_str()
      ->check(CLI::IsMember({"error", "warn", "info", "debug"}));
  CLI11_PARSE(app, argc, argv);
  c.sync = !no_sync;
  c.outbound_high_water = connection_buffer_kib << 10;
  c.follow_events = !no_follow_events;
  c.memory_budget = memory_budget_mb << 20;
  c.follow = follow || !c.store.empty();
  hvdb::server::SetLogLevel(log_level == "error"  ? hvdb::server::LogLevel::kError
                            : log_level == "warn" ? hvdb::server::LogLevel::kWarn
                            : log_level == "debug" ? hvdb::server::LogLevel::kDebug
                                                   : hvdb::server::LogLevel::kInfo);
  try {
    auto server = hvdb::server::Server::Create(c);
    if (!server.ok()) {
      std::fprintf(stderr, "hvdb-server: %s\n", server.status().ToString().c_str());
      return 1;
    }
    std::printf("hvdb-server listening on port %u%s%s\n", (*server)->port(),
                (*server)->local_socket().empty() ? "" : " and unix:",
                (*server)->local_socket().c_str());
    if ((*server)->http_port() != 0) {
      const std::string& h = c.http_listen;
      std::printf("hvdb-server web viewer at http://%s:%u/\n", h.substr(0, h.rfind(':')).c_str(),
                  (*server)->http_port());
    }
    std::fflush(stdout);
    (*server)->Run(/*handle_signals=*/true);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "hvdb-server: fatal: %s\n", e.what());
    return 1;
  }
  return 0;
}
