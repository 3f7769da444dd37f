#!/usr/bin/env bash
# Packs render-bench-gpu to carry to a GPU machine that has none of Debian's packages: the
# binary, the shared libraries such a machine lacks (lib/: OpenCV's core and imgproc, OpenEXR,
# libpng, libjpeg, zstd, ...), libglvnd's EGL/OpenGL dispatch libraries (lib-glvnd/, used only
# where the machine has no libEGL.so.1: the GPU's driver plugs into them) and run.sh, which
# sets the library path and runs it. glibc and libstdc++ are the machine's own.
#
#   bash scripts/pack-render-bench-gpu.sh [BUILD_DIR] [OUT.tar.gz]
#   # on the GPU machine:
#   tar xzf render-bench-gpu.tar.gz && render-bench-gpu/run.sh --require-gpu --out gpu.json
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}
OUT=$(realpath -m "${2:-render-bench-gpu.tar.gz}")
BIN=$BUILD/bench/render-bench-gpu
[ -x "$BIN" ] || { echo "pack: $BIN is missing: cmake --build $BUILD --target render-bench-gpu" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
dir=$work/render-bench-gpu
mkdir -p "$dir/lib" "$dir/lib-glvnd"
cp "$BIN" "$dir/"
ldd "$BIN" | awk '/=> \// {print $1, $3}' | while read -r name path; do
  case $name in
    ld-linux*|libc.so*|libm.so*|libdl.so*|libpthread.so*|librt.so*|libresolv.so*|libmvec.so*|\
    libstdc++.so*|libgcc_s.so*) ;;
    libEGL.so*|libGL.so*|libGLX.so*|libGLdispatch.so*|libOpenGL.so*|libX11.so*|libxcb.so*|\
    libXau.so*|libXdmcp.so*|libbsd.so*|libmd.so*) cp -L "$path" "$dir/lib-glvnd/$name" ;;
    *) cp -L "$path" "$dir/lib/$name" ;;
  esac
done
cat > "$dir/run.sh" <<'RUN'
#!/bin/sh
# Runs render-bench-gpu with its own libraries; libglvnd's dispatch only where the machine has
# no libEGL.so.1 of its own (its GPU driver's EGL vendor file must then be in
# /usr/share/glvnd/egl_vendor.d, as the driver installs it).
here=$(dirname "$(readlink -f "$0")")
path=$here/lib
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1 '; then path=$path:$here/lib-glvnd; fi
LD_LIBRARY_PATH=$path${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH} exec "$here/render-bench-gpu" "$@"
RUN
chmod +x "$dir/run.sh"
tar -C "$work" -czf "$OUT" render-bench-gpu
echo "pack: $OUT ($(du -h "$OUT" | cut -f1); lib/ $(du -sh "$dir/lib" | cut -f1), lib-glvnd/ $(du -sh "$dir/lib-glvnd" | cut -f1))"
