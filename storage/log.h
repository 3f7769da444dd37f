// Where the engine reports what it does on its own (a deferred merge, a takeover, a missing
// kernel feature): warnings and notes that are not the answer to any call. A server routes them
// into its own log (server/server.cc); the default handler writes "hvdb: MESSAGE" to stderr.
#ifndef HVDB_STORAGE_LOG_H_
#define HVDB_STORAGE_LOG_H_

#include <functional>
#include <string>

namespace hvdb {

enum class LogSeverity { kWarning, kNote };
using LogHandler = std::function<void(LogSeverity, const std::string&)>;

// Replaces the handler (null: the default). Thread-safe; the handler may be called from any
// of the engine's threads, one call at a time.
void SetLogHandler(LogHandler handler);
void LogWarning(const std::string& message);
void LogNote(const std::string& message);

}  // namespace hvdb

#endif  // HVDB_STORAGE_LOG_H_
