"""The seed paper's separated refinement (``--method paper``).

"Towards the Application of Linear Programming Methods For Multi-Camera Pose Estimation": the
reprojection error is written in its algebraic form (E)

    U = (u r3 - r1) . x + u t_z - t_x,    V = (v r3 - r2) . x + v t_z - t_y,

with (u, v) the normalised observation, r_k the rows of R and x a marker point. It is linear in
(x, t) for fixed R, so the scheme alternates:

1. per camera, its 3 Euler angles (R = Rz Ry Rx) by Levenberg-Marquardt on E_phi_n, the sum of
   U^2 + V^2 over that camera's observations, with points and translations fixed;
2. all translations and points at once by the LP of eq. (Li): minimise sum |U| + |V| with
   auxiliary variables, bounds of +-10 m, and the height constraints of eq. (extra) (the first
   200 points lie below every camera).

As written, that LP is not well posed (docs/decisions/0001-paper-lp-gauge.md): global
translation is free, and collapsing every camera and point to one place gives zero cost, which
(extra) allows. ``formulation="anchored"`` (the default) adds the least that fixes it: the gauge
camera keeps its pose, and one linearised wand-length equality anchors the scale,
``sum_f d_f . (x_f1 - x_f0) = F L`` with d_f the wand direction of the previous iterate.
``formulation="literal"`` solves the paper's LP unchanged, to show the collapse.

Each round's LP has the previous round's shape, so it is warm-started from that round's optimal
simplex basis: tens of times faster than a cold solve, which lets the rounds run to convergence
(docs/decisions/0005-paper-warm-start.md).
"""

from __future__ import annotations

import time

import numpy as np

from wandcal.calib.geometry import camera_centers, euler_to_matrix
from wandcal.calib.solve.wandmodel import WandProblem

# scipy.optimize, scipy.sparse and HiGHS are imported where they are used: the command line
# imports this module for its defaults, and they cost 0.3 s of start-up

BOUND_M = 10.0  # the paper's box on every translation and point coordinate
HEIGHT_CONSTRAINED_POINTS = 200  # the paper's choice: the wand starts low, below all cameras
MAX_ROUNDS = 300  # warm-started rounds take ~0.25 s at 8 x 1500, where the scheme converges in ~170
# interior point solves the first, cold (Li) LP 1.7x faster than dual simplex at 2300 observations (0.65 s
# against 1.1 s, HiGHS 1.15) and the gap grows with size
# Convergence. The rounds approach their fixed point linearly and slowly (each moves the cameras
# ~2% of the way at 8 x 1500), so one round's move says little about the distance left, and the
# LP's jumps between vertices make single moves noisy. The distance left is estimated from the
# moves over two successive windows of rounds, as the tail of a geometric series.
ROUND_TOL = 5e-6  # stop when the cameras are estimated this close (metres) to the fixed point
WINDOW = 10  # rounds per window
DEGENERATE_M = 1e-6  # a wand shorter than this after an LP means the LP collapsed it


def algebraic_residuals(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem) -> np.ndarray:
    """(M, 2) the paper's (U, V) for every observation (normalised units times depth)."""
    p = problem
    Rc, tc = R[p.camera], t[p.camera]
    Xp = X[p.point]
    xc = np.einsum("mij,mj->mi", Rc, Xp) + tc
    return p.xy * xc[:, 2:3] - xc[:, :2]


def rotation_step(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem, fixed: np.ndarray) -> np.ndarray:
    """Update every free camera's rotation by LM on E_phi_n (its algebraic squared error)."""
    from scipy.optimize import least_squares

    R = R.copy()
    for n in np.flatnonzero(~fixed):
        sel = problem.camera == n
        if 2 * sel.sum() < 3:
            continue  # too few observations to turn it: held; the result's checks refuse such a camera
        xy = problem.xy[sel]
        Xp = X[problem.point[sel]]
        R0, tn = R[n], t[n]

        def fun(delta, xy=xy, Xp=Xp, R0=R0, tn=tn):
            xc = Xp @ (euler_to_matrix(delta) @ R0).T + tn
            return (xy * xc[:, 2:3] - xc[:, :2]).ravel()

        res = least_squares(fun, np.zeros(3), method="lm", xtol=1e-12, ftol=1e-12)
        R[n] = euler_to_matrix(res.x) @ R0
    return R


def height_pairs(R: np.ndarray, t: np.ndarray, X: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(points, cameras) of the eq. (extra) rows: each of the first 200 points lies no higher
    than each camera, kept only where ``(R, t, X)`` satisfies it (else the LP may be infeasible)."""
    n_height = min(HEIGHT_CONSTRAINED_POINTS, len(X))
    ok = (X[:n_height] @ up)[:, None] <= (camera_centers(R, t) @ up)[None, :]
    points, cameras = np.nonzero(ok)
    return points, cameras


def lp_step(
    R: np.ndarray,
    t: np.ndarray,
    X: np.ndarray,
    problem: WandProblem,
    fixed: np.ndarray,
    up: np.ndarray,
    formulation: str = "anchored",
    time_limit: float | None = None,
    solver: str = "ipm",
    heights: tuple[np.ndarray, np.ndarray] | None = None,
    basis=None,
):
    """Solve eq. (Li) for all translations and points with the rotations fixed.

    Args:
        R: (N, 3, 3) rotations; t: (N, 3), X: (P, 3) current values (for the gauge, the
            linearised wand length and the height rows).
        problem: labelled observations; points are ``2 * frame + end``.
        fixed: (N,) cameras whose translation is held (the gauge; ignored when literal).
        up: (3,) the world's up direction for eq. (extra).
        formulation: "anchored" or "literal".
        heights: (points, cameras) index pairs of the eq. (extra) rows to impose; by default
            those of :func:`height_pairs` at the given state.
        basis: the basis of the previous round's LP (same shape), to warm-start from.

    Returns:
        (t (N, 3), X (P, 3), LpResult).
    """
    from wandcal.calib.solve.backend.highs import INF, solve_lp

    p = problem
    N, P, M = len(R), len(X), len(p.camera)
    nt, nx = 3 * N, 3 * P
    n_slack = 4 * M  # s+ and s- for U and V
    cols = nt + nx + n_slack
    entries = _projection_rows(R, p, nt, nx)
    n_rows = 2 * M
    row_lo = [np.zeros(2 * M)]
    row_hi = [np.zeros(2 * M)]
    jj, nn = height_pairs(R, t, X, up) if heights is None else heights
    _height_rows(entries, R, up, jj, nn, n_rows, nt)
    n_rows += len(jj)
    row_lo.append(np.full(len(jj), -INF))
    row_hi.append(np.zeros(len(jj)))
    col_lo = np.r_[np.full(nt + nx, -BOUND_M), np.zeros(n_slack)]
    col_hi = np.r_[np.full(nt + nx, BOUND_M), np.full(n_slack, INF)]
    if formulation in ("anchored", "per_frame"):
        for n in np.flatnonzero(fixed):
            col_lo[3 * n : 3 * n + 3] = col_hi[3 * n : 3 * n + 3] = t[n]
        target = _wand_rows(entries, X, p.length, formulation, n_rows, nt)
        row_lo.append(target)
        row_hi.append(target)
        n_rows += len(target)
    elif formulation != "literal":
        raise ValueError(f"formulation must be 'anchored', 'per_frame' or 'literal', not {formulation!r}")
    A = entries.matrix((n_rows, cols))
    cost = np.r_[np.zeros(nt + nx), np.ones(n_slack)]
    res = solve_lp(cost, A, np.concatenate(row_lo), np.concatenate(row_hi), col_lo, col_hi, time_limit, solver,
                   basis=basis)
    if not res or res.x is None:
        return t, X, res
    return res.x[:nt].reshape(N, 3), res.x[nt : nt + nx].reshape(P, 3), res


class _Entries:
    """The (row, column, value) entries of eq. (Li)'s sparse matrix, gathered block by block in
    the order they are added."""

    def __init__(self) -> None:
        self.rows: list[np.ndarray] = []
        self.cols: list[np.ndarray] = []
        self.vals: list[np.ndarray] = []

    def add(self, rows: np.ndarray, cols: np.ndarray, vals: np.ndarray) -> None:
        self.rows.append(rows)
        self.cols.append(cols)
        self.vals.append(vals)

    def matrix(self, shape: tuple[int, int]):
        """The entries as a scipy CSC matrix of ``shape``."""
        import scipy.sparse as sp

        return sp.csc_matrix((np.concatenate(self.vals), (np.concatenate(self.rows), np.concatenate(self.cols))),
                             shape=shape)


def _projection_rows(R: np.ndarray, p: WandProblem, nt: int, nx: int) -> _Entries:
    """Eq. (Li)'s rows 2i (U_i) and 2i+1 (V_i) of each observation i: coefficients on x_p (columns
    ``nt + 3p ..``), on t_n (columns ``3n ..``) and on the slack pair (columns ``nt + nx + 2r ..``)."""
    M = len(p.camera)
    Rc = R[p.camera]
    u, v = p.xy[:, 0], p.xy[:, 1]
    cx_u = u[:, None] * Rc[:, 2] - Rc[:, 0]
    cx_v = v[:, None] * Rc[:, 2] - Rc[:, 1]
    obs = np.arange(M)
    entries = _Entries()
    for k, (cx, coord, meas) in enumerate(((cx_u, 0, u), (cx_v, 1, v))):
        r = 2 * obs + k
        for j in range(3):
            entries.add(r, nt + 3 * p.point + j, cx[:, j])
        entries.add(r, 3 * p.camera + 2, meas)
        entries.add(r, 3 * p.camera + coord, -np.ones(M))
        entries.add(r, nt + nx + 2 * r, -np.ones(M))
        entries.add(r, nt + nx + 2 * r + 1, np.ones(M))
    return entries


def _height_rows(entries: _Entries, R: np.ndarray, up: np.ndarray, jj: np.ndarray, nn: np.ndarray, first_row: int,
                 nt: int) -> None:
    """Eq. (extra)'s rows from ``first_row`` on: up . x_j <= up . C_n for each pair (jj, nn) of
    (point, camera), with C_n = -R_n^T t_n linear in t_n."""
    hr = first_row + np.arange(len(jj))
    Ru = np.einsum("nij,j->ni", R, up)  # up . (R^T t) = (R up) . t
    for j in range(3):
        entries.add(hr, nt + 3 * jj + j, np.full(len(jj), up[j]))
        entries.add(hr, 3 * nn + j, Ru[nn, j])


def _wand_rows(entries: _Entries, X: np.ndarray, length: float, formulation: str, first_row: int,
               nt: int) -> np.ndarray:
    """The wand-length rows from ``first_row`` on, linearised about the ends ``X`` (P, 3): one row
    for the mean length ("anchored"), or one row per frame ("per_frame"). Returns their
    right-hand sides, metres (one per row)."""
    ends = X.reshape(-1, 2, 3)
    d = ends[:, 1] - ends[:, 0]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    F = len(d)
    fr = np.arange(F)
    wand_row = first_row + (fr if formulation == "per_frame" else np.zeros(F, dtype=np.int64))
    for j in range(3):
        entries.add(wand_row, nt + 3 * (2 * fr + 1) + j, d[:, j])
        entries.add(wand_row, nt + 3 * (2 * fr) + j, -d[:, j])
    return length * (np.ones(F) if formulation == "per_frame" else np.array([F]))


def _distance_left(centers: list[np.ndarray]) -> float:
    """Estimated distance (metres, largest over cameras) from the last centres to the fixed point:
    with the last window's move ``a`` and the one before ``b``, the rate per window is a / b
    and the rest of the way a r / (1 - r). Infinite until two windows have run, and while the
    moves do not shrink."""
    if len(centers) <= 2 * WINDOW:
        return np.inf
    a = np.linalg.norm(centers[-1] - centers[-1 - WINDOW], axis=1).max()
    b = np.linalg.norm(centers[-1 - WINDOW] - centers[-1 - 2 * WINDOW], axis=1).max()
    if a < ROUND_TOL:  # settled: what is left is the LP's jitter between neighbouring vertices
        return a
    if a >= b:
        return np.inf
    r = a / b
    return a * r / (1 - r)


def refine_paper(
    R: np.ndarray,
    t: np.ndarray,
    wand: np.ndarray,
    problem: WandProblem,
    fixed: np.ndarray,
    up: np.ndarray,
    formulation: str = "anchored",
    max_rounds: int = MAX_ROUNDS,
    time_limit: float | None = None,
    progress=None,
):
    """Alternate the rotation and LP steps until the cameras stop moving.

    Args:
        R, t: (N, 3, 3), (N, 3) start poses; wand: (F, 2, 3) start wand ends.
        problem: labelled observations. fixed: (N,) gauge cameras. up: (3,) world up.
        time_limit: seconds for each LP solve.

    Returns:
        (R, t, wand (F, 2, 3), info dict). info["status"] is "converged", "iteration_limit",
        "time_limit", "lp_<status>" or "degenerate" (an LP shrank a wand to a point; the state
        before that round is returned).
    """
    start = time.perf_counter()
    X = wand.reshape(-1, 3).copy()
    lp_seconds = 0.0
    status = "iteration_limit"
    rounds = 0
    # The LP keeps its shape from round to round (the eq. (extra) rows are chosen once, at the
    # start), so each round starts the simplex method from the last round's optimal basis.
    heights = height_pairs(R, t, X, up)
    basis = None
    centers = [camera_centers(R, t)]
    for rounds in range(1, max_rounds + 1):
        R_new = rotation_step(R, t, X, problem, fixed)
        C_old = camera_centers(R_new, t)
        if progress is not None:  # the LP is most of a round, and the first, cold one takes minutes at 8 x 1500
            progress({"stage": "refine", "message": f"paper round {rounds}: rotations done, solving the LP"
                      + (" (from the last round's basis)" if basis is not None else " (cold start: the longest)")})
        t_new, X_new, res = lp_step(R_new, t, X, problem, fixed, up, formulation, time_limit, heights=heights,
                                    basis=basis)
        lp_seconds += res.seconds
        basis = res.basis
        if not res:
            status = f"lp_{res.status}"
            break
        lengths = np.linalg.norm(X_new.reshape(-1, 2, 3)[:, 1] - X_new.reshape(-1, 2, 3)[:, 0], axis=1)
        if formulation != "literal" and not (np.all(np.isfinite(X_new)) and lengths.min() > DEGENERATE_M):
            # a wand shrank to a point: the LP found a degenerate optimum; keep the last state
            status = "degenerate"
            break
        R, t, X = R_new, t_new, X_new
        cost = float(np.abs(algebraic_residuals(R, t, X, problem)).sum())
        move = float(np.max(np.linalg.norm(camera_centers(R, t) - C_old, axis=1)))
        if progress is not None:
            progress({"stage": "refine", "iteration": rounds, "cost": cost, "message": f"paper round {rounds}: LP {res.status}, cameras moved {move * 1e3:.3f} mm"})
        if res.status == "time_limit":
            status = "time_limit"
            break
        centers.append(camera_centers(R, t))
        if move == 0.0 or _distance_left(centers) < ROUND_TOL:
            status = "converged"
            break
    return R, t, X.reshape(-1, 2, 3), {
        "iterations": rounds,
        "seconds": time.perf_counter() - start,
        "lp_seconds": lp_seconds,
        "status": status,
        "formulation": formulation,
    }
