"""``penumbra farm`` on a real Dask cluster on 127.0.0.1: a ``dask scheduler``
and two ``dask worker`` processes, machines dying mid-render, restarts.

Every subprocess has a timeout and every process a test starts is ended by
the fixture, whatever the test's outcome.
"""
import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import psutil
import pytest

from penumbra.core import exr
from helpers import PENUMBRA
from scenes import sample_path

BIN = os.path.dirname(sys.executable)
DASK = os.path.join(BIN, "dask")
SCENE = sample_path("torus_plane")
RENDER = ["--resolution", "32x32", "--methods", "pcf", "--no-previews", "--threads", "1"]
FARM_TIMEOUT = 300


def _stop(procs):
    for p in procs:
        if p.poll() is None:
            p.terminate()
    for p in procs:
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=15)


def _until(condition, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def render_children(pid):
    """The chunk renders a worker process runs (its ``python -m penumbra.cli`` children)."""
    try:
        kids = psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    out = []
    for k in kids:
        try:
            if "-m penumbra.cli render" in " ".join(k.cmdline()):
                out.append(k)
        except psutil.NoSuchProcess:
            pass
    return out


class Cluster:
    """A ``dask scheduler`` and named ``dask worker`` processes (no nanny: the
    worker process is the one a test kills), all on 127.0.0.1."""

    def __init__(self, root):
        self.root = root
        self.procs = []
        self.workers = {}
        self.logs = []
        sched_file = os.path.join(root, "scheduler.json")
        self._spawn([DASK, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                     "--scheduler-file", sched_file], "scheduler")
        _until(lambda: os.path.exists(sched_file) and os.path.getsize(sched_file) > 0, 60, "the scheduler")
        time.sleep(0.2)
        with open(sched_file) as f:
            self.address = json.load(f)["address"]
        assert self.address.startswith("tcp://127.0.0.1:")
        self._n = 0

    def _spawn(self, argv, name):
        log = open(os.path.join(self.root, f"{name}.log"), "w")
        self.logs.append(log)
        p = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                             cwd=self.root)
        self.procs.append(p)
        return p

    def connected(self):
        from distributed import Client
        with Client(self.address, timeout="10s") as c:
            return {w["name"] for w in c.scheduler_info()["workers"].values()}

    def ensure_workers(self, n=2):
        """Start workers until ``n`` are alive and connected; their names."""
        alive = {k: p for k, p in self.workers.items() if p.poll() is None}
        while len(alive) < n:
            self._n += 1
            name = f"w{self._n}"
            alive[name] = self.workers[name] = self._spawn(
                [DASK, "worker", self.address, "--name", name, "--nthreads", "1", "--no-nanny",
                 "--host", "127.0.0.1", "--no-dashboard", "--death-timeout", "60",
                 "--local-directory", os.path.join(self.root, name)], name)
        _until(lambda: set(alive) == self.connected(), 90, f"workers {sorted(alive)} to connect")
        return alive

    def idle(self):
        return not any(render_children(p.pid) for p in self.workers.values() if p.poll() is None)

    def close(self):
        for p in self.workers.values():     # they hold nothing; their render children follow them
            p.kill()
        _stop(self.procs)
        for log in self.logs:
            log.close()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    c = Cluster(str(tmp_path_factory.mktemp("dask")))
    try:
        yield c
    finally:
        c.close()


@pytest.fixture
def farm_procs():
    procs = []
    yield procs
    _stop(procs)


def farm_argv(cluster, out, frames="1-6", chunk=2, extra=()):
    return [PENUMBRA, "farm", SCENE, "--frames", frames, "--chunk", str(chunk), "--scheduler", cluster.address,
            "--out", str(out), *RENDER, *extra]


def run_farm(argv, **kw):
    return subprocess.run(argv, capture_output=True, text=True, timeout=FARM_TIMEOUT, stdin=subprocess.DEVNULL, **kw)


def _umask():
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def assert_frames_complete(out, frames):
    """Every frame's EXR and JSON exist and read back, with the umask's mode
    (the workers inherit it: 0644 under 022); nothing else is there."""
    names = sorted(os.listdir(out))
    assert names == sorted(f"torus_plane.{f:04d}.{e}" for f in frames for e in ("exr", "json")), names
    assert {os.stat(out / n).st_mode & 0o777 for n in names} == {0o666 & ~_umask()}
    for f in frames:
        rec = json.loads((out / f"torus_plane.{f:04d}.json").read_text())
        assert rec["frame"] == f and rec["resolution"] == [32, 32] and rec["exr"] == f"torus_plane.{f:04d}.exr"
        v = exr.read_multilayer(str(out / rec["exr"]))["Spot"]["pcf"]
        assert v.shape == (32, 32) and np.isfinite(v).all() and 0.0 <= v.min() < v.max() <= 1.0


def mtimes(out):
    return {n: os.stat(out / n).st_mtime_ns for n in os.listdir(out)}


def assert_second_run_writes_nothing(cluster, out, frames=range(1, 7)):
    before = mtimes(out)
    p = run_farm(farm_argv(cluster, out))
    assert p.returncode == 0, p.stdout + p.stderr
    assert f"0 written, {len(frames)} skipped (already there), 0 failed" in p.stdout
    assert mtimes(out) == before


def test_a_worker_killed_mid_render_loses_nothing(cluster, tmp_path, farm_procs):
    victim, other = cluster.ensure_workers(2).values()
    out = tmp_path / "out"
    log = open(tmp_path / "farm.log", "w+")
    farm = subprocess.Popen(farm_argv(cluster, out), stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    farm_procs.append(farm)
    children = _until(lambda: render_children(victim.pid), 120, "a chunk rendering on the victim worker")
    victim.send_signal(signal.SIGKILL)
    victim.wait(timeout=30)
    assert farm.wait(timeout=FARM_TIMEOUT) == 0, open(tmp_path / "farm.log").read()
    log.seek(0)
    summary = log.read()
    assert "6 frames in 3 chunks on 2 workers:" in summary and "6 written, 0 skipped (already there), 0 failed" in summary
    # the killed worker's render went with it (its watchdog), leaving no temporary file
    gone, alive = psutil.wait_procs(children, timeout=30)
    assert not alive
    assert_frames_complete(out, range(1, 7))
    assert_second_run_writes_nothing(cluster, out)


def test_the_farm_process_killed_and_restarted_loses_nothing(cluster, tmp_path, farm_procs):
    workers = cluster.ensure_workers(2)
    out = tmp_path / "out"
    farm = subprocess.Popen(farm_argv(cluster, out), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            stdin=subprocess.DEVNULL)
    farm_procs.append(farm)
    _until(lambda: any(render_children(p.pid) for p in workers.values()), 120, "a chunk rendering")
    farm.send_signal(signal.SIGKILL)
    farm.wait(timeout=30)
    p = run_farm(farm_argv(cluster, out))
    assert p.returncode == 0, p.stdout + p.stderr
    assert "6 frames in 3 chunks" in p.stdout and "0 failed" in p.stdout
    # chunks the killed client had started finish on the workers, atomically
    _until(cluster.idle, 120, "the workers to finish")
    assert_frames_complete(out, range(1, 7))
    assert_second_run_writes_nothing(cluster, out)


def test_a_crashing_chunk_is_retried_twice_then_reported(cluster, tmp_path, farm_procs):
    """Frame 1's first render is killed (the retry writes it), frame 2's every
    render is killed (three attempts, then reported with its error line),
    frame 3 renders: exit 1, since not every frame exists."""
    workers = cluster.ensure_workers(2)
    out = tmp_path / "out"
    farm = subprocess.Popen(farm_argv(cluster, out, frames="1-3", chunk=1), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL)
    farm_procs.append(farm)
    killed = {"1": 0, "2": 0}
    seen = set()
    deadline = time.monotonic() + FARM_TIMEOUT
    while farm.poll() is None and time.monotonic() < deadline:
        for w in workers.values():
            for child in render_children(w.pid):
                if child.pid in seen:
                    continue
                try:
                    cmd = child.cmdline()
                except psutil.NoSuchProcess:
                    continue
                chunk = cmd[cmd.index("--frames") + 1]
                if chunk == "2" or (chunk == "1" and killed["1"] == 0):
                    child.kill()
                    killed[chunk] += 1
                seen.add(child.pid)
        time.sleep(0.05)
    stdout, stderr = farm.communicate(timeout=60)
    assert farm.returncode == 1, stdout + stderr
    assert killed == {"1": 1, "2": 3}                     # retries=2: three attempts in all
    assert "3 frames in 3 chunks" in stdout and "2 written, 0 skipped (already there), 1 failed" in stdout
    assert "  failed 2: penumbra render exited -9" in stdout
    assert "frame/s" not in stderr and "s/frame" not in stderr and "%|" not in stderr   # no bar: not a terminal
    assert sorted(os.listdir(out)) == [f"torus_plane.{f:04d}.{e}" for f in (1, 3) for e in ("exr", "json")]


def _on_a_terminal(argv, timeout=FARM_TIMEOUT):
    """Run ``argv`` with stderr on a pseudo-terminal; its exit code, stdout and
    what it wrote to the terminal."""
    import fcntl
    import pty
    import select
    import struct
    import termios
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))   # a 120-column terminal
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=slave, stdin=subprocess.DEVNULL, text=True)
    os.close(slave)
    screen = b""
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.2)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:       # the terminal closed with the process
                    break
                if not chunk:
                    break
                screen += chunk
            elif p.poll() is not None:
                break
        stdout, _ = p.communicate(timeout=max(1.0, deadline - time.monotonic()))
    finally:
        if p.poll() is None:
            p.kill()
            p.wait(timeout=15)
        os.close(master)
    return p.returncode, stdout, screen.decode(errors="replace")


def test_progress_on_a_terminal_and_quiet(cluster, tmp_path):
    """On a terminal: frames done / total, rate and time left; --quiet (or a
    stderr that is no terminal) shows none."""
    cluster.ensure_workers(2)
    out = tmp_path / "out"
    rc, stdout, screen = _on_a_terminal(farm_argv(cluster, out, frames="1-2", chunk=1))
    assert rc == 0, stdout + screen
    assert "penumbra farm: 100%" in screen and "2/2" in screen, screen
    assert "frame/s" in screen or "s/frame" in screen, screen      # the rate
    assert "<00:00" in screen                                     # time left at the end
    rc, stdout, screen = _on_a_terminal(farm_argv(cluster, out, frames="1-2", chunk=1, extra=["--force", "--quiet"]))
    assert rc == 0 and "2 written, 0 skipped (already there), 0 failed" in stdout
    assert screen.strip() == ""


def test_local_workers_route(tmp_path):
    """--workers N: a LocalCluster of N worker processes on 127.0.0.1."""
    out = tmp_path / "out"
    p = run_farm([PENUMBRA, "farm", SCENE, "--frames", "3,4", "--chunk", "1", "--workers", "2", "--out", str(out),
                  *RENDER])
    assert p.returncode == 0, p.stdout + p.stderr
    assert "2 frames in 2 chunks on 2 workers: 2 written, 0 skipped (already there), 0 failed" in p.stdout
    assert_frames_complete(out, [3, 4])


@pytest.mark.parametrize("argv, message", [
    (["--frames", "1-3", "--out", "{out}"], "one of the arguments --scheduler --workers is required"),
    (["--frames", "1-3", "--workers", "0"], "argument --workers: --workers must be 1..1024, got 0"),
    (["--frames", "1-3", "--workers", "1", "--chunk", "x"], "argument --chunk: expected a whole number"),
    (["--frames", "3-1", "--workers", "1"], "bad --frames '3-1'"),
    (["--workers", "1"], "the following arguments are required: --frames"),
    (["--frames", "1", "--workers", "1", "--resolution", "3x"], "bad --resolution '3x'"),
    (["--frames", "1", "--workers", "1", "--samples", "0"], "bad --samples '0'"),
])
def test_bad_farm_arguments_exit_2_with_one_line(tmp_path, argv, message):
    argv = [a.replace("{out}", str(tmp_path / "out")) for a in argv]
    p = run_farm([PENUMBRA, "farm", SCENE, *argv])
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.splitlines() == [p.stderr.strip()] and message in p.stderr, p.stderr


def test_bad_input_found_by_the_farm_exits_2(cluster, tmp_path):
    cluster.ensure_workers(2)
    p = run_farm([PENUMBRA, "farm", str(tmp_path / "missing.blend"), "--frames", "1", "--workers", "1"])
    assert p.returncode == 2 and p.stderr.strip() == f"penumbra: error: no such file: {tmp_path / 'missing.blend'}"
    fake = tmp_path / "fake.blend"
    fake.write_text("not a blend")
    p = run_farm([PENUMBRA, "farm", str(fake), "--frames", "1-3", "--scheduler", cluster.address,
                  "--out", str(tmp_path / "out"), *RENDER])
    assert p.returncode == 2 and p.stderr.strip() == f"penumbra: error: not a .blend file: {fake}"
    assert "  failed 1-3: bad input: not a .blend file" in p.stdout        # once, not retried
    with socket_closed() as address:
        p = run_farm([PENUMBRA, "farm", SCENE, "--frames", "1", "--scheduler", address, "--out", str(tmp_path)])
    assert p.returncode == 2 and p.stderr.startswith(f"penumbra: error: cannot reach the Dask scheduler at {address}")


class socket_closed:
    """A tcp://127.0.0.1 address nothing listens on."""

    def __enter__(self):
        import socket
        s = socket.socket()
        s.bind(("127.0.0.1", 0))
        self.port = s.getsockname()[1]
        s.close()
        return f"tcp://127.0.0.1:{self.port}"

    def __exit__(self, *exc):
        return False
