// hvdb-ingest: recordings into hvdb datasets (docs/RECORDING.md), and the tools around it.
//
//   hvdb-ingest run REC --dataset NAME (--data DIR | --server HOST:PORT)   the pipeline
//   hvdb-ingest run REC --follow ...              the same on a recording being written (live)
//   hvdb-ingest replay SRC OUT --realtime FPS     write a recording frame by frame at a rate
//   hvdb-ingest check REC                         load every frame, report what is wrong
//   hvdb-ingest calibrate --left IMG... [--right IMG...] --out calibration.yml
//   hvdb-ingest stereo LEFT RIGHT ... --out DISP.pfm                      the matcher alone
//   hvdb-ingest generate OUT ...                  a synthetic recording with ground truth
//   hvdb-ingest submit REC --dataset NAME --server HOST:PORT   the same on a Slurm cluster
//   hvdb-ingest status JOB                        progress of a submitted ingest
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <iostream>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "client/backend.h"
#include "ingest/commands.h"
#include "ingest/live.h"
#include "ingest/pipeline.h"
#include "ingest/recording.h"

namespace hvdb::ingest {
namespace {

std::atomic<bool> g_stop{false};

// Ctrl-C / SIGTERM: finish the frames in hand, then stop; a second one kills (SA_RESETHAND).
void OnStopSignal(int) {
  g_stop = true;
  static const char kMsg[] = "\nhvdb-ingest: stopping after the frames in hand (again to kill)\n";
  ssize_t ignored = ::write(2, kMsg, sizeof kMsg - 1);
  (void)ignored;
}

void InstallStopHandlers() {
  struct sigaction sa {};
  sa.sa_handler = OnStopSignal;
  sa.sa_flags = SA_RESETHAND;  // no SA_RESTART: a wait returns at once to look at the flag
  sigemptyset(&sa.sa_mask);
  ::sigaction(SIGINT, &sa, nullptr);
  ::sigaction(SIGTERM, &sa, nullptr);
}

int Fail(const Status& st) {
  std::cerr << "hvdb-ingest: " << st.ToString() << "\n";
  return st.IsInvalidArgument() || st.IsNotFound() ? 2 : 1;
}

// run --follow: the follower, its JSON report and its summary.
int RunFollow(const std::string& dir, client::Backend& backend, const IngestOptions& o,
              FollowOptions f, bool quiet, const std::string& report_path) {
  if (quiet) f.status_every = 0;
  f.stop = &g_stop;
  InstallStopHandlers();
  auto r = FollowRecording(dir, backend, o, f);
  if (!r.ok()) return Fail(r.status());
  nlohmann::json j = r->ingest.ToJson();
  std::vector<double> lat = r->latency_s;
  std::sort(lat.begin(), lat.end());
  auto pct = [&](double p) { return lat.empty() ? 0.0 : lat[static_cast<size_t>(p * (lat.size() - 1))]; };
  j["timed_out"] = r->timed_out;
  j["interrupted"] = r->interrupted;
  j["max_behind_frames"] = r->max_behind;
  j["max_in_flight"] = r->max_in_flight;
  j["landed_to_committed_s"] = {{"median", pct(0.5)}, {"p90", pct(0.9)}, {"max", pct(1.0)}};
  if (!report_path.empty()) {
    std::ofstream out(report_path);
    out << j.dump(2) << "\n";
    if (!out) return Fail(Status::IOError(report_path + ": cannot write the report"));
  }
  const IngestReport& rep = r->ingest;
  std::printf("followed %s: %d of %d frames handled: %d ingested, %d already present, %d timed out, "
              "%d skipped as bad; %llu points in %.1f s; landed->committed median %.0f ms, p90 %.0f "
              "ms, max %.0f ms; at most %d frames behind%s\n",
              dir.c_str(), static_cast<int>(rep.frames.size()), rep.frames_total, rep.ingested,
              rep.present, r->timed_out, rep.skipped - r->timed_out,
              static_cast<unsigned long long>(rep.points), rep.seconds, 1000 * pct(0.5),
              1000 * pct(0.9), 1000 * pct(1.0), r->max_behind,
              r->interrupted ? " (stopped by a signal)" : "");
  return rep.skipped ? 3 : 0;
}

void RegisterRun(CLI::App& app, int* rc) {
  auto* cmd = app.add_subcommand("run", "Ingest a recording (stereo, depth or PLY) into a dataset");
  struct Args {
    std::string rec, data, server, token, report;
    size_t cache_mb = 256;
    IngestOptions o;
    double y = 0.40, uv = 0.15;
    bool no_photo = false, quiet = false, no_geometric = false, no_photos = false;
    std::string subpixel = "auto", filter = "none";
    bool follow = false;
    int fit_iterations = FitOptions{}.iterations;
    FollowOptions f;
  };
  auto a = std::make_shared<Args>();
  cmd->add_option("recording", a->rec, "recording directory (with recording.yml)")->required();
  cmd->add_option("--dataset", a->o.dataset, "dataset to ingest into (created if missing)")->required();
  cmd->add_option("--data", a->data, "data directory: write it directly (no server)");
  cmd->add_option("--server", a->server,
                  "HOST:PORT of a running hvdb-server to stream into (given a reading server, "
                  "the ingest commits to the writer it names)");
  cmd->add_option("--token", a->token, "access token for the server (read-write role)")
      ->envname("HVDB_TOKEN");
  cmd->add_option("--workers", a->o.workers, "frames processed in parallel (0: all cores; with --follow too, committed in order)")->capture_default_str();
  cmd->add_option("--first", a->o.first, "first recording frame")->capture_default_str();
  cmd->add_option("--count", a->o.count, "frames to ingest (-1: to the end)")->capture_default_str();
  cmd->add_option("--frame-offset", a->o.frame_offset, "dataset frame of recording frame 0")->capture_default_str();
  cmd->add_flag("--skip-bad-frames", a->o.skip_bad_frames, "report bad frames and go on without them");
  cmd->add_flag(
      "--skip-invalid", a->o.skip_invalid,
      "ply: leave out points with a NaN or infinite coordinate and say how many (default: "
      "such a frame is bad)");
  cmd->add_option("--report", a->report, "write the JSON report (per-frame statistics) here");
  cmd->add_option("--depth-out", a->o.depth_out, "write every depth map made as DIR/NNNNNN/<camera>.depth.exr (with --object-strokes also each view's matte, <camera>.alpha.png: check strokes on a few frames first)");
  cmd->add_option("--stride", a->o.stride, "depth: use every n-th pixel in x and y")->capture_default_str();
  cmd->add_option("--min-disparity", a->o.stereo.min_disparity, "stereo: smallest disparity (px)")->capture_default_str();
  cmd->add_option("--num-disparities", a->o.stereo.num_disparities, "stereo: disparities searched")->capture_default_str();
  cmd->add_option("--window", a->o.stereo.window, "stereo: matching window side (odd)")->capture_default_str();
  cmd->add_option("--spacetime", a->o.spacetime,
                  "stereo: frames on either side matched together with each frame (the spacetime "
                  "matcher, thesis 3.4, for projector patterns that change over time); default: "
                  "the recording's `spacetime` (0: single-frame stereo)")
      ->check(CLI::Range(0, 8));
  CLI::Option* subpixel_opt = cmd->add_option("--subpixel", a->subpixel,
                  "stereo: none (integer disparities), parabola (through the costs around the "
                  "winner), lm (Levenberg-Marquardt on disparity and its gradients) or auto: lm "
                  "for a recording under structured light (its recording.yml's structured_light, "
                  "1 by default), else parabola")
      ->capture_default_str()->check(CLI::IsMember({"none", "parabola", "lm", "auto"}));
  cmd->add_option("--filter", a->filter,
                  "none, or billboard: each view's depth as a billboard in its colour camera "
                  "smoothed by the bilateral filter of thesis 6.2 over the frames around and the "
                  "other views; for stereo in place of the LM (then --subpixel defaults to "
                  "parabola), for depth recordings with --billboard-baseline")
      ->capture_default_str()->check(CLI::IsMember({"none", "billboard"}));
  cmd->add_option("--billboard-radius", a->o.billboard.radius,
                  "billboard filter: B-spline support radius in pixels (thesis: 10, 21 x 21)")
      ->capture_default_str()->check(CLI::Range(1, 64));
  cmd->add_option("--billboard-frames", a->o.billboard.temporal_radius,
                  "billboard filter: frames on either side (thesis: 2, 5 frames in all)")
      ->capture_default_str()->check(CLI::Range(0, 16));
  cmd->add_option("--billboard-delta", a->o.billboard.delta_d,
                  "billboard filter: range threshold in disparity pixels (eq. 6.8)")
      ->capture_default_str()->check(CLI::PositiveNumber);
  cmd->add_option("--billboard-baseline", a->o.billboard_baseline,
                  "billboard filter, depth recordings: the depth sensor's baseline in metres (a "
                  "Kinect v1's: 0.075); its disparity space is fx * baseline / z")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--billboard-iterations", a->o.billboard.iterations,
                  "billboard filter: inter-view passes")
      ->capture_default_str()->check(CLI::Range(1, 10));
  cmd->add_option("--object-strokes", a->o.object_strokes,
                  "with --filter billboard: only the object marked in stroke images (PATTERN with "
                  "{camera}, relative to the recording; red on the object, blue on the rest, "
                  "painted on --strokes-frame): each view cut by graph cut and matted (thesis 6.4)");
  cmd->add_option("--strokes-frame", a->o.strokes_frame, "the recording frame the strokes were painted on")
      ->capture_default_str();
  cmd->add_flag("--no-photo-consistency", a->no_photo, "no photo-consistency outlier removal");
  cmd->add_flag("--no-geometric-consistency", a->no_geometric,
                "keep points that other views see through (no cross-view depth test)");
  cmd->add_option("--edge-radius", a->o.edge_radius,
                  "drop depth samples within this many pixels of a depth jump (mixed pixels; 0: keep)")
      ->check(CLI::Range(0, 16))->capture_default_str();
  cmd->add_flag("--no-photos", a->no_photos,
                "do not store the colour images with the points (textured renders need them)");
  cmd->add_flag("--gaussians", a->o.gaussians,
                "fit 3D Gaussian splats (opacity, covariance, SH colour) to each frame's colour "
                "photos, starting from its points, and store them in a Gaussian-splat dataset; "
                "frames in order, each warm-started from the one before and re-fitted where its "
                "photos changed (docs/RECORDING.md, \"Gaussian video\")");
  cmd->add_option("--fit-iterations", a->fit_iterations,
                  "--gaussians: optimisation steps of a frame fitted from its points (the "
                  "densification and SH schedule scale with them)")
      ->check(CLI::Range(1, 1000000))->capture_default_str();
  cmd->add_option("--fit-warm-iterations", a->o.gaussian.warm_iterations,
                  "--gaussians: steps of a frame warm-started from the one before (0: a third of "
                  "--fit-iterations)")
      ->check(CLI::Range(0, 1000000))->capture_default_str();
  cmd->add_option("--fit-sh-degree", a->o.gaussian.fit.sh_degree,
                  "--gaussians: spherical-harmonic degree of the colours (0-3)")
      ->check(CLI::Range(0, 3))->capture_default_str();
  cmd->add_option("--fit-resolution", a->o.gaussian.resolution_scale,
                  "--gaussians: photos fitted at 1/N of their size")
      ->check(CLI::Range(1, 64))->capture_default_str();
  cmd->add_option("--y-threshold", a->y, "photo-consistency: max luminance deviation (0..1)")->capture_default_str();
  cmd->add_option("--uv-threshold", a->uv, "photo-consistency: max chrominance deviation (0..1)")->capture_default_str();
  cmd->add_option("--cache-mb", a->cache_mb, "--data: block cache in MiB")->capture_default_str();
  cmd->add_flag("--quiet", a->quiet, "no progress bar (with --follow: no status lines)");
  cmd->add_flag("--follow", a->follow,
                "live: ingest the recording while it is being written (REC and its files may not "
                "exist yet). Frames are taken in order, each when all its files are complete "
                "(PNG: IEND chunk, JPEG: EOI marker, EXR: every scanline, binary PLY: every "
                "element; pose: 16 numbers and a newline; other files: closed by the writer or "
                "unchanged for 0.3 s) and it "
                "decodes; --workers frames are prepared at once and committed in frame order "
                "as soon as they are done; ends when the recording's `frames` are handled, or on "
                "Ctrl-C/SIGTERM after committing the frames in hand, in order (exit 0). "
                "docs/RECORDING.md, \"Live ingest\"");
  cmd->add_option("--frame-timeout", a->f.frame_timeout,
                  "--follow: seconds a frame's files may take to complete, counted from when the "
                  "follower starts waiting for it or, if later, when the frame before it completed "
                  "(no limit before the capture's first file appears); a frame that does not is "
                  "reported with the files it lacks, not committed, and the frames after it are "
                  "still taken (exit code 3)")
      ->capture_default_str()->check(CLI::Range(0.01, 86400.0));
  cmd->add_option("--status-every", a->f.status_every,
                  "--follow: seconds between status lines on stderr (frames handled, how far "
                  "behind the capture, latency)")
      ->capture_default_str()->check(CLI::Range(0.0, 3600.0));
  cmd->add_flag("--verbose", a->f.verbose,
                "--follow: a line per frame on stdout: when it is taken, and when it is "
                "committed with the time from its last file landing");
  cmd->callback([a, rc, subpixel_opt] {
    if (a->data.empty() == a->server.empty()) {
      *rc = Fail(Status::InvalidArgument("give exactly one of --data DIR and --server HOST:PORT"));
      return;
    }
    if (!(a->y > 0 && a->y <= 1 && a->uv > 0 && a->uv <= 1)) {
      *rc = Fail(Status::InvalidArgument("--y-threshold and --uv-threshold must be in (0, 1]"));
      return;
    }
    Result<Recording> rec = a->follow ? Result<Recording>(Recording{}) : OpenRecording(a->rec);
    if (!rec.ok()) {
      *rc = Fail(rec.status());
      return;
    }
    std::unique_ptr<client::Backend> backend;
    if (!a->data.empty()) {
      backend = client::MakeEmbeddedBackend(a->data, a->cache_mb << 20);
    } else {
      client::RemoteOptions ro;
      ro.address = a->server;
      ro.token = a->token;
      ro.follow_leader = true;  // commit to the writer whichever server of a cluster we were given
      auto b = client::MakeRemoteBackend(ro);
      if (!b.ok()) {
        *rc = Fail(b.status());
        return;
      }
      backend = std::move(b).value();
    }
    IngestOptions o = a->o;
    if (a->subpixel == "auto") {
      o.stereo.subpixel = rec->structured_light ? Subpixel::kLevenbergMarquardt : Subpixel::kParabola;
    } else {
      ParseSubpixel(a->subpixel, &o.stereo.subpixel);  // checked by CLI11
    }
    if (a->filter == "billboard") {
      o.filter = IngestOptions::Filter::kBillboard;
      // The filter replaces the LM (thesis 6.5). Its input keeps the parabola's subpixel
      // estimate: integer disparities of a smooth surface are plateaus wider than the kernel,
      // which no smoothing undoes (bench/README.md, "Billboards").
      if (subpixel_opt->count() == 0) o.stereo.subpixel = Subpixel::kParabola;
    }
    o.gaussian.fit = Scheduled(o.gaussian.fit, a->fit_iterations);
    o.photo_consistency = !a->no_photo;
    o.geometric_consistency = !a->no_geometric;
    o.photos = !a->no_photos;
    o.photo.max_dy = a->y;
    o.photo.max_du = o.photo.max_dv = a->uv;
    o.progress = !a->quiet && ::isatty(2);
    if (a->follow) {
      *rc = RunFollow(a->rec, *backend, o, a->f, a->quiet, a->report);
      return;
    }
    auto report = RunIngest(*rec, *backend, o);
    if (!report.ok()) {
      // The report says why (hvdb-ingest status shows it for a Slurm task).
      if (!a->report.empty())
        std::ofstream(a->report) << nlohmann::json{{"error", report.status().ToString()}}.dump(2) << "\n";
      *rc = Fail(report.status());
      return;
    }
    const nlohmann::json j = report->ToJson();
    if (!a->report.empty()) {
      std::ofstream out(a->report);
      out << j.dump(2) << "\n";
      if (!out) {
        *rc = Fail(Status::IOError(a->report + ": cannot write the report"));
        return;
      }
    }
    std::printf("ingested %d frames (%d already present, %d skipped), %llu points in %.1f s: "
                "%.2f frames/s, %.0f points/s, peak memory %.0f MiB\n",
                report->ingested, report->present, report->skipped,
                static_cast<unsigned long long>(report->points), report->seconds,
                j["frames_per_s"].get<double>(), j["points_per_s"].get<double>(), report->peak_rss_mb);
    if (report->skipped_invalid > 0) {
      int frames = 0;
      for (const FrameReport& f : report->frames) frames += f.skipped_invalid > 0;
      std::fprintf(
          stderr,
          "hvdb-ingest: skipped %llu points with a NaN or infinite coordinate in %d frame%s\n",
          static_cast<unsigned long long>(report->skipped_invalid), frames, frames == 1 ? "" : "s");
    }
    *rc = report->skipped ? 3 : 0;
  });
}

void RegisterCheck(CLI::App& app, int* rc) {
  auto* cmd = app.add_subcommand("check", "Load every frame of a recording and report what is wrong");
  auto rec_dir = std::make_shared<std::string>();
  cmd->add_option("recording", *rec_dir, "recording directory")->required();
  cmd->callback([rec_dir, rc] {
    auto rec = OpenRecording(*rec_dir);
    if (!rec.ok()) {
      *rc = Fail(rec.status());
      return;
    }
    int bad = 0;
    for (int i = 0; i < rec->frames; ++i) {
      auto f = LoadFrame(*rec, i);
      if (!f.ok()) {
        std::printf("frame %d: %s\n", i, f.status().ToString().c_str());
        ++bad;
      }
    }
    std::printf("%d frames, %d bad\n", rec->frames, bad);
    *rc = bad ? 1 : 0;
  });
}

void RegisterCalibrate(CLI::App& app, int* rc) {
  auto* cmd = app.add_subcommand(
      "calibrate", "Calibrate a camera or a stereo pair from checkerboard images (OpenCV)");
  struct Args {
    std::vector<std::string> left, right;
    std::string out, pattern = "9x6";
    CheckerboardOptions o;
  };
  auto a = std::make_shared<Args>();
  cmd->add_option("--left", a->left, "images of the (left) camera")->required();
  cmd->add_option("--right", a->right, "images of the right camera, same order (stereo)");
  cmd->add_option("--pattern", a->pattern, "inner corners, COLSxROWS")->capture_default_str();
  cmd->add_option("--square", a->o.square, "square side in metres")->capture_default_str();
  cmd->add_option("--left-name", a->o.left_name, "camera name in the YAML")->capture_default_str();
  cmd->add_option("--right-name", a->o.right_name, "camera name in the YAML")->capture_default_str();
  cmd->add_option("--out", a->out, "calibration YAML to write")->required();
  cmd->callback([a, rc] {
    int w = 0, h = 0;
    if (std::sscanf(a->pattern.c_str(), "%dx%d", &w, &h) != 2) {
      *rc = Fail(Status::InvalidArgument("--pattern must look like 9x6"));
      return;
    }
    a->o.pattern = {w, h};
    auto r = CalibrateCheckerboard(a->left, a->right, a->o);
    if (!r.ok()) {
      *rc = Fail(r.status());
      return;
    }
    for (const auto& s : r->skipped) std::printf("skipped %s\n", s.c_str());
    Status st = SaveCalibration(r->calibration, a->out);
    if (!st.ok()) {
      *rc = Fail(st);
      return;
    }
    std::printf("%zu views used; reprojection error (sigma_C): left %.3f px", r->used.size(), r->left_rms);
    if (!a->right.empty()) {
      const auto& rc2 = r->calibration.cameras[1];
      std::printf(", right %.3f px, stereo %.3f px; baseline %.4f m", r->right_rms, r->stereo_rms,
                  cv::norm(rc2.T));
    }
    std::printf("\nwrote %s\n", a->out.c_str());
    *rc = 0;
  });
}

}  // namespace
}  // namespace hvdb::ingest

int main(int argc, char** argv) {
  CLI::App app{"hvdb-ingest: turn recordings (stereo on structured light, depth, PLY) into hvdb "
               "datasets. Formats: docs/RECORDING.md."};
  app.require_subcommand(1);
  int rc = 0;
  hvdb::ingest::RegisterRun(app, &rc);
  hvdb::ingest::RegisterCheck(app, &rc);
  hvdb::ingest::RegisterCalibrate(app, &rc);
  hvdb::ingest::RegisterStereoCommand(app);
  hvdb::ingest::RegisterGenerateCommand(app);
  hvdb::ingest::RegisterReplayCommand(app);
  hvdb::ingest::RegisterSlurmCommands(app, &rc);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  return rc;
}
