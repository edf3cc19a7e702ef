"""Reprojection terms of the bundle adjustment: pixel residuals and their lean analytic Jacobians.

A term is one kind of observed unknown: the wand (per frame a midpoint and a unit direction, the
ends ``m -/+ L/2 d``) or free 3D points (single-point tracks). Cameras are shared by all terms.
Every state update is a re-linearisation about the current state: a camera's rotation moves by a
left increment ``R <- exp([w]) R``, a wand direction by ``d <- normalize(d + a u1 + b u2)`` in
its tangent plane, a point by ``X <- X + dX``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.solve.backend import schur

CAM_PARAMS = 6  # rotation increment w (3), translation t (3)
FRAME_PARAMS = 5  # midpoint (3), direction increments (a, b)
POINT_PARAMS = 3
# intrinsics a camera may refine, in this order, and how many parameters each takes: the focal
# length as a relative change of fx and fy together, the principal point (cx, cy), radial k1
INTRINSICS = {"focal": 1, "principal": 2, "k1": 1}
# a camera's time offset, refined when its observations carry their image velocity (``--sync
# auto``, docs/sync.md): one column after the intrinsics, the residual moving by dt v
TIME_PARAMS = 1


@dataclass(frozen=True, eq=False)
class BundleState:
    """R (N, 3, 3), t (N, 3) world->camera, metres; m (F, 3) wand midpoints; d (F, 3) unit wand
    directions; X (T, 3) free points; Q (F, 3, 3) a planar wand's axes (columns d, e, n:
    wandcal.calib.solve.markerwand.PlanarWandTerm), else None."""

    R: np.ndarray
    t: np.ndarray
    m: np.ndarray
    d: np.ndarray
    X: np.ndarray
    intr: np.ndarray | None = None  # (N, 9) fx, fy, cx, cy, k1, k2, p1, p2, k3 when refined
    Q: np.ndarray | None = None  # (F, 3, 3) a planar wand's frame axes, or None
    dt: np.ndarray | None = None  # (N,) time offsets refined, frames, when the terms carry velocities

    def refined_intr(self) -> np.ndarray:
        """(N, 9) the intrinsics, for terms that fit raw pixels (they are refined then)."""
        if self.intr is None:
            raise ValueError("a term fits raw pixels, but the bundle state holds no intrinsics")
        return self.intr

    def refined_dt(self) -> np.ndarray:
        """(N,) the time offsets in frames, for terms that carry velocities (they are refined then)."""
        if self.dt is None:
            raise ValueError("a term carries image velocities, but the bundle state holds no time offsets")
        return self.dt


@dataclass(frozen=True, eq=False)
class TimeFit:
    """Time offsets to refine (``--sync auto``, docs/sync.md), one column per camera after the
    intrinsics (``TIME_PARAMS``): velocity (M, 2) each wand observation's image velocity in the
    model's order, pixels a frame (normalised units times the focal length; with the intrinsics
    refined the lens's local stretch, a few percent, is left out of it); held (N,) bool the
    cameras whose offset stays at 0 (the reference camera, the gauge: a common shift of every
    camera is the wand's own time)."""

    velocity: np.ndarray
    held: np.ndarray


def camera_index(free: np.ndarray, camera: np.ndarray, n_cams: int) -> np.ndarray:
    """(M,) index of each observation's camera among the free ones, -1 for a fixed camera."""
    index = np.full(n_cams, -1)
    index[free] = np.arange(len(free))
    return index[camera]


ROWS_PER_CHUNK = 32_768  # observations linearised at once: bounds the temporaries (~15 MB)
Rows = slice | np.ndarray  # the observations a term works on: a chunk, or (K,) indices of some


class _Term:
    """What the terms share: residuals formed a chunk of observations at a time (so temporaries
    stay small), and the rows of the Jacobian for any range (``linearise_rows``), which the
    normal equations take a chunk at a time."""

    camera: np.ndarray
    xy: np.ndarray  # (M, 2) normalised image coordinates
    focal: np.ndarray  # (M, 2) pixels per normalised unit
    raw: tuple[np.ndarray, tuple[str, ...]] | None  # (uv (M, 2) raw pixels, refined intrinsics' names)
    # (M, 2) each observation's image velocity, residual pixels a frame, when the time offsets
    # are refined: the observation at the camera's offset moved by dt is xy - dt v, so r moves by +dt v
    velocity: np.ndarray | None = None

    def residuals(self, s: BundleState, rows: np.ndarray | None = None) -> np.ndarray:
        """(M, 2) pixel residuals; given ``rows`` (K,) indices of observations, theirs (K, 2)."""
        if rows is not None:
            return self._residuals(s, rows)
        n = len(self.camera)
        out = np.empty((n, 2))
        for a in range(0, n, ROWS_PER_CHUNK):
            sl = slice(a, a + ROWS_PER_CHUNK)
            out[sl] = self._residuals(s, sl)
        return out

    def linearise_rows(self, s: BundleState, sl: Rows) -> tuple[np.ndarray, np.ndarray]:
        """(r (K, 2), J (K, 2, c + p)) of the observations ``sl`` (a slice, or (K,) indices) at
        ``s``: the camera's c parameters (w, t, refined intrinsics) first, then the block's p."""
        return self._linearise(s, sl)

    def _residuals(self, s: BundleState, sl: Rows) -> np.ndarray:
        """(K, 2) pixel residuals of the observations ``sl``: each term's own model."""
        raise NotImplementedError

    def _linearise(self, s: BundleState, sl: Rows) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`linearise_rows`, each term's own."""
        raise NotImplementedError

    def _project(self, s: BundleState, X: np.ndarray, sl: Rows) -> np.ndarray:
        xc = np.einsum("mij,mj->mi", s.R[self.camera[sl]], X) + s.t[self.camera[sl]]
        if self.raw is not None:
            r = distorted_pixels(xc, s.refined_intr()[self.camera[sl]])[0] - self.raw[0][sl]
        else:
            r = (xc[:, :2] / xc[:, 2:3] - self.xy[sl]) * self.focal[sl]
        if self.velocity is not None:
            r += s.refined_dt()[self.camera[sl], None] * self.velocity[sl]
        return r


class WandTerm(_Term):
    """Observations of wand ends: camera (M,), frame (M,), end (M,) 0/1, xy (M, 2) normalised,
    focal (M, 2) pixels per normalised unit, length metres."""

    size = FRAME_PARAMS

    def __init__(self, camera, frame, end, xy, focal, length, n_frames, free, n_cams, raw=None, along=None,
                 velocity=None):
        """``raw``: None, or (uv (M, 2) raw pixels, refined intrinsics names) to fit raw pixels
        through the distortion with the cameras' intrinsics among the unknowns. ``along``: (M,)
        a multi-marker wand's marker positions on the axis, metres (WandProblem.along), or None.
        ``velocity``: (M, 2) image velocities in the residual's pixels a frame, to refine each
        camera's time offset (``TIME_PARAMS`` column), or None."""
        self.camera, self.frame, self.xy, self.focal = camera, frame, xy, focal
        self.raw = raw
        self.velocity = velocity
        self.half = np.where(end == 1, 0.5, -0.5) * length if along is None else np.asarray(along, float)
        self.structure = schur.TermStructure(camera_index(free, camera, n_cams), camera, frame, len(free), n_frames, FRAME_PARAMS)

    def _ends(self, s: BundleState, sl: Rows) -> np.ndarray:
        return s.m[self.frame[sl]] + self.half[sl, None] * s.d[self.frame[sl]]

    def _residuals(self, s: BundleState, sl: Rows) -> np.ndarray:
        return self._project(s, self._ends(s, sl), sl)

    def _linearise(self, s: BundleState, sl: Rows):
        camera, frame = self.camera[sl], self.frame[sl]
        Rc = s.R[camera]
        Y = np.einsum("mij,mj->mi", Rc, self._ends(s, sl))
        raw = None if self.raw is None else (self.raw[0][sl], self.raw[1])
        velocity = None if self.velocity is None else self.velocity[sl]
        r, J = _linearised_projection(Y, s, camera, Rc, self.xy[sl], self.focal[sl], raw, FRAME_PARAMS, velocity)
        u1, u2 = (u[frame] for u in tangent_basis(s.d))  # a frame's basis once, not once per observation
        c = J.shape[2] - FRAME_PARAMS
        dX = J[:, :, c : c + 3]  # d/dX of the end; the end moves by half * (a u1 + b u2)
        J[:, :, c + 3] = np.einsum("mki,mi->mk", dX, u1) * self.half[sl, None]
        J[:, :, c + 4] = np.einsum("mki,mi->mk", dX, u2) * self.half[sl, None]
        return r, J

    def moved(self, s: BundleState, dp: np.ndarray) -> BundleState:
        u1, u2 = tangent_basis(s.d)
        d = s.d + dp[:, 3:4] * u1 + dp[:, 4:5] * u2
        return replace(s, m=s.m + dp[:, :3], d=d / np.linalg.norm(d, axis=1, keepdims=True))


class PointTerm(_Term):
    """Observations of free points: camera (Q,), track (Q,), xy (Q, 2) normalised, focal (Q, 2)."""

    size = POINT_PARAMS

    def __init__(self, camera, track, xy, focal, n_tracks, free, n_cams, raw=None, timed=False):
        """``timed``: the cameras' time offsets are refined (the wand's motion shows them; a
        point is taken as still, its rows' time column zero)."""
        order = np.lexsort((camera, track))  # one group per (point, camera)
        self.order = order
        self.camera, self.track, self.xy, self.focal = camera[order], track[order], xy[order], focal[order]
        self.raw = None if raw is None else (raw[0][order], raw[1])
        self.velocity = np.zeros((len(camera), 2)) if timed else None
        self.structure = schur.TermStructure(camera_index(free, self.camera, n_cams), self.camera, self.track, len(free), n_tracks, POINT_PARAMS)

    def _residuals(self, s: BundleState, sl: Rows) -> np.ndarray:
        return self._project(s, s.X[self.track[sl]], sl)

    def _linearise(self, s: BundleState, sl: Rows):
        camera = self.camera[sl]
        Rc = s.R[camera]
        Y = np.einsum("mij,mj->mi", Rc, s.X[self.track[sl]])
        raw = None if self.raw is None else (self.raw[0][sl], self.raw[1])
        velocity = None if self.velocity is None else self.velocity[sl]
        return _linearised_projection(Y, s, camera, Rc, self.xy[sl], self.focal[sl], raw, POINT_PARAMS, velocity)

    def moved(self, s: BundleState, dp: np.ndarray) -> BundleState:
        return replace(s, X=s.X + dp)


def _linearised_projection(Y, s: BundleState, camera, Rc, xy, focal, raw, point_size, velocity=None):
    """(r, J) of one term's observations, with the camera's columns first: (w, t), when fitting
    raw pixels the refined intrinsics, and with ``velocity`` (K, 2) the time offset (d r / d dt =
    v); the last ``point_size`` columns start with d/dX."""
    timed = 0 if velocity is None else TIME_PARAMS
    if raw is None:
        if velocity is None:
            J = np.empty((len(Y), 2, CAM_PARAMS + point_size))
            return project_into(J, Y, s.t[camera], Rc, xy, focal), J
        J = np.empty((len(Y), 2, CAM_PARAMS + timed + point_size))
        r = project_into(J, Y, s.t[camera], Rc, xy, focal, CAM_PARAMS + timed)
        J[:, :, CAM_PARAMS] = velocity
        return r + s.refined_dt()[camera, None] * velocity, J
    uv, refine = raw
    k = sum(INTRINSICS[name] for name in refine)
    J = np.empty((len(Y), 2, CAM_PARAMS + k + timed + point_size))
    xc = Y + s.t[camera]
    pixels, A, dintr = distorted_pixels(xc, s.refined_intr()[camera], refine)
    J[:, 0, :3] = np.cross(Y, A[:, 0])
    J[:, 1, :3] = np.cross(Y, A[:, 1])
    J[:, :, 3:6] = A
    J[:, :, 6 : 6 + k] = dintr
    c = 6 + k + timed
    J[:, :, c : c + 3] = A @ Rc
    if velocity is None:
        return pixels - uv, J
    J[:, :, 6 + k] = velocity
    return pixels - uv + s.refined_dt()[camera, None] * velocity, J


def distorted_pixels(xc: np.ndarray, intr: np.ndarray, refine: tuple[str, ...] | None = None):
    """OpenCV's pinhole projection with distortion ``[k1, k2, p1, p2, k3]``.

    Args:
        xc: (M, 3) points in their cameras' frames, metres.
        intr: (M, 9) fx, fy, cx, cy, k1, k2, p1, p2, k3 of each point's camera.
        refine: when given, also return the derivatives.

    Returns:
        (M, 2) pixels; with ``refine``, also d(pixel)/d(xc) (M, 2, 3) and the derivatives w.r.t.
        the refined intrinsics (M, 2, k): the focal length as a relative change of fx and fy, the
        principal point, k1.
    """
    iz = 1.0 / xc[:, 2]
    x, y = xc[:, 0] * iz, xc[:, 1] * iz
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = intr.T
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    pixels = np.stack([fx * xd + cx, fy * yd + cy], axis=1)
    if refine is None:
        return pixels, None, None
    slope = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
    D = np.empty((len(x), 2, 2))  # d(xd, yd)/d(x, y), scaled by the focal lengths
    D[:, 0, 0] = fx * (radial + 2 * x * x * slope + 2 * p1 * y + 6 * p2 * x)
    D[:, 0, 1] = fx * (2 * x * y * slope + 2 * p1 * x + 2 * p2 * y)
    D[:, 1, 0] = fy * (2 * x * y * slope + 2 * p1 * x + 2 * p2 * y)
    D[:, 1, 1] = fy * (radial + 2 * y * y * slope + 6 * p1 * y + 2 * p2 * x)
    A = np.empty((len(x), 2, 3))  # d(pixel)/d(xc) = D @ [[1, 0, -x], [0, 1, -y]] / z
    A[:, :, 0] = D[:, :, 0] * iz[:, None]
    A[:, :, 1] = D[:, :, 1] * iz[:, None]
    A[:, :, 2] = -(D[:, :, 0] * x[:, None] + D[:, :, 1] * y[:, None]) * iz[:, None]
    cols = []
    for name in refine:
        if name == "focal":
            cols.append(np.stack([fx * xd, fy * yd], axis=1)[:, :, None])
        elif name == "principal":
            cols.append(np.broadcast_to(np.eye(2), (len(x), 2, 2)))
        else:
            cols.append(np.stack([fx * x * r2, fy * y * r2], axis=1)[:, :, None])
    return pixels, A, np.concatenate(cols, axis=2) if cols else np.zeros((len(x), 2, 0))


def moved_intrinsics(intr: np.ndarray, step: np.ndarray, refine: tuple[str, ...]) -> np.ndarray:
    """Intrinsics (N, 9) after a step (N, k) in the refined ones (see :func:`distorted_pixels`)."""
    out = intr.copy()
    col = 0
    for name in refine:
        if name == "focal":
            out[:, :2] *= (1 + step[:, col])[:, None]
        elif name == "principal":
            out[:, 2:4] += step[:, col : col + 2]
        else:
            out[:, 4] += step[:, col]
        col += INTRINSICS[name]
    return out


def project_into(J: np.ndarray, Y: np.ndarray, t: np.ndarray, R: np.ndarray, xy: np.ndarray, focal: np.ndarray,
                 point_col: int = CAM_PARAMS):
    """Pixel residuals (M, 2) of points ``R X + t`` with ``Y = R X`` (M, 3), against normalised
    ``xy`` (M, 2) scaled by ``focal`` (M, 2); writes into ``J[:, :, :6]`` the derivatives w.r.t.
    the camera's rotation increment w (``R <- exp([w]) R``) and its translation, and into
    ``J[:, :, point_col : point_col + 3]`` those w.r.t. the point X.

    With p = (x/z, y/z) of x_cam = Y + t, dp/dx_cam = [[1, 0, -px], [0, 1, -py]] / z; dx_cam/dw
    = -[Y]x, so row k of dp/dw is Y x (row k of dp/dx_cam); dx_cam/dX = R."""
    xc = Y + t
    iz = 1.0 / xc[:, 2]
    proj = xc[:, :2] * iz[:, None]
    r = (proj - xy) * focal
    fz = focal * iz[:, None]  # (M, 2)
    px, py = proj[:, 0], proj[:, 1]
    Yx, Yy, Yz = Y[:, 0], Y[:, 1], Y[:, 2]
    J[:, 0, 0] = -px * Yy
    J[:, 0, 1] = Yz + px * Yx
    J[:, 0, 2] = -Yy
    J[:, 1, 0] = -py * Yy - Yz
    J[:, 1, 1] = py * Yx
    J[:, 1, 2] = Yx
    J[:, 0, 3], J[:, 0, 4], J[:, 0, 5] = 1.0, 0.0, -px
    J[:, 1, 3], J[:, 1, 4], J[:, 1, 5] = 0.0, 1.0, -py
    if point_col == CAM_PARAMS:
        J[:, :, 6:9] = R[:, :2, :] - proj[:, :, None] * R[:, 2:3, :]
        J[:, :, :9] *= fz[:, :, None]
        return r
    J[:, :, point_col : point_col + 3] = R[:, :2, :] - proj[:, :, None] * R[:, 2:3, :]
    J[:, :, :6] *= fz[:, :, None]
    J[:, :, point_col : point_col + 3] *= fz[:, :, None]
    return r


def tangent_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (F, 3) orthogonal to each unit direction (F, 3) and to each other."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u1 = np.cross(d, helper)
    u1 /= np.linalg.norm(u1, axis=1, keepdims=True)
    return u1, np.cross(d, u1)


def exp_so3(w: np.ndarray) -> np.ndarray:
    """(K, 3) rotation vectors -> (K, 3, 3) matrices (Rodrigues' formula, batched)."""
    theta = np.linalg.norm(w, axis=1)
    small = theta < 1e-12
    k = w / np.where(small, 1.0, theta)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(theta)[:, None, None], (1 - np.cos(theta))[:, None, None]
    return np.eye(3) + s * K + c * (K @ K)
