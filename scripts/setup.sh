#!/usr/bin/env bash
# Installs hvdb's build and test dependencies from Debian 12 packages and builds everything
# (Release, Ninja, warnings as errors) into build/. Idempotent; run as root.
set -euo pipefail
cd "$(dirname "$0")/.."

PACKAGES=(
  build-essential cmake ninja-build pkg-config git
  libboost-dev libboost-system-dev libboost-program-options-dev libboost-graph-dev
  libflann-dev libopencv-dev libceres-dev libdraco-dev libopenexr-dev libglm-dev
  libegl-dev libgl-dev libegl-mesa0 libgl1-mesa-dri
  libgtest-dev libgmock-dev libbenchmark-dev
  libprotobuf-dev protobuf-compiler
  nlohmann-json3-dev libcli11-dev
  libspatialindex-dev libnanoflann-dev libpcl-dev python3-matplotlib
  clang libclang-rt-14-dev liburing-dev
  python3 python3-numpy pybind11-dev python3-pytest python3-open3d
  chromium chromium-driver python3-selenium
  librados-dev ceph-mon ceph-osd ceph-mgr ceph-common uuid-runtime
)
# The web viewer's JavaScript dependencies come from the npm registry (web/package-lock.json);
# Debian's npm unless a Node.js with its own npm is installed already.
command -v npm >/dev/null 2>&1 || PACKAGES+=(npm)

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "setup: installing ${#missing[@]} Debian packages: ${missing[*]}"
  if [ "$(id -u)" -ne 0 ]; then
    echo "setup: needs root to install packages (run: sudo $0)" >&2
    exit 1
  fi
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq
  apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

# The web viewer's pinned dependencies, installed into web/node_modules (served by hvdb-server
# --http; nothing is fetched from a CDN at run time). Again only when the lockfile changed.
if [ ! -f web/node_modules/.package-lock.json ] || [ web/package-lock.json -nt web/node_modules/.package-lock.json ]; then
  echo "setup: installing the web viewer's npm dependencies (web/package-lock.json)"
  npm ci --prefix web --no-audit --no-fund --loglevel=error
fi

BUILD_DIR=${HVDB_BUILD_DIR:-build}
cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DHVDB_WERROR=ON -DHVDB_BUILD_TESTS=ON >/dev/null
cmake --build "$BUILD_DIR"
echo "setup: built into $BUILD_DIR/"
# The Python package, so that Debian's python3 finds it anywhere ('import hvdb').
if [ "$(id -u)" -eq 0 ]; then
  site=$(/usr/bin/python3 -c 'import site; print(site.getsitepackages()[0])')  # /usr/local/lib/python3.11/dist-packages
  mkdir -p "$site"
  rm -rf "$site/hvdb"
  cp -r "$BUILD_DIR/python/hvdb" "$site/hvdb"
  echo "setup: installed the Python package hvdb into $site"
else
  echo "setup: not root, so the Python package is not installed; use PYTHONPATH=$BUILD_DIR/python"
fi
