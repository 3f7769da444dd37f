"""Fixtures of the browser tests: the real Panoptic sequence imported by the `hvdb` command
line, a real hvdb-server with --http serving the web viewer (web/), and Debian's headless
Chromium driven by Selenium. Binaries and paths come from CTest's environment
(tests/CMakeLists.txt)."""
import glob
import os
import subprocess
import time

import pytest
from selenium import webdriver
from selenium.webdriver.chrome.service import Service

CLI = os.environ.get("HVDB_CLI", "")
SERVER = os.environ.get("HVDB_SERVER", "")
SHARED = os.environ.get("HVDB_SHARED_DATA", "")
WEB_ROOT = os.environ.get("HVDB_WEB_ROOT", "")
PANOPTIC = os.path.join(SHARED, "cmu-panoptic-kinoptic-171026-pose3", "kinoptic_ptclouds")
DATASET = "panoptic"
FPS = 29.97


def run_cli(*args, server=None, data=None):
    cmd = [CLI] + (["--server", server] if server else ["--data", data]) + [str(a) for a in args]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr}")
    return r.stdout


@pytest.fixture(scope="session")
def server(tmp_path_factory):
    """hvdb-server on free ports with the dataset 'panoptic' (16 frames, metres, 29.97 fps)."""
    assert CLI and SERVER and WEB_ROOT, "run through CTest (HVDB_CLI, HVDB_SERVER, HVDB_WEB_ROOT)"
    files = sorted(glob.glob(os.path.join(PANOPTIC, "ptcloud_hd*.ply")))
    assert len(files) == 16, f"the Panoptic sequence is missing from {PANOPTIC}"
    data = str(tmp_path_factory.mktemp("web") / "data")
    run_cli("create", DATASET, "--fps", FPS, data=data)
    run_cli("import", DATASET, "--frame", "0", "--units-scale", "0.01", *files, data=data)
    port_file = data + ".port"
    log = open(data + ".log", "w")  # a file, not a pipe nobody reads: the server never blocks
    proc = subprocess.Popen(
        [SERVER, "--data", data, "--listen", "127.0.0.1:0", "--http", "127.0.0.1:0",
         "--web-root", WEB_ROOT, "--port-file", port_file, "--log-level", "info"],
        stdout=subprocess.DEVNULL, stderr=log)
    deadline = time.time() + 30
    ports = []
    while time.time() < deadline and len(ports) < 2:
        if os.path.exists(port_file):
            ports = open(port_file).read().split()
        if proc.poll() is not None:
            raise AssertionError("hvdb-server exited: " + open(data + ".log").read())
        time.sleep(0.05)
    assert len(ports) == 2, "hvdb-server did not start within 30 s"

    class S:
        address = "127.0.0.1:" + ports[0]
        http = "http://127.0.0.1:" + ports[1]
    yield S
    proc.terminate()
    try:
        proc.wait(timeout=30)
    finally:
        log.close()


@pytest.fixture(scope="session")
def browser():
    """Headless Chromium with its software WebGL2 (SwiftShader), device scale 1."""
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for a in ["--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
              "--window-size=1400,900", "--force-device-scale-factor=1",
              "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
              "--disable-background-timer-throttling", "--disable-renderer-backgrounding"]:
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    driver.set_script_timeout(120)
    yield driver
    driver.quit()
