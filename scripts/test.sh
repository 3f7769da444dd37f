#!/usr/bin/env bash
# Runs every test: set-up (packages + warnings-as-errors build), the full CTest suite, then
# the storage tests again under AddressSanitizer + UndefinedBehaviorSanitizer.
set -euo pipefail
cd "$(dirname "$0")/.."

bash scripts/setup.sh
ctest --test-dir build --output-on-failure -j2 --timeout 900

# Sanitizers: a separate Debug build of the storage tests.
cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=Debug -DHVDB_SANITIZE=ON -DHVDB_WERROR=ON \
  -DHVDB_BUILD_BENCH=OFF >/dev/null
cmake --build build-asan --target storage_tests
ASAN_OPTIONS=detect_leaks=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir build-asan --output-on-failure -j2 --timeout 900 -R '^(Crc32c|Point|BufferPool|Lod|KdTree|Hyperslice|Wal|Dataset|Crash|Corruption)'
