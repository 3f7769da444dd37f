// libFuzzer target for import-media's decoders (media/media.h): images (PNG and JPEG row by
// row, PGM/PPM, the rest through libavcodec), videos (libavformat/libavcodec from memory) and
// meshes (our checks of the declared structure, then assimp: OBJ, PLY, STL, OFF, glTF, GLB).
// Any bytes must give a result or an error, never a crash, a hang, a read of a file other than
// the input, or an allocation past the job's budget. The first byte picks the decoder and the
// format the client would have named. scripts/test.sh runs it on
// tests/media/import_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>

#include "media/media.h"

namespace {

const char* const kMeshFormats[] = {"obj", "ply", "stl", "off", "gltf", "glb", "", "fbx"};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  using namespace hvdb;
  // The budget a small server would give a job: what a decoder asks for past it is refused.
  static JobBudget memory(256u << 20, "--memory-budget");
  JobLimits limits;
  limits.memory = &memory;
  limits.max_seconds = 10;
  JobLease lease = limits.Lease();
  const media::Budget budget{&limits, &lease};
  const std::string_view bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  const uint8_t pick = data[0];
  switch (pick % 3) {
    case 0: {
      auto pic = media::DecodeImage(bytes, (pick & 8) ? "png" : "", 64, budget);
      if (pic.ok() && (pic->width <= 0 || pic->height <= 0 ||
                       pic->rgba.size() != size_t(pic->width) * pic->height * 4)) {
        __builtin_trap();
      }
      break;
    }
    case 1: {
      auto frames = media::DecodeVideo(bytes, "", 4, 32, 1u << 16, budget);
      if (frames.ok() && (frames->empty() || frames->size() > 4)) __builtin_trap();
      break;
    }
    default: {
      const std::string format = kMeshFormats[(pick >> 2) % 8];
      auto pts = media::SampleMesh(bytes, format, media::Placement{}, 0.05, 0, budget);
      if (pts.ok() && pts->empty()) __builtin_trap();
      break;
    }
  }
  return 0;
}
