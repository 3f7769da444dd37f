#!/usr/bin/env python3
"""Checks what the user-facing binaries load (issue: lean binaries).

  check_binaries.py --lean BIN... [--travels BIN...]

--lean: each binary (hvdb, hvdb-server, the Python module) must load no GDAL, no OpenCV
imgcodecs and no FFmpeg at start: those ~120 and ~130 libraries were most of every command's
start (FFmpeg is loaded on first use, formats/libav.h). --travels: each binary
(render-bench-gpu) must also fit a GPU machine without the Debian stack: its shared libraries
beyond glibc, libstdc++/libgcc and libGL/libEGL (which the GPU's driver brings) at most 40 MiB.
Run by CTest (LeanBinaries); prints each binary's count and size either way.
"""
import argparse
import os
import re
import subprocess
import sys

FORBIDDEN = re.compile(r"^lib(gdal|opencv_imgcodecs|avformat|avcodec|avutil|swscale)\.so")
# What a GPU machine has without Debian's packages: glibc, the C++ runtime, and the OpenGL/EGL
# dispatch libraries the driver installs.
SYSTEM = re.compile(
    r"^(ld-linux.*|linux-vdso.*|libc|libm|libdl|libpthread|librt|libresolv|libutil|libmvec|"
    r"libstdc\+\+|libgcc_s|libGL|libEGL|libGLX|libGLdispatch|libOpenGL)\.so")
TRAVEL_LIMIT = 40 << 20


def loaded(binary):
    """The shared libraries the dynamic loader maps for `binary`: {name: resolved path}."""
    out = subprocess.run(["ldd", binary], capture_output=True, text=True, check=True).stdout
    libs = {}
    for line in out.splitlines():
        m = re.match(r"\s*(\S+)\s+=>\s+(\S+)", line)
        if m:
            if m.group(2) == "not":
                sys.exit(f"{binary}: {m.group(1)} is not found")
            libs[m.group(1)] = os.path.realpath(m.group(2))
    return libs


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lean", nargs="*", default=[])
    ap.add_argument("--travels", nargs="*", default=[])
    args = ap.parse_args()
    failed = []
    for binary in args.lean + args.travels:
        libs = loaded(binary)
        size = sum(os.path.getsize(p) for p in libs.values())
        bad = sorted(n for n in libs if FORBIDDEN.match(n))
        print(f"{os.path.basename(binary)}: {len(libs)} shared libraries, {size / 2**20:.1f} MiB")
        if bad:
            failed.append(f"{binary} loads {', '.join(bad)}: link OpenCV's core modules only "
                          "(HVDB_OPENCV_CORE), read pictures through formats/image_codec.h and "
                          "call FFmpeg through formats/libav.h (hvdb_libav), never linked")
        if binary in args.travels:
            extra = {n: p for n, p in libs.items() if not SYSTEM.match(n)}
            extra_size = sum(os.path.getsize(p) for p in extra.values())
            print(f"  beyond glibc, libstdc++ and libGL/libEGL: {len(extra)} libraries, "
                  f"{extra_size / 2**20:.1f} MiB (limit {TRAVEL_LIMIT >> 20} MiB)")
            for n, p in sorted(extra.items(), key=lambda kv: -os.path.getsize(kv[1]))[:8]:
                print(f"    {os.path.getsize(p) / 2**20:6.1f} MiB  {n}")
            if extra_size > TRAVEL_LIMIT:
                failed.append(f"{binary}: {extra_size / 2**20:.1f} MiB of shared libraries to "
                              f"carry, over {TRAVEL_LIMIT >> 20} MiB")
    for f in failed:
        print("FAIL: " + f, file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
