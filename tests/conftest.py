import os
from pathlib import Path

import pytest

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
