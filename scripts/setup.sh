#!/usr/bin/env bash
# Installs what hvdb needs from Debian 12's packages and builds it (Release, Ninja, warnings as
# errors) into build/. Idempotent; run as root.
#
#   bash scripts/setup.sh         what building and serving need, and only the demo's targets:
#                                 hvdb, hvdb-server and the Python module (the README's first
#                                 command: a few minutes on a fresh machine)
#   bash scripts/setup.sh --all   also the tests' and benchmarks' packages (Chromium, Ceph, PCL,
#                                 Open3D, ...) and every target (scripts/test.sh runs this)
set -euo pipefail
cd "$(dirname "$0")/.."

ALL=0
case "${1:-}" in
  "") ;;
  --all) ALL=1 ;;
  -h|--help) sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
  *) echo "setup: unknown option '$1' (use --all, or nothing)" >&2; exit 2 ;;
esac

# Building and serving: the compiler, and the libraries hvdb-server, hvdb and the Python module
# link (storage, protocol, render, edit, codec); ca-certificates for the web viewer's download;
# emscripten compiles codec/ to WebAssembly for the web page's hvdb7 decoder (codec/wasm.cmake).
PACKAGES=(
  build-essential cmake ninja-build pkg-config ca-certificates
  libboost-dev libopencv-dev libdraco-dev libopenexr-dev libglm-dev libnanoflann-dev
  libpng-dev libjpeg-dev zlib1g-dev libzstd-dev
  libegl-dev libgl-dev libopengl-dev libegl-mesa0 libgl1-mesa-dri
  libprotobuf-dev protobuf-compiler nlohmann-json3-dev libcli11-dev liburing-dev librados-dev
  libavformat-dev libavcodec-dev libswscale-dev libavutil-dev libassimp-dev
  python3 python3-dev python3-numpy pybind11-dev
  emscripten
)
# The tests and benchmarks: ingest/ (Ceres), ffmpeg/ffprobe (the photo videos must decode with
# them), GoogleTest and Benchmark, the peers of the
# benchmarks (PCL, libspatialindex, FLANN, Open3D), clang for the fuzzers and sanitizers, the
# browser tests (Chromium), a real Ceph cluster for the RADOS tests, a one-node Slurm for the
# cluster ingest tests (scripts/slurm-dev.sh).
TEST_PACKAGES=(
  git libceres-dev libboost-graph-dev libflann-dev ffmpeg
  libgtest-dev libgmock-dev libbenchmark-dev
  libspatialindex-dev libpcl-dev python3-matplotlib
  clang libclang-rt-14-dev
  python3-pytest python3-open3d
  chromium chromium-driver python3-selenium nodejs
  ceph-mon ceph-osd ceph-mgr ceph-common uuid-runtime
  slurmctld slurmd slurm-client munge
)
if ((ALL)); then PACKAGES+=("${TEST_PACKAGES[@]}"); fi

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
# --http; nothing is fetched from a CDN at run time), checked against web/package-lock.json.
# Again only when the lockfile changed. With --all also the splat ecosystem's converters that
# the interop tests run with Debian's Node.js (tests/splat_interop/package-lock.json).
NPM_DIRS=(web)
if ((ALL)); then NPM_DIRS+=(tests/splat_interop); fi
for dir in "${NPM_DIRS[@]}"; do
  if [ ! -f "$dir/node_modules/.package-lock.json" ] || [ "$dir/package-lock.json" -nt "$dir/node_modules/.package-lock.json" ]; then
    echo "setup: installing the pinned npm packages of $dir ($dir/package-lock.json)"
    /usr/bin/python3 scripts/web_deps.py "$dir"
  fi
done

BUILD_DIR=${HVDB_BUILD_DIR:-build}
if ((ALL)); then
  cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DHVDB_WERROR=ON \
    -DHVDB_BUILD_TESTS=ON -DHVDB_BUILD_BENCH=ON -DHVDB_BUILD_INGEST=ON >/dev/null
  cmake --build "$BUILD_DIR"
else
  # A build directory configured already (by --all, say) keeps its configuration.
  if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
    cmake -S . -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE=Release -DHVDB_WERROR=ON \
      -DHVDB_BUILD_TESTS=OFF -DHVDB_BUILD_BENCH=OFF -DHVDB_BUILD_INGEST=OFF >/dev/null
  fi
  cmake --build "$BUILD_DIR" --target hvdb hvdb-server _hvdb
fi
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
