// libFuzzer target for formats/gaussians.h: any bytes go to DetectGaussianFormat and to every
// reader (3DGS PLY, .splat, SPZ, GLB, and the detecting ReadGaussians). A read either fails with an
// error or gives a cloud that passes ValidateGaussianCloud, which every writer then writes back
// and the matching reader reads again; never a crash, a hang, a leak or an allocation beyond
// what the bytes declare and hold. scripts/test.sh runs it on tests/formats/gaussian_fuzz_corpus.
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>

#include "formats/gaussians.h"

namespace {

using hvdb::formats::GaussianCloud;

void WriteBack(const GaussianCloud& c) {
  namespace f = hvdb::formats;
  if (!f::ValidateGaussianCloud(c, "fuzz").ok()) __builtin_trap();
  auto ply = f::WriteGaussianPly(c, "fuzz");
  if (!ply.ok()) __builtin_trap();  // a valid cloud always has a PLY
  auto again = f::ReadGaussianPly(*ply, "fuzz");
  if (!again.ok() || again->size() != c.size()) __builtin_trap();
  auto splat = f::WriteSplat(c, "fuzz");  // may refuse: a log scale beyond float's exp
  if (splat.ok() && !f::ReadSplat(*splat, "fuzz").ok()) __builtin_trap();
  for (int version : {3, 4}) {
    f::SpzWriteOptions options;
    options.version = version;
    auto spz = f::WriteSpz(c, "fuzz", options);  // may refuse: no splats, positions beyond 2^23
    if (spz.ok()) {
      auto back = f::ReadSpz(*spz, "fuzz");
      if (!back.ok() || back->size() != c.size()) __builtin_trap();
    }
  }
  auto glb = f::WriteGlb(c, "fuzz");  // may refuse: no splats, a log scale beyond float's exp
  if (glb.ok()) {
    auto back = f::ReadGlb(*glb, "fuzz");
    if (!back.ok() || back->size() != c.size()) __builtin_trap();
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  namespace f = hvdb::formats;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  (void)f::GaussianFormatName(f::DetectGaussianFormat(bytes));
  for (auto read : {&f::ReadGaussianPly, &f::ReadSplat, &f::ReadSpz, &f::ReadGlb,
                    &f::ReadGaussians}) {
    auto cloud = read(bytes, "fuzz");
    if (cloud.ok()) WriteBack(*cloud);
  }
  return 0;
}
