"""The wand reprojection model shared by bundle adjustment, the LP method and the CRB.

Parameters:
- per camera: 3 local Euler increments ``delta`` with ``R = E(delta) @ R0`` (E as in the seed
  paper, ``Rz Ry Rx``; increments about the start never meet gimbal lock), and ``t`` (3,);
- per wand frame: the midpoint ``m`` (3,) and 2 direction increments ``(a, b)`` with
  ``d = normalize(d0 + a e1 + b e2)``; the ends are ``m -/+ L/2 d``, so the wand length L is
  built into the parametrisation rather than fitted afterwards;
- per frame of a planar wand (``WandProblem.across`` given): the midpoint and 3 Euler increments
  ``w`` of the wand's own axes, ``Q = E(w) Q0`` with columns (d, e, n): the axis, the in-plane
  normal to it and the plane's normal; marker k is at ``m + o_k d + q_k e``.

Residuals are reprojection errors in pixels (normalised error times fx, fy). The gauge is fixed
by holding the cameras in ``fixed`` at their start (one camera: 6 DOF); scale comes from L.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from wandcal.calib.geometry import euler_jacobian, euler_rates, euler_to_matrix
from wandcal.calib.solve.reprojection import project_into

CAM_PARAMS = 6
FRAME_PARAMS = 5
PLANAR_FRAME_PARAMS = 6  # a planar wand's roll about its axis is observed: one more per frame


@dataclass(frozen=True, eq=False)
class WandProblem:
    """Labelled observations of wand ends.

    camera: (M,) camera index; frame: (M,) wand-frame index in [0, F); end: (M,) 0 or 1;
    xy: (M, 2) normalised coordinates; focal: (N, 2) fx, fy per camera; length: metres.
    along: (M,) for a wand of more markers (wandcal.calib.start.markerlabels), each observed
    marker's position on the axis from the midpoint of the end markers, metres (end 0 at
    -length/2, end 1 at +length/2); None for the two ends alone. across: (M,) for a planar wand,
    each observed marker's offset across the axis in the wand's plane, metres (wandcal.calib.wandlayout.plane_offsets); None
    for a collinear one.
    """

    camera: np.ndarray
    frame: np.ndarray
    end: np.ndarray
    xy: np.ndarray
    focal: np.ndarray
    length: float
    n_frames: int
    along: np.ndarray | None = None
    across: np.ndarray | None = None

    @property
    def n_cams(self) -> int:
        return len(self.focal)

    @property
    def point(self) -> np.ndarray:
        return 2 * self.frame + self.end

    def subset(self, keep: np.ndarray) -> WandProblem:
        return WandProblem(self.camera[keep], self.frame[keep], self.end[keep], self.xy[keep], self.focal, self.length,
                           self.n_frames, None if self.along is None else self.along[keep],
                           None if self.across is None else self.across[keep])

    @property
    def planar(self) -> bool:
        return self.across is not None

    @property
    def offsets(self) -> np.ndarray:
        """(M,) each observation's marker position on the axis from the wand's midpoint, metres."""
        return self.along if self.along is not None else np.where(self.end == 1, 0.5, -0.5) * self.length


class WandModel:
    """Residuals and sparse Jacobian of a :class:`WandProblem` about a start state.

    Args:
        problem: the observations.
        R0: (N, 3, 3), t0: (N, 3) start poses.
        wand0: (F, 2, 3) start wand ends (only their midpoint and direction are used).
        fixed: (N,) bool, cameras held at their start pose (the gauge).
        plane0: (F, 3) a planar wand's start in-plane direction across its axis (made normal to
            the axis here); needed when ``problem.planar``.
    """

    # the observations' sparse sums by frame and camera (wandcal.calib.solve.reduced.incidence), made once
    _slp_incidence: dict[str, Any] | None = None

    def __init__(self, problem: WandProblem, R0: np.ndarray, t0: np.ndarray, wand0: np.ndarray, fixed: np.ndarray,
                 plane0: np.ndarray | None = None):
        self.p = problem
        self.R0 = np.asarray(R0, float)
        self.t0 = np.asarray(t0, float)
        self.fixed = np.asarray(fixed, bool)
        self.free = np.flatnonzero(~self.fixed)
        self.m0 = wand0.mean(axis=1)
        d0 = wand0[:, 1] - wand0[:, 0]
        self.d0 = d0 / np.linalg.norm(d0, axis=1, keepdims=True)
        helper = np.where(np.abs(self.d0[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
        e1 = np.cross(self.d0, helper)
        self.e1 = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
        self.e2 = np.cross(self.d0, self.e1)
        self.frame_params = FRAME_PARAMS
        if problem.planar:
            if plane0 is None:
                raise ValueError("a planar wand's model needs its frames' start planes (plane0)")
            e = plane0 - np.einsum("fi,fi->f", plane0, self.d0)[:, None] * self.d0
            e /= np.linalg.norm(e, axis=1, keepdims=True)
            self.Q0 = np.stack([self.d0, e, np.cross(self.d0, e)], axis=2)  # (F, 3, 3), columns d, e, n
            self.frame_params = PLANAR_FRAME_PARAMS
        self.cam_col = np.full(problem.n_cams, -1)
        self.cam_col[self.free] = np.arange(len(self.free)) * CAM_PARAMS
        self.frame_col0 = len(self.free) * CAM_PARAMS
        self.n_params = self.frame_col0 + self.frame_params * problem.n_frames

    def x0(self) -> np.ndarray:
        x = np.zeros(self.n_params)
        x[: self.frame_col0] = np.concatenate([np.r_[0.0, 0.0, 0.0, self.t0[c]] for c in self.free]) if len(self.free) else []
        fr = x[self.frame_col0 :].reshape(-1, self.frame_params)
        fr[:, :3] = self.m0
        return x

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """x -> (delta (N,3), t (N,3), m (F,3), ab (F,2)); a planar wand's w (F,3) for ab."""
        delta = np.zeros((self.p.n_cams, 3))
        t = self.t0.copy()
        cams = x[: self.frame_col0].reshape(-1, CAM_PARAMS)
        delta[self.free] = cams[:, :3]
        t[self.free] = cams[:, 3:]
        fr = x[self.frame_col0 :].reshape(-1, self.frame_params)
        return delta, t, fr[:, :3], fr[:, 3:]

    def poses(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        delta, t, _, _ = self.unpack(x)
        return euler_to_matrix(delta) @ self.R0, t

    def axes(self, w: np.ndarray) -> np.ndarray:
        """(F, 3, 3) a planar wand's axes E(w) Q0 at increments w (F, 3): columns d, e, n."""
        return euler_to_matrix(w) @ self.Q0

    def directions(self, ab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.p.planar:
            return self.axes(ab)[:, :, 0], np.ones(len(ab))
        v = self.d0 + ab[:, :1] * self.e1 + ab[:, 1:] * self.e2
        norm = np.linalg.norm(v, axis=1, keepdims=True)
        return v / norm, norm[:, 0]

    def wand(self, x: np.ndarray) -> np.ndarray:
        """(F, 2, 3) wand ends at x."""
        _, _, m, ab = self.unpack(x)
        d, _ = self.directions(ab)
        half = 0.5 * self.p.length * d
        return np.stack([m - half, m + half], axis=1)

    def unit_frames(self, x: np.ndarray) -> np.ndarray:
        """(F, 2, 3) each frame's midpoint -/+ half its unit direction: what a WandModel starts
        from (``wand0``), the direction kept also where the wand has no length (the frames of a
        wand-less capture's point tracks, wandcal.calib.run.refine.with_tracks)."""
        _, _, m, ab = self.unpack(x)
        d, _ = self.directions(ab)
        return np.stack([m - 0.5 * d, m + 0.5 * d], axis=1)

    def _camera_points(self, x: np.ndarray):
        """The observed points in their cameras' frames, ``Y + t``: (delta, R (N, 3, 3), d, vnorm,
        sign, Y = R X (M, 3), t (M, 3) of each observation's camera)."""
        p = self.p
        delta, t, m, ab = self.unpack(x)
        R = euler_to_matrix(delta) @ self.R0
        d, vnorm = self.directions(ab)
        sign = p.offsets
        X = m[p.frame] + sign[:, None] * d[p.frame]
        if p.across is not None:
            X = X + p.across[:, None] * self.axes(ab)[p.frame, :, 1]
        return delta, R, d, vnorm, sign, np.einsum("mij,mj->mi", R[p.camera], X), t[p.camera]

    def residuals(self, x: np.ndarray) -> np.ndarray:
        """(2M,) pixel residuals, interleaved (u0, v0, u1, v1, ...)."""
        *_, Y, t = self._camera_points(x)
        xc = Y + t
        r = (xc[:, :2] / xc[:, 2:3] - self.p.xy) * self.p.focal[self.p.camera]
        return r.ravel()

    def jacobian(self, x: np.ndarray):
        """(2M, n_params) sparse Jacobian of :meth:`residuals` (a scipy.sparse csr_matrix)."""
        import scipy.sparse as sp  # for lp and the bound only: ba need not pay its start-up
        blocks, cols = self.jacobian_blocks(x)
        M = len(self.p.camera)
        rows = np.repeat(np.arange(2 * M).reshape(M, 2, 1), blocks.shape[2], axis=2)
        cols2 = np.repeat(cols[:, None, :], 2, axis=1)
        keep = cols2 >= 0
        return sp.csr_matrix((blocks[keep], (rows[keep], cols2[keep])), shape=(2 * M, self.n_params))

    def jacobian_blocks(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`linearised` without the residuals."""
        return self.linearised(x)[1:]

    def linearised(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The pixel residuals (M, 2) (:meth:`residuals`, from the same projection) and the dense
        per-observation Jacobian blocks: (M, 2, 6 + frame_params) values and (M, 6 +
        frame_params) columns (-1 = fixed camera).

        The derivatives by the camera's left rotation increment, its translation and the point
        are ``ba``'s, elementwise (calib/solve/reprojection.project_into); the Euler increments'
        follow through each camera's :func:`euler_rates`, and the wand direction's through each
        frame's tangent map. At 128 x 3000 (707k observations) this took 0.39 s on first use
        against 0.80 s for the batched 3 x 3 products per observation it replaces (their
        temporaries, fresh memory), and the same once memory is warm (decision 0029)."""
        p = self.p
        delta, R, d, vnorm, sign, Y, t = self._camera_points(x)
        cam, fr = p.camera, p.frame
        blocks = np.empty((len(cam), 2, CAM_PARAMS + self.frame_params))
        r = project_into(blocks, Y, t, R[cam], p.xy, p.focal[cam])
        blocks[:, :, :3] = np.einsum("mki,mij->mkj", blocks[:, :, :3], euler_rates(delta)[cam])
        dX = blocks[:, :, 6:9]  # d(pixel)/d(point)
        if p.across is not None:
            # X = m + E(w) Q0 (o, q, 0): dX/dw_k = dE_k Q0 (o, q, 0)
            body = np.einsum("mij,mj->mi", self.Q0[fr], np.stack([sign, p.across, np.zeros_like(sign)], axis=1))
            dE = euler_jacobian(self.unpack(x)[3])[fr]  # (M, 3, 3, 3): dE/dw_k
            blocks[:, :, 9:] = dX @ np.einsum("mkij,mj->mik", dE, body)
        else:
            # the direction's tangent map per frame: d(normalize(d0 + a e1 + b e2))/d(a, b), (F, 3, 2)
            tangent = (np.eye(3)[None] - d[:, :, None] * d[:, None, :]) / vnorm[:, None, None] @ np.stack([self.e1, self.e2], axis=2)
            blocks[:, :, 9:] = sign[:, None, None] * (dX @ tangent[fr])
        cam_base = self.cam_col[cam]
        cam_cols = np.where(cam_base[:, None] >= 0, cam_base[:, None] + np.arange(CAM_PARAMS), -1)
        frame_cols = self.frame_col0 + self.frame_params * fr[:, None] + np.arange(self.frame_params)
        return r, blocks, np.concatenate([cam_cols, frame_cols], axis=1)
