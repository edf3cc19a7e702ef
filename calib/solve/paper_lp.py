"""Eq. (Li) of the seed paper's refinement (``--method paper``): the LP that, with the rotations fixed,
finds every translation and point at once, and its set-up.

The algebraic reprojection error (E) of :mod:`wandcal.calib.solve.paper`,

    U = (u r3 - r1) . x + u t_z - t_x,    V = (v r3 - r2) . x + v t_z - t_y,

is linear in (x, t) for fixed R: minimise sum |U| + |V| with auxiliary variables, bounds of +-10 m, and
the height constraints of eq. (extra) (the first 200 points lie below every camera). In its
``"anchored"`` formulation (the default, docs/decisions/0001-paper-lp-gauge.md) the gauge camera keeps
its pose and one linearised wand-length equality anchors the scale; that LP is solved by the
block-arrow interior point (calib/solve/backend/arrowlp.py) to ``LP_TOL``, warm-started from the last
round's; HiGHS solves the other formulations, and the anchored one where the interior point stalls.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.solve.wandmodel import WandProblem

# SciPy and HiGHS are imported where they are used (see wandcal.calib.solve.paper)

BOUND_M = 10.0  # the paper's box on every translation and point coordinate
HEIGHT_CONSTRAINED_POINTS = 200  # the paper's choice: the wand starts low, below all cameras
LP_TOL = 1e-6  # each round's LP to this relative residual and gap (arrowlp.TOL, 1e-9, takes ~14 iterations, not 10)



def algebraic_residuals(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem) -> np.ndarray:
    """(M, 2) the paper's (U, V) for every observation (normalised units times depth)."""
    p = problem
    Rc, tc = R[p.camera], t[p.camera]
    Xp = X[p.point]
    xc = np.einsum("mij,mj->mi", Rc, Xp) + tc
    return p.xy * xc[:, 2:3] - xc[:, :2]


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
    solver: str = "arrow",
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
        solver: "arrow" (the anchored LP by the block-arrow interior point,
            calib/solve/backend/arrowlp.py; HiGHS's interior point where that stalls, and for the
            other formulations), or HiGHS's "ipm" or "simplex".
        heights: (points, cameras) index pairs of the eq. (extra) rows to impose; by default
            those of :func:`height_pairs` at the given state.
        basis: the previous round's result's ``basis`` (an LP of the same shape), to warm-start from.

    Returns:
        (t (N, 3), X (P, 3), ArrowResult or LpResult): its status, seconds, objective, iterations
        and ``basis`` for the next round.
    """
    jj, nn = height_pairs(R, t, X, up) if heights is None else heights
    if formulation == "anchored" and solver == "arrow":
        solved = _arrow_step(R, t, X, problem, fixed, up, time_limit, (jj, nn), basis)
        if solved is not None:
            return solved
        # the interior point stalled short of the optimum (rounding in a degenerate LP): HiGHS
        # solves the same LP, slower
        solver, basis = "ipm", None
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
    res = solve_lp(cost, A, np.concatenate(row_lo), np.concatenate(row_hi), col_lo, col_hi, time_limit,
                   "ipm" if solver == "arrow" else solver,
                   basis=basis)
    if not res or res.x is None:
        return t, X, res
    return res.x[:nt].reshape(N, 3), res.x[nt : nt + nx].reshape(P, 3), res


def _arrow_step(R, t, X, problem: WandProblem, fixed, up, time_limit, heights, warm):
    """:func:`lp_step`'s anchored LP by the block-arrow interior point, from ``warm`` (the last
    round's :class:`wandcal.calib.solve.backend.arrowlp.WarmStart`): (t, X, ArrowResult), or None
    where it stalled short of the optimum."""
    from wandcal.calib.solve.backend.arrowlp import WarmStart, solve

    deadline = None if time_limit is None else time.perf_counter() + time_limit
    res = solve(arrow_lp(R, t, X, problem, fixed, up, heights), warm if isinstance(warm, WarmStart) else None,
                deadline, LP_TOL)
    if not res:
        return (t, X, res) if res.status == "time_limit" else None
    G = int((~fixed).sum())
    t_new = t.copy()
    t_new[~fixed] = res.v[: 3 * G].reshape(-1, 3)
    X_new = res.v[3 * G :].reshape(-1, 3)
    return t_new, X_new, replace(res, objective=float(np.abs(algebraic_residuals(R, t_new, X_new, problem)).sum()))


def arrow_lp(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem, fixed: np.ndarray, up: np.ndarray,
             heights: tuple[np.ndarray, np.ndarray]):
    """Eq. (Li) in its anchored formulation as the dual-form LP of
    :class:`wandcal.calib.solve.backend.arrowlp.ArrowLp`: its unknowns are the free cameras'
    translations, then the points; a fixed camera's translation moves into the rows' costs.

    Args: as :func:`lp_step`; ``heights`` the (points, cameras) pairs of eq. (extra)."""
    from wandcal.calib.solve.backend.arrowlp import ArrowLp

    p = problem
    M = len(p.camera)
    slot = np.where(fixed, -1, np.cumsum(~fixed) - 1)  # each camera's place among the free ones
    Rc = R[p.camera]
    u, v = p.xy[:, 0], p.xy[:, 1]
    ax = np.concatenate([u[:, None] * Rc[:, 2] - Rc[:, 0], v[:, None] * Rc[:, 2] - Rc[:, 1]])  # U rows, then V
    at = np.zeros((2 * M, 3))
    at[:M, 0], at[:M, 2] = -1.0, u
    at[M:, 1], at[M:, 2] = -1.0, v
    jj, nn = heights
    Ru = np.einsum("nij,j->ni", R, up)  # up . C_n = -(R_n up) . t_n
    ax = np.concatenate([ax, np.tile(up, (len(jj), 1))])
    at = np.concatenate([at, Ru[nn]])
    camera = np.concatenate([p.camera, p.camera, nn])
    # a fixed camera's translation is a constant: (Li)'s residual a . x + b . t_n moves b . t_n to the
    # row's right-hand side (the observation rows' costs), and (extra)'s bound likewise
    const = np.einsum("kj,kj->k", at, t[camera])
    held = fixed[camera]
    cost = np.where(held, -const, 0.0)
    obs = np.arange(len(camera)) < 2 * M
    lp = ArrowLp(point=np.concatenate([p.point, p.point, jj]), ax=ax, camera=slot[camera],
                 at=np.where(held[:, None], 0.0, at), cost=cost, upper=np.where(obs, 2.0, np.inf),
                 r=np.zeros(3 * (int((~fixed).sum()) + len(X))), box=BOUND_M, link=None, link_cost=0.0,
                 n_cameras=int((~fixed).sum()), n_points=len(X))
    ends = X.reshape(-1, 2, 3)
    d = ends[:, 1] - ends[:, 0]
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    link = np.zeros((lp.n_cameras + len(X), 3))
    link[lp.n_cameras :] = np.stack([-d, d], axis=1).reshape(-1, 3)
    # the observation rows' y = y' - 1 with y' in [0, 2]: A^T 1 moves to the right-hand side
    return lp.with_rhs(lp.times(np.where(obs, 1.0, 0.0)), link.ravel(), p.length * len(d))


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
