"""The rig's two uncertainties, told apart: its geometry, and where the world frame places it.

A calibration's error splits into two parts that a user meets differently:

- **geometry**: each camera relative to the others. It is what 3D accuracy inside the volume
  depends on, and it is the same in every world frame (gauge-free);
- **placement**: one rigid motion of the whole rig (and, without a wand, one scale), which only
  moves every reconstruction rigidly. The static object, the axis points or the wand volume set it.

Both come from one covariance of every camera's centre and rotation (metres; radians, camera side,
``R <- exp([w]) R``): the best-fit rigid motion of the rig is found by weighted least squares on
two anchors per camera (its centre, and a point :data:`AXIS_POINT_M` along its optical axis, so the
fit sees the rotations too); its covariance is the placement, and what is left after removing it
is the geometry. Weights are 1 / sigma^2 of the previous pass (equal at first, none above the
median camera's), so a poorly seen camera does not drag the fit and with it every other camera.
This is the linear form of aligning the estimate to the truth before measuring its error
(the benchmarks' "aligned" error, which it predicts; tests/calib/solve/test_gauge_free.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.solve.uncertainty import frame_response

AXIS_POINT_M = 1.0  # the anchor along each optical axis: ties the fit to the cameras' rotations
MAX_REWEIGHTS = 8
REWEIGHT_RTOL = 0.01  # stop reweighting when no camera's sigma changes by more than 1%
RIGID, SIMILARITY = 6, 7  # gauge freedoms: with a wand the scale is measured, without it is not


@dataclass(frozen=True, eq=False)
class SplitUncertainty:
    """Per-camera geometry sigmas and the placement's.

    center_std: (N,) metres, sqrt(trace) of the centre's covariance with the rig's best-fit motion
    removed; rotation_std: (N,) radians, likewise; origin_std: metres, the world origin's 3D RMS
    displacement under the rig's best-fit motion; axes_std: radians, that motion's RMS angle;
    scale_std: relative 1-sigma of the rig's scale (None when the scale is not a freedom).
    """

    center_std: np.ndarray
    rotation_std: np.ndarray
    origin_std: float
    axes_std: float
    scale_std: float | None


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the cross-product matrices [v]x of (..., 3) vectors."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def pose_jacobian(R: np.ndarray, t: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(N, 6, 6K): how each camera's centre (3) and rotation (3, camera side) follow the free
    cameras' increments (w, dt) of a :class:`~wandcal.calib.solve.uncertainty.PoseCovariance`:
    dC = -R^T [t]x w - R^T dt, drot = w (a held camera's rows are zero)."""
    n, K = len(R), len(free)
    A = np.zeros((n, 6, K, 6))
    for k, cam in enumerate(free):
        Rt = R[cam].T
        A[cam, :3, k, :3] = -Rt @ _skew(t[cam])
        A[cam, :3, k, 3:] = -Rt
        A[cam, 3:, k, :3] = np.eye(3)
    return A.reshape(n, 6, K * 6)


def _anchor_map(R: np.ndarray) -> np.ndarray:
    """(N, 2, 3, 6): each camera's two anchors' displacement from its (dC, drot): the centre moves
    with dC; the axis point with dC + L R^T [e3]x drot (the optical axis R^T e3 turns with R)."""
    n = len(R)
    B = np.zeros((n, 2, 3, 6))
    B[:, 0, :, :3] = np.eye(3)
    B[:, 1, :, :3] = np.eye(3)
    B[:, 1, :, 3:] = AXIS_POINT_M * np.swapaxes(R, 1, 2) @ _skew(np.array([0.0, 0.0, 1.0]))
    return B


def _gauge(R: np.ndarray, C: np.ndarray, pivot: np.ndarray, freedoms: int) -> tuple[np.ndarray, np.ndarray]:
    """The rig's rigid motion (rotation phi about ``pivot``, translation tau, and a scale s about
    it when ``freedoms`` is 7): its effect on the anchors (N, 2, 3, g) and on (dC, drot) (N, 6, g).
    A world turned by phi moves a camera's centre by phi x (C - pivot) and turns it by -R phi."""
    n = len(R)
    anchors = np.stack([C, C + AXIS_POINT_M * R[:, 2, :]], axis=1) - pivot  # (N, 2, 3)
    Ga = np.zeros((n, 2, 3, freedoms))
    Ga[..., :3] = -_skew(anchors)
    Ga[..., 3:6] = np.eye(3)
    Gp = np.zeros((n, 6, freedoms))
    Gp[:, :, :6] = frame_response(C, R, pivot)  # a rigid motion of the rig is one of the world frame
    if freedoms == SIMILARITY:
        Ga[..., 6] = anchors
        Gp[:, :3, 6] = C - pivot
    return Ga, Gp


def split_uncertainty(R: np.ndarray, t: np.ndarray, cov: np.ndarray, scale_free: bool = False,
                      origin: np.ndarray | None = None) -> SplitUncertainty:
    """The geometry and placement parts of a covariance of every camera's pose.

    Args:
        R, t: (N, 3, 3), (N, 3) the poses (world->camera, metres) the covariance is about.
        cov: (N, 6, N, 6) covariance of each camera's (dC, drot): metres, radians (camera side).
        scale_free: True without a wand: the scale is a freedom of the gauge too.
        origin: (3,) the world origin in the poses' frame (default: their frame's origin).
    """
    n = len(R)
    C = camera_centers(R, t)
    pivot = C.mean(0)
    g = SIMILARITY if scale_free else RIGID
    Ga, Gp = _gauge(R, C, pivot, g)
    B = _anchor_map(R)
    S = cov.reshape(n * 6, n * 6)
    Ga2 = Ga.reshape(n * 6, g)
    own = cov[np.arange(n), :, np.arange(n), :]  # (N, 6, 6) each camera's block of S
    weight = np.ones(n)
    center = np.full(n, np.inf)
    for _ in range(MAX_REWEIGHTS):
        w = np.repeat(weight, 6)
        # the gauge fit H (g, 6N) = (Ga^T W Ga)^-1 (W Ga)^T B, B block-diagonal (N, 6, 6)
        WGaB = np.einsum("nag,nab->gnb", (Ga2 * w[:, None]).reshape(n, 6, g), B.reshape(n, 6, 6)).reshape(g, n * 6)
        H = np.linalg.solve(Ga2.T @ (Ga2 * w[:, None]), WGaB)
        # the diagonal blocks of P S P^T, P = I - Gp H, without the (6N)^3 products (0.19 s at
        # 128 cameras): S_nn - Gp_n (HS)_n - its transpose + Gp_n (H S H^T) Gp_n^T
        HS = (H @ S).reshape(g, n, 6)
        GHS = np.einsum("nag,gnb->nab", Gp, HS)
        blocks = own - GHS - GHS.transpose(0, 2, 1) + np.einsum("nag,gh,nbh->nab", Gp, HS.reshape(g, -1) @ H.T, Gp)
        last = center
        center = np.sqrt(np.maximum(np.einsum("nii->n", blocks[:, :3, :3]), 0.0))
        rotation = np.sqrt(np.maximum(np.einsum("nii->n", blocks[:, 3:, 3:]), 0.0))
        if np.allclose(center, last, rtol=REWEIGHT_RTOL, atol=0.0):
            break
        typical = float(np.median(center))
        if not typical > 0:
            break  # no camera has an error of its own: equal weights are as good as any
        # no weight above the median camera's: else the best camera pulls the fit onto itself
        weight = 1.0 / np.maximum(center, typical) ** 2
    theta = H @ S @ H.T  # (g, g): the rig's best-fit motion about the pivot
    o = (np.zeros(3) if origin is None else np.asarray(origin, float)) - pivot
    move_origin = np.concatenate([-_skew(o), np.eye(3)], axis=1)  # the origin's displacement from (phi, tau)
    origin_cov = move_origin @ theta[:6, :6] @ move_origin.T
    return SplitUncertainty(
        center_std=center, rotation_std=rotation,
        origin_std=float(np.sqrt(max(np.trace(origin_cov), 0.0))),
        axes_std=float(np.sqrt(max(np.trace(theta[:3, :3]), 0.0))),
        scale_std=float(np.sqrt(max(theta[6, 6], 0.0))) if scale_free else None,
    )


def gauge_covariance(R: np.ndarray, t: np.ndarray, free: np.ndarray, pose_cov: np.ndarray) -> np.ndarray:
    """(N, 6, N, 6) the covariance of every camera's (dC, drot) from a solve's (6K, 6K) covariance
    of its free cameras' increments (in the solve's own gauge)."""
    A = pose_jacobian(R, t, free).reshape(len(R) * 6, -1)
    return (A @ pose_cov @ A.T).reshape(len(R), 6, len(R), 6)
