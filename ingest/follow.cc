// The follower of a recording being written (ingest/live.h): waits for each frame's files with
// inotify, takes the frames in order, prepares several at once on a pool of workers
// (PrepareFrame) and commits them in frame order (CommitFrame), as the batch pipeline does.
#include <fcntl.h>
#include <poll.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "ingest/live.h"

namespace hvdb::ingest {

namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

// Absolute: inotify names events by the watched directory, which may be the recording's parent.
std::string Normal(const std::string& path) {
  std::error_code ec;
  return fs::absolute(path, ec).lexically_normal().string();
}

double RealtimeNowS() {
  timespec ts{};
  ::clock_gettime(CLOCK_REALTIME, &ts);
  return static_cast<double>(ts.tv_sec) + ts.tv_nsec * 1e-9;
}

// When the last of the files landed (seconds since the epoch; 0 when none is there): the newest
// of their mtimes and ctimes (a rename into place sets the ctime, not the mtime).
double Landed(const std::vector<std::string>& paths) {
  double newest = 0;
  for (const std::string& p : paths) {
    struct stat st {};
    if (::stat(p.c_str(), &st) != 0) continue;
    newest = std::max({newest, static_cast<double>(st.st_mtim.tv_sec) + st.st_mtim.tv_nsec * 1e-9,
                       static_cast<double>(st.st_ctim.tv_sec) + st.st_ctim.tv_nsec * 1e-9});
  }
  return newest;
}

// Waits for changes in the directories the awaited files are (or will be) in. inotify where the
// kernel and filesystem give events; Wait() is always bounded by its timeout, which is the
// safety net for filesystems that raise none (NFS, FUSE, bind mounts changed from outside):
// the caller looks at the files again after every wait, event or not.
class DirWatcher {
 public:
  explicit DirWatcher(bool inotify) : fd_(inotify ? ::inotify_init1(IN_NONBLOCK | IN_CLOEXEC) : -1) {}
  ~DirWatcher() {
    if (fd_ >= 0) ::close(fd_);
  }
  DirWatcher(const DirWatcher&) = delete;
  DirWatcher& operator=(const DirWatcher&) = delete;

  // Watches the deepest existing directory above each path (a frame's directory may not exist
  // yet: then its parent, whose IN_CREATE wakes us to watch the new one) and drops the rest.
  // Returns whether a watch was added: the caller must look at the files again before waiting,
  // since they may have landed before the watch was in place.
  bool WatchFor(const std::vector<std::string>& paths) {
    if (fd_ < 0) return false;
    std::set<std::string> want;
    for (const std::string& p : paths) {
      fs::path d = fs::path(Normal(p)).parent_path();
      std::error_code ec;
      while (!d.empty() && !fs::is_directory(d, ec) && d != d.parent_path()) d = d.parent_path();
      if (!d.empty()) want.insert(d.string());
    }
    bool added = false;
    for (const std::string& d : want) {
      if (dirs_.count(d)) continue;
      const int wd = ::inotify_add_watch(fd_, d.c_str(),
                                         IN_CREATE | IN_MOVED_TO | IN_CLOSE_WRITE | IN_MODIFY |
                                             IN_ATTRIB | IN_DELETE | IN_MOVED_FROM | IN_ONLYDIR);
      if (wd < 0) continue;  // e.g. out of watches: the bounded poll still sees the files
      dirs_[d] = wd;
      wds_[wd] = d;
      added = true;
    }
    for (auto it = dirs_.begin(); it != dirs_.end();) {
      if (want.count(it->first)) {
        ++it;
        continue;
      }
      ::inotify_rm_watch(fd_, it->second);
      wds_.erase(it->second);
      it = dirs_.erase(it);
    }
    return added;
  }

  // Sleeps until an event or timeout_ms; remembers which files were closed after writing or
  // renamed into place since their last change.
  // wake_fd (optional): a pipe the workers write to when a frame is prepared; drained here.
  void Wait(int timeout_ms, int wake_fd = -1) {
    pollfd p[2] = {{fd_, POLLIN, 0}, {wake_fd, POLLIN, 0}};  // negative fds are ignored
    if (::poll(p, 2, timeout_ms) <= 0) return;  // timeout, or EINTR (a signal: look at stop)
    if (p[1].revents & POLLIN) {
      char drain[64];
      while (::read(wake_fd, drain, sizeof drain) > 0) {
      }
    }
    if (fd_ < 0 || !(p[0].revents & POLLIN)) return;
    alignas(inotify_event) char buf[16384];
    while (true) {
      const ssize_t n = ::read(fd_, buf, sizeof buf);
      if (n <= 0) break;
      for (ssize_t off = 0; off < n;) {
        const auto* e = reinterpret_cast<const inotify_event*>(buf + off);
        off += static_cast<ssize_t>(sizeof(inotify_event) + e->len);
        auto d = wds_.find(e->wd);
        if (d == wds_.end() || e->len == 0) continue;
        const std::string path = d->second + "/" + e->name;
        if (e->mask & (IN_CLOSE_WRITE | IN_MOVED_TO)) {
          closed_.insert(path);
        } else if (e->mask & (IN_MODIFY | IN_CREATE | IN_DELETE | IN_MOVED_FROM)) {
          closed_.erase(path);
        }
      }
    }
  }

  bool Closed(const std::string& path) const { return closed_.count(Normal(path)) > 0; }
  void Forget(const std::string& path) { closed_.erase(Normal(path)); }

 private:
  int fd_;
  std::map<std::string, int> dirs_;
  std::map<int, std::string> wds_;
  std::set<std::string> closed_;
};

bool Stopped(const FollowOptions& f) { return f.stop != nullptr && f.stop->load(); }

// Opens the recording once recording.yml (and calibration.yml) are there and not being
// written: without limit while recording.yml is absent (the capture has not started), for
// frame_timeout once it is there.
Result<Recording> WaitForRecording(const std::string& dir, const FollowOptions& follow,
                                   DirWatcher* watcher, FileCompleteness* files, bool* stopped) {
  const std::string yml = (fs::path(dir) / "recording.yml").string();
  const std::string cal = (fs::path(dir) / "calibration.yml").string();
  std::optional<Clock::time_point> since;
  bool said = false;
  while (true) {
    if (Stopped(follow)) {
      *stopped = true;
      return Status::Cancelled("stopped while waiting for " + yml);
    }
    const bool added = watcher->WatchFor({yml, cal});
    const FileCheck y = files->Check(yml, watcher->Closed(yml));
    Status last;
    if (y.complete) {
      if (!since) since = Clock::now();
      // A stereo or depth recording needs its calibration written whole too.
      const FileCheck c = files->Check(cal, watcher->Closed(cal));
      Result<Recording> r = OpenRecording(dir);
      if (r.ok() && (r->kind == RecordingKind::kPly || c.complete)) return r;
      last = r.ok() ? Status::NotFound(cal + ": " + c.why) : r.status();
      if (Clock::now() - *since > std::chrono::duration<double>(follow.frame_timeout)) return last;
    } else if (!said && follow.status_every > 0) {
      std::fprintf(stderr, "hvdb-ingest: waiting for %s (%s)\n", yml.c_str(), y.why.c_str());
      said = true;
    }
    if (!added) watcher->Wait(follow.poll_ms);
  }
}

struct Slot {
  std::shared_ptr<const FrameInput> input;  // loaded: every file complete and decoded
  bool failed = false;                      // timed out
  std::string why;                          // what it still waits for
  std::optional<Clock::time_point> due, settled;
  double landed = 0;                        // when its last file landed (epoch seconds)
  double load_ms = 0;                       // reading and decoding its files
};

// A frame taken, in frame order until it is committed: prepared by a worker (`job`), or
// reported as it is (already present, timed out).
struct Taken {
  int frame = 0;
  FrameReport fr;
  bool job = false;
  int wlo = 0, whi = 0;                                   // its window
  std::vector<std::shared_ptr<const FrameInput>> window;  // frames wlo..whi, loaded
  double landed = 0, load_ms = 0;
  PreparedFrame prepared;  // the worker's, read once done
  bool done = false;       // under Workers::mu_
};

// Prepares taken frames on `n` threads, any order; each finished one is marked done and
// announced on a pipe the follower's wait polls. Queued frames not begun are dropped on
// destruction, those begun are finished (their threads joined).
class Workers {
 public:
  Workers(int n, std::function<void(Taken&)> work) : work_(std::move(work)) {
    if (::pipe2(pipe_, O_NONBLOCK | O_CLOEXEC) != 0) pipe_[0] = pipe_[1] = -1;
    for (int i = 0; i < n; ++i) threads_.emplace_back([this] { Run(); });
  }
  ~Workers() {
    {
      std::lock_guard lk(mu_);
      stop_ = true;
      queue_.clear();
    }
    cv_.notify_all();
    for (auto& t : threads_) t.join();
    for (int fd : pipe_)
      if (fd >= 0) ::close(fd);
  }
  Workers(const Workers&) = delete;
  Workers& operator=(const Workers&) = delete;

  void Add(std::shared_ptr<Taken> t) {
    {
      std::lock_guard lk(mu_);
      queue_.push_back(std::move(t));
    }
    cv_.notify_one();
  }
  bool Done(const Taken& t) {
    std::lock_guard lk(mu_);
    return t.done;
  }
  int wake_fd() const { return pipe_[0]; }

 private:
  void Run() {
    while (true) {
      std::shared_ptr<Taken> t;
      {
        std::unique_lock lk(mu_);
        cv_.wait(lk, [&] { return stop_ || !queue_.empty(); });
        if (queue_.empty()) return;
        t = std::move(queue_.front());
        queue_.pop_front();
      }
      work_(*t);
      {
        std::lock_guard lk(mu_);
        t->done = true;
      }
      if (pipe_[1] >= 0) {
        const char c = 1;
        [[maybe_unused]] const ssize_t n = ::write(pipe_[1], &c, 1);  // full: a wake is pending
      }
    }
  }

  std::function<void(Taken&)> work_;
  int pipe_[2] = {-1, -1};
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::shared_ptr<Taken>> queue_;
  bool stop_ = false;
  std::vector<std::thread> threads_;
};

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

Result<FollowReport> FollowRecording(const std::string& dir, client::Backend& backend,
                                     const IngestOptions& options, const FollowOptions& follow) {
  FollowReport out;
  DirWatcher watcher(follow.inotify);
  FileCompleteness files;
  Result<Recording> opened = WaitForRecording(dir, follow, &watcher, &files, &out.interrupted);
  if (out.interrupted) return out;
  if (!opened.ok()) return opened.status();
  const Recording rec = std::move(opened).value();
  IngestOptions opt = options;
  if (opt.dataset.empty()) return Status::InvalidArgument("no dataset given");
  if (opt.first < 0 || opt.first >= rec.frames)
    return Status::InvalidArgument("--first " + std::to_string(opt.first) +
                                   " is outside the recording's frames 0.." + std::to_string(rec.frames - 1));
  const int last = opt.count < 0 ? rec.frames : std::min(rec.frames, opt.first + opt.count);
  // Frames prepared at once, as RunIngest's workers (each frame's stages then share the cores
  // among them); committed in frame order by this thread. --workers 1: one frame at a time,
  // each with every core, the next prepared while this one commits.
  const int cores = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  if (opt.workers <= 0) opt.workers = cores;
  opt.workers = std::clamp(opt.workers, 1, std::max(1, last - opt.first));
  if (opt.max_in_flight <= 0) opt.max_in_flight = opt.workers + 1;  // taken and not committed
  if (opt.stereo.threads <= 0) opt.stereo.threads = std::max(1, cores / opt.workers);
  HVDB_ASSIGN_OR_RETURN(FrameProcessor proc, FrameProcessor::Make(rec, opt));
  HVDB_RETURN_IF_ERROR(EnsureDataset(backend, rec, opt.dataset, opt.gaussians));
  // --gaussians: each frame fitted on this thread as it comes to be committed, in frame order
  // (warm-started from the one before), while the workers prepare the next.
  GaussianVideoFitter fitter(opt.gaussian);
  const int radius = proc.window_radius();
  const auto timeout = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(follow.frame_timeout));
  const auto t_start = Clock::now();
  auto last_status = t_start;
  IngestReport& report = out.ingest;
  report.frames_total = last - opt.first;
  std::map<int, Slot> slots;
  bool started = false;  // a file of the recording's frames has appeared
  // How far behind the capture: frames up to the newest with all its files there, from the
  // next to handle. The scan stops at the first frame with no file yet (the capture's front).
  int newest = opt.first - 1;
  auto behind = [&](int next) {
    for (int j = std::max(newest + 1, next); j < last; ++j) {
      size_t have = 0;
      const std::vector<std::string> paths = FrameFiles(rec, j);
      for (const std::string& p : paths) have += fs::exists(p);
      if (have == 0) break;
      if (have == paths.size()) newest = j;
    }
    return std::max(0, newest + 1 - next);
  };
  auto status_line = [&](int next, const std::string& waiting) {
    if (follow.status_every <= 0 || Clock::now() - last_status < std::chrono::duration<double>(follow.status_every)) return;
    last_status = Clock::now();
    const int handled = static_cast<int>(report.frames.size());
    const int b = behind(opt.first + handled);
    out.max_behind = std::max(out.max_behind, b);
    std::fprintf(stderr, "follow: %d/%d frames handled (%d ingested, %d timed out, %d in flight), behind by %d frames (%.2f s)",
                 handled, last - opt.first, report.ingested, out.timed_out, next - opt.first - handled, b, b / rec.fps);
    if (!out.latency_s.empty())
      std::fprintf(stderr, ", landed->committed median %.0f ms, last %.0f ms", 1000 * Median(out.latency_s),
                   1000 * out.latency_s.back());
    if (!waiting.empty()) std::fprintf(stderr, "; waiting for frame %d: %s", next, waiting.c_str());
    std::fprintf(stderr, "\n");
  };

  // Frames taken and not yet committed, in frame order; `jobs` of them are being prepared or
  // wait to be committed (at most max_in_flight: that bounds the memory).
  std::deque<std::shared_ptr<Taken>> taken;
  int jobs = 0;
  Workers workers(opt.workers, [&](Taken& t) {
    const FrameLoader load = [&](int w) -> Result<std::shared_ptr<const FrameInput>> {
      if (w < t.wlo || w > t.whi) return Status::Internal("frame " + std::to_string(w) + " is not loaded");
      return t.window[static_cast<size_t>(w - t.wlo)];
    };
    t.prepared = PrepareFrame(rec, proc, opt, t.frame, t.wlo, t.whi, load, &t.fr);
    t.window.clear();  // the slots hold them while a later window needs them
  });
  // Commits (or reports) the frames at the front that are ready, in frame order.
  auto commit_ready = [&]() -> Status {
    while (!taken.empty() && (!taken.front()->job || workers.Done(*taken.front()))) {
      std::shared_ptr<Taken> t = std::move(taken.front());
      taken.pop_front();
      FrameReport& fr = t->fr;
      if (t->job) {
        --jobs;
        PreparedFrame d = std::move(t->prepared);
        fr.stage_ms["load"] = t->load_ms;  // read when it completed, before it was taken
        if (d.status.ok() && opt.gaussians) FitPreparedFrame(fitter, &d, &fr);
        if (!d.status.ok()) {
          fr.status = "skipped";
          fr.error = d.status.ToString();
          if (!opt.skip_bad_frames)
            return Status(d.status.code(), "frame " + std::to_string(t->frame) + ": " + d.status.message() +
                                               " (--skip-bad-frames goes on without it)");
          ++report.skipped;
          std::fprintf(stderr, "hvdb-ingest: skipped frame %d: %s\n", t->frame, fr.error.c_str());
        } else {
          const uint64_t bytes = d.bytes;
          auto n = CommitFrame(backend, opt, std::move(d), &fr);
          if (!n.ok())
            return Status(n.status().code(), "frame " + std::to_string(t->frame) + ": commit: " + n.status().message());
          ++report.ingested;
          report.points += *n;
          report.bytes_read += bytes;
          report.skipped_invalid += fr.skipped_invalid;
          const double latency = std::max(0.0, RealtimeNowS() - t->landed);
          out.latency_s.push_back(latency);
          fr.stage_ms["landed_to_committed"] = 1000 * latency;
          if (follow.verbose) {
            std::printf("frame %d: committed %llu points, %.0f ms after its last file landed\n", t->frame,
                        static_cast<unsigned long long>(*n), 1000 * latency);
            std::fflush(stdout);
          }
        }
      }
      report.frames.push_back(std::move(fr));
    }
    return Status::OK();
  };

  int next = opt.first;  // the next frame to take
  std::optional<int> present_checked;
  while (true) {
    HVDB_RETURN_IF_ERROR(commit_ready());
    // Stopped: no frame more is taken; those taken are prepared and committed, in order.
    if (next < last && Stopped(follow)) out.interrupted = true;
    if (out.interrupted || next >= last || jobs >= opt.max_in_flight) {
      if (taken.empty()) {
        if (out.interrupted || next >= last) break;
      } else {
        watcher.Wait(follow.poll_ms, workers.wake_fd());
      }
      continue;
    }
    auto take = [&](FrameReport fr) {
      auto t = std::make_shared<Taken>();
      t->frame = next;
      t->fr = std::move(fr);
      taken.push_back(std::move(t));
      return taken.back().get();
    };
    FrameReport fr;
    fr.frame = next;
    fr.dataset_frame = opt.frame_offset + static_cast<uint32_t>(next);
    // Resume: a frame already in the dataset needs no files.
    if (present_checked != next) {
      present_checked = next;
      HVDB_ASSIGN_OR_RETURN(bool present, FramePresent(backend, opt.dataset, fr.dataset_frame, rec.fps));
      if (present) {
        if (follow.verbose) {
          std::printf("frame %d: already in the dataset (resumed), not taken again\n", next);
          std::fflush(stdout);
        }
        fr.status = "present";
        ++report.present;
        take(std::move(fr));
        ++next;
        continue;
      }
    }
    // The frame and those around it its window needs: each loaded, or timed out.
    const int lo = std::max(0, next - radius), hi = std::min(rec.frames - 1, next + radius);
    std::vector<std::string> awaited;
    std::string waiting;
    int settle_ms = follow.poll_ms;  // a file without an end marker settles then, with no event
    for (int j = lo; j <= hi; ++j) {
      Slot& s = slots[j];
      if (s.input || s.failed) continue;
      const std::vector<std::string> paths = FrameFiles(rec, j);
      std::string why;
      bool any = false;
      for (const std::string& p : paths) {
        const FileCheck c = files.Check(p, watcher.Closed(p));
        any = any || c.why != "missing";
        if (!c.complete) why += (why.empty() ? "" : "; ") + p + ": " + c.why;
        if (c.settle_left_ms > 0) settle_ms = std::min(settle_ms, c.settle_left_ms);
      }
      started = started || any;
      if (why.empty()) {
        // Every file looks whole: decoding it is the final test (a file the markers were
        // wrong about is looked at again on its next change, until the timeout).
        const auto t_load = Clock::now();
        Result<FrameInput> f = LoadFrame(rec, j, opt.skip_invalid);
        s.load_ms = std::chrono::duration<double, std::milli>(Clock::now() - t_load).count();
        if (f.ok()) {
          s.input = std::make_shared<const FrameInput>(std::move(f).value());
          s.settled = Clock::now();
          s.landed = Landed(paths);
          for (const std::string& p : paths) watcher.Forget(p);
          continue;
        }
        why = f.status().ToString();
      }
      s.why = why;
      if (started && !s.due) {
        // Due a timeout after it is first awaited, or after the frame before it settled.
        Clock::time_point from = Clock::now();
        if (auto prev = slots.find(j - 1); prev != slots.end() && prev->second.settled)
          from = std::max(from, *prev->second.settled);
        s.due = from + timeout;
      }
      if (s.due && Clock::now() >= *s.due) {
        s.failed = true;
        s.settled = Clock::now();
        ++out.timed_out;
        std::fprintf(stderr,
                     "hvdb-ingest: frame %d (source frame %d) did not complete within %g s and is "
                     "not committed; going on with the frames after it. Not complete: %s\n",
                     j, rec.SourceFrame(j), follow.frame_timeout, why.c_str());
        continue;
      }
      if (waiting.empty()) {  // the first file it lacks, for the status line
        const size_t cut = why.find("; ");
        waiting = (j == next ? "" : "frame " + std::to_string(j) + " (in its window): ") + why.substr(0, cut);
        if (cut != std::string::npos) waiting += " (and more)";
      }
      awaited.insert(awaited.end(), paths.begin(), paths.end());
    }
    if (!awaited.empty()) {
      status_line(next, waiting);
      if (watcher.WatchFor(awaited)) continue;  // look again now the watches are in place
      int wait_ms = settle_ms;
      for (int j = lo; j <= hi; ++j) {
        const Slot& s = slots[j];
        if (s.due && !s.input && !s.failed)
          wait_ms = std::min<int>(wait_ms, static_cast<int>(std::chrono::duration_cast<std::chrono::milliseconds>(
                                                               *s.due - Clock::now()).count()) + 1);
      }
      watcher.Wait(std::max(1, wait_ms), workers.wake_fd());  // a prepared frame wakes it too
      continue;
    }
    Slot& centre = slots[next];
    if (centre.failed) {
      fr.status = "skipped";
      fr.error = "timed out: " + centre.why;
      ++report.skipped;
      take(std::move(fr));
    } else {
      // The window: the loaded frames next to it; a neighbour that timed out shortens it (as
      // the recording's ends do).
      int wlo = next, whi = next;
      while (wlo > lo && slots[wlo - 1].input) --wlo;
      while (whi < hi && slots[whi + 1].input) ++whi;
      if (wlo > lo || whi < hi)
        std::fprintf(stderr, "hvdb-ingest: frame %d is made with frames %d..%d around it, not %d..%d "
                             "(a frame next to it timed out)\n", next, wlo, whi, lo, hi);
      Taken* t = take(std::move(fr));
      t->job = true;
      t->wlo = wlo;
      t->whi = whi;
      for (int j = wlo; j <= whi; ++j) {
        t->window.push_back(slots[j].input);
        t->landed = std::max(t->landed, slots[j].landed);
      }
      t->load_ms = centre.load_ms;
      if (follow.verbose) {
        std::printf("frame %d: taken %.0f ms after its last file landed\n", next, 1000 * (RealtimeNowS() - t->landed));
        std::fflush(stdout);
      }
      ++jobs;
      out.max_in_flight = std::max(out.max_in_flight, jobs);
      workers.Add(taken.back());
    }
    ++next;
    out.max_behind = std::max(out.max_behind, behind(next));
    // Frames no later window needs are dropped (a frame being prepared holds its own).
    for (auto it = slots.begin(); it != slots.end() && it->first < next - radius;) it = slots.erase(it);
    status_line(next, "");
  }
  out.max_behind = std::max(out.max_behind, behind(next));
  report.seconds = std::chrono::duration<double>(Clock::now() - t_start).count();
  report.peak_rss_mb = PeakRssMb();
  return out;
}

}  // namespace hvdb::ingest
