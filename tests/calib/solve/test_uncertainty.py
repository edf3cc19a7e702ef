"""The predicted pose uncertainty (``center_std_mm``, ``rotation_std_deg``) against the
Cramér–Rao bound and against the real error's spread over seeded rigs."""

import numpy as np
import pytest
from scipy.stats import chi2

from wandcal.calib.geometry import camera_centers, rotation_angle
from wandcal.calib.judge.crb import pose_crb
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.scenes import perturbed_model, prepared_scene
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.solve.ba import bundle_adjust_points
from wandcal.calib.solve.uncertainty import registration_covariance
from wandcal.calib.start.world import apply, world_frame

NOISE = 0.3
# the bound is taken at the truth and the prediction at the estimate, with the noise estimated
# from ~2,800 residuals (relative error 1/sqrt(2 n) ~ 1.3%, 4 sigma ~ 5%) and the information
# matrix moved by the estimation error (a fraction of a percent here)
CRB_TOLERANCE = 0.06
SEEDS = 10
FALSE_ALARM = 1e-3  # two-sided chance that a right prediction fails the spread test


def test_ba_covariance_is_the_cramer_rao_bound_in_its_gauge():
    scene = prepared_scene(cameras=5, frames=300, noise_px=NOISE, seed=3, static=False)
    model = perturbed_model(scene, degrees=1.0, metres=0.03, seed=3)
    out = bundle_adjust_points(model, None, None, loss="linear")
    T = scene.sim.truth
    bound_c, bound_r = pose_crb(scene.setup.problem, T.R, T.t, T.wand[scene.setup.frames], 0, NOISE)
    cov = out.covariance.cov.reshape(4, 6, 4, 6)
    R, t = model.poses(out.x)
    for k, c in enumerate(out.covariance.free):
        block = cov[k, :, k, :]
        rot = np.sqrt(np.trace(block[:3, :3]))
        # the centre -R^T t moves with both: dC = [C]x dw - R^T dt for the left increment
        C = camera_centers(R, t)[c]
        G = np.hstack([np.array([[0, -C[2], C[1]], [C[2], 0, -C[0]], [-C[1], C[0], 0]]), -R[c].T])
        center = np.sqrt(np.trace(G @ block @ G.T))
        assert center == pytest.approx(bound_c[c], rel=CRB_TOLERANCE)
        assert rot == pytest.approx(bound_r[c], rel=CRB_TOLERANCE)


def _spread_bounds() -> tuple[float, float]:
    """Bounds on RMS(error / predicted) over the seeds' cameras. Each camera's squared error over
    its predicted variance has mean 1 and, being a 3D Gaussian's, at most the variance of a chi^2
    with one degree of freedom; the cameras of one rig share the world frame's error, so in the
    worst case they count as one sample per seed: a chi^2 with SEEDS degrees of freedom."""
    lo = chi2.ppf(FALSE_ALARM / 2, SEEDS) / SEEDS
    hi = chi2.ppf(1 - FALSE_ALARM / 2, SEEDS) / SEEDS
    return float(np.sqrt(lo)), float(np.sqrt(hi))


@pytest.mark.parametrize("static", [True, pytest.param(False, marks=pytest.mark.long)], ids=["static-object frame", "wand-only frame"])
def test_predicted_uncertainty_matches_the_real_error_spread(static):
    centre_ratios, rotation_ratios = [], []
    for seed in range(SEEDS):
        sim = simulate_capture(5, 400, NOISE, 0.0, static, 300 + seed)
        res = calibrate(sim.rig, sim.wand, sim.static)
        T = sim.truth
        if static:
            Rt, tt = T.R, T.t  # the simulator's world is the L-frame's
        else:
            # the result's frame built from the true poses and wand by the same rule
            Rw, tw, _ = world_frame(sim.rig, T.R, T.t, 0, wand=T.wand)
            Rt, tt, _ = apply(Rw, tw, T.R, T.t, np.zeros((0, 3)))
        pred_c = np.array([c.uncertainty.center_std_mm for c in res.cameras]) / 1000
        pred_r = np.radians([c.uncertainty.rotation_std_deg for c in res.cameras])
        err_c = np.linalg.norm(res.centers - camera_centers(Rt, tt), axis=1)
        err_r = rotation_angle(res.R, Rt)
        use = pred_c > 0  # a camera that is the world frame itself has no error to predict
        centre_ratios.append(err_c[use] / pred_c[use])
        rotation_ratios.append(err_r[use] / pred_r[use])
    lo, hi = _spread_bounds()
    for ratios in (centre_ratios, rotation_ratios):
        rms = float(np.sqrt(np.mean(np.square(np.concatenate(ratios)))))
        print(f"RMS(error/predicted) {rms:.2f} in [{lo:.2f}, {hi:.2f}]")
        assert lo < rms < hi, f"RMS of error / predicted {rms:.2f} outside [{lo:.2f}, {hi:.2f}]"


def test_every_result_carries_the_uncertainty_for_every_method():
    sim = simulate_capture(4, 200, NOISE, 0.0, True, 7)
    for method in ("ba", "lp"):
        doc = calibrate(sim.rig, sim.wand, sim.static, options=CalibrationOptions(method=method)).to_json()
        for cam in doc["cameras"]:
            assert 0 < cam["center_std_mm"] < 10 and 0 < cam["rotation_std_deg"] < 0.1


def test_registration_covariance_matches_monte_carlo():
    rng = np.random.default_rng(0)
    pts = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.3, 0], [0.25, 0.1, 0.02]])
    sigma = 1e-3
    cov, centroid = registration_covariance(pts, sigma)
    from wandcal.calib.geometry import kabsch, matrix_to_rotvec

    draws = []
    for _ in range(4000):
        Rw, tw, _ = kabsch(pts + rng.normal(0, sigma, pts.shape), pts)
        draws.append(np.concatenate([matrix_to_rotvec(Rw), Rw @ centroid + tw - centroid]))
    mc = np.cov(np.array(draws).T)
    # 4000 draws: a variance is known to sqrt(2 / 4000) ~ 2.2%, 4 sigma ~ 9%
    np.testing.assert_allclose(np.diag(mc), np.diag(cov), rtol=0.1)
