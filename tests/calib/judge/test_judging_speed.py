"""The judgement's faster paths (issue 31's speed) give what the plain code gave, bit for bit: the
pose columns (analytic in one pass; by finite differences with the step turns made once), each
camera's rows of the residuals' layout, and the step screen's views chosen before the gather.
Exact equality: these feed figures a result writes to the last digit."""

from __future__ import annotations

import numpy as np

from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.judge.faults import moved
from wandcal.calib.judge.faults.screen import POSE_STEP, _pose_columns
from wandcal.calib.judge.residuals import _rows_by_camera
from wandcal.calib.observations import camera_rows


def _project(R, t, X):
    Xc = X @ R.T + t
    return Xc[:, :2] / Xc[:, 2:]


def _plain_differences(R, t, X):
    """The forward differences as they were written first: seven projections, a turn made per step."""
    base = _project(R, t, X)
    cols = []
    for j in range(6):
        step = np.zeros(6)
        step[j] = POSE_STEP
        cols.append(((_project(rotvec_to_matrix(step[:3]) @ R, t + step[3:], X) - base) / POSE_STEP).ravel())
    return np.stack(cols, axis=1)


def _plain_analytic(R, t, X):
    """The analytic columns one at a time, each camera-frame motion broadcast."""
    RX = X @ R.T
    Xc = RX + t
    z = Xc[:, 2]
    x, y = Xc[:, 0] / z, Xc[:, 1] / z
    zero = np.zeros(len(X))
    moves = np.stack([np.stack([zero, -RX[:, 2], RX[:, 1]], axis=1), np.stack([RX[:, 2], zero, -RX[:, 0]], axis=1),
                      np.stack([-RX[:, 1], RX[:, 0], zero], axis=1)])
    cols = np.empty((2 * len(X), 6))
    for j in range(6):
        v = np.broadcast_to(moves[j] if j < 3 else np.eye(3)[j - 3][None, :], (len(X), 3))
        cols[0::2, j] = (v[:, 0] - x * v[:, 2]) / z
        cols[1::2, j] = (v[:, 1] - y * v[:, 2]) / z
    return cols


def test_pose_columns_are_the_plain_codes_bit_for_bit():
    rng = np.random.default_rng(31)
    for trial in range(60):
        R = rotvec_to_matrix(rng.normal(size=3))
        if trial % 3 == 0:
            R = np.asfortranarray(R)  # a pose not laid out as the step turns are
        t = rng.normal(size=3) + [0, 0, 5]
        X = rng.normal(size=(int(rng.integers(1, 800)), 3)) * rng.choice([1.0, 0.0], size=(1, 3), p=[0.8, 0.2])
        assert _pose_columns(R, t, X, differences=True).tobytes() == _plain_differences(R, t, X).tobytes()
        assert _pose_columns(R, t, X).tobytes() == _plain_analytic(R, t, X).tobytes()


def test_rows_by_camera_are_camera_rows_of_the_laid_out_observations():
    rng = np.random.default_rng(32)
    for trial in range(60):
        n = int(rng.integers(1, 20))
        pairs, tracks = rng.integers(0, n, int(rng.integers(0, 400))), rng.integers(0, n, int(rng.integers(1, 200)))
        tracks = tracks if trial % 2 else None
        laid_out = np.concatenate([pairs, pairs] + ([tracks] if tracks is not None else []))
        m = int(laid_out.max()) + 1 if len(laid_out) else 0
        want, got = camera_rows(laid_out, m), _rows_by_camera(pairs, tracks, m)
        assert len(got) == len(want)
        assert all(g.dtype == w.dtype and np.array_equal(g, w) for g, w in zip(got, want))


def test_the_step_screens_views_chosen_first_are_chosen_again():
    """step_suspects gathers only the views screen_views picks; step_screen picks them all again,
    in their order, so its p-value is the one of every view gathered."""
    rng = np.random.default_rng(33)
    for k in (50, 1999, 2000, 2001, 7000):
        time = rng.integers(0, 3000, k)
        xy, r = rng.normal(size=(k, 2)), 1e-3 * rng.normal(size=(k, 2))
        pick = moved.screen_views(time)
        assert np.array_equal(moved.screen_views(time[pick]), np.arange(len(pick)))
        assert moved.step_screen(xy[pick], r[pick], time[pick]) == moved.step_screen(xy, r, time)
    for k in range(0, 2 * moved.SCREEN_VIEWS, 7):  # the views as np.linspace spaced them, every k
        order = np.argsort(time := rng.integers(0, 500, k), kind="stable")
        want = order[np.linspace(0, k - 1, min(k, moved.SCREEN_VIEWS)).astype(np.int64)]
        assert np.array_equal(moved.screen_views(time), want)
