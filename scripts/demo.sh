#!/usr/bin/env bash
# The main job: hvdb-server on ./data (127.0.0.1:7878, and the Unix socket ./data/hvdb.sock
# that local clients switch to by themselves; the web viewer on http://127.0.0.1:8080/) with a demo dataset built from the real
# CMU Panoptic point-cloud video in ../shared/data (16 frames of a moving person), queried once
# through the server with the hvdb CLI, and frame 5 rendered through it into out/demo.png. The
# server keeps running in the foreground; Ctrl-C stops it gracefully.
set -euo pipefail
cd "$(dirname "$0")/.."

HVDB=build/client/hvdb
SERVER=build/server/hvdb-server
DATA=${HVDB_DATA:-./data}
LISTEN=${HVDB_LISTEN:-127.0.0.1:7878}
HTTP=${HVDB_HTTP:-127.0.0.1:8080}
SRC=../shared/data/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds
for b in "$HVDB" "$SERVER"; do
  if [ ! -x "$b" ]; then echo "demo: $b is missing; run scripts/setup.sh first" >&2; exit 1; fi
done
if [ ! -d "$SRC" ]; then
  echo "demo: $SRC not found: the demo reads the Panoptic frames from ../shared/data" >&2
  exit 1
fi

# Build the dataset embedded (fast, no server needed) unless it is there already.
if ! "$HVDB" --data "$DATA" describe panoptic >/dev/null 2>&1; then
  echo "demo: creating dataset 'panoptic' in $DATA (29.97 fps, positions in metres)"
  "$HVDB" --data "$DATA" create panoptic --fps 29.97
  "$HVDB" --data "$DATA" import panoptic --frame 0 --units-scale 0.01 "$SRC"/ptcloud_hd00000*.ply
fi
"$HVDB" --data "$DATA" check panoptic

if [ ! -f web/node_modules/gl-matrix/esm/index.js ]; then
  echo "demo: web/node_modules is missing; run scripts/setup.sh first (it installs web/package-lock.json's packages)" >&2
  exit 1
fi
"$SERVER" --data "$DATA" --listen "$LISTEN" --listen unix: --http "$HTTP" &
server_pid=$!
trap 'kill -TERM $server_pid 2>/dev/null || true' INT TERM
for _ in $(seq 100); do
  "$HVDB" --server "$LISTEN" ping >/dev/null 2>&1 && break
  sleep 0.1
done

echo
echo "== the connection (a local client takes the Unix socket and shared memory by itself):"
"$HVDB" --server "$LISTEN" ping

echo
echo "== describe, through the server:"
"$HVDB" --server "$LISTEN" describe panoptic
echo
echo "== slice orthogonal to t at frame 5 (t = 5/29.97 s), level of detail 2:"
"$HVDB" --server "$LISTEN" slice panoptic --normal 0 0 0 1 --offset 0.16683 --thickness 0.01 --lod 2 --json
echo
echo "== window over the raised arms (y < -1.3 m), all 16 frames, written to out/arms.ply:"
mkdir -p out
"$HVDB" --server "$LISTEN" window panoptic --box -1 0 -2 -1.3 -1 1 0 1 --out out/arms.ply
echo
echo "== frame 5 (t = 0.1668 s) rendered by the server from 3 m in front, written to out/demo.png:"
# Positions are metres with y pointing down (the CLI's default --up is 0 -1 0); the person stands
# within x -0.8..-0.06, y -1.73..-0.07, z -0.72..0.78. --renderer auto: EGL (GPU or llvmpipe),
# else the CPU renderer.
"$HVDB" --server "$LISTEN" render panoptic --box -10 10 -10 10 -10 10 0.15 0.18 \
  --look-at -0.4 -0.9 -3 -0.4 -0.9 0 --fov 40 --size 640 480 --out out/demo.png
cat <<MSG

hvdb-server is running on $LISTEN with the dataset 'panoptic' ($DATA).

Open the web viewer (play, slice, select, graph-cut and cut the video; press ? for help):
  http://$HTTP/?dataset=panoptic&t=0.1668&look_at=-0.4,-0.9,-3,-0.4,-0.9,0&fov=40

Or try, in another shell:
  $HVDB --server $LISTEN datasets
  $HVDB --server $LISTEN slice panoptic --normal 0 0 0 1 --offset 0.2 --thickness 0.02 --out slice.ply
  $HVDB --server $LISTEN stats panoptic
  $HVDB --server $LISTEN render panoptic --box -10 10 -10 10 -10 10 0.3 0.31 \\
      --look-at 1.5 -0.9 -2.5 -0.4 -0.9 0 --fov 40 --size 640 480 --out side.png
  python3 examples/frame_stats.py          # the same server from Python (README: From Python)
Ctrl-C stops the server.
MSG
wait $server_pid
