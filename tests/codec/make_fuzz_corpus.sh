#!/usr/bin/env bash
# Writes the seed corpus of hvdb7_decoder_fuzz with the hvdb-codec tool (run by hand after a
# bitstream change: bash tests/codec/make_fuzz_corpus.sh build/client/hvdb-codec
# tests/codec/fuzz_corpus). Each seed is one selector byte (bit 0: decode against the fuzzer's
# fixed 64-point reference) followed by a stream.
set -euo pipefail
codec=$1
out=$2
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir -p "$out"
rm -f "$out"/seed*
python3 - "$tmp" <<'PY'
import math, random, sys
d = sys.argv[1]
random.seed(1)
for n, name in [(40, "a"), (7, "b"), (300, "c")]:
    with open(f"{d}/{name}.ply", "w") as f:
        f.write(f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\n"
                "property float z\nproperty float nx\nproperty float ny\nproperty float nz\n"
                "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
        for i in range(n):
            x, y = random.random(), random.random()
            f.write(f"{x} {y} {0.1 * math.sin(3 * x)} 0 0 1 {random.randint(0, 255)} "
                    f"{random.randint(0, 255)} 100\n")
# The fuzzer's reference (hvdb7_decoder_fuzz.cc), record for record, and a frame near it.
with open(f"{d}/ref.ply", "w") as f:
    f.write("ply\nformat ascii 1.0\nelement vertex 64\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            + "".join(f"property float cov_{c}\n" for c in ["xx", "xy", "xz", "yy", "yz", "zz"])
            + "property uchar flags\nend_header\n")
    for i in range(64):
        f.write(f"{i % 4} {i // 4 % 4} {i // 16} {i * 4} 0 0 0 0 0 0 0 0 0\n")
with open(f"{d}/next.ply", "w") as f:
    f.write("ply\nformat ascii 1.0\nelement vertex 60\nproperty float x\nproperty float y\n"
            "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            "end_header\n")
    for i in range(60):
        f.write(f"{i % 4 + random.random() * 0.1} {i // 4 % 4} {i // 16} {i * 4} 10 20\n")
PY
i=0
while read -r sel input args; do
  args=${args//TMPREF/$tmp/ref.ply}
  # shellcheck disable=SC2086
  "$codec" encode "$tmp/$input.ply" "$tmp/s.hv7" $args >/dev/null
  printf "\\x$sel" >"$out/seed$i"
  cat "$tmp/s.hv7" >>"$out/seed$i"
  i=$((i + 1))
done <<'LIST'
00 a --qp 8 --geometry pairs
00 b --qp 0 --attributes all
00 c --progressive --chunk 64 --geometry pairs
00 c --qp 12 --qc 4 --qn 6 --attributes all --geometry pairs
00 a --progressive --attributes position --geometry pairs
00 c --levels 5 --attributes all --geometry pairs
01 next --levels 3 --progressive --chunk 64 --reference TMPREF --geometry pairs
00 a --qp 8
00 c --progressive --chunk 64
00 c --qp 12 --qc 4 --qn 6 --attributes all
00 a --attributes position
01 next --qp 6 --levels 3 --progressive --chunk 64 --reference TMPREF
01 next --qp 6 --attributes position --reference TMPREF
LIST
