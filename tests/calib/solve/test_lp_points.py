"""``lp`` refines point tracks beside the wand, as ``ba`` does (issue 23): each track is one more
frame of the wand model with its observations at the frame's midpoint (wandcal.calib.run.refine.with_tracks)."""

import numpy as np

from wandcal.calib.judge.crb import gauge_errors
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.sim.scenes import pairwise_points
from wandcal.calib.sim.simulate import simulate_capture

NOISE = 0.5


def _rms(sim, method, points):
    """RMS centre error (metres, camera 0's gauge) of a calibration, and the result."""
    r = calibrate(sim.rig, sim.wand, None, points=points, options=CalibrationOptions(method=method))
    assert r.solver.status == "converged"
    assert not any("only --method ba" in w for w in r.warnings)
    err, _ = gauge_errors(r.R, r.t, sim.truth.R, sim.truth.t, 0)
    return np.sqrt(np.mean(err[1:] ** 2)), r


def test_lp_refines_with_point_tracks_as_ba_does():
    """80 wand frames and 1500 points each seen by a ring pair of 6 cameras: the points more than
    halve the error of the wand alone, for lp as for ba (measured lp 4.25 -> 1.62 mm and 3.74 ->
    2.19 mm; ba with the points 1.99 and 2.05 mm)."""
    for seed in (3, 11):
        sim = simulate_capture(6, 80, NOISE, static=False, seed=seed)
        points = pairwise_points(sim, 1500, np.random.default_rng(seed), noise_px=NOISE)
        lp_wand, _ = _rms(sim, "lp", None)
        lp_points, r = _rms(sim, "lp", points)
        ba_points, _ = _rms(sim, "ba", points)
        assert r.points is not None and len(r.points) > 1000 and all(c.points.rms_px for c in r.cameras)
        assert lp_points < 0.7 * lp_wand
        assert lp_points < 1.25 * ba_points  # two estimators of the same model: the same error, to noise


# lp's loss is 96.5% efficient on Gaussian noise (calib/solve/robustloss.py), so its error is
# 1/sqrt(0.965) = 1.018x least squares' in expectation; an RMS over 2 seeds x 6 cameras x 3
# coordinates (36 values) has a relative sampling spread of 1/sqrt(2 * 36) = 0.12: two of those
LP_VS_BA = 1.018 * (1 + 2 / np.sqrt(2 * 36))


def test_lp_without_a_wand_calibrates_up_to_scale_as_ba_does():
    """Point tracks only (each seen by a ring pair of 6 cameras, sometimes three), no wand: the
    scale is free for lp as for ba, and their centres, each aligned to the truth by a similarity,
    are as near it."""
    from wandcal.calib.geometry import kabsch
    from wandcal.calib.rig import Rig

    errors = {"ba": [], "lp": []}
    for seed in (4, 5):
        sim = simulate_capture(6, 10, NOISE, static=False, seed=seed)
        points = pairwise_points(sim, 1000, np.random.default_rng(seed), noise_px=NOISE)
        for method in errors:
            r = calibrate(Rig(sim.rig.cameras, None), None, None, points=points, options=CalibrationOptions(method=method))
            assert r.world.scale == "arbitrary" and r.wand_report is None and r.solver.status == "converged"
            Ra, ta, s = kabsch(r.centers, sim.truth.centers, scale=True)
            errors[method] += list((s * r.centers @ Ra.T + ta - sim.truth.centers).ravel())
    rms = {m: float(np.sqrt(np.mean(np.square(e)))) for m, e in errors.items()}
    print(f"\ncentre RMS after similarity: ba {rms['ba'] * 1000:.2f} mm, lp {rms['lp'] * 1000:.2f} mm")
    assert rms["lp"] < LP_VS_BA * rms["ba"]
