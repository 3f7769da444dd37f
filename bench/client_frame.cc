// client-frame: the C++ peer of bench/python_bench.py. Fetches one frame of a dataset into a
// std::vector<Point> through the client library (client/backend.h), as a C++ program that
// wants the frame in memory would, and prints {"ms": .., "points": ..} (open or connect
// included, as on the Python side).
//   client-frame (--data DIR [--cache-mb N] | --server HOST:PORT) DATASET FRAME
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>

#include "client/backend.h"

int main(int argc, char** argv) {
  CLI::App app{"client-frame: one frame into memory through the C++ client library"};
  std::string data, server, dataset;
  uint32_t frame = 0;
  size_t cache_mb = 256;
  app.add_option("--data", data, "data directory (embedded)");
  app.add_option("--server", server, "HOST:PORT of an hvdb-server");
  app.add_option("--cache-mb", cache_mb, "block cache (embedded)")->capture_default_str();
  app.add_option("dataset", dataset)->required();
  app.add_option("frame", frame)->required();
  CLI11_PARSE(app, argc, argv);
  auto start = std::chrono::steady_clock::now();
  std::unique_ptr<hvdb::client::Backend> db;
  if (!server.empty()) {
    auto r = hvdb::client::MakeRemoteBackend({server, ""});
    if (!r.ok()) {
      std::fprintf(stderr, "client-frame: %s\n", r.status().ToString().c_str());
      return 1;
    }
    db = std::move(r).value();
  } else {
    db = hvdb::client::MakeEmbeddedBackend(data, cache_mb << 20);
  }
  auto info = db->Describe(dataset);
  if (!info.ok()) {
    std::fprintf(stderr, "client-frame: %s\n", info.status().ToString().c_str());
    return 1;
  }
  hvdb::Window w;
  double t = frame / info->fps;
  w.lo = {-1e30, -1e30, -1e30, t};
  w.hi = {1e30, 1e30, 1e30, t};
  auto q = db->Query(dataset, hvdb::Region(w), {});
  if (!q.ok()) {
    std::fprintf(stderr, "client-frame: %s\n", q.status().ToString().c_str());
    return 1;
  }
  std::vector<hvdb::Point> all;
  hvdb::Batch batch;
  for (;;) {
    auto more = (*q)->Next(&batch);
    if (!more.ok()) {
      std::fprintf(stderr, "client-frame: %s\n", more.status().ToString().c_str());
      return 1;
    }
    if (!*more) break;  // (the batch then holds nothing new)
    all.insert(all.end(), batch.points.begin(), batch.points.end());
  }
  double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
                  .count();
  std::printf("{\"ms\": %.3f, \"points\": %zu}\n", ms, all.size());
  return 0;
}
