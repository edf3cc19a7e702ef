"""The rig's geometry and the world's placement, told apart (calib/solve/gauge_free.py), against
the real errors of seeded rigs: the geometry sigma predicts each camera's error once the rig's
best-fit rigid motion onto the truth is removed, and the placement sigma predicts that motion."""

import numpy as np
import pytest
from scipy.stats import chi2

from wandcal.calib.geometry import camera_centers, rotation_angle
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.solve.gauge_free import AXIS_POINT_M, split_uncertainty

SEEDS = 10
NOISE = 0.3
FALSE_ALARM = 0.002  # two-sided; the bounds as tests/calib/solve/test_uncertainty.py derives them


def _bounds() -> tuple[float, float]:
    """RMS(error / predicted) over the seeds: each squared ratio has mean 1 and at most a chi^2
    with one degree of freedom's variance; the cameras of one rig share the fit's error, so at
    worst they count as one sample per seed."""
    return (float(np.sqrt(chi2.ppf(FALSE_ALARM / 2, SEEDS) / SEEDS)),
            float(np.sqrt(chi2.ppf(1 - FALSE_ALARM / 2, SEEDS) / SEEDS)))


def _anchors(R, t):
    C = camera_centers(R, t)
    return np.concatenate([C, C + AXIS_POINT_M * R[:, 2, :]])


def _aligned(R, t, R_true, t_true, weight):
    """The estimate moved by its weighted least-squares rigid fit onto the truth (on both anchors
    of every camera, as the split fits): (R, t) aligned, and the fit (Rw, tw)."""
    src, dst = _anchors(R, t), _anchors(R_true, t_true)
    w = np.tile(weight, 2) / (2 * weight.sum())
    mu_s, mu_t = w @ src, w @ dst
    U, _, Vt = np.linalg.svd((dst - mu_t).T @ ((src - mu_s) * w[:, None]))
    Rw = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    tw = mu_t - Rw @ mu_s
    return R @ Rw.T, t - np.einsum("nij,j->ni", R @ Rw.T, tw), Rw, tw


def test_geometry_and_placement_sigmas_match_the_real_errors():
    geo_c, geo_r, origin, axes = [], [], [], []
    for seed in range(SEEDS):
        sim = simulate_capture(6, 600, NOISE, 0.0, True, 500 + seed)
        res = calibrate(sim.rig, sim.wand, sim.static)
        geo = np.array([c.uncertainty.geometry.std_mm for c in res.cameras]) / 1000
        weight = 1 / np.maximum(geo, np.median(geo)) ** 2
        Ra, ta, Rw, tw = _aligned(res.R, res.t, sim.truth.R, sim.truth.t, weight)
        geo_c.append(np.linalg.norm(camera_centers(Ra, ta) - sim.truth.centers, axis=1) / geo)
        geo_r.append(rotation_angle(Ra, sim.truth.R) / np.radians([c.uncertainty.geometry.rotation_std_deg for c in res.cameras]))
        place = res.world.placement
        origin.append(np.linalg.norm(tw) / (place.origin_std_mm / 1000))  # where the fit takes the origin
        axes.append(rotation_angle(Rw[None], np.eye(3)[None])[0] / np.radians(place.axes_std_deg))
        # the split's parts add up to the total (they are orthogonal in the fit's metric)
        total = np.array([c.uncertainty.center_std_mm for c in res.cameras])
        assert np.all(geo * 1000 < total)
    lo, hi = _bounds()
    for name, ratios in (("geometry centres", geo_c), ("geometry rotations", geo_r), ("origin", origin), ("axes", axes)):
        rms = float(np.sqrt(np.mean(np.square(np.concatenate([np.atleast_1d(r) for r in ratios])))))
        print(f"{name}: RMS(error / predicted) {rms:.2f} in [{lo:.2f}, {hi:.2f}]")
        assert lo < rms < hi, f"{name}: RMS of error / predicted {rms:.2f} outside [{lo:.2f}, {hi:.2f}]"


def test_a_rigid_motion_of_the_whole_rig_is_no_geometry_error():
    """Any covariance of one rigid motion of all the cameras (the world frame's own noise) has no
    geometry part; a camera's own noise keeps its share."""
    sim = simulate_capture(5, 50, NOISE, 0.0, False, 1)
    R, t = sim.truth.R, sim.truth.t
    C, n = camera_centers(R, t), len(R)
    rng = np.random.default_rng(0)
    A = np.zeros((n, 6, 6))  # (dC, drot) of each camera for the motion (phi, tau)
    for i in range(n):
        A[i, :3, :3] = -np.array([[0, -C[i, 2], C[i, 1]], [C[i, 2], 0, -C[i, 0]], [-C[i, 1], C[i, 0], 0]])
        A[i, :3, 3:] = np.eye(3)
        A[i, 3:, :3] = -R[i]
    M = rng.normal(size=(6, 6))
    frame = A.reshape(n * 6, 6) @ (M @ M.T) @ A.reshape(n * 6, 6).T
    split = split_uncertainty(R, t, frame.reshape(n, 6, n, 6))
    # rounding only: the motion's own size is of order one
    assert split.axes_std > 0.1 and np.all(split.center_std < 1e-6) and np.all(split.rotation_std < 1e-6)
    own = np.zeros((n, 6, n, 6))
    own[2, :3, 2, :3] = np.eye(3) * 1e-6
    split = split_uncertainty(R, t, (frame + own.reshape(n * 6, n * 6)).reshape(n, 6, n, 6))
    assert split.center_std[2] == pytest.approx(np.sqrt(3e-6), rel=0.3) and np.all(np.delete(split.center_std, 2) < 1e-3)
