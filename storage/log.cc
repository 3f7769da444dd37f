#include "storage/log.h"

#include <cstdio>
#include <mutex>

namespace hvdb {

namespace {

std::mutex g_mu;
LogHandler g_handler;

void Emit(LogSeverity severity, const std::string& message) {
  std::lock_guard<std::mutex> l(g_mu);
  if (g_handler) {
    g_handler(severity, message);
  } else {
    std::fprintf(stderr, "hvdb: %s\n", message.c_str());
  }
}

}  // namespace

void SetLogHandler(LogHandler handler) {
  std::lock_guard<std::mutex> l(g_mu);
  g_handler = std::move(handler);
}

void LogWarning(const std::string& message) { Emit(LogSeverity::kWarning, message); }
void LogNote(const std::string& message) { Emit(LogSeverity::kNote, message); }

}  // namespace hvdb
