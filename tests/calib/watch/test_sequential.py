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


def test_the_smallest_detectable_turn_scores_what_the_test_names_half_the_time():
    """The turn :meth:`CameraTest.smallest_turn_deg` reports, along the camera's worst axis, has the
    non-centrality at which S passes the threshold half the time, over the whole span and each half
    (the smaller of the three); along any other axis the same turn scores more."""
    from wandcal.calib.watch.sequential import GLR_WINDOWS, median_detected

    rng = np.random.default_rng(5)
    test = CameraTest()
    for w in range(BASELINE_WINDOWS + GLR_WINDOWS):
        test.add(*_window(rng, np.zeros(6)), start=w * WINDOW_FRAMES)
    turn = np.radians(test.smallest_turn_deg())
    first, end = BASELINE_WINDOWS, len(test.g)
    mid = first + (end - first) // 2
    axes = np.linalg.qr(rng.normal(size=(3, 3)))[0].T
    scores = []
    for axis in [*axes, np.array([1.0, 0.0, 0.0])]:
        change = np.r_[turn * axis, np.zeros(3)]
        scores.append(min(_statistic_over(test, change, lo, hi) for lo, hi in ((first, end), (first, mid), (mid, end))))
    assert min(scores) >= median_detected() * (1 - 1e-9)


def _statistic_over(test, change, lo, hi):
    """A change's noise-free statistic over windows lo..hi-1 (``statistic_of`` over lo.. of the first hi)."""
    part = CameraTest()
    for w in range(hi):
        part.add(test.g[w], test.H[w], test.sse[w], test.n[w], test.start[w])
    return part.statistic_of(change, lo)


def test_a_step_among_windows_that_wander_is_a_knock_at_its_window():
    """A real camera's apparent pose wanders window to window far beyond its blobs' noise (its model a
    little off): a ramp bent to that wander must not be taken for a drift; the step is a knock."""
    step = BASELINE_WINDOWS + 10
    rng = np.random.default_rng(11)
    wander = rng.normal(0.0, 3e-5, (BASELINE_WINDOWS + 30, 6)) * [1, 1, 1, 0, 0, 0]  # ~10x the noise's pose scatter
    changes = wander.copy()
    changes[step:] += 3 * CHANGE
    test = CameraTest()
    for w, change in enumerate(changes):
        test.add(*_window(rng, change), start=w * WINDOW_FRAMES)
    alarm = Alarm(0, step * WINDOW_FRAMES, (step + 6) * WINDOW_FRAMES - 1, GLR_THRESHOLD, CHANGE)
    kind, frame, frames, _ = classify(test, alarm)
    assert (kind, frame, frames) == ("knock", step * WINDOW_FRAMES, 0)
