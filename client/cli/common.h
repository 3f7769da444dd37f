// What the families of `hvdb` subcommands share (client/cli/): the context they run in, usage
// and error reporting, number checks, the progress bar, the options of a region, a label bit
// and a camera, and the output of a commit.
#ifndef HVDB_CLIENT_CLI_COMMON_H_
#define HVDB_CLIENT_CLI_COMMON_H_

#include <array>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "formats/ply.h"
#include "storage/database.h"
#include "storage/status.h"

namespace hvdb::cli {

using json = nlohmann::json;
using Clock = std::chrono::steady_clock;

inline constexpr int kExitOk = 0;
inline constexpr int kExitError = 1;
inline constexpr int kExitUsage = 2;

inline constexpr const char* kSkipInvalidHelp =
    "Leave out points with a NaN or infinite coordinate and say how many (default: such a file "
    "is an error and nothing of it is loaded)";

// The options before (or after) the subcommand that pick the database.
struct GlobalArgs {
  std::string data = "./data";
  size_t cache_mb = 256;
  std::string server;
  std::string token;
  std::string wire = "records";
  // To tell options given from defaults.
  CLI::Option *data_opt = nullptr, *cache_opt = nullptr, *token_opt = nullptr;
};

// What the commands run with: the global options, the database (made by main.cc once the
// command line is parsed) and what each subcommand does.
//
// Registering the commands allocates nothing but what CLI11 does: each family keeps its
// arguments in static storage and the table below is a fixed array of function pointers. The
// help lists an option's needs and excludes in the order of the options' addresses (CLI11
// keeps them in a std::set<Option*>), so other allocations in between would reorder them.
class Context {
 public:
  using Run = int (*)(Context&);

  GlobalArgs global;
  std::unique_ptr<client::Backend> backend;

  client::Backend& db() { return *backend; }
  // `run` is what `cmd` does when it is the command given; it returns the exit status and
  // prints its own errors.
  void Add(CLI::App* cmd, Run run);
  // Runs the command the line gave; nullopt when none was.
  std::optional<int> RunParsed();

 private:
  std::array<std::pair<CLI::App*, Run>, 32> commands_{};
  size_t count_ = 0;
};

double MsSince(Clock::time_point start);
std::string Printf(const char* fmt, ...) __attribute__((format(printf, 1, 2)));
// "512 B", "12.3 KiB", "4.56 MiB": for byte counts.
std::string Bytes(uint64_t v);

void PrintJson(const json& j);
// Prints "hvdb: <status>"; returns the exit status of an error.
int Fail(const Status& s);
// A usage error of `command` (the subcommand at fault, or "" for the top level); returns its
// exit status.
int Usage(const std::string& command, const std::string& msg);

// Number checks with plain messages (CLI11's own print the whole double range).
CLI::Validator Positive();
CLI::Validator NonNegative();

// Frames done / total, points per second and time left, redrawn in place on stderr. Only when
// stderr is a terminal: redirected output gets no carriage-return noise.
class ProgressBar {
 public:
  explicit ProgressBar(uint64_t total);
  ~ProgressBar() { Clear(); }
  ProgressBar(const ProgressBar&) = delete;
  ProgressBar& operator=(const ProgressBar&) = delete;

  void Update(uint64_t done, uint64_t points);
  void Clear();

 private:
  bool enabled_;
  bool drawn_ = false;
  uint64_t total_;
  Clock::time_point start_;
};

// Reads a PLY file for import, edit --paste or composite; points left out by ro.skip_invalid
// are said on stderr (after bar's line is cleared), so none goes missing unnoticed.
Result<std::vector<Point>> ReadPlyNoting(const std::string& path, const formats::ReadOptions& ro,
                                         uint64_t* skipped = nullptr, ProgressBar* bar = nullptr);

// How a command that commits a transaction shows it, printed by PrintCommit. As JSON: `fields`
// with "lsn" (and "inserted", "removed" where the command knows them) added. As text, one line:
//   <before>committed lsn L[ (inserted I, removed R)]<after>
// where lsn 0 (nothing was committed) may instead say so, or print nothing.
struct CommitOutput {
  uint64_t lsn = 0;
  std::optional<uint64_t> inserted, removed;
  json fields = json::object();
  std::string before, after;
  bool counts_in_text = false;  // the "(inserted I, removed R)" part
  enum class IfNone { kPrint, kSayNothingChanged, kQuiet } if_none = IfNone::kPrint;
};
// The same result for every command that commits: CommitInfo's lsn and counts.
CommitOutput Committed(const CommitInfo& ci);
void PrintCommit(bool as_json, const CommitOutput& out);

// A --box X0 X1 Y0 Y1 Z0 Z1 T0 T1 as a Window; nullopt (after a usage message) if malformed.
std::optional<hvdb::Window> BoxToWindow(const std::vector<double>& v, const std::string& command,
                                        const std::string& option, int* rc);
// A hyperslice from --normal/--offset/--thickness (and the frame bound and --clip-box);
// nullopt (after a usage message) if malformed.
std::optional<hvdb::Slice> MakeSlice(const std::vector<double>& normal, double offset,
                                     double thickness, bool clip_frames, uint32_t max_frames,
                                     const std::vector<double>& clip_box,
                                     const std::string& command, int* rc);

// The region an editing command works in: a 4D box, or a hyperslice as `slice` takes it.
// A dataset's name and --json: datasets, describe, stats, check, drop.
struct NameArgs {
  std::string name;
  bool json = false;
};

struct RegionArgs {
  std::vector<double> box, normal, clip_box;
  double offset = 0, thickness = 0;
  bool clip_frames = false;
  uint32_t max_frames = 0;
  CLI::Option *box_opt = nullptr, *normal_opt = nullptr;
  CLI::Option *offset_opt = nullptr, *thickness_opt = nullptr;
};
// --box or --normal/--offset/--thickness as the region of an editing command, shown in the
// help under `group`.
void AddRegionOptions(CLI::App* cmd, RegionArgs* r, const std::string& group);
// The region given by AddRegionOptions' options into *out (nullopt: none given). False (after
// a usage message, exit status in *rc) if malformed.
bool ParseRegion(const RegionArgs& r, const std::string& command, std::optional<Region>* out,
                 int* rc);

// A label bit option: 0..31.
CLI::Option* AddBit(CLI::App* cmd, const std::string& name, int* bit, const std::string& help);

// The camera a lasso, marquee or brush is drawn through, or an image rendered through.
struct CameraArgs {
  std::string file;
  std::vector<double> look_at;
  std::vector<double> up{0, -1, 0};
  double fov = 0;
  std::vector<uint32_t> size;
  CLI::Option *file_opt = nullptr, *look_at_opt = nullptr;
};
// The pinhole camera of --look-at EX EY EZ TX TY TZ --fov DEG --size W H [--up UX UY UZ]:
// OpenCV axes (x right, y down, z forward), square pixels, the principal point at the image
// centre (pixel centres at integers), `fov` the vertical field of view. world_from_camera's
// columns are the camera's axes and centre in the world.
std::optional<CameraInfo> LookAtCamera(const CameraArgs& a, const std::string& command, int* rc);
// A camera file: {"fx", "fy", "cx", "cy", "width", "height", "world_from_camera": [16 values,
// row-major]}. Its problems are errors of the file (exit status 1), named with the file.
Result<CameraInfo> ReadCameraFile(const std::string& path);

}  // namespace hvdb::cli

#endif  // HVDB_CLIENT_CLI_COMMON_H_
