"""Bump detection (``check_cameras``) and re-solving only the knocked cameras (``solve_only``) on
seeded rigs with one camera knocked by 1 degree and 3 cm."""

import numpy as np
import pytest

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import camera_centers, rotation_angle
from wandcal.calib.judge.bumps import check_cameras
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.resolve import solve_only
from wandcal.calib.sim.scenes import knocked_capture
from wandcal.calib.sim.simulate import simulate_capture

NOISE = 0.3
KNOCK_DEG, KNOCK_M = 1.0, 0.03
# a 3D error over its predicted RMS: P(|x| > 4 sigma_rms) < 1e-3 for any 3D Gaussian (Chebyshev
# is far looser; for an isotropic one it is ~1e-7), so a right prediction fails once in a thousand
SIGMAS = 4.0


@pytest.fixture(scope="module", params=[0, 3], ids=["cam1 knocked", "cam4 knocked"])
def knocked(request):
    sim = simulate_capture(6, 800, NOISE, 0.0, True, 11)
    base = calibrate(sim.rig, sim.wand, sim.static)
    wand, R, t = knocked_capture(sim, request.param, KNOCK_DEG, KNOCK_M, 800, 5 + request.param)
    return sim, base, request.param, wand, R, t


def test_check_names_the_knocked_camera_and_no_other(knocked):
    sim, base, cam, wand, _, _ = knocked
    expected = np.array([c.reprojection_rms_px for c in base.cameras])
    checks = check_cameras(sim.rig, base.R, base.t, wand, expected)
    assert [c.id for c in checks if c.moved] == [sim.rig.cameras[cam].id]
    assert "recalibrate it with --solve-only" in checks[cam].reason


def test_check_finds_nothing_on_a_fresh_capture_of_an_untouched_rig():
    sim = simulate_capture(6, 800, NOISE, 0.0, True, 11)
    base = calibrate(sim.rig, sim.wand, sim.static)
    wand, _, _ = knocked_capture(sim, 0, 0.0, 0.0, 800, 99)
    checks = check_cameras(sim.rig, base.R, base.t, wand)
    assert not any(c.moved for c in checks)
    # leave-one-out errors of a right rig are the blob noise's (median radius 1.18 sigma, a little
    # more from the others' triangulation), far under the limit
    assert all(c.median_px < 3 * NOISE for c in checks)


def test_solve_only_places_the_camera_at_its_new_pose_and_keeps_the_others_bit_for_bit(knocked):
    sim, base, cam, wand, R_true, t_true = knocked
    cid = sim.rig.cameras[cam].id
    out = solve_only(sim.rig, wand, base.R, base.t, [cid], base.world, base.cameras)
    held = np.arange(6) != cam
    assert np.array_equal(out.R[held], base.R[held]) and np.array_equal(out.t[held], base.t[held])
    assert out.world == base.world
    err = np.linalg.norm(out.centers[cam] - camera_centers(R_true, t_true)[cam])
    # within the noise: the camera's own predicted spread given the held cameras, and theirs
    held_std = np.median([c.uncertainty.center_std_mm for c in base.cameras]) / 1000
    new_std = out.cameras[cam].uncertainty.center_std_mm / 1000
    assert err < SIGMAS * np.hypot(new_std, held_std)
    moved_by = np.linalg.norm(camera_centers(R_true, t_true)[cam] - sim.truth.centers[cam])
    assert moved_by == pytest.approx(KNOCK_M)
    rot = rotation_angle(out.R[cam : cam + 1], R_true[cam : cam + 1])[0]
    assert rot < SIGMAS * np.radians(np.hypot(out.cameras[cam].uncertainty.rotation_std_deg,
                                              np.median([c.uncertainty.rotation_std_deg for c in base.cameras])))
    assert out.to_json()["solver"]["solved_only"] == [cid]


def test_solve_only_refuses_to_leave_fewer_than_two_held_cameras():
    sim = simulate_capture(3, 200, NOISE, 0.0, True, 2)
    base = calibrate(sim.rig, sim.wand, sim.static)
    with pytest.raises(CalibrationError, match="at least 2 cameras held"):
        solve_only(sim.rig, sim.wand, base.R, base.t, ["cam1", "cam2"], base.world)
