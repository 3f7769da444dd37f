"""Timing whole processes, as the issue benchmarks do: a command run to its end (its failure
ends the benchmark, naming it), its wall clock and its CPU time, and the summary of repeats."""
import resource
import statistics
import subprocess
import sys
import time


def run(cmd, who):
    """The command's stdout; exits naming `who` and the command if it fails."""
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{who}: {' '.join(cmd)} failed ({r.returncode}): {r.stderr}")
    return r.stdout


def clocked(cmd, who):
    """(wall seconds, CPU seconds of the child: user + sys, its stdout)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out = run(cmd, who)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), out


def stats(xs):
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs)}
