"""A moved camera re-solved without a wand: its pose fitted to the take's markers as the cameras
that did not move triangulate them. Scale and world frame are the standing calibration's: the
points are in its frame and the other cameras are held."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.geometry import camera_centers, rotvec_to_matrix
from wandcal.calib.watch.health import PARAMS, linearised, solve_pose_change

STEPS = 5  # Gauss-Newton steps from the standing pose: a knock of a degree converges in three
MIN_POINTS = 30  # fewer markers than this fix no pose worth writing (6 unknowns, noise 0.3 px)
OUTLIER_PX = 1.5  # as health's: 5 sigma of 0.3 px


@dataclass(frozen=True, eq=False)
class Resolved:
    """A camera's pose re-solved from a take. R (3, 3), t (3,) world->camera; points: markers
    used; rms_px: their residual, pixels per axis (as health's); center_std_mm, rotation_std_deg: 1-sigma of the centre and the
    orientation from the fit's covariance (sigma^2 H^-1); moved_mm, turned_deg: from the standing pose."""

    R: np.ndarray
    t: np.ndarray
    points: int
    rms_px: float
    center_std_mm: float
    rotation_std_deg: float
    moved_mm: float
    turned_deg: float


def resolve_camera(R0: np.ndarray, t0: np.ndarray, focal: float, X: np.ndarray, xy: np.ndarray) -> Resolved | None:
    """Fit a camera's pose to markers X (k, 3), metres, seen at normalised xy (k, 2), starting from
    its standing pose R0 (3, 3), t0 (3,); None with fewer than :data:`MIN_POINTS` markers."""
    if len(X) < MIN_POINTS:
        return None
    R, C = R0.copy(), -R0.T @ t0
    keep = np.ones(len(X), bool)
    for step in range(STEPS):
        J, r = linearised(R, -R @ C, focal, X, xy)
        if step == 1:  # drop markers the first fit does not explain (a blob taken for another)
            keep = np.hypot(r[:, 0], r[:, 1]) < OUTLIER_PX
        H = np.einsum("kpi,kpj->ij", J[keep], J[keep])
        p = solve_pose_change(H, np.einsum("kpi,kp->i", J[keep], r[keep]))
        R = rotvec_to_matrix(p[:3]) @ R
        C = C + p[3:]
    J, r = linearised(R, -R @ C, focal, X, xy)
    J, r = J[keep], r[keep]
    H = np.einsum("kpi,kpj->ij", J, J)
    s2 = float((r ** 2).sum() / max(2 * len(r) - PARAMS, 1))
    cov = s2 * np.linalg.pinv(H, rcond=1e-10, hermitian=True)
    t = -R @ C
    turned = np.degrees(np.arccos(np.clip((np.trace(R @ R0.T) - 1) / 2, -1, 1)))
    return Resolved(R, t, int(keep.sum()), float(np.sqrt((r ** 2).sum() / max(2 * len(r), 1))),
                    float(np.sqrt(np.trace(cov[3:, 3:])) * 1000), float(np.degrees(np.sqrt(np.trace(cov[:3, :3])))),
                    float(np.linalg.norm(C - camera_centers(R0[None], t0[None])[0]) * 1000), float(turned))
