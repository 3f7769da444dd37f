#!/usr/bin/env bash
# The Debian package (packaging/): cpack builds it from this build, and it holds what an
# administrator needs: the binaries, the Python package, the systemd unit, its configuration
# as a conffile, maintainer scripts that parse, and the library dependencies.
#   deb_package_test.sh BUILD_DIR
set -euo pipefail
build=$1
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
(cd "$build" && cpack -G DEB -B "$out" >/dev/null 2>&1)
deb=$(ls "$out"/hvdb_*_amd64.deb)
contents=$(dpkg-deb -c "$deb")
for f in ./usr/bin/hvdb ./usr/bin/hvdb-server ./usr/bin/hvdb-ingest ./usr/bin/hvdb-ingest-all ./usr/bin/hvdb-codec \
         ./usr/lib/python3/dist-packages/hvdb/__init__.py \
         ./usr/lib/python3/dist-packages/hvdb/__init__.pyi \
         ./usr/lib/systemd/system/hvdb-server.service ./etc/hvdb/hvdb-server.conf \
         ./usr/share/doc/hvdb/PROTOCOL.md ./usr/share/hvdb/web/index.html \
         ./usr/share/hvdb/web/src/main.js ./usr/share/hvdb/web/node_modules/gl-matrix/esm/index.js \
         ./usr/share/hvdb/web/src/hvdb7_worker.js ./usr/share/hvdb/web/wasm/hvdb7.js \
         ./usr/share/hvdb/web/wasm/hvdb7.wasm; do
  grep -qF " $f" <<<"$contents" || { echo "missing from the package: $f" >&2; exit 1; }
done
grep -q "/usr/lib/python3/dist-packages/hvdb/_hvdb.cpython-" <<<"$contents" ||
  { echo "missing from the package: the _hvdb extension module" >&2; exit 1; }
ctl=$(mktemp -d)
dpkg-deb -e "$deb" "$ctl"
grep -qx "/etc/hvdb/hvdb-server.conf" "$ctl/conffiles"
for s in postinst prerm postrm; do sh -n "$ctl/$s"; test -x "$ctl/$s"; done
depends=$(dpkg-deb -f "$deb" Depends)
# FFmpeg, assimp and librados are loaded on first use, not linked: named by hand
# (packaging/CMakeLists.txt).
for d in python3-numpy libopencv-core adduser libprotobuf libavformat libavcodec libswscale libassimp \
         librados2; do
  grep -q "$d" <<<"$depends" || { echo "Depends lacks $d: $depends" >&2; exit 1; }
done
# The unit runs the packaged binary with the packaged configuration, as user hvdb.
unit=$(dpkg-deb --fsys-tarfile "$deb" | tar -xO ./usr/lib/systemd/system/hvdb-server.service)
grep -qx "ExecStart=/usr/bin/hvdb-server --config /etc/hvdb/hvdb-server.conf" <<<"$unit"
grep -qx "User=hvdb" <<<"$unit"
rm -rf "$ctl"
echo "ok: $(basename "$deb"), $(wc -l <<<"$contents") entries"
