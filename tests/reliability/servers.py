"""Helpers for the tests that drive the real server over loopback (tests/service/conftest.py's
:class:`Server`): polling with a deadline instead of fixed sleeps."""

from __future__ import annotations

import time

POLL_TIMEOUT_S = 60.0  # a busy 2-core CI box; every condition polled here is met in seconds
POLL_INTERVAL_S = 0.05


def poll(condition, what: str, timeout_s: float = POLL_TIMEOUT_S):
    """Call ``condition()`` until it returns something truthy, and return that; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = condition()
        if value:
            return value
        time.sleep(POLL_INTERVAL_S)
    raise AssertionError(f"waited {timeout_s:g} s for {what}")
