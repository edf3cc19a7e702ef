"""The sequential test alone, on windows of synthetic residuals with a known noise: a step in a
camera's pose is named at its window; a one-window burst of the same size (a few residuals of high
leverage off together, as merged markers' images give in clean takes) is not."""

import numpy as np

from wandcal.calib.watch.health import WINDOW_FRAMES
from wandcal.calib.watch.sequential import (
    BASELINE_WINDOWS,
    GLR_THRESHOLD,
    PERSIST_WINDOWS,
    Alarm,
    CameraTest,
    classify,
)

NOISE_PX = 0.3
RESIDUALS = 400  # a window of 40 markers' residuals
CHANGE = np.array([1e-3, 0.0, 0.0, 0.0, 0.0, 0.0])  # 0.057 deg: ~1 px at f = 1100 px, far past the threshold


def _window(rng, change):
    """(g, H, sse, n) of one window: residuals r = J change + noise, J of unit-scale pixels a radian x 1100."""
    J = rng.normal(0.0, 1100.0, (RESIDUALS, 2, 6))
    r = J @ change + rng.normal(0.0, NOISE_PX, (RESIDUALS, 2))
    H = np.einsum("kpi,kpj->ij", J, J)
    g = np.einsum("kpi,kp->i", J, r)
    fit = np.linalg.solve(H, g)
    sse = float(((r - J @ fit) ** 2).sum())
    return g, H, sse, float(RESIDUALS)


def _run(changes, seed):
    """The test over windows with the given (W, 6) pose change each: (the first alarm's window, its k)."""
    rng = np.random.default_rng(seed)
    test = CameraTest()
    for w, change in enumerate(changes):
        test.add(*_window(rng, change), start=w * WINDOW_FRAMES)
        S, k, _ = test.glr()
        if S > GLR_THRESHOLD:
            return w, k
    return None, None


def test_a_step_is_named_at_its_window():
    step = BASELINE_WINDOWS + 10
    changes = np.zeros((BASELINE_WINDOWS + 40, 6))
    changes[step:] = CHANGE
    for seed in range(3):
        alarmed, k = _run(changes, seed)
        assert k == step
        assert step < alarmed < step + 2 * PERSIST_WINDOWS  # named once each half holds enough windows


def test_a_one_window_burst_is_no_alarm():
    burst = BASELINE_WINDOWS + 10
    changes = np.zeros((BASELINE_WINDOWS + 40, 6))
    changes[burst] = CHANGE  # hundreds in chi-square units in one window, gone in the next
    for seed in range(3):
        assert _run(changes, seed) == (None, None)


def test_a_step_after_the_tests_k_is_a_knock_at_its_window():
    """The GLR's k may be the window before the move's (a knock late in a window shows there little):
    the step is still found at its own window, named a knock, not a ramp over the two."""
    step = BASELINE_WINDOWS + 10
    changes = np.zeros((BASELINE_WINDOWS + 30, 6))
    changes[step:] = CHANGE
    rng = np.random.default_rng(7)
    test = CameraTest()
    for w, change in enumerate(changes):
        test.add(*_window(rng, change), start=w * WINDOW_FRAMES)
    alarm = Alarm(0, (step - 1) * WINDOW_FRAMES, (step + 4) * WINDOW_FRAMES - 1, GLR_THRESHOLD, CHANGE)
    kind, frame, frames, change = classify(test, alarm)
    assert (kind, frame, frames) == ("knock", step * WINDOW_FRAMES, 0)
    # the change's rotation within 5 sigma of one window's noise (0.3 px over 400 residuals at 1100 px a radian)
    assert abs(change[0] - CHANGE[0]) < 5 * NOISE_PX / 1100.0 / np.sqrt(RESIDUALS)
