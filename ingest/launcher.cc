// `hvdb-ingest`: the stereo matcher on one pair runs here; every other subcommand (and --help)
// is hvdb-ingest-all beside this file, which this process becomes (execv).
//
// Why two binaries: `hvdb-ingest stereo` is timed as a whole command against OpenCV's SGBM,
// and hvdb-ingest-all links the database, the renderers and media import, about 230 shared
// libraries whose loading took 115 ms before main() — twice the matcher's own time. This one
// links the matcher, libpng/libjpeg and OpenCV's core only.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>

#include <CLI/CLI.hpp>

#include "ingest/commands.h"

namespace {

// The directory of this executable (the installed one, not the name it was called by).
std::string SelfDir() {
  std::error_code ec;
  const auto self = std::filesystem::read_symlink("/proc/self/exe", ec);
  return ec ? std::string() : self.parent_path().string();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc >= 2 && std::strcmp(argv[1], "stereo") == 0) {
    CLI::App app{"hvdb-ingest: turn recordings (stereo on structured light, depth, PLY) into hvdb "
                 "datasets. Formats: docs/RECORDING.md."};
    app.require_subcommand(1);
    hvdb::ingest::RegisterStereoCommand(app);
    try {
      app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
      return app.exit(e);
    }
    return 0;
  }
  const std::string full = SelfDir() + "/hvdb-ingest-all";
  argv[0] = const_cast<char*>("hvdb-ingest");
  ::execv(full.c_str(), argv);
  std::fprintf(stderr, "hvdb-ingest: cannot run %s: %s (it is installed beside hvdb-ingest; "
                       "reinstall the package or rebuild)\n", full.c_str(), std::strerror(errno));
  return 127;
}
