"""Cameras that look into water through a flat window, as the matcher's camera model
(:class:`wandcal.calib.watch.match.CameraModel`): a blob's epipolar line in another camera is a
curve, traced by sampling its ray in the water over the depths the volume spans and projecting the
samples (calib/refraction.py); points are triangulated where their rays in the water meet, then
refined on their reprojection error.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from wandcal.calib.refraction import FlatWindow, nearest_to_rays, project_through_window, trace_into_medium

CURVE_SAMPLES = 24  # points along a ray's stretch in the volume: the polyline is within 5e-5 px of the curve on the
#                     simulated cavity (a flat window barely bends it; tests/calib/watch/test_refracted.py)
FRAME_GAP_PX = 1e7  # frames side by side in one k-d tree, this far apart (as the matcher's)
GAUSS_NEWTON_STEPS = 3  # from where the rays meet (within a few micrometres of the optimum) to the reprojection optimum
STEP_M = 1e-7  # central differences of the projection: 0.1 um, ~1e-3 px at the cavity's scale, far above rounding


class Refracted:
    """Cameras at poses R (C, 3, 3), t (C, 3) (metres, world->camera), each behind its window;
    depth (C, 2): metres below each camera's window (its water-side face) between which points are
    sought (the measurement volume's near and far side); focal (C,): pixels, for the epipolar gate."""

    def __init__(self, R: np.ndarray, t: np.ndarray, windows: Sequence[FlatWindow], depth: np.ndarray,
                 focal: np.ndarray):
        self.R, self.t, self.windows = R, t, tuple(windows)
        self.depth, self.focal = np.asarray(depth, dtype=float), np.asarray(focal, dtype=float)

    def epipolar_pairs(self, a, b, xa, xb, tol_px):
        from scipy.spatial import cKDTree

        fa, ia = np.nonzero(np.isfinite(xa[..., 0]))
        fb, jb = np.nonzero(np.isfinite(xb[..., 0]))
        empty = np.zeros(0, np.int64)
        if not len(fa) or not len(fb):
            return empty, empty, empty
        curve = self._curves(a, b, xa[fa, ia]) * self.focal[b]  # (Na, S, 2) px in b
        p0, p1 = curve[:, :-1], curve[:, 1:]
        mid = (p0 + p1) / 2
        half = np.linalg.norm(p1 - p0, axis=-1) / 2
        ok = np.isfinite(half)
        seg_a, seg_s = np.nonzero(ok)
        tree = cKDTree(np.column_stack([xb[fb, jb] * self.focal[b], fb * FRAME_GAP_PX]))
        near = tree.query_ball_point(np.column_stack([mid[ok], fa[seg_a] * FRAME_GAP_PX]), half[ok] + tol_px)
        n_near = np.array([len(v) for v in near])
        if not n_near.sum():
            return empty, empty, empty
        q = np.repeat(np.arange(len(near)), n_near)
        hit = np.concatenate([np.asarray(v, dtype=np.int64) for v in near])
        d = _segment_distance(xb[fb[hit], jb[hit]] * self.focal[b], p0[seg_a[q], seg_s[q]], p1[seg_a[q], seg_s[q]])
        keep = d < tol_px
        pair = np.unique(np.column_stack([seg_a[q][keep], hit[keep]]), axis=0)
        return fa[pair[:, 0]], ia[pair[:, 0]], jb[pair[:, 1]]

    def _curves(self, a: int, b: int, xy: np.ndarray) -> np.ndarray:
        """(N, S, 2) normalised coordinates in camera b of xy (N, 2)'s rays in camera a, sampled
        over a's depth range; NaN where b cannot see the sample."""
        origin, direction = trace_into_medium(self.windows[a], self.R[a], self.t[a], xy)
        down = -(direction @ self.windows[a].normal)  # depth gained a metre along the ray
        depths = np.linspace(self.depth[a, 0], self.depth[a, 1], CURVE_SAMPLES)
        with np.errstate(invalid="ignore", divide="ignore"):
            X = origin[:, None] + (depths[None, :] / down[:, None])[..., None] * direction[:, None]
        proj = project_through_window(self.windows[b], self.R[b], self.t[b], X.reshape(-1, 3))
        return proj.reshape(len(xy), CURVE_SAMPLES, 2)

    def two_ray_points(self, a, b, xa, xb):
        oa, da = trace_into_medium(self.windows[a], self.R[a], self.t[a], xa)
        ob, db = trace_into_medium(self.windows[b], self.R[b], self.t[b], xb)
        n = len(xa)
        return nearest_to_rays(np.concatenate([oa, ob]), np.concatenate([da, db]), np.tile(np.arange(n), 2), n)

    def project(self, X):
        return np.stack([project_through_window(w, self.R[c], self.t[c], X) for c, w in enumerate(self.windows)], axis=1)

    def triangulate(self, p, c, xy, X0):
        """Where the views' rays in the water meet, then :data:`GAUSS_NEWTON_STEPS` on the
        reprojection error (central-difference Jacobians); X0 where the rays give no point."""
        origin, direction = np.empty((len(p), 3)), np.empty((len(p), 3))
        for cam in np.unique(c):
            sel = c == cam
            origin[sel], direction[sel] = trace_into_medium(self.windows[cam], self.R[cam], self.t[cam], xy[sel])
        X = nearest_to_rays(origin, direction, p, len(X0))
        X = np.where(np.isfinite(X), X, X0)
        for _ in range(GAUSS_NEWTON_STEPS):
            X = self._gauss_newton_step(p, c, xy, X)
        return X

    def jacobians(self, p: np.ndarray, c: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(M, 2, 3) d(normalised projection of view m)/d(its point X[p[m]]), per metre (central
        differences of :data:`STEP_M`)."""
        J = np.empty((len(p), 2, 3))
        for k in range(3):
            dX = np.zeros(3)
            dX[k] = STEP_M
            J[:, :, k] = (self.project_views(p, c, X + dX) - self.project_views(p, c, X - dX)) / (2 * STEP_M)
        return J

    def _gauss_newton_step(self, p, c, xy, X):
        r = self.residuals(p, c, xy, X)
        J = self.jacobians(p, c, X)
        good = np.isfinite(r).all(1) & np.isfinite(J).all((1, 2))
        A = np.zeros((len(X), 3, 3))
        g = np.zeros((len(X), 3))
        np.add.at(A, p[good], np.einsum("mki,mkj->mij", J[good], J[good]))
        np.add.at(g, p[good], np.einsum("mki,mk->mi", J[good], r[good]))
        solvable = np.linalg.cond(A) < 1e15
        step = np.zeros_like(X)
        step[solvable] = np.linalg.solve(A[solvable], g[solvable][..., None])[..., 0]
        return X - step

    def project_views(self, p: np.ndarray, c: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(M, 2) normalised projection of view m's point X[p[m]] (X (P, 3)) in its camera c[m]."""
        out = np.full((len(p), 2), np.nan)
        for cam in np.unique(c):
            sel = c == cam
            out[sel] = project_through_window(self.windows[cam], self.R[cam], self.t[cam], X[p[sel]])
        return out

    def residuals(self, p, c, xy, X):
        return self.project_views(p, c, X) - xy


def _segment_distance(x: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """(M,) distance of points x (M, 2) from the segments p0-p1 (M, 2 each)."""
    d = p1 - p0
    length2 = (d * d).sum(1)
    s = np.clip(((x - p0) * d).sum(1) / np.where(length2 > 0, length2, 1.0), 0.0, 1.0)
    return np.linalg.norm(x - p0 - s[:, None] * d, axis=1)
