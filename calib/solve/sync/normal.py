"""The normal equations of :func:`wandcal.calib.solve.sync.fit.fit_timing`'s Gauss-Newton step: each
camera's [pose,] phase[, drift] columns with the wand ends eliminated point by point (a 3 x 3 Schur
complement each), every camera's observations weighed by its own blob noise, and the outliers
(beyond ``OUTLIER_LIMIT`` of a camera's own robust sigma) left out.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.solve.sync.tracks import SMALL
from wandcal.calib.triangulate import refine_points, triangulate_points

OUTLIER_LIMIT = 4.0  # robust sigmas: an observation beyond is left out of a step (chi2 with 2 dof: 3e-4 of clean ones)
MIN_OUTLIER_PX = 1.0  # never cut closer than this, so a clean rig keeps all its observations


def normal_equations(R, t, pairs: WandPairs, xy, vel, keep, focal, centre, k, poses, X_last=None, cut=None,
                     spread=None):
    """The reduced normal equations of each camera's [pose,] phase[, drift] columns, the wand ends
    eliminated point by point: S (N w, N w), rhs (N w,), the residuals' sigma (pixels), the
    observations each camera gave, the wand ends (2F, 3) triangulated (from ``X_last`` when given)
    and the outliers (P, K) bool, each pair row's markers left out (``cut``, when given, instead of
    judging them again). A residual r (observed - projected, pixels) changes by
    G d(theta) - A dX: G = -v f [1, f - centre] for the offsets (v the track's velocity), and for
    a pose (R <- exp([w]x) R, t <- t + dt) -f P [-[R X]x, I], P the projection's derivative."""
    n, K = len(R), xy.shape[1]  # K: the wand's markers (its two ends, or every marker of a longer wand)
    F = len(pairs.frames)
    rows = np.flatnonzero(keep)
    point = np.concatenate([pairs.frame[rows] * K + k for k in range(K)])
    cam = np.concatenate([pairs.camera[rows]] * K)
    obs = np.concatenate([xy[rows, k] for k in range(K)])
    v = np.concatenate([vel[rows, k] for k in range(K)])
    fr = np.concatenate([pairs.frames[pairs.frame[rows]]] * K).astype(float)
    # from the last step's wand ends a few Gauss-Newton steps suffice; the linear start only once
    needed = np.bincount(point, minlength=K * F) >= 2
    if X_last is not None and np.all(np.isfinite(X_last[needed])):
        X = refine_points(R, t, point, cam, obs, np.where(needed[:, None], X_last, np.nan))
    else:
        X = triangulate_points(R, t, point, cam, obs, K * F)
    ok = np.isfinite(X[point]).all(1)
    RX = np.einsum("mij,mj->mi", R[cam], np.where(ok[:, None], X[point], 0.0))
    Xc = RX + t[cam]
    z = Xc[:, 2]
    z = np.where(np.abs(z) > SMALL, z, SMALL)
    proj = Xc[:, :2] / z[:, None]
    fc = focal[cam]
    r = (obs - proj) * fc
    e = np.linalg.norm(r, axis=1)
    # each camera's own robust sigma: a camera still out of time has larger residuals, and they
    # are the signal, not outliers
    if cut is None:
        cut = _outliers(e, ok, cam, rows, n, (len(pairs), K))
    ok &= ~cut[np.concatenate([rows] * K), np.repeat(np.arange(K), len(rows))]
    views = np.bincount(point[ok], minlength=K * F)
    ok &= views[point] >= 2
    Pj = np.zeros((len(z), 2, 3))  # d proj / d x_cam, pixels, times z
    Pj[:, 0, 0], Pj[:, 1, 1] = fc[:, 0], fc[:, 1]
    Pj[:, :, 2] = -proj * fc
    Pj /= z[:, None, None]
    A = Pj @ R[cam]  # (M, 2, 3) d proj / dX, pixels a metre
    g = -v * fc  # (M, 2) d r / d phase, pixels a frame
    G = g[:, :, None] * (np.stack([np.ones(len(fr)), fr - centre[cam]], 1)[:, None, :k])  # (M, 2, k)
    if poses:  # d r / d(w, dt) = -P [-[RX]x, I]; a row p of P [RX]x is p x RX
        G = np.concatenate([_cross_rows(Pj, RX), -Pj, G], axis=2)
    width = G.shape[2]
    A, G, r, point, cam = A[ok], G[ok], r[ok], point[ok], cam[ok]
    used = np.bincount(cam, minlength=n)
    share = np.concatenate([spread[rows]] * K)[ok] if spread is not None else None
    pooled, weight = _camera_weights(r, point, cam, used, width, share)
    A, G, r = A * weight[:, :, None], G * weight[:, :, None], r * weight
    S, rhs = _eliminated(A, G, r, point, cam, n, K * F)
    return S, rhs, float(np.sqrt(pooled)), used, X, cut


def _outliers(e: np.ndarray, ok: np.ndarray, cam: np.ndarray, rows: np.ndarray, n: int,
              shape: tuple[int, int]) -> np.ndarray:
    """(P, K) bool, ``shape``: each pair row's markers (its ends, K = 2) whose residual length
    ``e`` (K R,) pixels passes ``OUTLIER_LIMIT`` of its camera's own robust sigma (at least
    ``MIN_OUTLIER_PX``)."""
    limit = np.full(n, MIN_OUTLIER_PX)
    for c in range(n):
        mine = ok & (cam == c)
        if mine.any():
            limit[c] = max(OUTLIER_LIMIT * np.sqrt(np.median(e[mine] ** 2) / (2 * np.log(2))), MIN_OUTLIER_PX)
    cut = np.zeros(shape, bool)
    cut[np.concatenate([rows] * shape[1]), np.repeat(np.arange(shape[1]), len(rows))] = e > limit[cam]
    return cut


def _camera_weights(r: np.ndarray, point: np.ndarray, cam: np.ndarray, used: np.ndarray, width: int,
                    share: np.ndarray | None) -> tuple[float, np.ndarray]:
    """(the pooled blob variance, pixels^2; (M, 1) each observation's weight, its camera's noise
    against the pooled) from the residuals ``r`` (M, 2) pixels, the share of each residual's
    variance the resampling kept (M,), or None for all of it.

    Each camera's blob noise, from its residuals less the share the resampling smoothed away:
    the values' noise is correlated from frame to frame, and over the slowly turning image
    velocity that an offset is seen through it adds up to a whole blob's; the residuals' own
    variance, 0.64 of it half-way between frames, made the standard errors 1.2-1.3x optimistic."""
    n = len(used)
    M = len(r)
    dof_share = max(2 * M - 3 * len(np.unique(point)) - n * width, 1) / (2 * M)
    share = share if share is not None else np.ones(M)
    noise = np.bincount(cam, (r**2).sum(1), minlength=n) / np.maximum(2 * np.bincount(cam, share, minlength=n), 1e-300)
    noise = noise / dof_share
    noise = np.where(used > 0, noise, 1.0)
    pooled = float(np.sum(noise * used) / max(used.sum(), 1))
    weight = np.sqrt(pooled / np.maximum(noise, 1e-300))[cam][:, None]  # each camera by its noise, in pixels
    return pooled, weight


def _eliminated(A: np.ndarray, G: np.ndarray, r: np.ndarray, point: np.ndarray, cam: np.ndarray, n: int,
                n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera columns' normal equations with the points eliminated point by point: S (n w,
    n w), rhs (n w,), from each observation's point Jacobian ``A`` (M, 2, 3), camera Jacobian
    ``G`` (M, 2, w) and residual ``r`` (M, 2), all weighted."""
    width = G.shape[2]
    H = _sums(point, _outer_sum(A, A), n_points)
    ar = _sums(point, np.einsum("mai,ma->mi", A, r), n_points)
    D = np.zeros((n, width, width))
    gr = np.zeros((n, width))
    for c in range(n):  # a camera's block is one product over its observations
        mine = cam == c
        Gc = G[mine].reshape(-1, width)
        D[c], gr[c] = Gc.T @ Gc, Gc.T @ r[mine].ravel()
    seen = np.flatnonzero(np.bincount(point, minlength=n_points) >= 2)
    slot = np.full(n_points, -1)
    slot[seen] = np.arange(len(seen))
    # a camera sees a wand end once, so each (end, camera) block of B is one observation's A^T G
    B = np.zeros((len(seen) * n, 3, width))
    at = slot[point] >= 0
    B[slot[point[at]] * n + cam[at]] = np.matmul(A[at].transpose(0, 2, 1), G[at])
    B = B.reshape(len(seen), n, 3, width).transpose(0, 2, 1, 3).reshape(len(seen), 3, n * width)
    Hinv = np.linalg.inv(H[seen] + np.eye(3) * SMALL)
    W = np.einsum("pij,pjq->piq", Hinv, B)
    S = -(B.reshape(-1, n * width).T @ W.reshape(-1, n * width))  # one matrix product over all points
    for c in range(n):
        S[c * width : (c + 1) * width, c * width : (c + 1) * width] += D[c]
    rhs = -gr.ravel() + np.einsum("piq,pi->q", W, ar[seen])
    return S, rhs


def _cross_rows(P: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, 2, 3) each row of P (M, 2, 3) crossed with v (M, 3): P @ [v]x."""
    v0, v1, v2 = v[:, None, 0], v[:, None, 1], v[:, None, 2]
    p0, p1, p2 = P[:, :, 0], P[:, :, 1], P[:, :, 2]
    return np.stack([p1 * v2 - p2 * v1, p2 * v0 - p0 * v2, p0 * v1 - p1 * v0], axis=2)


def _outer_sum(A: np.ndarray, G: np.ndarray) -> np.ndarray:
    """(M, i, k) A[m]^T G[m] of A (M, 2, i) and G (M, 2, k): the two rows' outer products
    (for 3 x 3, faster than an einsum or a batched matmul)."""
    return A[:, 0, :, None] * G[:, 0, None, :] + A[:, 1, :, None] * G[:, 1, None, :]


def _sums(index: np.ndarray, values: np.ndarray, size: int) -> np.ndarray:
    """(size, ...) the sums of ``values`` (M, ...) by ``index`` (M,): one bincount a component."""
    flat = values.reshape(len(values), -1)
    out = np.stack([np.bincount(index, flat[:, j], minlength=size) for j in range(flat.shape[1])], axis=1)
    return out.reshape(size, *values.shape[1:])
