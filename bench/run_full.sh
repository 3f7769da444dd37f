#!/usr/bin/env bash
# Runs hvdb-bench at the thesis's sizes and stores what bench/README.md's table is made of in
# bench/results/: full.json, the PNG plots (full.*.png), full.log and machine.txt.
#
#   bash bench/run_full.sh [hvdb-bench options...]
#
# Build first (scripts/setup.sh --all builds build/; HVDB_BUILD_DIR picks another build directory).
# The datasets go to $HVDB_BENCH_SCRATCH (default: <build>/bench-scratch; a few GB, removed at
# the end). Takes ~9 minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${HVDB_BUILD_DIR:-build}
BIN="$BUILD_DIR/bench/hvdb-bench"
SCRATCH=${HVDB_BENCH_SCRATCH:-$BUILD_DIR/bench-scratch}
OUT=bench/results
[ -x "$BIN" ] || { echo "run_full: $BIN not built (run scripts/setup.sh --all)" >&2; exit 1; }
mkdir -p "$OUT" "$SCRATCH"

{
  echo "# Machine of the latest full run ($(date -u +%Y-%m-%dT%H:%M:%SZ))"
  echo "## uname -a";      uname -a
  echo "## os";            grep PRETTY_NAME /etc/os-release || true
  echo "## nproc";         nproc
  echo "## lscpu";         lscpu | grep -E 'Model name|^CPU\(s\)|Thread|Core|Socket|MHz|L1d|L2|L3|Hypervisor|Virtualization' || true
  echo "## memory";        free -h
  echo "## disk (scratch: $SCRATCH)"; df -hT "$SCRATCH"
  echo;                    lsblk -d -o NAME,SIZE,ROTA,TYPE,MODEL 2>/dev/null || true
  echo "## compiler";      c++ --version | head -1
  echo "## peers (Debian packages)"
  dpkg-query -W -f='${Package} ${Version}\n' libspatialindex-dev libnanoflann-dev libpcl-dev python3-matplotlib 2>/dev/null || true
  echo "## load average before the run"; cat /proc/loadavg
} > "$OUT/machine.txt"

"$BIN" --out "$OUT/full.json" --scratch "$SCRATCH" "$@" 2>&1 | tee "$OUT/full.log"
echo "## load average after the run" >> "$OUT/machine.txt"
cat /proc/loadavg >> "$OUT/machine.txt"
python3 bench/report.py "$OUT/full.json" > "$OUT/table.md" 2>/dev/null ||
  /usr/bin/python3 bench/report.py "$OUT/full.json" > "$OUT/table.md"
echo "run_full: results in $OUT/ (table: $OUT/table.md)"
