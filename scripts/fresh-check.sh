#!/usr/bin/env bash
# How long a newcomer waits: makes a clean Debian 12 root with debootstrap, clones this
# repository into it (HEAD, as committed), runs the README's first command there as root
# (`bash scripts/setup.sh && bash scripts/demo.sh`) and prints the seconds from its start until
# the demo's server answers a ping, apt's downloads included. Run by hand, as root, on the
# machine's network (not part of the test command: it downloads ~1 GB and takes minutes).
#
#   bash scripts/fresh-check.sh [ROOT]     ROOT: where to make the root (default /tmp/hvdb-fresh);
#                                         it is removed first. HVDB_MIRROR overrides the mirror.
#
# The demo reads ../shared/data, which is bind-mounted read-only beside the clone, as a user's
# checkout has it. The last line is JSON: {"seconds_to_serving": S, "setup_seconds": S, ...}.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=${1:-/tmp/hvdb-fresh}
MIRROR=${HVDB_MIRROR:-http://deb.debian.org/debian}
if [ "$(id -u)" -ne 0 ]; then echo "fresh-check: run as root (debootstrap, chroot)" >&2; exit 1; fi
command -v debootstrap >/dev/null || { apt-get install -y -qq debootstrap >/dev/null; }
[ -d ../shared/data ] || { echo "fresh-check: ../shared/data is missing (the demo reads it)" >&2; exit 1; }

cleanup() {
  for m in proc sys dev/pts dev work/shared; do umount -l "$ROOT/$m" 2>/dev/null || true; done
}
trap cleanup EXIT
cleanup
rm -rf "$ROOT"
echo "fresh-check: debootstrap bookworm into $ROOT (not timed)"
t0=$(date +%s)
debootstrap --variant=minbase bookworm "$ROOT" "$MIRROR" >/dev/null
echo "fresh-check: root made in $(( $(date +%s) - t0 )) s"
# The machine's network settings go with it: its resolver, its apt sources, and the local
# certificate authorities it trusts (a proxy's, say), which ca-certificates adds on install.
cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
if compgen -G "/usr/local/share/ca-certificates/*.crt" >/dev/null; then
  mkdir -p "$ROOT/usr/local/share/ca-certificates"
  cp /usr/local/share/ca-certificates/*.crt "$ROOT/usr/local/share/ca-certificates/"
fi
mkdir -p "$ROOT/work/shared"
mount -t proc proc "$ROOT/proc"
mount --rbind /sys "$ROOT/sys"
mount --rbind /dev "$ROOT/dev"
mount --bind -o ro ../shared "$ROOT/work/shared"
# A clean clone of what is committed: git is not in minbase, so the clone is made here.
git clone -q --no-hardlinks "$(pwd)" "$ROOT/work/hvdb"

# The README's first command, as a user runs it; its output goes to a log. The server stays in
# the foreground there, so it runs in the background here and is polled.
cat >"$ROOT/work/run.sh" <<'EOF'
#!/bin/bash
cd /work/hvdb
export PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
start=$(date +%s.%N)
echo "$start" >/work/start
( bash scripts/setup.sh && date +%s.%N >/work/setup_done && bash scripts/demo.sh ) >/work/readme.log 2>&1
EOF
chmod +x "$ROOT/work/run.sh"
echo "fresh-check: running 'bash scripts/setup.sh && bash scripts/demo.sh' in the clean root (timed)"
setsid chroot "$ROOT" /work/run.sh &
runner=$!  # its own process group: the demo's server goes with it
served=""
while kill -0 "$runner" 2>/dev/null; do
  if [ -x "$ROOT/work/hvdb/build/client/hvdb" ] &&
     chroot "$ROOT" /work/hvdb/build/client/hvdb --server 127.0.0.1:7878 describe panoptic >/dev/null 2>&1; then
    served=$(date +%s.%N)
    break
  fi
  sleep 1
done
start=$(cat "$ROOT/work/start")
kill -TERM -- "-$runner" 2>/dev/null || true
wait "$runner" 2>/dev/null || true
if [ -z "$served" ]; then
  echo "fresh-check: the demo never served; the end of its log:" >&2
  tail -n 30 "$ROOT/work/readme.log" >&2
  exit 1
fi
setup_done=$(cat "$ROOT/work/setup_done" 2>/dev/null || echo "$served")
grep '^setup: ' "$ROOT/work/readme.log" || true
/usr/bin/python3 - "$start" "$setup_done" "$served" <<'EOF'
import json, sys
start, setup, served = (float(v) for v in sys.argv[1:])
print(f"fresh-check: the demo server answered {served - start:.0f} s after the README's first command started "
      f"(set-up {setup - start:.0f} s, demo until serving {served - setup:.0f} s)")
print(json.dumps({"seconds_to_serving": round(served - start, 1), "setup_seconds": round(setup - start, 1),
                  "demo_seconds": round(served - setup, 1)}))
EOF
