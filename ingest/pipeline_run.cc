// RunIngest: a recording's frames on worker threads, each prepared and committed by the
// worker that took it (ingest/pipeline.h), with a progress bar and the run's report.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <deque>
#include <mutex>
#include <thread>

#include "ingest/pipeline.h"

namespace hvdb::ingest {

namespace {

using Clock = std::chrono::steady_clock;

// The run's one status line on stderr: the frame bar, and while a frame's Gaussians are fitted
// (on a worker), that fit's iteration, so that neither overwrites the other.
class ProgressLine {
 public:
  void Frames(int done, int total, double secs, bool final) {
    std::lock_guard<std::mutex> l(mu_);
    done_ = done;
    total_ = total;
    secs_ = secs;
    if (final) fit_total_ = 0;
    Draw();
    if (final) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  }
  void Fit(int step, int total) {
    if (step % 10 != 0 && step != total) return;
    std::lock_guard<std::mutex> l(mu_);
    fit_step_ = step;
    fit_total_ = step == total ? 0 : total;  // a finished fit leaves the line
    Draw();
    std::fflush(stderr);
  }

 private:
  void Draw() {
    const int width = 30;
    const int fill = total_ ? done_ * width / total_ : width;
    const double fps = secs_ > 0 ? done_ / secs_ : 0;
    const double eta = fps > 0 ? (total_ - done_) / fps : 0;
    char fit[64] = "";
    if (fit_total_ > 0) {
      std::snprintf(fit, sizeof fit, "  fitting Gaussians %d/%d", fit_step_, fit_total_);
    }
    char line[192];
    const int n =
        std::snprintf(line, sizeof line, "[%.*s%.*s] %d/%d frames  %.2f frames/s  ETA %.0f s%s",
                      fill, "==============================", width - fill,
                      "                              ", done_, total_, fps, eta, fit);
    // Spaces over what a longer line before left on the terminal.
    std::fprintf(stderr, "\r%s%*s", line, std::max(0, shown_ - n), "");
    shown_ = n;
  }
  std::mutex mu_;
  int done_ = 0, total_ = 0, fit_step_ = 0, fit_total_ = 0, shown_ = 0;
  double secs_ = 0;
};

}  // namespace

Result<IngestReport> RunIngest(const Recording& rec, client::Backend& backend,
                               const IngestOptions& options_in) {
  IngestOptions opt = options_in;
  if (opt.dataset.empty()) return Status::InvalidArgument("no dataset given");
  if (opt.first < 0 || opt.first >= rec.frames)
    return Status::InvalidArgument("--first " + std::to_string(opt.first) +
                                   " is outside the recording's frames 0.." +
                                   std::to_string(rec.frames - 1));
  const int last = opt.count < 0 ? rec.frames : std::min(rec.frames, opt.first + opt.count);
  // By default no more workers than frames: a single frame's stages (stereo, photo-consistency)
  // then get the cores an idle worker would hold (the 8-camera SJTU frame: 2x on two cores).
  if (opt.workers <= 0) opt.workers = std::clamp(last - opt.first, 1, HardwareThreads());
  // Gaussians: frames in order, each warm-started from the one before; the fit takes every
  // core, so one worker.
  if (opt.gaussians) opt.workers = 1;
  if (opt.max_in_flight <= 0) opt.max_in_flight = opt.workers + 1;
  if (opt.stereo.threads <= 0) opt.stereo.threads = std::max(1, HardwareThreads() / opt.workers);
  // Options are checked (and strokes read) before anything is created.
  HVDB_ASSIGN_OR_RETURN(FrameProcessor proc, FrameProcessor::Make(rec, opt));
  HVDB_RETURN_IF_ERROR(EnsureDataset(backend, rec, opt.dataset, opt.gaussians));

  const auto t_start = Clock::now();
  IngestReport report;
  report.frames_total = last - opt.first;
  std::vector<FrameReport> reports(static_cast<size_t>(report.frames_total));
  // Resume: which frames are already in the dataset (each got there in one atomic bulk load).
  std::vector<int> pending;
  for (int i = opt.first; i < last; ++i) {
    FrameReport& fr = reports[static_cast<size_t>(i - opt.first)];
    fr.frame = i;
    fr.dataset_frame = opt.frame_offset + static_cast<uint32_t>(i);
    HVDB_ASSIGN_OR_RETURN(bool present,
                          FramePresent(backend, opt.dataset, fr.dataset_frame, rec.fps));
    if (present) {
      fr.status = "present";
      ++report.present;
    } else {
      pending.push_back(i);
    }
  }

  // Each worker prepares a frame and commits it: each frame is one atomic bulk load, so frames
  // go in in any order and a resumed run skips exactly those that are in. Loads into new frames
  // build their trees on the committing thread (Database::BulkLoad), so commits of different
  // frames overlap as their preparation does. A remote backend has one connection: its commits
  // take turns (the server builds the trees). This thread reports.
  const FrameLoader load = [&](int w) -> Result<std::shared_ptr<const FrameInput>> {
    HVDB_ASSIGN_OR_RETURN(FrameInput f, LoadFrame(rec, w, opt.skip_invalid));
    return std::make_shared<const FrameInput>(std::move(f));
  };
  struct Done {
    int index = 0;
    Status prepared, committed;
    uint64_t loaded = 0, bytes = 0;
  };
  std::mutex mu, remote_mu;
  std::condition_variable cv_done;
  std::deque<Done> done;
  std::atomic<size_t> next{0};
  std::atomic<bool> stop{false};
  GaussianFrameOptions fit_options = opt.gaussian;
  ProgressLine line;
  if (opt.progress && !fit_options.fit.progress) {
    fit_options.fit.progress = [&line](int step, int total) { line.Fit(step, total); };
  }
  // A failed frame stops the run: the fit in progress stops with it instead of finishing a
  // frame that would not be committed.
  fit_options.fit.cancelled = [&stop] { return stop.load(); };
  GaussianVideoFitter fitter(fit_options);
  const bool one_connection = backend.remote();
  auto worker = [&] {
    while (!stop) {
      const size_t k = next++;
      if (k >= pending.size()) return;
      const int i = pending[k];
      FrameReport& fr = reports[static_cast<size_t>(i - opt.first)];
      // With the spacetime matcher or the billboard filter, the frames on either side too
      // (within the recording).
      const int st = proc.window_radius();
      PreparedFrame d = PrepareFrame(rec, proc, opt, i, std::max(0, i - st),
                                     std::min(rec.frames - 1, i + st), load, &fr);
      if (opt.gaussians && d.status.ok() && !stop) FitPreparedFrame(fitter, &d, &fr);
      Done r;
      r.index = i;
      r.prepared = d.status;
      r.bytes = d.bytes;
      if (d.status.ok() && !stop) {
        std::unique_lock<std::mutex> turn(remote_mu, std::defer_lock);
        if (one_connection) turn.lock();
        auto loaded = CommitFrame(backend, opt, std::move(d), &fr);
        if (loaded.ok()) {
          r.loaded = *loaded;
        } else {
          r.committed = loaded.status();
        }
      } else if (d.status.ok()) {
        continue;  // stopping: not committed, not reported
      }
      std::lock_guard lk(mu);
      done.push_back(std::move(r));
      cv_done.notify_all();
    }
  };
  std::vector<std::thread> threads;
  for (int w = 0; w < opt.workers; ++w) threads.emplace_back(worker);

  Status failure;
  size_t handled = 0;
  const int total = static_cast<int>(pending.size());
  if (opt.progress) line.Frames(0, total, 0, false);
  while (handled < pending.size()) {
    Done r;
    {
      std::unique_lock lk(mu);
      cv_done.wait(lk, [&] { return !done.empty(); });
      r = std::move(done.front());
      done.pop_front();
    }
    FrameReport& fr = reports[static_cast<size_t>(r.index - opt.first)];
    if (!r.prepared.ok()) {
      fr.status = "skipped";
      fr.error = r.prepared.ToString();
      if (!opt.skip_bad_frames) {
        failure = Status(r.prepared.code(), "frame " + std::to_string(r.index) + ": " +
                                                r.prepared.message() +
                                                " (--skip-bad-frames goes on without it)");
      } else {
        ++report.skipped;
        if (opt.progress)
          std::fprintf(stderr, "\nskipped frame %d: %s\n", r.index, fr.error.c_str());
      }
    } else if (!r.committed.ok()) {
      failure = Status(r.committed.code(),
                       "frame " + std::to_string(r.index) + ": commit: " + r.committed.message());
    } else {
      ++report.ingested;
      report.points += r.loaded;
      report.skipped_invalid += fr.skipped_invalid;
      report.bytes_read += r.bytes;
    }
    ++handled;
    if (opt.progress) line.Frames(static_cast<int>(handled), total, MsSince(t_start) / 1000, false);
    if (!failure.ok()) break;
  }
  stop = true;
  for (auto& t : threads) t.join();
  if (opt.progress) line.Frames(static_cast<int>(handled), total, MsSince(t_start) / 1000, true);
  if (!failure.ok()) return failure;
  report.seconds = MsSince(t_start) / 1000;
  report.peak_rss_mb = PeakRssMb();
  report.frames = std::move(reports);
  return report;
}

}  // namespace hvdb::ingest
