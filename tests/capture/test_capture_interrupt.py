"""``wandcal capture`` stopped by its operator, on a real pseudo-terminal with real signals: Ctrl-C
(the terminal's ^C, which signals the whole foreground process group, the guidance's solver
process too), end of input (^D) at the pause, and the terminal closing (SIGHUP). Each leaves a
folder that says what it holds, exits 130 and prints no traceback. Every wait polls the terminal
or the folder against a deadline; none sleeps."""

from __future__ import annotations

import csv
import json
import os
import pty
import select
import sys
import time
from pathlib import Path

import pytest

from wandcal.capture.folder import read_capture
from wandcal.drivers.trigger_emulator import EmulatorProcess

REPO = Path(__file__).resolve().parents[2]
DEADLINE_S = 120.0  # a loaded 2-core machine: the child imports NumPy and spawns the solver process
CTRL_C, CTRL_D = b"\x03", b"\x04"
PROMPT = "press Enter to record the wand"
# Free-running simulated cameras at 100 Hz: a 5000-set run lasts 50 s, far longer than any test waits
LONG = ["--camera", "sim://?cameras=3&seed=2", "--frames", "5000", "--rate", "100", "--images", "none"]


class Terminal:
    """``wandcal ARGS`` as the session leader of a new pseudo-terminal, which is its controlling
    terminal: ^C and ^D written here reach it through the terminal's line discipline."""

    def __init__(self, *args: str):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])))
        self.pid, self.fd = pty.fork()
        if self.pid == 0:  # the child: nothing but exec
            os.execve(sys.executable, [sys.executable, "-m", "wandcal.service.cli", *args], env)
        self.output = b""
        self.code: int | None = None

    @property
    def text(self) -> str:
        return self.output.decode(errors="replace")

    def _read(self, timeout: float) -> bool:
        """Read what the terminal shows within ``timeout`` s; False once the child closed it."""
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return True
        try:
            chunk = os.read(self.fd, 65536)
        except OSError:  # EIO: every process holding the terminal is gone
            return False
        self.output += chunk
        return bool(chunk)

    def wait_for(self, condition, what: str) -> None:
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"no {what} within {DEADLINE_S:g} s:\n{self.text[-3000:]}"
            if not self._read(0.05):
                assert condition(), f"the capture ended before {what}:\n{self.text[-3000:]}"

    def send(self, keys: bytes) -> None:
        os.write(self.fd, keys)

    def finish(self) -> int:
        """Read until the child exits; its exit code."""
        deadline = time.monotonic() + DEADLINE_S
        while self._read(0.05):
            assert time.monotonic() < deadline, f"the capture did not end:\n{self.text[-3000:]}"
        return self.exit_code(deadline)

    def hang_up(self) -> int:
        """Close the terminal, as closing its window does (the kernel sends SIGHUP); the exit code."""
        os.close(self.fd)
        self.fd = -1
        return self.exit_code(time.monotonic() + DEADLINE_S)

    def exit_code(self, deadline: float) -> int:
        while True:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.code = os.waitstatus_to_exitcode(status)
                return self.code
            assert time.monotonic() < deadline, "the capture did not exit"
            select.select([], [], [], 0.05)  # a bounded poll of the child's state

    def close(self) -> None:
        if self.code is None:
            os.kill(self.pid, 9)
            os.waitpid(self.pid, 0)
        if self.fd >= 0:
            os.close(self.fd)


@pytest.fixture
def terminals():
    opened: list[Terminal] = []

    def start(*args: str) -> Terminal:
        opened.append(Terminal(*args))
        return opened[-1]

    yield start
    for t in opened:
        t.close()


def wand_rows(folder: Path) -> int:
    if not (folder / "sync.csv").is_file():
        return 0
    with open(folder / "sync.csv", newline="") as fh:
        return max(sum(1 for row in csv.reader(fh) if row) - 1, 0)


def log(folder: Path) -> dict:
    return json.loads((folder / "capture.json").read_text())


def assert_clean(t: Terminal) -> None:
    assert "Traceback" not in t.text and "BrokenProcessPool" not in t.text, t.text[-3000:]


def test_ctrl_c_during_the_wand_keeps_a_partial_capture_that_calibrates(tmp_path, terminals):
    out = tmp_path / "cap"
    t = terminals("capture", *LONG, "--out", str(out))
    # the guidance has spoken (its solver process is running) and 300 sets are on disk
    t.wait_for(lambda: "guidance:" in t.text and wand_rows(out) >= 300, "300 wand sets with guidance")
    t.send(CTRL_C)
    assert t.finish() == 130
    assert_clean(t)
    doc = log(out)
    assert doc["state"] == "partial" and doc["error"] == "interrupted by the user"
    assert doc["frame_sets"] == wand_rows(out) >= 300
    assert f"interrupted; kept {doc['frame_sets']} wand sets" in t.text
    assert f"wandcal calibrate {out}" in t.text and "--overwrite" in t.text
    assert read_capture(out).wand.frame.max() < doc["frame_sets"]  # the points level reads, up to the last set


def _ctrl_c_at_the_pause(t, out) -> None:
    """^C at the pause's prompt: exit 130, no traceback, the 5 static sets kept as a partial capture
    and the message saying how to go on."""
    t.send(CTRL_C)
    assert t.finish() == 130
    assert_clean(t)
    assert log(out)["state"] == "partial" and log(out)["static_sets"] == 5 and wand_rows(out) == 0
    assert "kept 0 wand sets and 5 static sets" in t.text and f"same --out {out}" in t.text


def test_ctrl_c_at_the_pause_leaves_a_folder_the_same_command_records_into(tmp_path, terminals):
    out = tmp_path / "cap"
    with EmulatorProcess() as emu:
        args = ["capture", "--camera", "sim://?cameras=3&seed=2", "--trigger", emu.url, "--static-frames", "5",
                "--frames", "40", "--rate", "200", "--images", "none", "--no-guidance", "--out", str(out)]
        t = terminals(*args)
        t.wait_for(lambda: PROMPT in t.text, "the pause's prompt")
        _ctrl_c_at_the_pause(t, out)

        again = terminals(*args)  # the same command, the same --out: accepted, and this time Enter
        again.wait_for(lambda: PROMPT in again.text, "the second run's prompt")
        again.send(b"\r")
        assert again.finish() == 0, again.text[-3000:]
    assert f"replacing a partial capture of 0 wand sets in {out}" in again.text
    assert log(out)["state"] == "complete" and wand_rows(out) == 40


FREE_RUN_PAUSE = ["capture", "--camera", "sim://?cameras=3&seed=2", "--static-frames", "5", "--frames", "40",
                  "--rate", "200", "--images", "none", "--no-guidance"]


def test_free_running_cameras_pause_for_the_l_frame_until_enter(tmp_path, terminals):
    out = tmp_path / "cap"
    t = terminals(*FREE_RUN_PAUSE, "--out", str(out))  # no trigger, no --no-pause
    t.wait_for(lambda: PROMPT in t.text, "the pause's prompt")
    assert wand_rows(out) == 0  # the cameras stream on, but nothing reaches the wand run
    t.send(b"\r")
    assert t.finish() == 0, t.text[-3000:]
    assert_clean(t)
    doc = log(out)
    assert doc["state"] == "complete" and doc["static_sets"] == 5 and doc["frame_sets"] == wand_rows(out) == 40
    assert doc["complete_sets"] == 45  # the simulator's script held through the pause: every wand frame came
    assert read_capture(out).static is not None


def test_ctrl_c_in_a_free_running_pause_keeps_the_static_sets(tmp_path, terminals):
    out = tmp_path / "cap"
    t = terminals(*FREE_RUN_PAUSE, "--out", str(out))
    t.wait_for(lambda: PROMPT in t.text, "the pause's prompt")
    _ctrl_c_at_the_pause(t, out)
    again = terminals(*FREE_RUN_PAUSE, "--no-pause", "--out", str(out))  # usable: recorded into again
    assert again.finish() == 0, again.text[-3000:]
    assert log(out)["state"] == "complete" and wand_rows(out) == 40


def test_end_of_input_at_the_pause_stops_as_ctrl_c_does(tmp_path, terminals):
    out = tmp_path / "cap"
    with EmulatorProcess() as emu:
        t = terminals("capture", "--camera", "sim://?cameras=2&seed=4", "--trigger", emu.url, "--static-frames", "5",
                      "--frames", "40", "--rate", "200", "--images", "none", "--no-guidance", "--out", str(out))
        t.wait_for(lambda: PROMPT in t.text, "the pause's prompt")
        t.send(CTRL_D)
        assert t.finish() == 130
    assert_clean(t)
    assert log(out)["state"] == "partial" and log(out)["static_sets"] == 5


def test_a_closed_terminal_keeps_what_was_recorded(tmp_path, terminals):
    out = tmp_path / "cap"
    t = terminals("capture", *LONG, "--out", str(out))
    t.wait_for(lambda: "guidance:" in t.text and wand_rows(out) >= 100, "100 wand sets with guidance")
    assert t.hang_up() == 130
    doc = log(out)
    assert doc["state"] == "partial" and doc["frame_sets"] == wand_rows(out) >= 100


def test_a_folder_with_a_capture_is_refused_unless_overwrite(tmp_path, terminals):
    out = tmp_path / "cap"
    short = ["capture", "--camera", "sim://?cameras=2&seed=4", "--frames", "20", "--images", "none", "--no-guidance",
             "--out", str(out)]
    assert terminals(*short).finish() == 0
    refused = terminals(*short)
    assert refused.finish() == 2
    assert "already holds a complete capture of 20 wand sets" in refused.text and "--overwrite" in refused.text
    replaced = terminals(*short, "--overwrite")
    assert replaced.finish() == 0 and log(out)["state"] == "complete"
