#!/usr/bin/env bash
# Installs the Debian package into a clean Debian 12 root and checks that it works there:
# hvdb-server starts with the packaged configuration (as the packaged user), the command line
# reaches it, and Debian's python3 imports hvdb and queries it. Not part of the test command:
# it downloads a minimal Debian (debootstrap, ~150 MB) and the package's dependencies.
#   sudo bash scripts/deb-check.sh [ROOT_DIR]        (default: /var/tmp/hvdb-deb-root)
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${1:-/var/tmp/hvdb-deb-root}
MIRROR=${DEBIAN_MIRROR:-http://deb.debian.org/debian}
if [ "$(id -u)" -ne 0 ]; then echo "deb-check: run as root (chroot, debootstrap)" >&2; exit 1; fi

deb=$(bash scripts/package.sh | tail -n 1)
echo "deb-check: package $deb"
if ! command -v debootstrap >/dev/null; then
  apt-get install -y -qq --no-install-recommends debootstrap >/dev/null
fi
if [ ! -x "$ROOT/usr/bin/apt-get" ]; then
  echo "deb-check: making a clean Debian 12 root in $ROOT (debootstrap --variant=minbase)"
  rm -rf "$ROOT"
  debootstrap --variant=minbase bookworm "$ROOT" "$MIRROR" >/dev/null
fi
cleanup() {
  # Best effort on the way out, whatever failed: nothing of it must outlive the script.
  # The server started below (minbase has no pkill; the pattern is unique to this script).
  pkill -f "port-file /tmp/deb-check.port" 2>/dev/null || true
  sleep 0.5
  for m in proc dev/pts dev; do umount "$ROOT/$m" 2>/dev/null || true; done
}
trap cleanup EXIT
mount -t proc proc "$ROOT/proc"
mount --bind /dev "$ROOT/dev"
mount --bind /dev/pts "$ROOT/dev/pts"
cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
cp "$deb" "$ROOT/tmp/hvdb.deb"

echo "deb-check: installing the package and its dependencies in the clean root"
chroot "$ROOT" sh -c 'apt-get update -qq && DEBIAN_FRONTEND=noninteractive \
  apt-get install -y -qq --no-install-recommends /tmp/hvdb.deb >/dev/null'
chroot "$ROOT" dpkg -s hvdb | sed -n 's/^\(Version\|Status\): /  \1: /p'
chroot "$ROOT" sh -c 'test -f /usr/lib/systemd/system/hvdb-server.service && \
  test -f /etc/hvdb/hvdb-server.conf && getent passwd hvdb >/dev/null && \
  test "$(stat -c %U /var/lib/hvdb)" = hvdb'
echo "  unit, configuration, user hvdb and /var/lib/hvdb: present"
chroot "$ROOT" hvdb-server --help | head -n 1

# The packaged configuration as the unit runs it (user hvdb), on a free port rather than 7878
# (this root shares the host's network).
chroot "$ROOT" sh -c 'rm -f /tmp/deb-check.port; su -s /bin/sh hvdb -c \
  "hvdb-server --config /etc/hvdb/hvdb-server.conf --listen 127.0.0.1:0 --http 127.0.0.1:0 \
   --port-file /tmp/deb-check.port \
   >/tmp/server.log 2>&1 &"'
for _ in $(seq 100); do
  [ -s "$ROOT/tmp/deb-check.port" ] && break
  sleep 0.1
done
port=$(sed -n 1p "$ROOT/tmp/deb-check.port" 2>/dev/null || true)  # empty is reported just below
http_port=$(sed -n 2p "$ROOT/tmp/deb-check.port" 2>/dev/null || true)  # likewise
if [ -z "$port" ] || [ -z "$http_port" ]; then
  echo "deb-check: hvdb-server did not start:" >&2
  cat "$ROOT/tmp/server.log" >&2
  exit 1
fi
echo "  hvdb-server started as user hvdb on port $port (data /var/lib/hvdb)"
chroot "$ROOT" hvdb --server "127.0.0.1:$port" ping
chroot "$ROOT" hvdb --server "127.0.0.1:$port" drop check >/dev/null 2>&1 || true  # a rerun
chroot "$ROOT" hvdb --server "127.0.0.1:$port" create check --fps 30 >/dev/null
chroot "$ROOT" python3 -c "
import hvdb, numpy as np
db = hvdb.connect('127.0.0.1:$port')
with db.transaction('check') as tx:
    tx.insert(hvdb.points(np.random.default_rng(1).normal(size=(1000, 3)), frame=0))
print('  python3: import hvdb ok;', db.datasets(), len(db.frame('check', frame=0)), 'points')
"
# The web viewer from the packaged files (share/hvdb/web, its npm dependency included).
chroot "$ROOT" python3 -c "
import urllib.request
for path in ('/', '/src/main.js', '/node_modules/gl-matrix/esm/index.js'):
    with urllib.request.urlopen('http://127.0.0.1:$http_port' + path) as r:
        assert r.status == 200, (path, r.status)
print('  web viewer: served on port $http_port from /usr/share/hvdb/web')
"
echo "deb-check: the package works in a clean Debian 12 root"
