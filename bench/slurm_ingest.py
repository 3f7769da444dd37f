#!/usr/bin/python3
"""slurm-ingest: bulk ingest on a Slurm cluster (issue 38, part 3), as a user runs it.

A generated stereo recording is ingested by `hvdb-ingest submit` through a real hvdb-server, once
as 1 array task and once as 2, on a one-node Slurm of this machine (scripts/slurm-dev.sh, or the
cluster SLURM_CONF names). Per run it records the wall time from submit to the job's end (Slurm
scheduling included), each task's frames/s from its report (`run --report`) and the per-stage
median times (`hvdb-ingest status --json`).

Then the server's commit rate, measured apart: the frames just ingested, exported as PLY files
(`hvdb export --codec raw`) and made a PLY recording, are loaded into a fresh server by 1, 2
and 4 concurrent `hvdb-ingest run --server` processes on disjoint ranges (no stereo: reading a
PLY file and committing it), frames/s over all of them; the best is the commit rate (a lower
bound: the clients share this machine's cores with the server). Also the commit stage as the
stereo tasks saw it (1 / the median time of a frame's photos + points).

From these: the per-task rate (frames/s of one task with the machine to itself) and the scaling
statement: N nodes give min(N x per-task rate, commit rate) frames/s; it stops scaling at
N = commit rate / per-task rate.

Usage: bench/slurm_ingest.py [--build build] [--frames 16] [--runs 3] [--out FILE]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.dirname(HERE)


def run(cmd, **kw):
    return subprocess.run(cmd, check=True, capture_output=True, text=True, **kw)


def start_server(build, data, work):
    port_file = os.path.join(work, os.path.basename(data) + ".port")
    if os.path.exists(port_file):
        os.unlink(port_file)  # a previous server's
    p = subprocess.Popen([os.path.join(build, "server", "hvdb-server"), "--data", data, "--listen",
                          "127.0.0.1:0", "--port-file", port_file, "--log-level", "warn"],
                         stdout=subprocess.DEVNULL)
    for _ in range(200):
        if os.path.exists(port_file) and open(port_file).read().strip():
            return p, "127.0.0.1:" + open(port_file).read().split()[0]
        time.sleep(0.05)
    p.kill()
    sys.exit("hvdb-server did not start")


def commit_capacity(args, ingest, work, data):
    """Frames/s a fresh server takes from 1, 2 and 4 concurrent PLY ingests of `data`'s frames."""
    ply = os.path.join(work, "ply")
    run([os.path.join(args.build, "client", "hvdb"), "--data", data, "export", "v", ply,
         "--codec", "raw"])
    with open(os.path.join(ply, "recording.yml"), "w") as f:
        f.write("%%YAML:1.0\n---\nformat: hvdb-recording\nversion: 1\nkind: ply\nframes: %d\n"
                "fps: 10\nply: \"v_{frame:06d}.ply\"\n" % args.frames)
    out = []
    # Interleaved, so that a burst of other load on the machine does not hit one count only.
    for k in range(args.runs):
        for clients in (1, 2, 4):
            data2 = os.path.join(work, "commit-%d-%d" % (clients, k))
            server, addr = start_server(args.build, data2, work)
            try:
                # The dataset first, so the clients do not race to create it.
                run([ingest, "run", ply, "--server", addr, "--dataset", "v", "--count", "0", "--quiet"])
                per = -(-args.frames // clients)
                t0 = time.monotonic()
                procs = [subprocess.Popen([ingest, "run", ply, "--server", addr, "--dataset", "v",
                                           "--first", str(c * per), "--count", str(per), "--quiet",
                                           "--workers", "1"], stdout=subprocess.DEVNULL)
                         for c in range(clients) if c * per < args.frames]
                if any(p.wait() != 0 for p in procs):
                    sys.exit("a PLY ingest failed")
                wall = time.monotonic() - t0
                out.append({"clients": clients, "wall_s": wall, "frames_per_s": args.frames / wall})
                print("commit: %d client(s): %.2f frames/s" % (clients, args.frames / wall), flush=True)
            finally:
                server.terminate()
                server.wait()
    return out


def one_run(args, ingest, rec, work, tasks, k):
    data = os.path.join(work, "data-%d-%d" % (tasks, k))
    server, addr = start_server(args.build, data, work)
    try:
        job_dir = os.path.join(work, "job-%d-%d" % (tasks, k))
        # One task: the whole machine (a node of its own); two: a CPU each, side by side.
        cpus = os.cpu_count() // tasks
        t0 = time.monotonic()
        job = run([ingest, "submit", rec, "--dataset", "v", "--server", addr, "--frames-per-task",
                   str(-(-args.frames // tasks)), "--cpus-per-task", str(cpus), "--job-dir",
                   job_dir, "--", "--num-disparities", "32"]).stdout.strip().splitlines()[-1]
        while True:
            st = json.loads(run([ingest, "status", job, "--json"]).stdout)
            if st["finished"]:
                break
            time.sleep(0.2)
        wall = time.monotonic() - t0
        if st["frames_committed"] != args.frames:
            sys.exit("job %s: %d of %d frames committed: %s" % (job, st["frames_committed"],
                                                               args.frames, json.dumps(st)))
        reports = [json.load(open(os.path.join(job_dir, "task-%d.json" % t["id"])))
                   for t in st["tasks"]]
        return {
            "tasks": tasks,
            "wall_s": wall,
            "frames_per_s": args.frames / wall,
            "task_frames_per_s": [r["frames_per_s"] for r in reports],
            "task_seconds": [r["seconds"] for r in reports],
            "stage_median_ms": st["stage_median_ms"],
        }
    finally:
        server.terminate()
        server.wait()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--build", default=os.path.join(SOURCE, "build"))
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--out", default=os.path.join(HERE, "results", "slurm_ingest.json"))
    args = ap.parse_args()
    args.build = os.path.abspath(args.build)
    ingest = os.path.join(args.build, "ingest", "hvdb-ingest")
    work = tempfile.mkdtemp(prefix="hvdb-slurm-bench-")
    own_cluster = not os.environ.get("SLURM_CONF")
    if own_cluster:
        cluster = os.path.join(work, "slurm")
        run(["bash", os.path.join(SOURCE, "scripts", "slurm-dev.sh"), "start", cluster])
        os.environ["SLURM_CONF"] = os.path.join(cluster, "slurm.conf")
    try:
        rec = os.path.join(work, "rec")
        run([ingest, "generate", rec, "--bricks", "2", "--frames", str(args.frames), "--width",
             str(args.width), "--height", str(args.height)])
        runs = []
        for k in range(args.runs):
            for tasks in (1, 2):
                r = one_run(args, ingest, rec, work, tasks, k)
                print("run %d, %d task(s): %.1f s, %.2f frames/s; tasks %s frames/s" % (
                    k, tasks, r["wall_s"], r["frames_per_s"],
                    ", ".join("%.2f" % f for f in r["task_frames_per_s"])), flush=True)
                runs.append(r)
        commits = commit_capacity(args, ingest, work, os.path.join(work, "data-1-0"))
    finally:
        if own_cluster:
            subprocess.run(["bash", os.path.join(SOURCE, "scripts", "slurm-dev.sh"), "stop", cluster],
                           capture_output=True)
        subprocess.run(["rm", "-rf", work])

    def med(tasks, f):
        return statistics.median(f(r) for r in runs if r["tasks"] == tasks)

    per_task = med(1, lambda r: r["task_frames_per_s"][0])
    commit_ms = med(1, lambda r: r["stage_median_ms"].get("commit", 0) +
                    r["stage_median_ms"].get("photos", 0))
    commit_ms_2 = med(2, lambda r: r["stage_median_ms"].get("commit", 0) +
                      r["stage_median_ms"].get("photos", 0))
    commit_by_clients = {c: statistics.median(r["frames_per_s"] for r in commits if r["clients"] == c)
                         for c in sorted({r["clients"] for r in commits})}
    commit_rate = max(commit_by_clients.values())
    n_max = commit_rate / per_task
    scaling = [{"nodes": n, "frames_per_s": min(n * per_task, commit_rate)}
               for n in (1, 2, 4, 8, 16, 32, 64, 128)]
    out = {
        "schema": "hvdb-slurm-ingest/1",
        "date": time.strftime("%Y-%m-%d"),
        "machine": "%d cores" % os.cpu_count(),
        "recording": {"kind": "generated stereo", "bricks": 2, "frames": args.frames,
                      "width": args.width, "height": args.height, "num_disparities": 32},
        "runs": runs,
        "median": {
            "one_task_frames_per_s": med(1, lambda r: r["frames_per_s"]),
            "two_tasks_frames_per_s": med(2, lambda r: r["frames_per_s"]),
            "per_task_frames_per_s": per_task,
            "two_tasks_each_frames_per_s": med(2, lambda r: statistics.median(r["task_frames_per_s"])),
            "commit_ms_per_frame": commit_ms,
            "commit_ms_per_frame_two_tasks": commit_ms_2,
        },
        "commit_runs": commits,
        "server_commit_frames_per_s_by_clients": commit_by_clients,
        "server_commit_frames_per_s": commit_rate,
        "commit_stage_frames_per_s": 1000.0 / commit_ms,
        "scaling": scaling,
        "stops_scaling_at_nodes": n_max,
        "statement": ("N nodes (one task each, this machine's speed) give min(N x %.2f, %.1f) "
                      "frames/s: the server's commits are the limit from about %d nodes on"
                      % (per_task, commit_rate, max(1, int(n_max)))),
    }
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=2)
        f.write("\n")
    print(out["statement"])


if __name__ == "__main__":
    main()
