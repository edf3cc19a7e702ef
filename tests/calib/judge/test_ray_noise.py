"""The rays' own noise from their miss at points fitted to them (calib/judge/residuals.py:
ray_noise_factors): the fitted miss times the factor is the noise put in, at two, three and four views."""

import numpy as np
import pytest

from wandcal.calib.geometry import row_norms
from wandcal.calib.judge.residuals import Residuals, ray_noise_factors
from wandcal.calib.sim.simulate import look_at
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

NOISE = 1e-3  # per axis, normalised (1 px at a 1000 px focal length)
POINTS = 3000


def fitted(views: int, rng: np.random.Generator) -> Residuals:
    """Four cameras on a ring 3 m from a 1 m volume; every point seen by ``views`` of them at random,
    with Gaussian noise NOISE per axis, triangulated from those views; its rows as Residuals."""
    poses = [look_at(3.0 * np.array([np.cos(a), np.sin(a), 0.5]), np.zeros(3)) for a in np.linspace(0, 2 * np.pi, 5)[:4]]
    R, t = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
    X = rng.uniform(-0.5, 0.5, (POINTS, 3))
    camera = np.concatenate([rng.permutation(4)[:views] for _ in range(POINTS)])
    point = np.repeat(np.arange(POINTS), views)
    Xc = np.einsum("mij,mj->mi", R[camera], X[point]) + t[camera]
    xy = Xc[:, :2] / Xc[:, 2:] + rng.normal(0, NOISE, (len(point), 2))
    fit = triangulate_points(R, t, point, camera, xy, POINTS)
    residual = reprojection_errors(R, t, point, camera, xy, fit)
    n = len(point)
    return Residuals(camera=camera, point=-1 - point, xy=xy, residual=residual, focal=np.ones(n), depth=Xc[:, 2],
                     outlier=np.zeros(n, bool), X=np.zeros((0, 3)), frames=np.zeros(0, int), extent=1.0, limit_px=1.0)


@pytest.mark.parametrize("views", [2, 3, 4])
def test_the_fitted_miss_times_the_factor_is_the_noise_put_in(views):
    res = fitted(views, np.random.default_rng(views))
    factors = ray_noise_factors(res, 4)
    for c in range(4):
        mine = res.camera == c
        miss = np.sqrt(np.mean(row_norms(res.residual[mine]) ** 2))  # the RMS ray angle, radians
        noise = factors[c] * miss
        # the 2D noise's RMS is sqrt(2) NOISE; an RMS of m squares has a relative standard error of
        # 1/sqrt(2 m), the fitted one's larger by the factor (fewer degrees of freedom): 4 of them
        se = factors[c] / np.sqrt(2 * mine.sum())
        assert noise == pytest.approx(np.sqrt(2) * NOISE, rel=4 * se)
        assert factors[c] > 1.0
    # every point of ``views`` views keeps 1 - 3 / (2 views) of its noise's square: 2 at two views
    assert factors == pytest.approx([1.0 / np.sqrt(1.0 - 1.5 / views)] * 4)
