#!/usr/bin/python3
"""live-latency: the live row end to end (issue 34), as a user runs it.

A real RGB-D recording (7-Scenes red kitchen, 640x480, ../shared/data) is copied into a new
directory at its capture rate by `hvdb-ingest replay --realtime FPS --loop N` (each frame's
files renamed into place at its time), while `hvdb-ingest run --follow --server` ingests it
into an hvdb-server, a Python client watches the dataset (`db.watch`), and the web page in
Chromium follows it in Live mode (`?live=1`). Per frame it timestamps, on this machine's clock:

  landed     the frame's last file renamed into place (the newest ctime/mtime of its files)
  committed  landed + the follower's own landed->committed time (its --report)
  event      the watch event's arrival at the Python client
  page_event the event's arrival in the page (window.hvdbLive.onScreen[].eventWall)
  first      the frame's first picture in the page, its coarse levels (onScreen[].firstDrawnWall)
  drawn      the frame complete on screen (onScreen[].drawnWall)

and writes medians and p99 of each step and of landed->drawn as JSON, with the frames the
follower dropped (timed out: it never skips one silently) and how far behind it fell. The page
draws the newest frame: frames that arrive while it draws are shown only if still newest, so
landed->drawn is over the frames it drew (their count is in the JSON).

Usage: bench/live_latency.py [--build build] [--seconds 60] [--fps 30] [--out FILE]
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.dirname(HERE)
SHARED = os.path.join(os.path.dirname(SOURCE), "shared", "data")
SEVEN = os.path.join(SHARED, "sevenscenes-redkitchen-rgbd", "rgbd-frames")


def percentile(values, p):
    if not values:
        return None
    v = sorted(values)
    return v[min(len(v) - 1, int(p * len(v)))]


def summary(values):
    return {"n": len(values),
            "median_ms": statistics.median(values) if values else None,
            "p99_ms": percentile(values, 0.99),
            "max_ms": max(values) if values else None}


def write_recording(d, fps):
    """The 7-Scenes frames 150..189 as a depth recording whose files stay in ../shared."""
    os.makedirs(d)
    with open(os.path.join(d, "calibration.yml"), "w") as f:
        f.write("%YAML:1.0\n---\ncameras:\n   - name: kinect\n     width: 640\n     height: 480\n"
                "     K: !!opencv-matrix\n       rows: 3\n       cols: 3\n       dt: d\n"
                "       data: [ 585, 0, 320, 0, 585, 240, 0, 0, 1 ]\n"
                "     R: !!opencv-matrix\n       rows: 3\n       cols: 3\n       dt: d\n"
                "       data: [ 1, 0, 0, 0, 1, 0, 0, 0, 1 ]\n"
                "     T: !!opencv-matrix\n       rows: 3\n       cols: 1\n       dt: d\n"
                "       data: [ 0, 0, 0 ]\n     reprojection_error: 0.5\n")
    frames = len([n for n in os.listdir(SEVEN) if n.endswith(".pose.txt")])
    with open(os.path.join(d, "recording.yml"), "w") as f:
        f.write("%YAML:1.0\n---\nformat: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\n"
                f"frames: {frames}\nfps: {fps}\nfirst_frame: 150\ndepth_encoding: \"png16\"\n"
                "depth_scale: 0.001\ndepth_invalid: [ 0, 65535 ]\ncameras:\n"
                f"   - {{ name: kinect, colour: \"{SEVEN}/frame-{{frame:06d}}.color.png\", "
                f"depth: \"{SEVEN}/frame-{{frame:06d}}.depth.png\", "
                f"pose: \"{SEVEN}/frame-{{frame:06d}}.pose.txt\" }}\n")
    return frames


SJTU = os.path.join(SHARED, "sjtu-fvv-multiview-rgbd")


def write_sjtu_recording(d, fps):
    """The SJTU stage frame (8 cameras, 1920x1080 colour + inverse depth), one frame whose files
    replay replicates: as bench/real_recordings.cc writes it for ingest-bench."""
    os.makedirs(d)
    tok = open(os.path.join(SJTU, "para_cameras.txt")).read().split()
    zmin, zmax, i = float(tok[0]), float(tok[1]), 2

    def mat(rows, cols, v):
        return (f"!!opencv-matrix\n       rows: {rows}\n       cols: {cols}\n       dt: d\n"
                f"       data: [ {', '.join(repr(float(x)) for x in v)} ]\n")
    cams, files = "cameras:\n", "cameras:\n"
    for _ in range(10):
        cid = int(tok[i + 1]); w, h = int(tok[i + 3]), int(tok[i + 4])
        fx, fy, cx, cy = map(float, tok[i + 6:i + 10])
        R = list(map(float, tok[i + 11:i + 20])); C = list(map(float, tok[i + 21:i + 24]))
        i += 24
        if not os.path.exists(os.path.join(SJTU, "frame_0", "images", f"{cid}.png")):
            continue  # cameras held out of the shared copy
        T = [-(R[3 * r] * C[0] + R[3 * r + 1] * C[1] + R[3 * r + 2] * C[2]) for r in range(3)]
        name = f"cam{cid}"
        cams += (f"   - name: {name}\n     width: {w}\n     height: {h}\n     K: "
                 + mat(3, 3, [fx, 0, cx, 0, fy, cy, 0, 0, 1]) + "     R: " + mat(3, 3, R)
                 + "     T: " + mat(3, 1, T) + "     reprojection_error: 0.5\n")
        files += (f"   - {{ name: {name}, colour: \"{SJTU}/frame_0/images/{cid}.png\", "
                  f"depth: \"{SJTU}/frame_0/depths/{cid}.png\" }}\n")
    with open(os.path.join(d, "calibration.yml"), "w") as f:
        f.write("%YAML:1.0\n---\n" + cams)
    with open(os.path.join(d, "recording.yml"), "w") as f:
        f.write("%YAML:1.0\n---\nformat: \"hvdb-recording\"\nversion: 1\nkind: \"depth\"\n"
                f"frames: 1\nfps: {fps}\ndepth_encoding: \"inverse8\"\ndepth_invalid: [ 0 ]\n"
                f"z_near: {zmin!r}\nz_far: {zmax!r}\nworld_scale: 0.37\n" + files)
    return 1


def landed(live_dir, frame):
    d = os.path.join(live_dir, "frames", f"{frame:06d}")
    times = []
    for n in os.listdir(d):
        st = os.stat(os.path.join(d, n))
        times.append(max(st.st_mtime, st.st_ctime))
    return max(times)


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for a in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1280,720",
              "--force-device-scale-factor=1", "--use-angle=swiftshader",
              "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
              "--disable-background-timer-throttling", "--disable-renderer-backgrounding"]:
        opts.add_argument(a)
    d = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    d.set_script_timeout(120)
    return d


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--build", default=os.path.join(SOURCE, "build"))
    ap.add_argument("--seconds", type=float, default=60, help="capture length (the sequence looped)")
    ap.add_argument("--fps", type=float, default=30)
    ap.add_argument("--out", default="")
    ap.add_argument("--no-browser", action="store_true", help="stop at the watch event")
    ap.add_argument("--source", choices=["7scenes", "sjtu"], default="7scenes",
                    help="7-Scenes RGB-D 640x480, or the SJTU stage frame (8 cameras, 1080p) replicated")
    ap.add_argument("--stride", type=int, default=1, help="depth: every n-th pixel (hvdb-ingest --stride)")
    ap.add_argument("--ingest-arg", action="append", default=[],
                    help="more arguments for hvdb-ingest run (e.g. --ingest-arg=--no-photo-consistency)")
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.build, "python"))
    import hvdb

    server_bin = os.path.join(a.build, "server", "hvdb-server")
    ingest_bin = os.path.join(a.build, "ingest", "hvdb-ingest")
    work = tempfile.mkdtemp(prefix="hvdb_live_latency_")
    procs = []
    try:
        write = write_sjtu_recording if a.source == "sjtu" else write_recording
        per_loop = write(os.path.join(work, "src"), a.fps)
        loops = max(1, round(a.seconds * a.fps / per_loop))
        port_file = os.path.join(work, "port")
        srv = subprocess.Popen([server_bin, "--data", os.path.join(work, "data"), "--listen",
                                "127.0.0.1:0", "--listen", "unix:" + os.path.join(work, "s.sock"),
                                "--http", "127.0.0.1:0", "--port-file", port_file,
                                "--log-level", "warn"],
                               stdout=subprocess.DEVNULL, stderr=open(os.path.join(work, "server.log"), "w"))
        procs.append(srv)
        for _ in range(500):
            if os.path.exists(port_file) and len(open(port_file).read().split()) == 2:
                break
            time.sleep(0.02)
        port, http_port = open(port_file).read().split()
        address = f"127.0.0.1:{port}"
        live = os.path.join(work, "live")
        # The dataset and the page first: the frames timed are those of the capture.
        db = hvdb.connect(address)
        db.create("live", fps=a.fps)
        driver = None
        if not a.no_browser:
            driver = browser()
            driver.get(f"http://127.0.0.1:{http_port}/?dataset=live&live=1")
            for _ in range(600):
                if driver.execute_script("return !!window.hvdbLive"):
                    break
                time.sleep(0.1)
        events = {}
        stop = threading.Event()

        def watch():
            # Resumed from the last LSN seen each time it has been quiet for 0.25 s, until told
            # to stop (the watch's own resume: nothing lost, nothing twice).
            last = None
            while not stop.is_set():
                for ev in db.watch("live", from_lsn=last, timeout=0.25):
                    if ev["kind"] == "bulk" and ev["frames"][0] not in events:
                        events[ev["frames"][0]] = time.time()
                    if ev["kind"] != "live" or last is None:
                        last = ev["lsn"]
                    if stop.is_set():
                        return

        watcher = threading.Thread(target=watch)
        watcher.start()
        follow = subprocess.Popen([ingest_bin, "run", live, "--follow", "--dataset", "live",
                                   "--server", address, "--report", os.path.join(work, "report.json"),
                                   "--status-every", "5", "--stride", str(a.stride)] + a.ingest_arg,
                                  stdout=subprocess.DEVNULL, stderr=open(os.path.join(work, "follow.log"), "w"))
        procs.append(follow)
        t0 = time.time()
        replay = subprocess.run([ingest_bin, "replay", os.path.join(work, "src"), live,
                                 "--realtime", str(a.fps), "--loop", str(loops)],
                                capture_output=True, text=True)
        if replay.returncode != 0:
            sys.exit("replay failed: " + replay.stderr)
        follow.wait(timeout=600)
        time.sleep(1.0)  # the last frames reach the page
        stop.set()
        watcher.join()
        on_screen = driver.execute_script("return window.hvdbLive.onScreen") if driver else []
        if driver:
            driver.quit()
        report = json.load(open(os.path.join(work, "report.json")))
        frames = {f["dataset_frame"]: f for f in report["frames"]}
        total = per_loop * loops
        steps = {"landed_to_committed": [], "committed_to_event": [], "event_to_page": [],
                 "page_event_to_first_picture": [], "page_event_to_drawn": [], "landed_to_event": [],
                 "landed_to_first_picture": [], "landed_to_drawn": []}
        drawn = {s["frame"]: s for s in on_screen if s.get("kind") != "catch-up"}
        for f in range(total):
            rec = frames.get(f)
            if rec is None or rec.get("status") != "ingested":
                continue
            t_landed = landed(live, f)
            t_committed = t_landed + rec["stage_ms"]["landed_to_committed"] / 1000
            steps["landed_to_committed"].append(1000 * (t_committed - t_landed))
            if f in events:
                steps["committed_to_event"].append(1000 * (events[f] - t_committed))
                steps["landed_to_event"].append(1000 * (events[f] - t_landed))
            if f in drawn:
                s = drawn[f]
                if f in events:
                    steps["event_to_page"].append(s["eventWall"] - 1000 * events[f])
                first = s.get("firstDrawnWall", s["drawnWall"])
                steps["page_event_to_first_picture"].append(first - s["eventWall"])
                steps["page_event_to_drawn"].append(s["drawnWall"] - s["eventWall"])
                steps["landed_to_first_picture"].append(first - 1000 * t_landed)
                steps["landed_to_drawn"].append(s["drawnWall"] - 1000 * t_landed)
        ingested = sum(1 for f in frames.values() if f.get("status") == "ingested")
        out = {
            "bench": "live_latency",
            "recording": ("SJTU stage frame, 8 cameras 1920x1080 colour + depth, replicated"
                          if a.source == "sjtu" else
                          "7-Scenes red kitchen RGB-D 640x480 (../shared/data), looped"),
            "stride": a.stride, "ingest_args": a.ingest_arg,
            "fps": a.fps, "frames_captured": total, "capture_seconds": total / a.fps,
            "frames_ingested": ingested,
            "frames_dropped_by_ingest": report.get("timed_out", 0) + total - len(frames),
            "max_behind_frames": report.get("max_behind_frames"),
            "frames_drawn_by_page": len(steps["landed_to_drawn"]),
            "replay_late_note": replay.stdout.strip().splitlines()[-1:] if replay.stdout else [],
            "steps": {k: summary(v) for k, v in steps.items()},
            "targets": {"landed_to_first_picture_p99_ms": 1000, "frames_dropped_by_ingest": 0},
            "wall_seconds": time.time() - t0,
        }
        ltd = out["steps"]["landed_to_first_picture"]["median_ms"]
        if ltd:
            med = {k: out["steps"][k]["median_ms"] or 0 for k in
                   ("landed_to_committed", "committed_to_event", "event_to_page",
                    "page_event_to_first_picture")}
            out["shares_of_median"] = {k: v / ltd for k, v in med.items()}
        text = json.dumps(out, indent=2)
        if a.out:
            with open(a.out, "w") as f:
                f.write(text + "\n")
        print(text)
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout=20)
                except subprocess.TimeoutExpired:
                    p.kill()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
