"""Cramér-Rao bound of the camera poses, and errors measured in the same gauge.

The bound is taken from the wand model's Jacobian at the true state, with the gauge camera held
fixed and the scale set by the wand, exactly the parametrisation of ``--method ba``. Errors are
compared in that gauge: an estimate is first moved rigidly so that its gauge camera coincides
with the true one.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.geometry import camera_centers, euler_jacobian, rotation_angle
from wandcal.calib.solve.wandmodel import CAM_PARAMS, WandModel, WandProblem


def orient_wand(wand: np.ndarray, problem: WandProblem, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Order each frame's true ends (F, 2, 3) like the problem's labels (which are only
    consistent across cameras, not with the simulator's end order)."""
    X = wand[problem.frame, problem.end]
    X_other = wand[problem.frame, 1 - problem.end]
    def err(P):
        xc = np.einsum("mij,mj->mi", R[problem.camera], P) + t[problem.camera]
        return np.linalg.norm(xc[:, :2] / xc[:, 2:3] - problem.xy, axis=1)
    worse = np.bincount(problem.frame, err(X) - err(X_other), minlength=len(wand)) > 0
    out = wand.copy()
    out[worse] = wand[worse, ::-1]
    return out


def pose_crb(problem: WandProblem, R: np.ndarray, t: np.ndarray, wand: np.ndarray, gauge: int, sigma_px: float):
    """Per-camera bound on the centre and rotation errors.

    Args:
        problem: the observations (their values do not matter, only who sees what).
        R, t: (N, 3, 3), (N, 3) true poses; wand: (F, 2, 3) true wand ends, in any end order.
        gauge: index of the fixed camera. sigma_px: blob noise per axis, pixels.

    Returns:
        (center_rms (N,) metres, rotation_rms (N,) radians): square roots of the traces of the
        bound's covariance blocks (0 for the gauge camera).
    """
    fixed = np.zeros(len(R), bool)
    fixed[gauge] = True
    return model_crb(WandModel(problem, R, t, orient_wand(wand, problem, R, t), fixed), sigma_px)


def model_crb(model: WandModel, sigma_px: float):
    """:func:`pose_crb` of a model already at the true state (its start), whatever its markers."""
    R, t, problem = model.R0, model.t0, model.p
    x = model.x0()
    J = model.jacobian(x).tocsc()
    nc = model.frame_col0
    Jc, Jf = J[:, :nc], J[:, nc:]
    Icc = (Jc.T @ Jc).toarray()
    Icf = (Jc.T @ Jf).toarray()
    Iff = (Jf.T @ Jf).tocsr()
    F, k = problem.n_frames, model.frame_params
    # the frame block is block-diagonal (5 x 5 per frame, 6 x 6 for a planar wand): invert it block by block
    blocks = np.zeros((F, k, k))
    coo = Iff.tocoo()
    blocks[coo.row // k, coo.row % k, coo.col % k] = coo.data
    blocks += 1e-12 * np.eye(k)
    inv = np.linalg.inv(blocks)
    Icf3 = Icf.reshape(nc, F, k)
    schur = Icc - np.einsum("cfi,fij,dfj->cd", Icf3, inv, Icf3)
    cov = sigma_px**2 * np.linalg.inv(schur)
    dE = euler_jacobian(np.zeros(3))
    center_rms = np.zeros(len(R))
    rot_rms = np.zeros(len(R))
    for k, c in enumerate(model.free):
        block = cov[k * CAM_PARAMS : (k + 1) * CAM_PARAMS, k * CAM_PARAMS : (k + 1) * CAM_PARAMS]
        # C = -R^T t with R = E(delta) R0: dC/ddelta_k = -(dE_k R0)^T t, dC/dt = -R^T
        G = np.zeros((3, CAM_PARAMS))
        for j in range(3):
            G[:, j] = -(dE[j] @ R[c]).T @ t[c]
        G[:, 3:] = -R[c].T
        center_rms[c] = np.sqrt(np.trace(G @ block @ G.T))
        rot_rms[c] = np.sqrt(np.trace(block[:3, :3]))
    return center_rms, rot_rms


def gauge_errors(R: np.ndarray, t: np.ndarray, R_true: np.ndarray, t_true: np.ndarray, gauge: int):
    """Centre (N,) metres and rotation (N,) radians errors after moving the estimate rigidly so
    that its gauge camera coincides with the true one (the gauge of :func:`pose_crb`)."""
    # world map x' = Q x + s taking the estimated gauge camera onto the true one
    Q = R_true[gauge].T @ R[gauge]
    s = R_true[gauge].T @ (t[gauge] - t_true[gauge])
    R_al = R @ Q.T
    C_al = camera_centers(R, t) @ Q.T + s
    return np.linalg.norm(C_al - camera_centers(R_true, t_true), axis=1), rotation_angle(R_al, R_true)
