// Live 3D video: ingesting a recording while it is being written (`hvdb-ingest run --follow`),
// and writing one at a capture rate to rehearse that (`replay`, `generate --realtime`).
//
// The follower takes recording frames in order, each as soon as all its cameras' files are
// present and complete (FileCompleteness below), processes it with the same per-frame pipeline
// as RunIngest (PrepareFrame, CommitFrame: the same points and photos) and commits it as soon
// as it and the frames before it are done, so readers see frames appear live. Up to `workers`
// frames are prepared at once (a frame's stages are mostly serial: one frame at a time cannot
// use the cores), always committed in frame order. A frame whose files do not complete within
// `frame_timeout` is reported by name and left out; later frames still are taken. It ends
// when the recording's declared frames are handled, or when *stop becomes true (Ctrl-C,
// SIGTERM) after committing, in order, the frames in hand. docs/RECORDING.md, "Live ingest".
#ifndef HVDB_INGEST_LIVE_H_
#define HVDB_INGEST_LIVE_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "client/backend.h"
#include "ingest/pipeline.h"
#include "ingest/recording.h"

namespace hvdb::ingest {

// Every file recording frame i needs (colour, depth, pose, grey pairs, or the PLY), in the
// order LoadFrame reads them.
std::vector<std::string> FrameFiles(const Recording& recording, int i);

// Whether a file is completely written. With `why` set to what is missing when not.
//   PNG   its last 12 bytes are the IEND chunk
//   JPEG  it ends with the EOI marker FF D9
//   EXR   OpenEXR finds every scanline/tile in it (InputFile::isComplete)
//   PLY   its header is complete and, for binary bodies of fixed-size properties, the file
//         holds every element; otherwise (ASCII, list properties) as "other"
//   .txt  (poses) 16 numbers and a final newline; else as "other"
//   other not modified for `settle_ms` (by its mtime, or size and
//         mtime unchanged between two looks that far apart), or closed by its writer /
//         renamed into place since its last change (`closed`, from inotify)
// A file is only looked at under its final name; writers that write a temporary file and
// rename it into place are complete at once.
struct FileCheck {
  bool complete = false;
  std::string why;  // not complete: "missing", "incomplete: no IEND chunk yet", ...
  int settle_left_ms = 0;  // "other" files: when to look again without an event
};
class FileCompleteness {
 public:
  explicit FileCompleteness(int settle_ms = 300) : settle_ms_(settle_ms) {}
  // closed: the writer closed the file (IN_CLOSE_WRITE) or renamed it into place
  // (IN_MOVED_TO) after its last modification.
  FileCheck Check(const std::string& path, bool closed = false);

 private:
  struct Seen {
    int64_t size = -1, mtime_ns = -1;
    int64_t since_ms = 0;  // steady clock ms when this size/mtime was first seen
  };
  int settle_ms_;
  std::map<std::string, Seen> seen_;
};

struct FollowOptions {
  double frame_timeout = 10;  // seconds a frame may take to complete, from when it is due
  double status_every = 5;    // seconds between status lines on stderr (0: none)
  bool verbose = false;       // a line per frame on stdout (taken, committed, latency)
  int poll_ms = 250;          // the safety net's poll period (filesystems without inotify)
  bool inotify = true;        // false: the poll alone (tests of the safety net)
  // Set by a signal handler: take no more frames, commit those taken (in order), return.
  const std::atomic<bool>* stop = nullptr;
};

struct FollowReport {
  IngestReport ingest;  // frames: handled ones, in frame order (status ingested/present/skipped)
  int timed_out = 0;    // frames left out because their files did not complete in time
  bool interrupted = false;
  // Per committed frame: seconds from its last file landing (the newest mtime or ctime, which
  // a rename into place sets, of its files and of the frames it waited for) to its points
  // committed.
  std::vector<double> latency_s;
  int max_behind = 0;   // the most frames it was behind the capture (see the status line)
  int max_in_flight = 0;  // the most frames taken and not yet committed at once
};

// Waits for REC/recording.yml (and the calibration) to be readable, then follows it. `dir`
// may not exist yet. Options as RunIngest's (workers: frames prepared at once, 0: the cores;
// max_in_flight: frames taken and not yet committed, 0: workers + 1).
Result<FollowReport> FollowRecording(const std::string& dir, client::Backend& backend,
                                     const IngestOptions& options, const FollowOptions& follow);

// Replays recording src into the new directory out at `fps` (0: as fast as possible):
// recording.yml and calibration.yml first (written to temporary names, renamed into place),
// then frame after frame its files copied under temporary names and renamed into place, frame
// k at start + k / fps, `loop` times over (frame numbers go on: loop 2 of a 10-frame
// recording writes frames 0..19). `count` (> 0) takes only the first count frames of src.
// progress (optional) gets (frames written, total, seconds late of the last frame).
struct ReplayOptions {
  double fps = 0;
  int loop = 1;
  int count = -1;
  const std::atomic<bool>* stop = nullptr;
};
struct ReplayReport {
  int frames = 0;
  int late = 0;           // frames renamed into place after their time
  double max_late_s = 0;  // the most any was late
  double seconds = 0;
};
Result<ReplayReport> ReplayRecording(const std::string& src, const std::string& out,
                                     const ReplayOptions& options,
                                     const std::function<void(int, int, double)>& progress = {});

}  // namespace hvdb::ingest

#endif  // HVDB_INGEST_LIVE_H_
