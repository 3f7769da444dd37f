// Eight-lane float vectors for the CPU splatter's inner loops (internal to render/).
//
// GCC/Clang vector extensions rather than intrinsics: the same source compiles to AVX2 in the
// clone built for x86-64-v3 and to pairs of SSE2 operations in the baseline clone (see
// HVDB_RENDER_CLONES), and to plain code elsewhere. No library in Debian offers a vectorised
// exp we could inline into these loops (libmvec needs -ffast-math), hence Exp() below.
#ifndef HVDB_RENDER_SIMD_H_
#define HVDB_RENDER_SIMD_H_

#include <cstdint>
#include <cstring>

// The helpers below pass vectors by value; they are always inlined. (Their includer silences
// GCC's -Wpsabi note about that for the non-AVX clone.)
namespace hvdb::render::internal {

typedef float F8 __attribute__((vector_size(32)));
typedef int32_t I8 __attribute__((vector_size(32)));

template <typename F>
struct VecTraits;
template <>
struct VecTraits<F8> {
  using I = I8;
  static constexpr int kLanes = 8;
  static constexpr F8 kIota = {0, 1, 2, 3, 4, 5, 6, 7};
};

#define HVDB_SIMD_INLINE inline __attribute__((always_inline))
// For lambdas called in the hot loops: inlined into the caller's clone (see below).
#define HVDB_SIMD_LAMBDA __attribute__((always_inline))

// The hot functions are built three times, for AVX-512, for AVX2+FMA and for the x86-64
// baseline, and the loader picks one for the CPU it runs on (GNU ifunc): packages run on any
// x86-64 and still use the wide units where there are some.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && defined(__OPTIMIZE__) && \
    !defined(__SANITIZE_ADDRESS__)
#define HVDB_RENDER_CLONES \
  __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define HVDB_RENDER_CLONES
#endif

template <typename F>
HVDB_SIMD_INLINE F Broadcast(float v) {
  return F{} + v;
}
template <typename F>
HVDB_SIMD_INLINE F Load(const float* p) {
  F v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
template <typename F>
HVDB_SIMD_INLINE void Store(float* p, F v) {
  std::memcpy(p, &v, sizeof v);
}
template <typename F>
HVDB_SIMD_INLINE F Min(F a, F b) {
  return a < b ? a : b;
}
template <typename F>
HVDB_SIMD_INLINE F Max(F a, F b) {
  return a > b ? a : b;
}
template <typename F, typename I>
HVDB_SIMD_INLINE F Select(I mask, F a, F b) {
  return mask ? a : b;
}
// True when any lane is set. The halves are OR-ed in registers: a memcmp against zero made GCC
// spill the mask to the stack and reload it in 8-byte pieces (a store-forwarding stall on
// every early-out test: ~13 % of the visibility pass's time at 1080p).
HVDB_SIMD_INLINE bool Any(I8 mask) {
  typedef int32_t I4 __attribute__((vector_size(16)));
  const I4 lo = __builtin_shufflevector(mask, mask, 0, 1, 2, 3);
  const I4 hi = __builtin_shufflevector(mask, mask, 4, 5, 6, 7);
  const I4 both = lo | hi;
  uint64_t a, b;
  std::memcpy(&a, &both, 8);
  std::memcpy(&b, reinterpret_cast<const char*>(&both) + 8, 8);
  return (a | b) != 0;
}

// e^x for x <= 0 (the kernel exp(-q/2)), lane by lane: Cephes' expf (range reduction by
// ln 2 in two parts, degree-5 polynomial), relative error below 2e-7 — std::exp's result to
// within a unit or two of the last place, so images match the scalar renderer. Arguments
// below -87 give e^-87 (the kernel is cut off long before that).
template <typename F>
HVDB_SIMD_INLINE F Exp(F x) {
  using I = typename VecTraits<F>::I;
  x = Max(x, Broadcast<F>(-87.0f));
  F fx = x * 1.44269504088896341f + 0.5f;
  I n = __builtin_convertvector(fx, I);  // truncates towards zero
  F fn = __builtin_convertvector(n, F);
  fn = Select(fn > fx, fn - 1.0f, fn);  // floor
  n = __builtin_convertvector(fn, I);
  x = x - fn * 0.693359375f;
  x = x - fn * -2.12194440e-4f;
  F z = x * x;
  F y = Broadcast<F>(1.9875691500e-4f);
  y = y * x + 1.3981999507e-3f;
  y = y * x + 8.3334519073e-3f;
  y = y * x + 4.1665795894e-2f;
  y = y * x + 1.6666665459e-1f;
  y = y * x + 5.0000001201e-1f;
  y = y * z + x + 1.0f;
  I bits = (n + 127) << 23;  // 2^n
  F scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return y * scale;
}

}  // namespace hvdb::render::internal

#endif  // HVDB_RENDER_SIMD_H_
