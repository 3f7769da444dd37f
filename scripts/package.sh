#!/usr/bin/env bash
# Builds the Debian package of hvdb (CPack, packaging/CMakeLists.txt) from the build in build/
# (run scripts/setup.sh first, or let this do it with --setup) and prints its path.
#   bash scripts/package.sh [--setup]
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${HVDB_BUILD_DIR:-build}
if [ "${1:-}" = "--setup" ]; then bash scripts/setup.sh --all; fi
if [ ! -f "$BUILD_DIR/CPackConfig.cmake" ]; then
  echo "package: $BUILD_DIR is not configured; run scripts/setup.sh --all (or pass --setup)" >&2
  exit 1
fi
cmake --build "$BUILD_DIR" >/dev/null
out="$BUILD_DIR/package"
mkdir -p "$out"
(cd "$BUILD_DIR" && cpack -G DEB -B "$(pwd)/package" >/dev/null 2>&1) || {
  echo "package: cpack failed; rerun by hand: (cd $BUILD_DIR && cpack -G DEB -B package)" >&2
  exit 1
}
deb=$(ls -t "$out"/hvdb_*_amd64.deb | head -n 1)
echo "$deb"
