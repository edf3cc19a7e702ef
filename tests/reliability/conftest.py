"""Fixtures of the reliability tests (real servers on loopback ports) and their summary: how
many bad inputs of each kind this run tried."""

from __future__ import annotations

import pytest

from tests.reliability.fuzzing import TRIED
from tests.service.conftest import (
    Server,
    free_port,
    server_env,
    small_capture,  # noqa: F401  (a fixture the tests here share)
)


@pytest.fixture
def server(tmp_path):
    """``server(**settings)``: a started ``wandcal serve`` on a loopback port, stopped after the test."""
    started = []

    def make(**settings) -> Server:
        (tmp_path / "replay").mkdir(exist_ok=True)
        srv = Server(port=free_port(), env=server_env(tmp_path, **settings), log=tmp_path / "server.log",
                     token=settings.get("token"))
        started.append(srv)
        return srv.start()

    yield make
    for srv in started:
        srv.stop()


def pytest_terminal_summary(terminalreporter):
    if not TRIED:
        return
    terminalreporter.section("bad inputs tried (tests/reliability)")
    for kind, count in sorted(TRIED.items()):
        terminalreporter.write_line(f"{count:6d}  {kind}")
    terminalreporter.write_line(f"{sum(TRIED.values()):6d}  in all, of {len(TRIED)} kinds")
