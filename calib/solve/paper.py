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

This module holds the rounds, the rotation step and the rounds' stop; the LP of eq. (Li), its
set-up and its stop (``LP_TOL``) are in :mod:`wandcal.calib.solve.paper_lp`. Each round's LP is
solved by an interior point that eliminates the points (each row touches one point and one
camera), warm-started from the last round's; the rotation step is Newton's method
on each camera's quadratic E_phi_n; and where the rounds creep along one slow direction, the
next round starts the estimated rest of the way along it (docs/decisions/0005-paper-warm-start.md,
0033-paper-at-speed.md).
"""

from __future__ import annotations

import time

import numpy as np

from wandcal.calib.geometry import camera_centers
from wandcal.calib.solve.paper_lp import algebraic_residuals, arrow_lp, height_pairs, lp_step
from wandcal.calib.solve.wandmodel import WandModel, WandProblem

# SciPy and threadpoolctl are imported where they are used (HiGHS in paper_lp): the command line
# imports this module for its defaults, and they cost 0.3 s of start-up

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
DEGENERATE_M = 1e-6  # a wand shorter than this after an LP means the LP collapsed it

# The names tests and benches import from here; the LP's are re-exported from paper_lp.
__all__ = ["DEGENERATE_M", "JUMP_CAP", "MAX_ROUNDS", "ROUND_TOL", "STOP_SIGMA", "WINDOW", "algebraic_residuals",
           "arrow_lp", "exp_turn", "height_pairs", "lp_step", "refine_paper", "rotation_step", "stop_tolerance"]


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
