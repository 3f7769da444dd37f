#!/usr/bin/env bash
# A one-node Ceph cluster for development and tests, with every file in DIR:
#
#   scripts/ceph-dev.sh start DIR      # one monitor, one manager, one OSD (BlueStore on a
#                                      # sparse 4 GiB file); writes DIR/ceph.conf; loopback only
#   scripts/ceph-dev.sh stop DIR       # stops the daemons; nothing of the cluster keeps running
#   scripts/ceph-dev.sh status DIR
#   scripts/ceph-dev.sh osd-stop DIR   # stops (kills) the OSD, as a failure would
#   scripts/ceph-dev.sh osd-start DIR  # starts it again; its data is still there
#
# No authentication (the daemons bind 127.0.0.1 only), replication size 1: a real RADOS
# cluster for tests of hvdb's RADOS store, not a production layout. Needs Debian's ceph-mon, ceph-osd, ceph-mgr and ceph-common (scripts/
# setup.sh installs them). After ceph's own vstart.sh, which does the same from a source tree.
set -euo pipefail

usage() {
  sed -n '2,13p' "$0" | sed 's/^# \{0,1\}//'
  exit 2
}
[ $# -eq 2 ] || usage
cmd=$1
dir=$(realpath -m "$2")
conf="$dir/ceph.conf"

pids() {
  local f
  for f in "$dir"/run/*.pid; do
    [ -f "$f" ] && cat "$f"
  done
  return 0
}

stop() {
  local p left
  for p in $(pids); do
    if kill -0 "$p" 2>/dev/null; then kill "$p"; fi
  done
  # Daemons flush and exit within seconds; whatever is left after 20 s is killed.
  for _ in $(seq 1 40); do
    left=""
    for p in $(pids); do kill -0 "$p" 2>/dev/null && left="$left $p"; done
    [ -z "$left" ] && break
    sleep 0.5
  done
  for p in $left; do
    if kill -0 "$p" 2>/dev/null; then kill -9 "$p"; fi
  done
  rm -f "$dir"/run/*.pid
}

free_port() {
  python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

start() {
  for tool in ceph-mon ceph-osd ceph-mgr ceph monmaptool ceph-authtool uuidgen; do
    command -v "$tool" >/dev/null || {
      echo "ceph-dev.sh: $tool not found (install ceph-mon ceph-osd ceph-mgr ceph-common: bash scripts/setup.sh --all)" >&2
      exit 1
    }
  done
  if [ -f "$conf" ] && [ -n "$(pids)" ]; then
    # A start always gives a fresh cluster (a test run cut short may have left one running).
    echo "ceph-dev.sh: stopping the cluster that still runs in $dir" >&2
    stop
  fi
  rm -rf "$dir"
  mkdir -p "$dir"/{mon.a,osd.0,mgr.x,run,log}
  local fsid port
  fsid=$(uuidgen)
  port=$(free_port)
  cat >"$conf" <<EOF
[global]
fsid = $fsid
mon host = v2:127.0.0.1:$port
public addr = 127.0.0.1
ms bind ipv6 = false
auth cluster required = none
auth service required = none
auth client required = none
osd pool default size = 1
osd pool default min size = 1
osd pool default pg autoscale mode = off
osd pool default pg num = 8
osd pool default pgp num = 8
mon allow pool size one = true
mon allow pool delete = true
mon data avail warn = 1
mon data avail crit = 0
osd crush chooseleaf type = 0
osd objectstore = bluestore
bluestore block create = true
bluestore block size = 4294967296
bluestore block db create = false
bluestore block wal create = false
bluestore fsck on mkfs = false
bluestore cache size = 268435456
osd op num shards = 1
osd op num threads per shard = 2
run dir = $dir/run
keyring = $dir/keyring
[mon]
pid file = $dir/run/\$name.pid
admin socket = $dir/run/\$name.asok
log file = $dir/log/\$name.log
[osd]
pid file = $dir/run/\$name.pid
admin socket = $dir/run/\$name.asok
log file = $dir/log/\$name.log
[mgr]
pid file = $dir/run/\$name.pid
admin socket = $dir/run/\$name.asok
log file = $dir/log/\$name.log
[client]
admin socket =
log file =
[mon.a]
mon data = $dir/mon.a
[osd.0]
osd data = $dir/osd.0
[mgr.x]
mgr data = $dir/mgr.x
EOF
  ceph-authtool --create-keyring "$dir/keyring" --gen-key -n mon. --cap mon 'allow *' >/dev/null
  monmaptool --create --fsid "$fsid" --addv a "[v2:127.0.0.1:$port]" "$dir/monmap" >/dev/null
  ceph-mon -c "$conf" --mkfs -i a --monmap "$dir/monmap" --keyring "$dir/keyring" 2>>"$dir/log/setup.log"
  ceph-mon -c "$conf" -i a 2>>"$dir/log/setup.log"
  local uuid
  uuid=$(uuidgen)
  ceph -c "$conf" --connect-timeout 30 osd new "$uuid" 0 >/dev/null
  ceph-osd -c "$conf" -i 0 --mkfs --osd-uuid "$uuid" >/dev/null 2>&1
  ceph-osd -c "$conf" -i 0 2>>"$dir/log/setup.log"
  ceph-mgr -c "$conf" -i x 2>>"$dir/log/setup.log"
  # Ready when the OSD is up and in.
  for _ in $(seq 1 120); do
    if ceph -c "$conf" --connect-timeout 5 osd stat 2>/dev/null | grep -q "1 up.*1 in"; then
      echo "ceph-dev.sh: cluster up in $dir; clients use -c $conf"
      return 0
    fi
    sleep 0.5
  done
  echo "ceph-dev.sh: the OSD did not come up within 60 s; logs in $dir/log" >&2
  stop
  exit 1
}

wait_osd() {  # $1: "up" or "down"
  for _ in $(seq 1 120); do
    if [ "$1" = up ]; then
      ceph -c "$conf" --connect-timeout 5 osd stat 2>/dev/null | grep -q "1 up" && return 0
    else
      ceph -c "$conf" --connect-timeout 5 osd stat 2>/dev/null | grep -q "0 up" && return 0
    fi
    sleep 0.5
  done
  echo "ceph-dev.sh: the OSD is not $1 after 60 s" >&2
  return 1
}

case "$cmd" in
  start) start ;;
  stop) stop ;;
  osd-stop)
    kill -9 "$(cat "$dir/run/osd.0.pid")"
    rm -f "$dir/run/osd.0.pid"
    # Tell the monitor at once instead of waiting for its heartbeat grace.
    if ! ceph -c "$conf" --connect-timeout 10 osd down 0 >/dev/null 2>&1; then
      echo "ceph-dev.sh: the monitor was not told; it marks the OSD down after its grace" >&2
    fi
    ;;
  osd-start)
    ceph-osd -c "$conf" -i 0 2>>"$dir/log/setup.log"
    wait_osd up
    # Up is not serving: its placement groups peer first, and a client's operation waits for
    # that (past a short store timeout=S, under load). Wait until every one is active+clean.
    for _ in $(seq 1 120); do
      ceph -c "$conf" --connect-timeout 5 pg stat 2>/dev/null |
        grep -qE '^(0 pgs:|([0-9]+) pgs: \2 active\+clean)' && exit 0
      sleep 0.5
    done
    echo "ceph-dev.sh: the OSD's placement groups are not active+clean after 60 s" >&2
    exit 1
    ;;
  status) ceph -c "$conf" --connect-timeout 5 -s ;;
  *) usage ;;
esac
