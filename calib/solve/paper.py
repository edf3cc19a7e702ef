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

Each round's LP is solved by an interior point that eliminates the points (each row touches one
point and one camera), warm-started from the last round's; the rotation step is Newton's method
on each camera's quadratic E_phi_n; and where the rounds creep along one slow direction, the
next round starts the estimated rest of the way along it (docs/decisions/0005-paper-warm-start.md,
0033-paper-at-speed.md).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.solve.wandmodel import WandModel, WandProblem

# SciPy, threadpoolctl and HiGHS are imported where they are used: the command line imports this
# module for its defaults, and they cost 0.3 s of start-up

BOUND_M = 10.0  # the paper's box on every translation and point coordinate
HEIGHT_CONSTRAINED_POINTS = 200  # the paper's choice: the wand starts low, below all cameras
MAX_ROUNDS = 300  # a round takes ~0.19 s of CPU at 8 x 1500 (decisions 0033, 0045, 0060)
# Convergence. The rounds approach their fixed point linearly and slowly (each moves the cameras
# ~2% of the way at 8 x 1500), so one round's move says little about the distance left, and the
# LP's jumps between vertices make single moves noisy. The distance left is estimated from the
# moves over two successive windows of rounds, as the tail of a geometric series.
ROUND_TOL = 5e-6  # the least stop tolerance, metres: below it a window's move is the LP's jitter between vertices
# Stop when every camera is estimated within this fraction of the smallest camera-centre standard
# error (apart from the rig's placement, at the start) of the fixed point. At 8 x 1500 that sigma is
# 200-240 um, and where the rounds stop on their creep already moves by ~75 um with the LP's
# tolerance; the 5 um stop (ROUND_TOL alone) took 2-5x the rounds for a change in the cameras' errors
# against the truth of 0.00-0.03 mm (decision 0060, measured there with these values)
STOP_SIGMA = 0.1
WINDOW = 5  # rounds per window (10 before decision 0060: jumps half as often)
JUMP_CAP = 10.0  # the longest jump along the tail, in windows' moves (0: no jumps, the paper's plain rounds)
LP_TOL = 1e-6  # each round's LP to this relative residual and gap (arrowlp.TOL, 1e-9, takes ~14 iterations, not 10)
DEGENERATE_M = 1e-6  # a wand shorter than this after an LP means the LP collapsed it


def algebraic_residuals(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem) -> np.ndarray:
    """(M, 2) the paper's (U, V) for every observation (normalised units times depth)."""
    p = problem
    Rc, tc = R[p.camera], t[p.camera]
    Xp = X[p.point]
    xc = np.einsum("mij,mj->mi", Rc, Xp) + tc
    return p.xy * xc[:, 2:3] - xc[:, :2]


def rotation_step(R: np.ndarray, t: np.ndarray, X: np.ndarray, problem: WandProblem, fixed: np.ndarray) -> np.ndarray:
    """Update every free camera's rotation to the minimiser of E_phi_n (its algebraic squared
    error) with the points and translations fixed, nearest the current rotation.

    The paper takes it by LM on 3 Euler angles per camera. E_phi_n is a quadratic in the 9 entries
    of R_n, ``r^T H r + 2 g^T r + const`` (U and V are linear in them), so its minimiser on the
    rotations is found here by Newton's method on the rotation's tangent space, every camera at
    once (:func:`_newton_rotations`): the same minimiser (5e-11 from scipy's LM with the paper's
    1e-12 tolerances at 8 x 1500, decision 0033), in 5 ms against 0.43 s of CPU.
    """
    R = R.copy()
    cams = [n for n in np.flatnonzero(~fixed) if 2 * np.count_nonzero(problem.camera == n) >= 3]
    # a camera with too few observations to turn it is held; the result's checks refuse such a camera
    if cams:
        H, g = _quadratic_forms(t, X, problem, cams)
        R[cams] = _newton_rotations(R[cams], H, g)
    return R


_SKEW = np.zeros((3, 3, 3))  # _SKEW[k] = [e_k]_x, the generator of a turn about axis k
_SKEW[0, 2, 1], _SKEW[0, 1, 2] = 1.0, -1.0
_SKEW[1, 0, 2], _SKEW[1, 2, 0] = 1.0, -1.0
_SKEW[2, 1, 0], _SKEW[2, 0, 1] = 1.0, -1.0
NEWTON_STEPS = 50  # Newton converges quadratically from the last round's rotation: 3-5 steps are taken
NEWTON_DONE = 1e-14  # radians: a step this small ends it (scipy's LM stopped at xtol 1e-12)


def _quadratic_forms(t: np.ndarray, X: np.ndarray, problem: WandProblem, cams: list) -> tuple[np.ndarray, np.ndarray]:
    """E_phi_n = r^T H r + 2 g^T r + const for each camera n of ``cams``, r the rows of R_n
    stacked (9,): (H (C, 9, 9), g (C, 9)). U = -x . r1 + u x . r3 + u t_z - t_x, V alike."""
    p = problem
    H, g = np.empty((len(cams), 9, 9)), np.empty((len(cams), 9))
    for i, n in enumerate(cams):
        sel = p.camera == n
        xy, Xp, tn = p.xy[sel], X[p.point[sel]], t[n]
        m = len(xy)
        A = np.zeros((2 * m, 9))
        A[:m, 0:3], A[:m, 6:9] = -Xp, xy[:, :1] * Xp
        A[m:, 3:6], A[m:, 6:9] = -Xp, xy[:, 1:] * Xp
        c = np.r_[xy[:, 0] * tn[2] - tn[0], xy[:, 1] * tn[2] - tn[1]]
        H[i], g[i] = A.T @ A, A.T @ c
    return H, g


def _newton_rotations(R: np.ndarray, H: np.ndarray, g: np.ndarray) -> np.ndarray:
    """The rotations (C, 3, 3) minimising ``r^T H r + 2 g^T r`` each, by Newton's method on
    R <- exp([d]_x) R from ``R``: the gradient 2 J^T (H r + g) and the Hessian
    2 J^T H J + 2 (H r + g) . d2r, with J (9, 3) the columns vec([e_k]_x R)."""
    second = 0.5 * (np.einsum("kab,lbc->klac", _SKEW, _SKEW) + np.einsum("lab,kbc->klac", _SKEW, _SKEW))
    for _ in range(NEWTON_STEPS):
        r = R.reshape(-1, 9)
        J = np.einsum("kab,nbc->nkac", _SKEW, R).reshape(len(R), 3, 9).transpose(0, 2, 1)
        Hr = np.einsum("nij,nj->ni", H, r) + g
        grad = 2 * np.einsum("nik,ni->nk", J, Hr)
        hess = 2 * np.einsum("nik,nij,njl->nkl", J, H, J) + 2 * np.einsum("klac,ncd,nad->nkl", second, R,
                                                                            Hr.reshape(-1, 3, 3))
        d = -_solve_descent(hess, grad)
        R = exp_turn(d) @ R
        if np.abs(d).max() < NEWTON_DONE:
            break
    return R


def _solve_descent(hess: np.ndarray, grad: np.ndarray) -> np.ndarray:
    """hess^-1 grad (C, 3) per camera, with hess (C, 3, 3) shifted to positive definite where it is
    not (far from the minimum, or a camera whose points and translation collapsed: a zero
    quadratic, whose step is zero)."""
    low = np.linalg.eigvalsh(hess)[:, 0]
    scale = np.abs(hess).max(axis=(1, 2))
    shift = np.where(low <= 1e-12 * scale, 1e-12 * scale - low + 1e-300, 0.0)
    return np.linalg.solve(hess + shift[:, None, None] * np.eye(3), grad[..., None])[..., 0]


def exp_turn(d: np.ndarray) -> np.ndarray:
    """exp([d]_x) (C, 3, 3) for turns d (C, 3), radians (Rodrigues' formula)."""
    th = np.linalg.norm(d, axis=-1)[:, None, None]
    K = np.einsum("nk,kij->nij", d, _SKEW)
    small = th < 1e-8
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th**2 / 6, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th**2 / 24, (1 - np.cos(ths)) / ths**2)
    return np.eye(3) + a * K + b * (K @ K)


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


def _distance_left(centers: list[np.ndarray], settled: float = ROUND_TOL) -> float:
    """Estimated distance (metres, largest over cameras) from the last centres to the fixed point:
    with the last window's move ``a`` and the one before ``b``, the rate per window is a / b
    and the rest of the way a r / (1 - r). Infinite until two windows have run, and while the
    moves do not shrink; ``a`` where it is under ``settled`` (metres)."""
    return _tail(centers, settled)[0]


def _tail(centers: list[np.ndarray], settled: float = ROUND_TOL) -> tuple[float, float]:
    """(:func:`_distance_left`, the rate per window r, or nan where there is none)."""
    if len(centers) <= 2 * WINDOW:
        return np.inf, np.nan
    a = np.linalg.norm(centers[-1] - centers[-1 - WINDOW], axis=1).max()
    b = np.linalg.norm(centers[-1 - WINDOW] - centers[-1 - 2 * WINDOW], axis=1).max()
    if a < settled:  # settled: what is left is the LP's jitter between neighbouring vertices
        return a, np.nan
    if a >= b:
        return np.inf, np.nan
    r = a / b
    return a * r / (1 - r), r


def _turned_on(R: np.ndarray, R_before: np.ndarray, factor: float) -> np.ndarray:
    """(N, 3, 3) the rotations ``R`` turned on by ``factor`` times the turn that brought them
    from ``R_before``: exp(factor log(R R_before^T)) R."""
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_matrix(R @ np.swapaxes(R_before, -1, -2)).as_rotvec()
    return exp_turn(factor * turn) @ R


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
    from threadpoolctl import threadpool_limits

    # one BLAS thread: the products are vectors of a few 10k entries and 3 x 3 blocks, where a
    # second thread costs more in hand-offs than it gains (a 65k dot product took 0.68 ms of CPU
    # with two threads on a loaded machine, 0.016 ms with one; decision 0033)
    with threadpool_limits(limits=1, user_api="blas"):
        tol = stop_tolerance(R, t, wand, problem, fixed) if formulation == "anchored" else ROUND_TOL
        return _rounds(R, t, wand, problem, fixed, up, formulation, max_rounds, time_limit, progress, tol=tol)


def stop_tolerance(R: np.ndarray, t: np.ndarray, wand: np.ndarray, problem: WandProblem, fixed: np.ndarray) -> float:
    """The rounds' stop tolerance, metres: ``STOP_SIGMA`` times the smallest camera-centre standard
    error apart from the rig's placement (the information of the wand model at the start poses
    ``R`` (N, 3, 3), ``t`` (N, 3) and ``wand`` (F, 2, 3), its noise from the residuals there), and
    at least ``ROUND_TOL``; ``ROUND_TOL`` where there is no such error (no wand frame)."""
    if STOP_SIGMA <= 0 or not problem.n_frames:
        return ROUND_TOL
    from wandcal.calib.solve.ba import bundle_adjust_points
    from wandcal.calib.solve.gauge_free import gauge_covariance, split_uncertainty

    pc = bundle_adjust_points(WandModel(problem, R, t, wand, fixed), None, None, loss="linear", max_iter=0).covariance
    if pc is None:
        return ROUND_TOL
    sigma = split_uncertainty(R, t, gauge_covariance(R, t, pc.free, pc.cov)).center_std
    sigma = sigma[np.isfinite(sigma) & (sigma > 0)]
    return max(ROUND_TOL, STOP_SIGMA * float(sigma.min())) if len(sigma) else ROUND_TOL


def _rounds(R, t, wand, problem: WandProblem, fixed, up, formulation: str, max_rounds: int, time_limit, progress, *,
            tol: float):
    """:func:`refine_paper`'s rounds, until the cameras are estimated within ``tol`` (metres) of
    the fixed point."""
    start = time.perf_counter()
    X = wand.reshape(-1, 3).copy()
    lp_seconds = 0.0
    status = "iteration_limit"
    rounds = 0
    # The LP keeps its shape from round to round (the eq. (extra) rows are chosen once, at the
    # start), so each round starts the simplex method from the last round's optimal basis.
    heights = height_pairs(R, t, X, up)
    basis = None
    centers, turns = [camera_centers(R, t)], [R]
    ahead, jumps = None, 0  # the rotations of a jump along the tail, for the next round's LP
    for rounds in range(1, max_rounds + 1):
        R_new = rotation_step(R, t, X, problem, fixed) if ahead is None else ahead
        ahead = None
        C_old = camera_centers(R_new, t)
        if progress is not None:  # the LP is most of a round
            progress({"stage": "refine", "message": f"paper round {rounds}: rotations done, solving the LP"})
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
        turns.append(R)
        left, rate = _tail(centers, tol)
        if move == 0.0 or left < tol:
            status = "converged"
            break
        if JUMP_CAP > 0 and np.isfinite(rate):
            # the rounds creep along one slow direction (moves a window apart point the same way):
            # go the estimated rest of the way at once, then judge the rounds from there afresh
            ahead = _turned_on(R, turns[-1 - WINDOW], min(rate / (1 - rate), JUMP_CAP))
            centers, turns, jumps = [], [], jumps + 1
    return R, t, X.reshape(-1, 2, 3), {
        "iterations": rounds,
        "seconds": time.perf_counter() - start,
        "lp_seconds": lp_seconds,
        "status": status,
        "formulation": formulation,
        "jumps": jumps,
    }
