// Runs a shell command for the tests that drive the project's binaries as a user would: its
// exit status and its stdout and stderr together.
#ifndef HVDB_TESTS_RUN_COMMAND_H_
#define HVDB_TESTS_RUN_COMMAND_H_

#include <sys/wait.h>

#include <cstdio>
#include <string>

namespace hvdb::testing {

struct CommandRun {
  int code = -1;  // exit status; -1 if it did not exit normally
  std::string out;
};

inline CommandRun RunCommand(const std::string& cmd) {
  CommandRun r;
  FILE* p = popen((cmd + " 2>&1").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  int st = pclose(p);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

// Runs `cmd` in directory `dir` with its stdout and stderr apart (stderr through a file there,
// stderr.txt), for tests that parse what a command prints and check its error messages.
struct SplitRun {
  int code = -1;  // exit status; -1 if it did not exit normally
  std::string out, err;
};

inline SplitRun RunInDir(const std::string& dir, const std::string& cmd) {
  const std::string err = dir + "/stderr.txt";
  SplitRun r;
  FILE* p = popen(("cd '" + dir + "' && " + cmd + " 2>'" + err + "'").c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  int st = pclose(p);
  r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  if (FILE* e = std::fopen(err.c_str(), "rb")) {
    while ((n = fread(buf, 1, sizeof buf, e)) > 0) r.err.append(buf, n);
    std::fclose(e);
  }
  return r;
}

}  // namespace hvdb::testing

#endif  // HVDB_TESTS_RUN_COMMAND_H_
