"""Multi-view triangulation, vectorised over points with any number of views."""

from __future__ import annotations

import numpy as np

GAUSS_NEWTON_STEPS = 3  # from the DLT start, three steps reach the reprojection optimum to < 1e-9


def triangulate_points(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, n_points: int
) -> np.ndarray:
    """Triangulate points seen in several cameras: linear DLT, then Gauss-Newton on the
    reprojection error in normalised coordinates.

    Args:
        R: (N, 3, 3), t: (N, 3) world->camera poses, metres.
        point: (M,) point index of each observation.
        camera: (M,) camera index of each observation.
        xy: (M, 2) normalised image coordinates.
        n_points: number of points P.

    Returns:
        (P, 3) world points; NaN rows for points seen by fewer than two cameras.
    """
    P = np.concatenate([R, t[:, :, None]], axis=2)[camera]  # (M, 3, 4)
    rows = np.concatenate(
        [xy[:, 0:1] * P[:, 2] - P[:, 0], xy[:, 1:2] * P[:, 2] - P[:, 1]], axis=0
    )  # (2M, 4)
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    owner = np.concatenate([point, point])
    AtA = _summed_outer(owner, rows, n_points)
    views = np.bincount(point, minlength=n_points)
    ok = views >= 2
    X = np.full((n_points, 3), np.nan)
    if not ok.any():
        return X
    _, vecs = np.linalg.eigh(AtA[ok])
    h = vecs[:, :, 0]
    X[ok] = h[:, :3] / h[:, 3:4]
    return refine_points(R, t, point, camera, xy, X)


def refine_points(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, X: np.ndarray
) -> np.ndarray:
    """Gauss-Newton steps on each point's reprojection error (shapes as :func:`triangulate_points`)."""
    X = X.copy()
    ok = np.all(np.isfinite(X), axis=1)
    use = ok[point]
    pt, cam, obs = point[use], camera[use], xy[use]
    Rm = R[cam]
    for _ in range(GAUSS_NEWTON_STEPS):
        xc = np.einsum("mij,mj->mi", Rm, X[pt]) + t[cam]
        z = xc[:, 2]
        r = xc[:, :2] / z[:, None] - obs
        # d(x/z, y/z)/dX = (row_xy - proj * row_z) / z
        J = (Rm[:, :2, :] - (xc[:, :2] / z[:, None])[:, :, None] * Rm[:, 2:3, :]) / z[:, None, None]
        JtJ = _summed_outer(np.repeat(pt, 2), J.reshape(-1, 3), len(X))
        Jtr = np.stack([np.bincount(pt, (J[:, :, i] * r).sum(1), minlength=len(X)) for i in range(3)], axis=1)
        JtJ[~ok] = np.eye(3)
        # a point whose rays are (nearly) parallel has a singular JtJ: damp it, and keep the last
        # estimate wherever the step is not finite rather than fail the whole set
        damp = 1e-12 * np.trace(JtJ, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 1e-300 * np.eye(3)
        step = np.linalg.solve(JtJ + damp, Jtr[:, :, None])[:, :, 0]
        good = np.all(np.isfinite(step), axis=1)
        X[good] -= step[good]
    return X


def _summed_outer(owner: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
    """(n, k, k): for each owner, the sum of the outer products of its rows (R, k); symmetric, so
    each of the k(k+1)/2 distinct entries is one ``np.bincount`` (np.add.at is ~10x slower)."""
    k = rows.shape[1]
    out = np.empty((n, k, k))
    for i in range(k):
        for j in range(i, k):
            out[:, i, j] = out[:, j, i] = np.bincount(owner, rows[:, i] * rows[:, j], minlength=n)
    return out


def reprojection_errors(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, X: np.ndarray
) -> np.ndarray:
    """(M, 2) normalised reprojection residuals ``project(X) - xy``."""
    xc = np.einsum("mij,mj->mi", R[camera], X[point]) + t[camera]
    return xc[:, :2] / xc[:, 2:3] - xy
