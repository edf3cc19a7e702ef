"""Fixtures of the capture tests."""

import pytest

from wandcal.capture.recording import framesets


@pytest.fixture
def patient_stall_limit(monkeypatch):
    """A camera silent for STALL_S (2 s) stops holding back sets, right for a rig; but on a loaded
    2-core machine a simulated camera's reader thread can be starved that long, and a set then goes
    out without it (stop 45's CI, decision 0108). For the tests that are not about stalls
    (test_sync.py's are)."""
    monkeypatch.setattr(framesets, "STALL_S", 30.0)
