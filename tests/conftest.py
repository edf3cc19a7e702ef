import os
import sys
from pathlib import Path

import pytest

# Bytecode is kept even where the environment says not to (PYTHONDONTWRITEBYTECODE=1 on this machine's image):
# every test module's assertion rewrite and every `wandcal` subprocess's import otherwise compiles its
# source again (the collection spent 95 of its 196 s compiling and rewriting, session 24).
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("WANDCAL_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture
def shared_data():
    """The third-party data beside the repository (../shared/data); skips the test when absent.

    Some of it carries no licence: it is read in place and never copied into the repository.
    """
    if not SHARED_DATA.is_dir():
        pytest.skip(f"third-party data not found at {SHARED_DATA}")
    return SHARED_DATA


# Each xdist worker's seconds in tests, printed at the end: whether the two workers were balanced (a
# simulation of xdist's schedulers on the suite's durations found `load` in collection order within
# a few seconds of even; the time is the tests' own, not the tail).
_WORKER_SECONDS: dict[str, float] = {}


def pytest_runtest_logreport(report):
    """Each xdist worker's seconds in tests (setup, call and teardown), for the balance line below."""
    node = getattr(report, "node", None)
    if node is not None:
        worker = node.gateway.id
        _WORKER_SECONDS[worker] = _WORKER_SECONDS.get(worker, 0.0) + report.duration


def pytest_terminal_summary(terminalreporter):
    if _WORKER_SECONDS:
        terminalreporter.write_line("seconds in tests by xdist worker: " + ", ".join(
            f"{w} {s:.0f}" for w, s in sorted(_WORKER_SECONDS.items())))


def long_except(values, keep, ids=None) -> list:
    """``values`` as parameters, each but those in ``keep`` marked ``long`` (decision 0111): the default
    suite runs one or two cases of a path, ``-m long`` the rest. ``ids``: a function naming a value."""
    name = ids or str
    return [pytest.param(v, id=name(v), marks=() if name(v) in keep else pytest.mark.long) for v in values]


@pytest.fixture
def patient_stall_limit(monkeypatch):
    """A camera silent for STALL_S (2 s) stops holding back sets, right for a rig; but on a loaded
    2-core machine a simulated camera's reader thread can be starved that long, and a set then goes
    out without it (stop 45's CI, decision 0108; this session's suite, cam3 of test_capture_pty and
    cam2 of test_replay). For the in-process recordings that are not about stalls (test_sync.py's and
    test_faults.py's stalled camera are)."""
    from wandcal.capture.recording import framesets  # here: the package is imported after the bytecode switch

    monkeypatch.setattr(framesets, "STALL_S", 30.0)
