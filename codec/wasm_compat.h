// Force-included into the WebAssembly build of the decoder (codec/wasm.cmake): Debian 12's
// emscripten (3.1.6) ships a libc++ without std::bit_cast, which storage/coding.h uses.
#ifndef HVDB_CODEC_WASM_COMPAT_H_
#define HVDB_CODEC_WASM_COMPAT_H_

#include <bit>

#if defined(__EMSCRIPTEN__) && !defined(__cpp_lib_bit_cast)
namespace std {
template <class To, class From>
constexpr To bit_cast(const From& from) noexcept {
  return __builtin_bit_cast(To, from);
}
}  // namespace std
#endif

#endif  // HVDB_CODEC_WASM_COMPAT_H_
