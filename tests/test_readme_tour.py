"""The README's tour of the command line, run as written, top to bottom, in an empty folder.

Each line of the tour's ``sh`` block runs in order as a real ``wandcal`` process, and its result is
checked: the exit code, the files it should make, and that it replaced no file an earlier line
made. Only these are changed, each for a stated reason:

- sizes (:data:`FAST`): the tour's 8 x 1500 simulation, 20 paper rounds and 3000-set capture
  take minutes on a shared 2-core machine; the same commands at smaller sizes exercise the same
  code. The capture example at its full size is the second test.
- ``SESSION_easyWandData.mat``, the user's own session: the Brown wind tunnel session from
  ``../shared/data`` (those two lines are skipped, and say so, when it is absent).
- ``wandcal trigger-emulator`` runs in the background, as in the second terminal the tour asks
  for, and the path it prints replaces ``/dev/ttyACM0`` (there is no board here).
- ``wandcal serve --port 8750``: a free port; the test asks it for its health, registers a capture
  by path as the README's service section shows, and stops it with SIGINT, as Ctrl-C does.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SESSION = "easywand_brown_windtunnel_4cam/calibration1/extrinsicCalib_20230228_easyWandData.mat"
# option -> {the tour's value: the value run here}; applied to every line that has the option
FAST = {
    "--cameras": {"8": "4"},
    "--frames": {"1500": "300", "600": "200", "3000": "300", "150": "60"},
    "--max-rounds": {"20": "3"},
    "--static-frames": {"100": "20"},
}
# Files a line may rewrite, with the reason: 'detect' exists to replace a capture's points level.
REWRITES = {"detect": ("wand.csv", "static.csv", "blobs.csv")}
PROCESS_TIMEOUT_S = 600.0  # a hung line fails the test instead of hanging it
START_TIMEOUT_S = 60.0  # serve spawns solver processes that import numpy/scipy; slow on a busy box
STOP_TIMEOUT_S = 5.0  # the README: serve stops within a few seconds of Ctrl-C


def tour_lines(section: str = "## A quick tour of the command line") -> list[list[str]]:
    """The commands of the first ``sh`` block after ``section`` in README.md, comments dropped."""
    text = (REPO / "README.md").read_text()
    after = text[text.index(section):]
    block = re.search(r"```sh\n(.*?)```", after, re.S).group(1)
    return [shlex.split(line, comments=True) for line in block.splitlines() if line.strip()]


def fast(argv: list[str]) -> list[str]:
    out = list(argv)
    for i, arg in enumerate(out[:-1]):
        if arg in FAST and out[i + 1] in FAST[arg]:
            out[i + 1] = FAST[arg][out[i + 1]]
    return out


HASHED_BYTES = 1 << 20  # results, CSV and JSON are compared by content; images (0.5 MB PNGs) by time


def snapshot(root: Path) -> dict[Path, object]:
    """Each file's content digest (its time and size when large): a file rewritten with the same
    content is not replaced."""
    def stamp(p: Path):
        st = p.stat()
        if st.st_size <= HASHED_BYTES:
            return hashlib.sha256(p.read_bytes()).hexdigest()
        return st.st_mtime_ns, st.st_size

    return {p: stamp(p) for p in root.rglob("*") if p.is_file()}


def run(argv: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    assert argv[0] == "wandcal", argv
    # the operator's Enter at capture's pause after the L-frame (stdin is no terminal here: it reads a line)
    return subprocess.run([sys.executable, "-m", "wandcal.service.cli", *argv[1:]], cwd=cwd, capture_output=True,
                          text=True, timeout=PROCESS_TIMEOUT_S, env=env, check=False, input="\n")


def wait_for(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"{what} within {timeout_s} s")


class Emulator:
    """``wandcal trigger-emulator`` in the background; ``path`` is the pseudo-terminal it printed."""

    def __init__(self, argv: list[str], cwd: Path):
        self.log = cwd / "emulator.log"
        with open(self.log, "w") as out:  # the emulator writes through its own copy of the descriptor
            self.proc = subprocess.Popen([sys.executable, "-m", "wandcal.service.cli", *argv[1:]], cwd=cwd,
                                         stdout=out, stderr=subprocess.STDOUT)
        found = wait_for(lambda: re.search(r"/dev/pts/\d+", self.log.read_text()) or self.proc.poll() is not None,
                         START_TIMEOUT_S, "the trigger emulator printed no pseudo-terminal")
        assert self.proc.poll() is None, self.log.read_text()
        self.path = found.group(0)

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def serve_and_stop(argv: list[str], cwd: Path) -> None:
    """The tour's serve line on a free port, with the service section's replay root; checked and
    stopped with SIGINT."""
    service = [" ".join(line) for line in tour_lines("## The service in brief")]
    # what this function does in place of the section's two lines: the replay root, then the curl
    assert service[0].startswith("WANDCAL_REPLAY_ROOT=$PWD/out wandcal serve") and "-F path=sim" in service[1]
    port = free_port()
    argv = [port if a == "8750" else a for a in argv]
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDCAL_")}
    env.update(WANDCAL_REPLAY_ROOT=str(cwd / "out"), WANDCAL_DATA_DIR=str(cwd / "wandcal-data"))
    log = cwd / "serve.log"
    with open(log, "w") as out:  # the server writes through its own copy of the descriptor
        proc = subprocess.Popen([sys.executable, "-m", "wandcal.service.cli", *map(str, argv[1:]), "--log-level",
                                 "warning"], cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}/api/v1"
    try:
        def healthy():
            assert proc.poll() is None, log.read_text()
            try:
                return httpx.get(url + "/health", timeout=1.0).status_code == 200
            except httpx.TransportError:
                return False

        wait_for(healthy, START_TIMEOUT_S, "serve did not answer")
        # the service section's curl -F path=sim: a multipart form
        r = httpx.post(url + "/captures", files={"path": (None, "sim")}, timeout=30.0)
        assert r.status_code == 201, r.text
        assert r.json()["cameras"] == [f"cam{i}" for i in range(1, 5)]
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(STOP_TIMEOUT_S + 20)
    assert proc.returncode == 0, log.read_text()
    assert "Traceback" not in log.read_text()


def check_line(argv: list[str], r: subprocess.CompletedProcess, cwd: Path) -> None:
    """What each kind of line must have made, beyond exit code 0."""
    command = argv[1]
    if command == "calibrate":
        wrote = re.search(r"^wrote (\S+)", r.stdout, re.M)
        assert wrote, r.stdout
        doc = json.loads((cwd / wrote.group(1)).read_text())
        method = argv[argv.index("--method") + 1] if "--method" in argv else "ba"
        assert doc["format"] == "wandcal-result/1" and doc["solver"]["method"] == method
        assert "HiGHS" not in r.stdout  # the solver's banner is not part of the result
        truth = (cwd / argv[2] / "truth.json")
        if truth.is_file() and "--solve-only" not in argv and method == "ba":
            C = np.array([c["center"] for c in doc["cameras"]])
            Ct = np.array([c["center"] for c in json.loads(truth.read_text())["cameras"]])
            if doc["world"]["frame"] == "static_object":
                # world from the L-frame: the simulator's own frame, to a few mm (tests/service/test_cli.py)
                assert np.linalg.norm(C - Ct, axis=1).max() < 0.005, (argv, C - Ct)
            else:  # a floor or a drop sets the vertical alone: the cameras' heights above their mean agree
                dz = (C[:, 2] - C[:, 2].mean()) - (Ct[:, 2] - Ct[:, 2].mean())
                assert doc["world"]["frame"] in ("floor", "gravity") and np.abs(dz).max() < 0.005, (argv, dz)
    elif command == "simulate":
        assert (cwd / argv[2] / "truth.json").is_file()
    elif command == "report":
        assert (cwd / argv[argv.index("--out") + 1] / "index.html").is_file()
    elif command == "export":
        assert (cwd / argv[argv.index("--out") + 1]).stat().st_size > 0
    elif command == "check":
        assert "every camera agrees" in r.stdout, r.stdout  # the same rig, nothing moved
    elif command == "demo":
        assert "nan" not in r.stdout, r.stdout
    elif command == "capture":
        out = cwd / argv[argv.index("--out") + 1]
        want = int(argv[argv.index("--frames") + 1]), int(argv[argv.index("--static-frames") + 1])
        assert f"recorded {want[0]} wand sets and {want[1]} static sets" in r.stdout + r.stderr, r.stdout + r.stderr
        assert (out / "wand.csv").is_file() and (out / "static.csv").is_file()
    elif command in ("import", "detect"):
        folder = argv[argv.index("--out") + 1] if "--out" in argv else argv[2]
        assert (cwd / folder / "wand.csv").is_file()


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
@pytest.mark.slow
def test_readme_tour_runs_top_to_bottom(tmp_path, shared_data_or_none):
    lines = [fast(argv) for argv in tour_lines()]
    assert [a[0] for a in lines] == ["wandcal"] * len(lines)
    emulator = None
    skipped = []
    try:
        for words in lines:
            argv = words
            if "SESSION_easyWandData.mat" in argv or (argv[1] == "calibrate" and argv[2] == "out/easywand"):
                if shared_data_or_none is None:
                    skipped.append(" ".join(argv))
                    continue
                argv = [str(shared_data_or_none / SESSION) if a == "SESSION_easyWandData.mat" else a for a in argv]
            if argv[1] == "trigger-emulator":
                emulator = Emulator(argv, tmp_path)
                continue
            if argv[1] == "serve":
                serve_and_stop(argv, tmp_path)
                continue
            if "/dev/ttyACM0" in argv:
                assert emulator is not None, "the tour starts the trigger emulator before the capture"
                argv = [emulator.path if a == "/dev/ttyACM0" else a for a in argv]
            before = snapshot(tmp_path)
            r = run(argv, tmp_path)
            assert r.returncode == 0, f"{' '.join(argv)} exited {r.returncode}:\n{r.stdout}\n{r.stderr}"
            assert "Traceback" not in r.stderr
            after = snapshot(tmp_path)
            allowed = REWRITES.get(argv[1], ())
            changed = [str(p.relative_to(tmp_path)) for p, stamp in before.items()
                       if p.name not in allowed and p.name != "emulator.log" and after.get(p) != stamp]
            assert not changed, f"{' '.join(argv)} replaced files of earlier lines: {changed}"
            check_line(argv, r, tmp_path)
    finally:
        if emulator is not None:
            emulator.close()
    if skipped:
        print(f"skipped without ../shared/data (the user's own easyWand session): {skipped}")


@pytest.fixture
def shared_data_or_none():
    """../shared/data as tests/conftest.py finds it, or None: the tour runs without it, less two lines."""
    root = Path(os.environ.get("WANDCAL_SHARED_DATA", REPO.parent / "shared" / "data"))
    return root if (root / SESSION).is_file() else None


@pytest.mark.long  # decision 0111: a shorter test of the same path stays in the default suite
@pytest.mark.slow
def test_readme_capture_example_as_written(tmp_path):
    """The tour's capture line at its full size (3000 wand sets after 100 of the L-frame), with the
    emulator's pseudo-terminal for /dev/ttyACM0; then the tour's calibrate of it."""
    lines = tour_lines()
    emulator = Emulator(next(a for a in lines if a[1] == "trigger-emulator"), tmp_path)
    try:
        argv = next(a for a in lines if a[1] == "capture" and "/dev/ttyACM0" in a)
        argv = [emulator.path if a == "/dev/ttyACM0" else a for a in argv]
        r = run(argv, tmp_path)
        assert r.returncode == 0, r.stdout + r.stderr
    finally:
        emulator.close()
    out = argv[argv.index("--out") + 1]
    frames, static = int(argv[argv.index("--frames") + 1]), int(argv[argv.index("--static-frames") + 1])
    assert f"recorded {frames} wand sets and {static} static sets" in r.stdout + r.stderr
    r = run(["wandcal", "calibrate", out], tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    check_line(["wandcal", "calibrate", out], r, tmp_path)
