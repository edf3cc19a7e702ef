"""The geometry sigma's own standard error (wandcal.calib.judge.residuals.place_sigma_errors,
decision 0041): the bootstrap's over the points that place a camera, to first order."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.judge.residuals import Residuals, place_sigma_errors
from wandcal.calib.judge.verdict import SIGMA_REL_SE, camera_verdict

STEP = 1e-7


def _project(C: np.ndarray, turn: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Camera at centre C, turned by the small rotation vector ``turn`` from the identity: (K, 2)."""
    wx, wy, wz = turn
    Rt = np.eye(3) + np.array([[0, -wz, wy], [wz, 0, -wx], [-wy, wx, 0]])
    Xc = (X - C) @ Rt.T
    return Xc[:, :2] / Xc[:, 2:]


def _information(X: np.ndarray) -> np.ndarray:
    """(K, 6, 6) each point's information on (turn, centre) of a camera at the origin looking along
    +z, by finite differences (independent of the module's analytic rows); half of it, as a point
    of two views takes up half the error."""
    base = _project(np.zeros(3), np.zeros(3), X)
    cols = []
    for j in range(6):
        d = np.zeros(6)
        d[j] = STEP
        cols.append((_project(d[3:], d[:3], X) - base) / STEP)
    J = np.stack(cols, axis=2)  # (K, 2, 6)
    return 0.5 * np.einsum("kai,kaj->kij", J, J)


def _scene(rng: np.random.Generator, n: int) -> tuple[np.ndarray, Residuals]:
    """n points in front of camera 0 (at the origin, looking along +z), each also seen by camera 1,
    at depths from 1 to 20 m (log-uniform: a few near points hold most of the information)."""
    depth = np.exp(rng.uniform(np.log(1.0), np.log(20.0), n))
    xy = rng.uniform(-0.4, 0.4, (n, 2))
    res = Residuals(camera=np.repeat([0, 1], n), point=-1 - np.tile(np.arange(n), 2), xy=np.tile(xy, (2, 1)),
                    residual=np.zeros((2 * n, 2)), focal=np.full(2 * n, 1000.0), depth=np.tile(depth, 2),
                    outlier=np.zeros(2 * n, bool), X=np.zeros((0, 3)), frames=np.zeros(0, np.int64), extent=10.0,
                    limit_px=1.0)
    X = np.concatenate([xy * depth[:, None], depth[:, None]], axis=1)
    return X, res


def test_the_sigmas_standard_error_is_the_bootstraps_over_its_points():
    rng = np.random.default_rng(7)
    X, res = _scene(rng, 150)
    info = _information(X)
    predicted = place_sigma_errors(np.stack([np.eye(3), np.eye(3)]), res, 2)[0]
    draws = 2000
    sigma = np.empty(draws)
    for k in range(draws):
        pick = rng.integers(0, len(X), len(X))
        sigma[k] = np.sqrt(np.trace(np.linalg.inv(info[pick].sum(axis=0))[3:, 3:]))
    full = np.sqrt(np.trace(np.linalg.inv(info.sum(axis=0))[3:, 3:]))
    observed = np.std(sigma) / full
    # 2,000 draws know a standard deviation to 1/sqrt(2 * 2000) = 1.6% of itself; the first order
    # (the delta method) is the rest of the tolerance at 150 points
    assert predicted is not None
    assert abs(predicted - observed) <= 0.15 * observed, (predicted, observed)


def test_a_camera_placed_by_alike_points_keeps_the_measured_floor_and_one_on_few_gets_its_own():
    rng = np.random.default_rng(3)
    _, alike = _scene(rng, 400)
    alike = replace(alike, depth=np.full(800, 5.0))  # every point as far: none stands out
    R = np.stack([np.eye(3), np.eye(3)])
    assert place_sigma_errors(R, alike, 2)[0] < SIGMA_REL_SE
    # a geometry sigma 1.25 times its limit: poor with the floor's 11%, at the limit with a 25% error
    report = {"observations": 2000, "geometry_of_volume": 1.25e-3, "geometry_std_mm": 2.5}
    assert camera_verdict(report, "cam1", 2.0, None)["level"] == "poor"
    held = camera_verdict(report | {"geometry_std_rel_se": 0.25}, "cam1", 2.0, None)
    assert held["level"] == "good" and held["at_limit"][0]["criterion"] == "geometry"
