"""Multi-view triangulation, vectorised over points with any number of views.

Every per-point sum is one ``np.bincount`` over flat (M,) rows of the observations, taken
:data:`CHUNK` observations at a time (einsum over gathered (M, 3, 3) stacks and their strided
columns were the cost before, and the memory: 247 MB -> 47 MB at 8 cameras x 32,000 frames), and
every Gauss-Newton 3x3 system is solved in closed form (its adjugate). The DLT's 4x4 null vectors
still come from ``np.linalg.eigh``, about a third of a call. Closed-form alternatives were tried:
the inhomogeneous 3x3 solution as the start moves a few poorly conditioned points by up to 2e-6 m
after the three Gauss-Newton steps (they have not converged there), and an inverse iteration from
it cannot tell when it has converged (its Schur complement cancels), so the exact start was kept.
"""

from __future__ import annotations

import numpy as np

GAUSS_NEWTON_STEPS = 3  # from the DLT start, three steps reach the reprojection optimum to < 1e-9
CHUNK = 32768  # observations per pass: the temporaries of a chunk stay in cache
_UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # a symmetric 3x3's distinct entries
_UPPER4 = tuple((i, j) for i in range(4) for j in range(i, 4))
DAMPING = 1e-12  # relative to the trace: keeps near-parallel rays' normal equations invertible


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
        (P, 3) world points, metres; NaN rows for points seen by fewer than two cameras.
    """
    views = np.bincount(point, minlength=n_points)
    ok = views >= 2
    X = np.full((n_points, 3), np.nan)
    if not ok.any():
        return X
    P_table = np.ascontiguousarray(np.concatenate([R, t[:, :, None]], axis=2).reshape(-1, 12).T)  # (12, N)
    sums = np.zeros((10, n_points))  # the upper triangle of each point's 4x4 A^T A
    for s in range(0, len(point), CHUNK):
        sl = slice(s, s + CHUNK)
        P = np.take(P_table, camera[sl], axis=1)  # (12, C): P[4 i + j]
        x, y = xy[sl, 0], xy[sl, 1]
        # the DLT rows x * P3 - P1 and y * P3 - P2 of each observation, each scaled to unit length
        rx = [x * P[8 + j] - P[j] for j in range(4)]
        ry = [y * P[8 + j] - P[4 + j] for j in range(4)]
        nx = 1.0 / np.sqrt(rx[0] ** 2 + rx[1] ** 2 + rx[2] ** 2 + rx[3] ** 2)
        ny = 1.0 / np.sqrt(ry[0] ** 2 + ry[1] ** 2 + ry[2] ** 2 + ry[3] ** 2)
        rx = [r * nx for r in rx]
        ry = [r * ny for r in ry]
        for k, (i, j) in enumerate(_UPPER4):
            sums[k] += np.bincount(point[sl], rx[i] * rx[j] + ry[i] * ry[j], minlength=n_points)
    AtA = np.empty((int(ok.sum()), 4, 4))
    for k, (i, j) in enumerate(_UPPER4):
        AtA[:, i, j] = AtA[:, j, i] = sums[k][ok]
    del sums
    _, vecs = np.linalg.eigh(AtA)  # the null vector of the stacked rows
    h = vecs[:, :, 0]
    X[ok] = h[:, :3] / h[:, 3:4]
    return refine_points(R, t, point, camera, xy, X)


def triangulate_left_out(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, n_points: int,
    cameras: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each observation's point triangulated from the *other* cameras' observations of it alone
    (shapes as :func:`triangulate_points`; ``cameras`` (N,) bool: the cameras whose observations
    may be used, default all), in one call: each observation's point is a point of its own.

    Returns:
        X (M, 3) metres, NaN where fewer than two other cameras saw the point; ``of`` (L,) and
        ``mate`` (L,): the observations used, ``mate`` for the point of observation ``of``. Each
        point's sums run over its observations in their order here, so X is what triangulating
        one camera's points at a time, without it, gives, to the last digit.
    """
    by_point = np.argsort(point, kind="stable")  # each point's observations, in their order here
    start = np.searchsorted(point[by_point], np.arange(n_points + 1))
    lo, hi = start[point], start[point + 1]
    width = hi - lo
    mate = by_point[np.repeat(lo - np.cumsum(width) + width, width) + np.arange(int(width.sum()))]  # same-point rows
    of = np.repeat(np.arange(len(point)), width)
    keep = camera[mate] != camera[of]
    if cameras is not None:
        keep &= cameras[camera[mate]]
    mate, of = mate[keep], of[keep]
    return triangulate_points(R, t, of, camera[mate], xy[mate], len(point)), of, mate


def refine_points(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, X: np.ndarray
) -> np.ndarray:
    """Gauss-Newton steps on each point's reprojection error (shapes as :func:`triangulate_points`;
    ``X`` (P, 3) is the start, NaN rows are left as they are).

    The Jacobian of (x/z, y/z) in X is ``(R_row_x - u R_row_z) / z`` (and likewise for y); its
    3x3 normal equations per point are summed with np.bincount and solved by their adjugate.
    """
    n = len(X)
    ok = np.all(np.isfinite(X), axis=1)
    use = ok[point]
    if not use.all():
        point, camera, xy = point[use], camera[use], xy[use]
    Rt_table = np.ascontiguousarray(np.concatenate([R.reshape(-1, 9), t], axis=1).T)  # (12, N): R[3 i + j], then t[i]
    Xt = np.ascontiguousarray(X.T)  # (3, P)
    for _ in range(GAUSS_NEWTON_STEPS):
        A = np.zeros((9, n))  # the normal equations' six distinct entries, then the gradient
        for s in range(0, len(point), CHUNK):
            sl = slice(s, s + CHUNK)
            pt, r = point[sl], np.take(Rt_table, camera[sl], axis=1)
            Xp = np.take(Xt, pt, axis=1)
            xc = [r[3 * i] * Xp[0] + r[3 * i + 1] * Xp[1] + r[3 * i + 2] * Xp[2] + r[9 + i] for i in range(3)]
            iz = 1.0 / xc[2]
            u, v = xc[0] * iz, xc[1] * iz
            ax = [(r[j] - u * r[6 + j]) * iz for j in range(3)]  # d(x/z)/dX
            ay = [(r[3 + j] - v * r[6 + j]) * iz for j in range(3)]  # d(y/z)/dX
            rx, ry = u - xy[sl, 0], v - xy[sl, 1]
            for k, (i, j) in enumerate(_UPPER):
                A[k] += np.bincount(pt, ax[i] * ax[j] + ay[i] * ay[j], minlength=n)
            for i in range(3):
                A[6 + i] += np.bincount(pt, ax[i] * rx + ay[i] * ry, minlength=n)
        a00, a01, a02, a11, a12, a22, g0, g1, g2 = A
        for d in (a00, a11, a22):
            d[~ok] = 1.0
        # a point whose rays are (nearly) parallel has a singular system: damp it, and keep the
        # last estimate wherever the step is not finite rather than fail the whole set
        damp = DAMPING * (a00 + a11 + a22) + 1e-300
        step = solve_symmetric_3x3(a00 + damp, a01, a02, a11 + damp, a12, a22 + damp, g0, g1, g2)
        good = np.isfinite(step[0]) & np.isfinite(step[1]) & np.isfinite(step[2])
        Xt[:, good] -= step[:, good]
    return Xt.T.copy()


def solve_symmetric_3x3(a, b, c, d, e, f, g0, g1, g2) -> np.ndarray:
    """(3, P) solutions of the symmetric systems [[a, b, c], [b, d, e], [c, e, f]] x = g, each
    argument (P,), by the adjugate (Cramer's rule); non-finite where a system is singular."""
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
        return np.stack(
            [(c00 * g0 + c01 * g1 + c02 * g2) * inv_det,
             (c01 * g0 + c11 * g1 + c12 * g2) * inv_det,
             (c02 * g0 + c12 * g1 + c22 * g2) * inv_det]
        )


def reprojection_errors(
    R: np.ndarray, t: np.ndarray, point: np.ndarray, camera: np.ndarray, xy: np.ndarray, X: np.ndarray
) -> np.ndarray:
    """(M, 2) normalised reprojection residuals ``project(X) - xy`` (R (N, 3, 3), t (N, 3) poses,
    X (P, 3) points, metres; the rest as :func:`triangulate_points`)."""
    Rt_table = np.ascontiguousarray(np.concatenate([R.reshape(-1, 9), t], axis=1).T)  # (12, N)
    Xt = np.ascontiguousarray(X.T)
    out = np.empty((len(point), 2))
    for s in range(0, len(point), CHUNK):
        sl = slice(s, s + CHUNK)
        r, Xp = np.take(Rt_table, camera[sl], axis=1), np.take(Xt, point[sl], axis=1)
        xc = [r[3 * i] * Xp[0] + r[3 * i + 1] * Xp[1] + r[3 * i + 2] * Xp[2] + r[9 + i] for i in range(3)]
        out[sl, 0] = xc[0] / xc[2] - xy[sl, 0]
        out[sl, 1] = xc[1] / xc[2] - xy[sl, 1]
    return out
