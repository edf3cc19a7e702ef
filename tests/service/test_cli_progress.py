"""What the command line prints besides its result: a progress line on a terminal only, nothing
with --quiet or into a pipe (but a command's closing line everywhere), never HiGHS's banner; its
version; its words."""

from __future__ import annotations

import io
import json
import os
import pty
import select
import subprocess
import sys
import time

import pytest

from tests.service.conftest import simulated_capture
from wandcal.service.cli.support.progress import REDRAW_S, ProgressLine

READ_TIMEOUT_S = 300.0  # a busy 2-core machine; the loop ends as soon as the process does


def wandcal(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "wandcal.service.cli", *args], capture_output=True, text=True,
                          cwd=cwd, timeout=READ_TIMEOUT_S, check=False)


def on_a_terminal(*args) -> tuple[int, str]:
    """Run with stderr on a pseudo-terminal (stdout piped apart); returns (exit code, terminal text)."""
    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "wandcal.service.cli", *args], stdout=subprocess.DEVNULL,
                            stderr=slave, stdin=subprocess.DEVNULL)
    os.close(slave)
    chunks = []
    deadline = time.monotonic() + READ_TIMEOUT_S
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            try:
                data = os.read(master, 65536)
            except OSError:  # the process closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    os.close(master)
    return proc.wait(30), b"".join(chunks).decode(errors="replace")


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return simulated_capture(tmp_path_factory.mktemp("progress") / "cap", cameras=4, frames=200, seed=3)[0]


@pytest.mark.parametrize("method", ["ba", "lp", "paper"])
def test_progress_on_a_terminal_and_none_elsewhere(capture, tmp_path, method):
    extra = ["--max-rounds", "3"] if method == "paper" else []
    code, text = on_a_terminal("calibrate", str(capture), "--method", method, "--out", str(tmp_path / "a.json"), *extra)
    assert code == 0, text
    assert f"refining with method '{method}'" in text and "done" in text
    code, text = on_a_terminal("calibrate", str(capture), "--method", method, "--out", str(tmp_path / "b.json"),
                               "--quiet", *extra)
    assert code == 0 and "refine" not in text
    r = wandcal("calibrate", str(capture), "--method", method, "--out", str(tmp_path / "c.json"), *extra)
    assert r.returncode == 0, r.stderr
    assert "refine" not in r.stderr and "\r" not in r.stderr  # a pipe gets no progress line
    assert "HiGHS" not in r.stdout and "Copyright" not in r.stdout


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_the_line_shows_rounds_and_cost_and_its_clock_moves_while_a_step_runs():
    term = Terminal()
    line = ProgressLine(term)
    line({"stage": "refine", "iteration": 3, "cost": 12.5, "message": "paper round 3"})
    assert "refine" in term.getvalue() and "iter 3  cost 12.5" in term.getvalue()
    drawn = term.getvalue().count("\r")
    # no event for a while (a long LP): the ticker redraws the line with the time gone by
    deadline = time.monotonic() + READ_TIMEOUT_S
    while term.getvalue().count("\r") == drawn and time.monotonic() < deadline:
        time.sleep(0.05)
    line.close()
    assert term.getvalue().count("\r") > drawn and term.getvalue().endswith("\n")
    for quiet in (ProgressLine(Terminal(), quiet=True), ProgressLine(io.StringIO())):
        quiet({"stage": "refine", "iteration": 1, "cost": 1.0})
        quiet.update("detect [###...] 3/10")
        quiet.close()
        assert quiet.stream.getvalue() == ""


class Clock:
    """A clock the test moves by hand (seconds)."""

    def __init__(self):
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_one_policy_for_a_command_s_own_text_and_its_closing_line():
    clock = Clock()
    term = Terminal()
    line = ProgressLine(term, clock=clock)
    line.update("wand 1/10")
    line.update("wand 2/10")  # at the same instant: not drawn
    clock.now += REDRAW_S
    line.update("wand 3/10")
    assert "wand 1/10" in term.getvalue() and "wand 2/10" not in term.getvalue() and "wand 3/10" in term.getvalue()
    line.done("recorded 10 wand sets")
    assert term.getvalue().endswith("\r\033[Krecorded 10 wand sets\n")  # the closing line replaces the progress
    line.close()  # after done(), nothing more
    line.update("wand 4/10")
    assert term.getvalue().endswith("recorded 10 wand sets\n")
    # the closing line is the command's result: printed into a pipe and with --quiet too, and alone
    for other in (ProgressLine(io.StringIO(), clock=clock), ProgressLine(Terminal(), quiet=True, clock=clock)):
        with other:
            other.update("wand 1/10")
            other.done("recorded 10 wand sets")
        assert other.stream.getvalue() == "recorded 10 wand sets\n"


def test_an_error_ends_the_line_before_its_message():
    term = Terminal()
    with pytest.raises(RuntimeError), ProgressLine(term) as line:
        line({"stage": "detect", "message": "frame 3"})
        raise RuntimeError("camera cam2 vanished")
    assert term.getvalue().endswith("\n") and line.ended


def test_highs_banner_stays_off_stdout_with_quiet(capture, tmp_path):
    r = wandcal("calibrate", str(capture), "--method", "lp", "--quiet", "--out", str(tmp_path / "r.json"))
    assert r.returncode == 0, r.stderr
    assert "HiGHS" not in r.stdout + r.stderr and r.stdout.startswith("camera")


def test_each_method_writes_its_own_file_and_says_when_it_replaces_one(capture):
    for method, name in (("ba", "result.json"), ("lp", "result-lp.json")):
        r = wandcal("calibrate", str(capture), "--method", method, "--quiet")
        assert r.returncode == 0, r.stderr
        assert r.stdout.rstrip().endswith(f"wrote {capture / name}")
    r = wandcal("calibrate", str(capture), "--quiet")
    assert r.stdout.rstrip().endswith(f"wrote {capture / 'result.json'} (replacing the earlier ba result)")


def test_version_and_help_defaults():
    r = wandcal("--version")
    assert r.returncode == 0 and r.stdout.startswith("wandcal ")
    for command, defaults in (("simulate", ("default 8)", "default 1500)", "default 1)")),
                              ("demo", ("default 6)", "default 800)", "default 1)"))):
        text = " ".join(wandcal(command, "--help").stdout.split())
        for words in defaults:
            assert words in text, (command, words)


def test_wandless_demo_prints_no_nan():
    r = wandcal("demo", "--cameras", "3", "--frames", "150", "--no-static")
    assert r.returncode == 0, r.stderr
    assert "nan" not in r.stdout and "aligned (mm)" in r.stdout


def test_guidance_on_a_session_without_a_wand_judges_its_points_and_does_not_ask_for_a_length(shared_data, tmp_path):
    """A points-only session (issue 32): each camera's points, links and coverage, no sigma without a scale."""
    session = shared_data / "multicamselfcal_strawlab_testdata" / "DATA20090709_111010"
    r = wandcal("import", "svoboda", str(session), "--focal-px", "600", "--out", str(tmp_path / "cap"))
    assert r.returncode == 0, r.stderr
    r = wandcal("guidance", str(tmp_path / "cap"), "--json")
    assert r.returncode == 0 and "length" not in r.stderr, r.stderr
    doc = json.loads(r.stdout)
    assert doc["solve"]["points_only"] and all(c["frames"] > 0 and c["center_std_mm"] is None for c in doc["cameras"])
