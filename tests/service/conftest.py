"""Fixtures for the service tests: simulated capture folders and real servers on loopback ports."""

from __future__ import annotations

import contextlib
import faulthandler
import io
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from wandcal.calib.judge.coverage import GRID
from wandcal.calib.rig import WandObservations
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.capture.folder import read_capture, write_capture
from wandcal.drivers.capture_files import RIG_FILE, STATIC_FILE, WAND_FILE

REPO = Path(__file__).resolve().parents[2]
STARTUP_TIMEOUT_S = 60.0  # spawning workers imports numpy/scipy/OpenCV; slow on a busy 2-core CI box
JOB_TIMEOUT_S = 120.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def capture_files(folder: Path) -> dict:
    """multipart ``files=`` for httpx from a capture folder."""
    names = [n for n in (RIG_FILE, WAND_FILE, STATIC_FILE) if (folder / n).is_file()]
    return {n: (n, (folder / n).read_bytes(), "application/octet-stream") for n in names}


@dataclass
class Server:
    """A ``wandcal serve`` subprocess on a loopback port."""

    port: int
    env: dict
    log: Path
    proc: subprocess.Popen | None = None
    token: str | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def client(self, **kwargs) -> httpx.Client:
        headers = {"Authorization": f"Bearer {self.token}"} if self.token else {}
        # a connection per request: httpx does not resend a request on a kept-alive connection that the
        # server closed as it was sent (a browser does), and on a starved CI box that race lost a test
        kwargs.setdefault("limits", httpx.Limits(max_keepalive_connections=0))
        return httpx.Client(base_url=self.url + "/api/v1", headers=headers, timeout=120.0, **kwargs)  # a first report is drawn on the GET: >30 s on a busy machine

    def start(self, timeout_s: float = STARTUP_TIMEOUT_S) -> Server:
        with open(self.log, "ab") as log:  # the server writes through its own copy of the descriptor
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "wandcal.service.cli", "serve", "--port", str(self.port), "--log-level", "warning"],
                cwd=REPO, env=self.env, stdout=log, stderr=subprocess.STDOUT,
            )
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log.read_text()}")
            try:
                if httpx.get(self.url + "/api/v1/health", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"server did not answer within {timeout_s:g} s:\n{self.log.read_text()}")

    def kill(self) -> None:
        """SIGKILL: no shutdown code runs, as when the machine loses power."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.kill()


def server_env(tmp_path: Path, **settings) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDCAL_")}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    env["WANDCAL_DATA_DIR"] = str(tmp_path / "data")
    env["WANDCAL_REPLAY_ROOT"] = str(tmp_path / "replay")
    for key, value in settings.items():
        env[f"WANDCAL_{key.upper()}"] = str(value)
    return env


@pytest.fixture
def make_server(tmp_path):
    servers = []

    def make(**settings) -> Server:
        (tmp_path / "replay").mkdir(exist_ok=True)
        token = settings.get("token")
        server = Server(port=free_port(), env=server_env(tmp_path, **settings), log=tmp_path / "server.log", token=token)
        servers.append(server)
        return server

    yield make
    for s in servers:
        s.stop()


def simulated_capture(folder: Path, **simulation):
    """A points-level capture folder from :func:`wandcal.calib.sim.simulate.simulate_capture`, and the simulation."""
    sim = simulate_capture(**simulation)
    write_capture(folder, sim.rig, sim.wand, sim.static)
    return folder, sim


@pytest.fixture(scope="session")
def small_capture(tmp_path_factory):
    """4 cameras, 300 frames, 0.3 px noise, with the L-frame: a capture folder and its truth."""
    return simulated_capture(tmp_path_factory.mktemp("capture") / "small", cameras=4, frames=300, noise_px=0.3,
                             seed=11)


@pytest.fixture(scope="session")
def big_capture(tmp_path_factory):
    """A capture big enough that the solve takes seconds, so a kill or cancel lands while it runs."""
    return simulated_capture(tmp_path_factory.mktemp("big") / "capture", cameras=8, frames=1500, noise_px=0.3, seed=5)


@pytest.fixture(scope="session")
def watch_standing(tmp_path_factory) -> Path:
    """The watch tests' standing result (test_cli_watch, test_live_take, test_page_watch): ``wandcal
    simulate --cameras 6 --frames 600 --seed 7`` calibrated by the command line, once a worker (each
    of them made the same file itself). Read it, or copy it before writing beside it."""
    root = tmp_path_factory.mktemp("watch_standing")
    for args in (("simulate", root / "wand", "--cameras", 6, "--frames", 600, "--seed", 7),
                 ("calibrate", root / "wand", "--out", root / "standing.json", "--quiet")):
        r = wandcal(*args)
        assert r.returncode == 0, r.stderr
    return root / "standing.json"


WATCH_KNOCK = ("--take", "--cameras", 6, "--frames", 600, "--seed", 7, "--move", "cam2:300:0.3:2")


@pytest.fixture(scope="session")
def watch_knock_take(watch_standing) -> Path:
    """The watch tests' knocked take (test_cli_watch, test_watch_api): ``wandcal simulate --take``
    of :data:`WATCH_KNOCK` beside :func:`watch_standing` (its folder)."""
    knock = watch_standing.parent / "knock"
    r = wandcal("simulate", knock, *WATCH_KNOCK)
    assert r.returncode == 0, r.stderr
    return knock


@pytest.fixture(scope="session")
def watch_knock(watch_standing, watch_knock_take) -> tuple[Path, subprocess.CompletedProcess]:
    """:func:`watch_knock_take`, and ``wandcal watch STANDING KNOCK --json --write knock_updated.json``
    run on it once a worker (each file ran the same command): minutes here, so only the long tests ask."""
    knock = watch_knock_take
    return knock, wandcal("watch", watch_standing, knock, "--json", "--write", knock.parent / "knock_updated.json",
                          timeout=900)


def wait_job(client: httpx.Client, job_id: str, timeout_s: float = JOB_TIMEOUT_S, until=("done", "failed", "cancelled")):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/jobs/{job_id}").json()
        if job["state"] in until:
            return job
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} still {job['state']} after {timeout_s} s")


EMPTY_CAMERA = 1  # cam2: the camera whose left third of the image the wand never reaches


# commands whose claims are about the process itself (signals, its exit, a terminal): always a subprocess
PROCESS_COMMANDS = {"serve", "capture"}


def wandcal(*args, timeout: float = 600) -> subprocess.CompletedProcess:
    """``wandcal ARGS...`` as a user runs it (arguments may be paths or numbers), from the repository.

    A batch command runs in this process (``wandcal.service.cli.main``, its output captured): a
    subprocess spent 4-13 s of this machine's CPU importing NumPy, SciPy and OpenCV again before its
    first line (decision 0111). A command of :data:`PROCESS_COMMANDS` starts ``python -m
    wandcal.service.cli`` instead. A run in process past ``timeout`` ends the worker with
    every thread's stack on stderr (faulthandler), as a subprocess past it would fail the test."""
    argv = [str(a) for a in args]
    if argv and argv[0] in PROCESS_COMMANDS:
        return subprocess.run([sys.executable, "-m", "wandcal.service.cli", *argv], capture_output=True, text=True,
                              cwd=REPO, timeout=timeout, check=False)
    return _in_process(argv, timeout)


def _in_process(argv: list[str], timeout: float) -> subprocess.CompletedProcess:
    from wandcal.service.cli import main

    out, err = io.StringIO(), io.StringIO()
    # a subprocess writes an unhandled logger's warnings to its stderr (logging's last resort): so here
    said = logging.StreamHandler(err)
    said.setLevel(logging.WARNING)
    logging.getLogger().addHandler(said)
    faulthandler.dump_traceback_later(timeout, exit=True)
    try:
        with contextlib.chdir(REPO), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors and --help
                if isinstance(exc.code, str):  # a message: printed, exit 1, as the interpreter does
                    print(exc.code, file=sys.stderr)
                code = exc.code if isinstance(exc.code, int) else int(exc.code is not None)
    finally:
        faulthandler.cancel_dump_traceback_later()
        logging.getLogger().removeHandler(said)
    return subprocess.CompletedProcess(["wandcal", *argv], code, out.getvalue(), err.getvalue())


def left_third_px(width: int) -> float:
    """The right edge of the coverage grid's left third, pixels (wandcal.calib.judge.coverage splits columns
    into thirds of whole cells)."""
    return round(GRID[1] / 3) * width / GRID[1]


@pytest.fixture(scope="session")  # one report for test_report*.py
def sim_report(tmp_path_factory):
    """A simulated 4-camera capture whose cam2 never sees the wand in its left third, its
    result, and its report drawn by the command line."""
    tmp = tmp_path_factory.mktemp("report")
    sim = simulate_capture(4, 300, 0.3, 0.0, True, 11)
    cam = sim.rig.cameras[EMPTY_CAMERA]
    keep = ~((sim.wand.camera == EMPTY_CAMERA) & (sim.wand.uv[:, 0] < left_third_px(cam.width)))
    wand = WandObservations(sim.wand.frame[keep], sim.wand.camera[keep], sim.wand.uv[keep])
    folder = tmp / "capture"
    write_capture(folder, sim.rig, wand, sim.static)
    cap = read_capture(folder)
    result = calibrate(cap.rig, cap.wand, cap.static)
    (tmp / "result.json").write_text(json.dumps(result.to_json()))
    run = wandcal("report", str(tmp / "result.json"), "--capture", str(folder), "--out", str(tmp / "out"))
    assert run.returncode == 0, run.stderr
    return tmp, sim, run
