"""Fixtures of the Python client's tests: the real Panoptic sequence imported by the `hvdb`
command line into a data directory, opened embedded or served by a real hvdb-server started on
a free port. Binaries and data come from CTest's environment (tests/CMakeLists.txt)."""
import glob
import os
import shutil
import subprocess
import time

import pytest

import hvdb

CLI = os.environ.get("HVDB_CLI", "")
SERVER = os.environ.get("HVDB_SERVER", "")
SHARED = os.environ.get("HVDB_SHARED_DATA", "")
PANOPTIC = os.path.join(SHARED, "cmu-panoptic-kinoptic-171026-pose3", "kinoptic_ptclouds")
DATASET = "pan"


def run_cli(*args, data=None, server=None, check=True):
    """Runs `hvdb` with --data or --server; returns the CompletedProcess."""
    cmd = [CLI] + (["--server", server] if server else ["--data", data]) + list(args)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if check and r.returncode != 0:
        raise AssertionError(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr}")
    return r


@pytest.fixture(scope="session")
def panoptic_files():
    files = sorted(glob.glob(os.path.join(PANOPTIC, "ptcloud_hd*.ply")))
    assert len(files) == 16, f"the Panoptic sequence is missing from {PANOPTIC}"
    return files


@pytest.fixture(scope="session")
def seeded_dir(tmp_path_factory, panoptic_files):
    """A data directory holding dataset 'pan': the 16 Panoptic frames, in metres, at 30 fps."""
    assert CLI and SERVER, "run through CTest (HVDB_CLI and HVDB_SERVER are set there)"
    d = str(tmp_path_factory.mktemp("seed") / "data")
    run_cli("create", DATASET, "--fps", "30", data=d)
    run_cli("import", DATASET, "--frame", "0", "--units-scale", "0.01", *panoptic_files, data=d)
    return d


class Server:
    """A real hvdb-server on a free port (and its Unix socket: the local fast path)."""

    def __init__(self, data_dir, name="server", follow=False):
        """follow: a second server on the same data, reading and following the first."""
        self.data_dir = data_dir
        self.name, self.follow = name, follow
        self.proc = None
        self.start()

    def start(self):
        port_file = os.path.join(self.data_dir, self.name + ".port")
        if os.path.exists(port_file):
            os.remove(port_file)
        self.proc = subprocess.Popen(
            [SERVER, "--data", self.data_dir, "--listen", "127.0.0.1:0",
             "--listen", "unix:" + os.path.join(self.data_dir, self.name + ".sock"),
             "--port-file", port_file, "--log-level", "warn"] + (["--follow"] if self.follow else []),
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.time() + 30
        while time.time() < deadline:
            if os.path.exists(port_file) and open(port_file).read().strip():
                self.address = "127.0.0.1:" + open(port_file).read().strip()
                return
            if self.proc.poll() is not None:
                raise AssertionError("hvdb-server exited: " + self.proc.stderr.read().decode())
            time.sleep(0.05)
        raise AssertionError("hvdb-server did not start within 30 s")

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=30)

    def restart(self):
        self.stop()
        self.start()


@pytest.fixture(params=["embedded", "server"])
def env(request, seeded_dir, tmp_path):
    """(db, cli_args, restart): a fresh copy of the seeded directory, opened in one mode, the
    `hvdb` arguments that reach the same data, and a function that closes and reopens it (a
    server restart in server mode)."""
    d = str(tmp_path / "data")
    shutil.copytree(seeded_dir, d)
    if request.param == "embedded":
        state = {"db": hvdb.open(d)}

        def reopen():
            state["db"].close()
            state["db"] = hvdb.open(d)
            return state["db"]

        def cli(*args, check=True):
            # The directory is locked by the embedded database while it is open.
            state["db"].close()
            try:
                return run_cli(*args, data=d, check=check)
            finally:
                state["db"] = hvdb.open(d)
                env_obj.db = state["db"]

        env_obj = Env(state["db"], cli, reopen, "embedded")
        yield env_obj
        state["db"].close()
    else:
        server = Server(d)
        state = {"db": hvdb.connect(server.address)}

        def reopen():
            state["db"].close()
            server.restart()
            state["db"] = hvdb.connect(server.address)
            return state["db"]

        def cli(*args, check=True):
            return run_cli(*args, server=server.address, check=check)

        env_obj = Env(state["db"], cli, reopen, "server", server.address)
        yield env_obj
        state["db"].close()
        server.stop()


class Env:
    def __init__(self, db, cli, reopen, mode, address=None):
        self.db, self.cli, self._reopen, self.mode = db, cli, reopen, mode
        self.address = address  # the server's, in server mode

    def reopen(self):
        self.db = self._reopen()
        return self.db
