#!/usr/bin/env bash
# The main job: a demo dataset on disk in ./data, built from the real CMU Panoptic point-cloud
# video in ../shared/data (16 frames of a moving person), then queried with the hvdb CLI.
set -euo pipefail
cd "$(dirname "$0")/.."

HVDB=build/client/hvdb
DATA=${HVDB_DATA:-./data}
SRC=../shared/data/cmu-panoptic-kinoptic-171026-pose3/kinoptic_ptclouds
if [ ! -x "$HVDB" ]; then echo "demo: $HVDB is missing; run scripts/setup.sh first" >&2; exit 1; fi
if [ ! -d "$SRC" ]; then
  echo "demo: $SRC not found: the demo reads the Panoptic frames from ../shared/data" >&2
  exit 1
fi

if ! "$HVDB" --data "$DATA" describe panoptic >/dev/null 2>&1; then
  echo "demo: creating dataset 'panoptic' in $DATA (29.97 fps, positions in metres)"
  "$HVDB" --data "$DATA" create panoptic --fps 29.97
  "$HVDB" --data "$DATA" import panoptic --frame 0 --units-scale 0.01 "$SRC"/ptcloud_hd00000*.ply
fi
"$HVDB" --data "$DATA" describe panoptic
echo
echo "== slice orthogonal to t at frame 5 (t = 5/29.97 s), level of detail 2:"
"$HVDB" --data "$DATA" slice panoptic --normal 0 0 0 1 --offset 0.16683 --thickness 0.01 --lod 2 --json
echo
echo "== window over the raised arms (y < -1.3 m), all 16 frames, written to out/arms.ply:"
mkdir -p out
"$HVDB" --data "$DATA" window panoptic --box -1 0 -2 -1.3 -1 1 0 1 --out out/arms.ply
echo
"$HVDB" --data "$DATA" check panoptic
echo
echo "demo: done. Try: $HVDB --data $DATA --help"
