"""Bundle adjustment with the wand length built in (``--method ba``): a Schur-complement
Levenberg–Marquardt with a robust loss.

The unknowns are those of :class:`wandcal.calib.solve.wandmodel.WandModel` (free camera poses; per wand frame
a midpoint and a direction, the ends ``m -/+ L/2 d``), re-linearised about the current state at
every iteration: a camera's rotation moves by a left increment ``R <- exp([w]) R``, a direction
by ``d <- normalize(d + a u1 + b u2)`` in its tangent plane. The Jacobian is analytic and lean
(batched 2x3 products, no sparse matrix per iteration); the damped normal equations are solved by
eliminating the frames' 5x5 blocks (:mod:`wandcal.calib.solve.backend.schur`).

The iterations themselves, the robust loss and the stop: :mod:`wandcal.calib.solve.ba.levenberg`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from wandcal.calib.geometry import camera_centers, matrix_to_euler
from wandcal.calib.observations import PointTracks
from wandcal.calib.solve.ba.levenberg import CAUCHY_SIGMAS, STOP_SE, LevenbergMarquardt
from wandcal.calib.solve.backend import schur
from wandcal.calib.solve.markerwand import PlanarWandTerm, planar_term
from wandcal.calib.solve.reprojection import CAM_PARAMS, INTRINSICS, BundleState, PointTerm, TimeFit, WandTerm
from wandcal.calib.solve.uncertainty import PoseCovariance
from wandcal.calib.solve.wandmodel import WandModel

LOSSES = ("cauchy", "linear")
DEFAULT_LOSS = "cauchy"
MAX_ITER = 100
__all__ = ["CAUCHY_SIGMAS", "DEFAULT_LOSS", "LOSSES", "MAX_ITER", "STOP_SE", "BundleResult", "IntrinsicsFit",
           "bundle_adjust", "bundle_adjust_points"]


def bundle_adjust(
    model: WandModel, x0: np.ndarray | None = None, progress=None, loss: str = DEFAULT_LOSS, max_iter: int = MAX_ITER
):
    """Minimise the (robust) pixel reprojection error over all free cameras and wand frames.

    Args:
        model: the problem about its start state.
        x0: (n_params,) start in the model's parameters; ``model.x0()`` when None.
        progress: optional callable(dict) told about each iteration.
        loss: "cauchy" (default) or "linear" (plain least squares).
        max_iter: most Levenberg–Marquardt iterations.

    Returns:
        (x, info): x in the model's parameters; info = {"iterations", "cost", "seconds", "status",
        "message", "loss", "loss_scale_px", "evaluations"}.
    """
    out = bundle_adjust_points(model, None, None, x0=x0, progress=progress, loss=loss, max_iter=max_iter)
    return out.x, out.info


@dataclass(frozen=True, eq=False)
class IntrinsicsFit:
    """Intrinsics to refine: start values intr (N, 9) = fx, fy, cx, cy, k1, k2, p1, p2, k3; the
    names refined (a subset of ``wandcal.calib.solve.reprojection.INTRINSICS``, in its order); the raw pixels
    of the wand observations (M, 2) and of the point tracks (Q, 2) in the model's order."""

    intr: np.ndarray
    refine: tuple[str, ...]
    wand_uv: np.ndarray
    point_uv: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class BundleResult:
    """x: the model's parameters; X: (T, 3) points or None; intr: (N, 9) refined intrinsics or
    None; camera_std: (N, c) standard errors of each camera's parameters (w, t, refined
    intrinsics, time offset; 0 where held); covariance: the free poses' covariance (None when
    standard errors were not asked for); info: the solver's record; dt: (N,) the time offsets
    refined (frames, added to the observations' own: an observation moved by dt is xy - dt v), or
    None."""

    x: np.ndarray
    X: np.ndarray | None
    intr: np.ndarray | None
    camera_std: np.ndarray
    info: dict
    covariance: PoseCovariance | None = None
    dt: np.ndarray | None = None


def _point_term(tracks: PointTracks, focal: np.ndarray, free: np.ndarray, n: int, intrinsics: IntrinsicsFit | None,
                timed: bool) -> PointTerm:
    """The single-point tracks' term (focal: (N,) pixels; raw pixels when the intrinsics are refined)."""
    raw = None
    if intrinsics is not None and intrinsics.refine:
        if intrinsics.point_uv is None:
            raise ValueError("bundle_adjust_points: refining the intrinsics with point tracks needs their raw "
                             "pixels (IntrinsicsFit.point_uv)")
        raw = (intrinsics.point_uv, intrinsics.refine)
    return PointTerm(tracks.camera, tracks.track, tracks.xy, focal[tracks.camera], tracks.n_tracks, free, n, raw, timed)


def _load_wide_inverse(width: int) -> None:
    """Load scipy's LAPACK when a reduced system ``width`` wide is inverted by it
    (:func:`wandcal.calib.solve.backend.schur._spd_inverse`): before the solve's one-thread BLAS
    limit, which holds only the BLAS libraries loaded when it starts (loaded inside, its BLAS ran on
    both cores: 256 x 3000, 11.2 -> 13.0 CPU s for the whole command)."""
    if width >= schur.LAPACK_INVERSE_WIDTH:
        import scipy.linalg.lapack  # noqa: F401


def bundle_adjust_points(
    model: WandModel,
    tracks: PointTracks | None,
    X0: np.ndarray | None,
    x0: np.ndarray | None = None,
    progress=None,
    loss: str = DEFAULT_LOSS,
    max_iter: int = MAX_ITER,
    intrinsics: IntrinsicsFit | None = None,
    stop_se: float = STOP_SE,
    standard_errors: bool = True,
    timing: TimeFit | None = None,
    *,
    judge_frames: bool = True,
) -> BundleResult:
    """:func:`bundle_adjust` with single-point tracks as free 3D points beside the wand, and
    optionally the cameras' intrinsics among the unknowns (fitting raw pixels through the lens
    distortion).

    Args:
        tracks: the points' observations (``wandcal.calib.observations.PointTracks``), or None.
        X0: (T, 3) their start positions, metres.
        intrinsics: what to refine, or None to hold the intrinsics.
        stop_se: stop when every parameter is estimated to be within this many standard errors
            of the optimum (a robust first stage that a least squares polish follows needs less).
        standard_errors: compute ``camera_std`` (one more evaluation and solve; a first stage
            whose result is polished further does not need them).
        timing: the time offsets to refine with the poses, or None to hold them (no extra column).
        judge_frames: False: ``stop_se`` is judged on the cameras and points, not the wand frames.

    Without wand observations the scale is free: it is held by fixing the one translation
    component of one camera that most changes with it (the poses are then up to scale).
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    start = time.perf_counter()
    x0 = model.x0() if x0 is None else x0
    p = model.p
    n = p.n_cams
    refine = intrinsics.refine if intrinsics is not None else ()
    # a camera held for the gauge keeps its pose, but its intrinsics and time offset may still move
    every = bool(refine) or timing is not None
    free = np.arange(n) if every else model.free
    terms: list[WandTerm | PlanarWandTerm | PointTerm] = []
    if len(p.camera):
        raw = (intrinsics.wand_uv, refine) if intrinsics is not None and refine else None
        if p.planar and timing is not None:  # the pipeline refines a planar wand's markers after the sync
            raise ValueError("bundle_adjust_points: a planar wand's term carries no image velocities to refine offsets with")
        terms.append(planar_term(p, free, raw) if p.planar else
                     WandTerm(p.camera, p.frame, p.end, p.xy, p.focal[p.camera], p.length, p.n_frames, free, n, raw,
                              p.along, timing.velocity if timing is not None else None))
    if tracks is not None and len(tracks):
        terms.append(_point_term(tracks, p.focal, free, n, intrinsics, timing is not None))
    R, t = model.poses(x0)
    wand = model.wand(x0) if p.n_frames else np.zeros((0, 2, 3))
    d = wand[:, 1] - wand[:, 0]
    X = np.zeros((0, 3)) if X0 is None else np.asarray(X0, float)
    intr = intrinsics.intr.copy() if intrinsics is not None and refine else None
    Q = model.axes(model.unpack(x0)[3]) if p.planar else None
    dt = np.zeros(n) if timing is not None else None
    state = BundleState(R, t, wand.mean(axis=1), d / np.linalg.norm(d, axis=1, keepdims=True), X, intr, Q, dt)
    frozen = [(int(np.flatnonzero(free == g)[0]), j) for g in np.flatnonzero(model.fixed) for j in range(CAM_PARAMS)] if every else []
    if timing is not None:
        time_col = CAM_PARAMS + sum(INTRINSICS[name] for name in refine)
        frozen += [(int(g), time_col) for g in np.flatnonzero(timing.held)]  # free is every camera
    if not len(p.camera):
        frozen.append(_scale_gauge(R, t, free, model.fixed, frozen))
    solver = LevenbergMarquardt(terms, free, loss, frozen, refine, stop_se, timing is not None, judge_frames=judge_frames)
    # the dense products here are small: a second BLAS thread costs more in hand-offs than it
    # gains (0.26 s against 0.42 s at 8 x 1500 on 2 cores, and no gain at 32 x 2000)
    _load_wide_inverse(solver.n_free * solver.cam_size)
    with threadpool_limits(limits=1, user_api="blas"):
        state, info = solver.run(state, progress, max_iter)
        std = solver.standard_errors(state) if standard_errors else np.full((len(free), solver.cam_size), np.nan)
    info |= {"seconds": time.perf_counter() - start}
    camera_std = np.zeros((n, std.shape[1]))
    camera_std[free] = std
    return BundleResult(_pack(model, state), state.X if X0 is not None else None, state.intr, camera_std, info,
                        getattr(solver, "covariance", None), state.dt)


def _scale_gauge(R: np.ndarray, t: np.ndarray, free: np.ndarray, fixed: np.ndarray, frozen) -> tuple[int, int]:
    """(free-camera index, translation component) to hold so that, with the fixed cameras, the
    scale is fixed: scaling the world about a fixed camera's centre C0 moves camera k's t by
    R_k (C0 - C_k), so hold the component where that is largest."""
    C = camera_centers(R, t)
    C0 = C[np.flatnonzero(fixed)[0]]
    v = np.einsum("kij,kj->ki", R[free], C0 - C[free])
    for k, j in frozen:
        if j >= 3:
            v[k, j - 3] = 0.0
    k, j = np.unravel_index(np.argmax(np.abs(v)), v.shape)
    return int(k), 3 + int(j)


def _pack(model: WandModel, s: BundleState) -> np.ndarray:
    """The state in the model's parameters: Euler increments about R0, t, and per frame the
    midpoint and the direction's coordinates (a, b) with d parallel to d0 + a e1 + b e2 (a planar
    wand's: the Euler increments of its axes about Q0)."""
    x = np.zeros(model.n_params)
    cams = x[: model.frame_col0].reshape(-1, CAM_PARAMS)
    f = model.free
    cams[:, :3] = matrix_to_euler(s.R[f] @ np.swapaxes(model.R0[f], 1, 2))
    cams[:, 3:] = s.t[f]
    fr = x[model.frame_col0 :].reshape(-1, model.frame_params)
    fr[:, :3] = s.m
    if model.p.planar:
        fr[:, 3:] = matrix_to_euler(s.Q @ np.swapaxes(model.Q0, 1, 2))
        return x
    along = np.einsum("fi,fi->f", s.d, model.d0)
    fr[:, 3] = np.einsum("fi,fi->f", s.d, model.e1) / along
    fr[:, 4] = np.einsum("fi,fi->f", s.d, model.e2) / along
    return x
