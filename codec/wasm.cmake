# The web page's hvdb7 decoder (web/src/hvdb7_worker.js): the codec library's own sources,
# compiled to WebAssembly by Debian's emscripten, so that a change to codec/ reaches the
# browser without a second decoder to keep in step. Outputs web/wasm/hvdb7.{js,wasm} in the
# build tree and copies them into the source tree's web/ (what hvdb-server --http serves for
# a binary of this build tree; git ignores them); the package installs them from the build tree.
find_program(HVDB_EMCC emcc)
if(NOT HVDB_EMCC)
  message(FATAL_ERROR "emcc (emscripten) is missing: the web page's hvdb7 decoder is compiled "
                      "with it. Run scripts/setup.sh (it installs Debian's emscripten).")
endif()

# The same source list as hvdb_codec (new codec files come along), plus what codec/ takes
# from storage/: Status, Point, little-endian coding and CRC-32C.
get_target_property(_wasm_codec_sources hvdb_codec SOURCES)
set(_wasm_sources ${CMAKE_CURRENT_SOURCE_DIR}/wasm_decoder.cc)
foreach(_s IN LISTS _wasm_codec_sources)
  if(NOT IS_ABSOLUTE ${_s})
    set(_s ${CMAKE_CURRENT_SOURCE_DIR}/${_s})
  endif()
  list(APPEND _wasm_sources ${_s})
endforeach()
list(APPEND _wasm_sources ${CMAKE_SOURCE_DIR}/storage/status.cc
  ${CMAKE_SOURCE_DIR}/storage/crc32c.cc ${CMAKE_SOURCE_DIR}/storage/point.cc)
file(GLOB _wasm_headers CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/*.h
  ${CMAKE_SOURCE_DIR}/storage/*.h)

# Only the header-only libraries it needs on emcc's include path: all of /usr/include would
# put the host's C library in front of emscripten's.
set(_wasm_inc ${CMAKE_CURRENT_BINARY_DIR}/wasm-include)
file(MAKE_DIRECTORY ${_wasm_inc})
find_path(_wasm_nanoflann_dir nanoflann.hpp HINTS ${_codec_nanoflann_inc} REQUIRED)
file(CREATE_LINK ${_wasm_nanoflann_dir}/nanoflann.hpp ${_wasm_inc}/nanoflann.hpp SYMBOLIC)
file(CREATE_LINK ${Boost_INCLUDE_DIRS}/boost ${_wasm_inc}/boost SYMBOLIC)

set(_wasm_out ${CMAKE_BINARY_DIR}/web/wasm)
set(HVDB7_WASM_FILES ${_wasm_out}/hvdb7.js ${_wasm_out}/hvdb7.wasm CACHE INTERNAL "")
set(_wasm_exports "['_hvdb7_buffer','_hvdb7_decode','_hvdb7_error']")
add_custom_command(
  OUTPUT ${_wasm_out}/hvdb7.js ${_wasm_out}/hvdb7.wasm
  COMMAND ${CMAKE_COMMAND} -E make_directory ${_wasm_out}
  # NODE_PATH: emcc's JavaScript optimiser needs Debian's node-acorn, which a node from
  # outside Debian does not find on its own.
  COMMAND ${CMAKE_COMMAND} -E env NODE_PATH=/usr/share/nodejs
          ${HVDB_EMCC} -std=c++20 -O3 -DNDEBUG -include ${CMAKE_CURRENT_SOURCE_DIR}/wasm_compat.h
          -I${CMAKE_SOURCE_DIR} -isystem ${_wasm_inc} ${_wasm_sources}
          -sALLOW_MEMORY_GROWTH=1 -sMODULARIZE=1 -sEXPORT_ES6=1 -sENVIRONMENT=worker
          -sEXPORT_NAME=createHvdb7 -sEXPORTED_FUNCTIONS=${_wasm_exports}
          -o ${_wasm_out}/hvdb7.js
  COMMAND ${CMAKE_COMMAND} -E make_directory ${CMAKE_SOURCE_DIR}/web/wasm
  COMMAND ${CMAKE_COMMAND} -E copy_if_different ${_wasm_out}/hvdb7.js ${_wasm_out}/hvdb7.wasm
          ${CMAKE_SOURCE_DIR}/web/wasm/
  DEPENDS ${_wasm_sources} ${_wasm_headers} ${CMAKE_CURRENT_SOURCE_DIR}/wasm_compat.h
  COMMENT "emcc: the web page's hvdb7 decoder (web/wasm/hvdb7.wasm)"
  VERBATIM)
add_custom_target(hvdb7_wasm ALL DEPENDS ${_wasm_out}/hvdb7.js ${_wasm_out}/hvdb7.wasm)
