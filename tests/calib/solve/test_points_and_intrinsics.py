"""The whole pipeline on sparse and wand-less rigs, with axis points, and with rough intrinsics.

Tolerances come from the injected noise: the Cramér–Rao bound where the wand model has one
(``wandcal.calib.judge.crb``), the solver's own standard errors for the intrinsics (checked here against the
truth), and first-order error propagation stated beside each test otherwise.
"""

import dataclasses

import numpy as np
import pytest

from wandcal.calib.geometry import camera_centers, distort_points, kabsch, project_normalized
from wandcal.calib.judge.crb import gauge_errors, pose_crb
from wandcal.calib.observations import wand_pairs
from wandcal.calib.rig import AxisObservations, Camera, Rig
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import build_problem
from wandcal.calib.sim.scenes import pairwise_points, pairwise_wand
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.labels import label_ends

NOISE = 0.5


def test_a_rig_whose_cameras_share_only_pairwise_views_calibrates():
    ratios = []
    for seed in (3, 11):
        sim = simulate_capture(6, 600, NOISE, static=False, seed=seed)
        wand = pairwise_wand(sim, np.random.default_rng(seed))
        result = calibrate(sim.rig, wand, None)
        # the bound of the same observations, labelled at the truth, in camera 0's gauge
        pairs = wand_pairs(sim.rig, wand)
        labelled, _ = label_ends(sim.truth.R, sim.truth.t, pairs, np.ones(6, bool), sim.rig.wand_length)
        setup = build_problem(sim.rig, labelled, sim.truth.R, sim.truth.t)
        bound, _ = pose_crb(setup.problem, sim.truth.R, sim.truth.t, sim.truth.wand[setup.frames], 0, NOISE)
        err, _ = gauge_errors(result.R, result.t, sim.truth.R, sim.truth.t, 0)
        ratios += list(err[1:] / bound[1:])
    # an efficient estimator has RMS(error / sqrt(CRB)) ~ 1; 10 cameras make 1.7 a >99% bound
    assert np.sqrt(np.mean(np.square(ratios))) < 1.7


def test_points_only_calibrates_up_to_scale():
    """1500 points, each seen by a ring pair of 6 cameras (sometimes three), no wand."""
    sim = simulate_capture(6, 10, NOISE, static=False, seed=4)
    rig = Rig(sim.rig.cameras, None)
    points = pairwise_points(sim, 1500, np.random.default_rng(4), noise_px=NOISE)
    result = calibrate(rig, None, None, points=points)
    assert result.world.scale == "arbitrary" and result.wand_report is None
    C, Ct = result.centers, sim.truth.centers
    Ra, ta, s = kabsch(C, Ct, scale=True)
    err = np.linalg.norm(s * C @ Ra.T + ta - Ct, axis=1)
    # each ring pair sees ~500 points at ~3.5 m, a ray's error is 0.5 px / 1075 px = 0.47 mrad:
    # a pair's relative pose to ~0.47 mrad x (20-50, the rotation/baseline trade-off over a
    # 60 degree view) / sqrt(500) ~ 0.4-1 mrad, ~1.5-4 mm at the 4 m lever; 10 mm is ~3x that
    assert err.max() < 0.010, err
    for cam in result.cameras:
        assert cam.points.rms_px < 1.5 * np.sqrt(2) * NOISE  # the 2D error of 0.5 px per axis


def test_wand_length_absent_refuses_other_methods_with_a_reason():
    sim = simulate_capture(4, 10, NOISE, static=False, seed=4)
    points = pairwise_points(sim, 300, np.random.default_rng(4), noise_px=NOISE)
    from wandcal.calib.errors import CalibrationError

    with pytest.raises(CalibrationError, match="--method ba or lp, not 'paper'"):
        calibrate(Rig(sim.rig.cameras, None), None, None, points=points, options=CalibrationOptions(method="paper"))


def test_axis_points_set_the_world_frame():
    """An origin, a point on +z and one on +x, seen by every camera, instead of an L-frame."""
    sim = simulate_capture(6, 600, 0.3, static=False, seed=8)
    axis_xyz = {"origin": [0.0, 0.0, 0.0], "+z": [0.0, 0.0, 0.5], "+x": [0.5, 0.0, 0.0]}
    rng = np.random.default_rng(8)
    role, camera, uv = [], [], []
    for c, cam in enumerate(sim.rig.cameras):
        for name, X in axis_xyz.items():
            p = distort_points(cam, project_normalized(sim.truth.R[c], sim.truth.t[c], np.array([X])))[0]
            role.append(name), camera.append(c), uv.append(p + rng.normal(0, 0.3 / np.sqrt(50), 2))  # averaged over 50 frames
    axis = AxisObservations(role, camera, uv)
    result = calibrate(sim.rig, sim.wand, None, axis=axis)
    assert result.world.frame == "axis" and result.world.details["axes_given"] == ["+z", "+x"]
    err = np.linalg.norm(result.centers - sim.truth.centers, axis=1)
    # 6 rays of 0.04 px put each axis point within ~0.1 mm; +z over 0.5 m then tilts the frame by
    # ~0.2 mrad, 0.8 mm at the cameras' 4 m: 5 mm leaves room for the refinement's own ~0.5 mm
    assert err.max() < 0.005, err


def test_intrinsics_refinement_recovers_a_3_percent_focal_error():
    sim = simulate_capture(6, 600, 0.3, static=True, seed=5)
    signs = np.array([1, -1, 1, -1, 1, -1])
    cams = []
    for c, sign in zip(sim.rig.cameras, signs):
        K = c.K.copy()
        K[:2, :2] *= 1 + 0.03 * sign
        cams.append(Camera(c.id, c.width, c.height, K, c.dist))
    rough = dataclasses.replace(sim.rig, cameras=tuple(cams))
    held = calibrate(rough, sim.wand, sim.static)
    fitted = calibrate(rough, sim.wand, sim.static, options=CalibrationOptions(refine_intrinsics=("focal",)))
    true_f = np.array([c.K[0, 0] for c in sim.rig.cameras])
    got = np.array([cam.intrinsics.focal_px for cam in fitted.cameras])
    std = np.array([cam.intrinsics.focal_std_px for cam in fitted.cameras])
    # the solver's standard errors describe the real error: |z| < 4 for all six (p > 0.999)
    assert np.all(np.abs(got - true_f) < 4 * std), (got - true_f, std)
    assert np.all(std < 0.002 * true_f)
    err_held = np.linalg.norm(held.centers - sim.truth.centers, axis=1)
    err_fitted = np.linalg.norm(fitted.centers - sim.truth.centers, axis=1)
    assert err_fitted.max() < 0.1 * err_held.max()  # a 3% focal error moves cameras by ~10 cm
    assert fitted.solver.refined_intrinsics == ("focal",) and fitted.rig.cameras[0].K[0, 0] == got[0]
    assert np.allclose(camera_centers(fitted.R, fitted.t), fitted.centers)
