"""The static object's frame, differentiated in closed form, against rebuilding it."""

import numpy as np

from wandcal.calib.geometry import rotvec_to_matrix
from wandcal.calib.sim.simulate import simulate_capture
from wandcal.calib.start.static import solve_static, static_frame_jacobian
from wandcal.calib.start.world import _static_views, world_frame

NOISE_PX = 0.3
STEP = 1e-6  # forward differences: far above rounding, far below the rig's curvature


def _frame_change(Rw0, tw0, Rw, tw):
    dR = Rw @ Rw0.T
    return np.r_[0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]]), tw - tw0]


def test_static_frame_jacobian_matches_rebuilding_the_frame():
    sim = simulate_capture(6, 200, NOISE_PX, 0.0, True, 3)
    rig, R, t = sim.rig, sim.truth.R, sim.truth.t
    poses = solve_static(rig, sim.static)
    Rw0, tw0, world = world_frame(rig, R, t, 0, sim.static, poses)
    cams = [rig.index(c) for c in world["cameras_used"]]
    J = static_frame_jacobian(R, t, *_static_views(rig, sim.static, poses, cams), rig.static_markers)
    numeric = np.zeros_like(J)
    for c in range(len(R)):
        for j in range(6):
            Rp, tp = R.copy(), t.copy()
            if j < 3:
                Rp[c] = rotvec_to_matrix(STEP * np.eye(3)[j]) @ R[c]
            else:
                tp[c, j - 3] += STEP
            Rw, tw, _ = world_frame(rig, Rp, tp, 0, sim.static, poses)
            numeric[:, c, j] = _frame_change(Rw0, tw0, Rw, tw) / STEP
    # the closed form is Gauss-Newton's: it leaves out the residuals' own curvature, a share of
    # about the blobs' noise over the focal length (normalised residuals), well under 10 of them
    tolerance = 10 * NOISE_PX / rig.cameras[0].focal[0]
    assert np.abs(J - numeric).max() <= tolerance * np.abs(numeric).max() + 10 * STEP
    assert np.abs(numeric).max() > 0  # the frame follows the cameras that triangulate it
