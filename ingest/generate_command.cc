// hvdb-ingest generate OUT: a synthetic structured-light stereo recording with ground truth
// (ingest/generator.h); hvdb-ingest replay SRC OUT: a recording written again frame by frame
// at a capture rate (ingest/live.h), to rehearse live ingest with real data.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <string>

#include "ingest/commands.h"
#include "ingest/generator.h"
#include "ingest/live.h"

namespace hvdb::ingest {

namespace {

struct GenerateArgs {
  std::string out;
  GeneratorOptions options;
  bool no_distortion = false;
  bool quiet = false;
};

void RunGenerate(const GenerateArgs& args) {
  GeneratorOptions options = args.options;
  options.distortion = !args.no_distortion;
  if (Status st = options.Validate(); !st.ok()) {
    std::fprintf(stderr, "hvdb-ingest: %s\n", st.ToString().c_str());
    throw CLI::RuntimeError(2);  // a usage error, as in hvdb
  }
  const auto start = std::chrono::steady_clock::now();
  // One self-overwriting line on a terminal, one line per frame into a log.
  const bool show = !args.quiet, tty = ::isatty(2) != 0;
  auto progress = [&](int done, int total) {
    if (!show) return;
    std::fprintf(stderr, tty ? "\rgenerate: frame %d/%d" : "generate: frame %d/%d\n", done, total);
    if (tty && done == total) std::fprintf(stderr, "\n");
    std::fflush(stderr);
  };
  Result<GeneratedRecording> rec = GenerateRecording(options, args.out, progress);
  if (!rec.ok()) {
    if (show && tty) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "hvdb-ingest: %s\n", rec.status().ToString().c_str());
    throw CLI::RuntimeError(rec.status().IsInvalidArgument() ? 2 : 1);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("wrote %s: %d frames at %g fps, %zu bricks, %zu cameras of %dx%d, ground truth in "
              "%s/groundtruth (%.1f s)\n",
              args.out.c_str(), rec->frames, rec->fps, rec->calibration.bricks.size(),
              rec->calibration.cameras.size(), options.width, options.height, args.out.c_str(),
              seconds);
}

}  // namespace

void RegisterGenerateCommand(CLI::App& app) {
  auto args = std::make_shared<GenerateArgs>();
  CLI::App* cmd = app.add_subcommand(
      "generate",
      "Write a synthetic structured-light stereo recording (bricks of two grey cameras, a colour "
      "camera and a random-stripe projector around a ray-cast scene) with ground-truth depth "
      "(groundtruth/NNNNNN/<camera>.depth.exr) and object ids into OUT");
  cmd->add_option("OUT", args->out, "output directory; must be empty or absent")->required();
  GeneratorOptions& o = args->options;
  cmd->add_option("--bricks", o.bricks, "bricks on an arc around the scene (1..16)")
      ->capture_default_str();
  cmd->add_option("--frames", o.frames, "frames to generate (1..100000)")->capture_default_str();
  cmd->add_option("--width", o.width, "image width of every camera (16..4096)")
      ->capture_default_str();
  cmd->add_option("--height", o.height, "image height of every camera (16..4096)")
      ->capture_default_str();
  cmd->add_option("--seed", o.seed, "random seed: scene jitter, rig, stripe patterns, noise")
      ->capture_default_str();
  cmd->add_option("--fps", o.fps, "frames per second (the moving box moves 0.4 m/s)")
      ->capture_default_str();
  cmd->add_flag("--no-distortion", args->no_distortion,
                "pinhole cameras without lens distortion");
  cmd->add_option("--supersample", o.supersample, "rays per pixel and axis, for antialiasing (1..8)")
      ->capture_default_str();
  cmd->add_option("--noise", o.noise_sigma, "Gaussian sensor noise sigma in grey levels (0..64)")
      ->capture_default_str();
  cmd->add_option("--baseline", o.baseline, "metres between a brick's grey cameras (0.01..1)")
      ->capture_default_str();
  cmd->add_option("--realtime", o.realtime_fps,
                  "write the frames one by one at this rate, as a capture would, to rehearse "
                  "`run --follow`: recording.yml and calibration.yml first, then each frame's "
                  "images under temporary names renamed into place at start + frame / FPS (later "
                  "if rendering is slower); 0: as fast as possible")
      ->capture_default_str();
  cmd->add_flag("--quiet", args->quiet, "no progress line");
  cmd->callback([args] { RunGenerate(*args); });
}

void RegisterReplayCommand(CLI::App& app) {
  struct Args {
    std::string src, out;
    ReplayOptions o;
    bool quiet = false;
  };
  auto a = std::make_shared<Args>();
  CLI::App* cmd = app.add_subcommand(
      "replay",
      "Write an existing recording (stereo, depth or PLY; its files may live elsewhere) into the "
      "new directory OUT frame by frame at a capture rate, to rehearse `run --follow` with real "
      "data: recording.yml and calibration.yml first, then each frame's files copied under "
      "temporary names and renamed into place (layout frames/NNNNNN/<camera>.<role>.<ext>)");
  cmd->add_option("SRC", a->src, "recording directory to replay")->required();
  cmd->add_option("OUT", a->out, "output directory; must be empty or absent")->required();
  cmd->add_option("--realtime", a->o.fps, "frames per second (0: as fast as possible)")
      ->required()->check(CLI::Range(0.0, 1000.0));
  cmd->add_option("--loop", a->o.loop, "play the recording this many times (frame numbers go on)")
      ->capture_default_str()->check(CLI::Range(1, 100000));
  cmd->add_option("--count", a->o.count, "only the first COUNT frames of SRC (-1: all)")
      ->capture_default_str();
  cmd->add_flag("--quiet", a->quiet, "no progress line");
  cmd->callback([a] {
    const bool tty = ::isatty(2) != 0;
    auto progress = [&](int done, int total, double late) {
      if (a->quiet) return;
      std::fprintf(stderr, tty ? "\rreplay: frame %d/%d (%.0f ms late)   " : "replay: frame %d/%d (%.0f ms late)\n",
                   done, total, 1000 * late);
      if (tty && done == total) std::fprintf(stderr, "\n");
    };
    auto r = ReplayRecording(a->src, a->out, a->o, progress);
    if (!r.ok()) {
      std::fprintf(stderr, "hvdb-ingest: %s\n", r.status().ToString().c_str());
      throw CLI::RuntimeError(r.status().IsInvalidArgument() || r.status().IsNotFound() ? 2 : 1);
    }
    std::printf("replayed %s into %s: %d frames in %.1f s (%d late by more than half a frame, at "
                "most %.0f ms)\n",
                a->src.c_str(), a->out.c_str(), r->frames, r->seconds, r->late, 1000 * r->max_late_s);
  });
}

}  // namespace hvdb::ingest
