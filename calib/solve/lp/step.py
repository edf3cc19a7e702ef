"""One trust-region LP step of the LP method on an exact working set of (row, breakpoint) pairs.

The step minimises the robust loss of the reduced rows (calib/solve/reduced.py) linearised about a
state; the loss is convex piecewise-linear, so this is an LP, solved in its small dual form by an
interior-point method (calib/solve/backend/ipm.py) whose basis is then certified optimal (primal and
dual feasible: ipm.certified_duals), or, where it is not, HiGHS's simplex carries on from it
(calib/solve/backend/highs.py). Design and measurements: docs/decisions/0004-lp-method.md, 0024.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from wandcal.calib.solve.backend.ipm import certified_duals, solve_dual_form
from wandcal.calib.solve.reduced import ReducedSystem

NEAR_BREAK = 0.01  # a row within this many sigmas of a breakpoint, at the predicted step, starts in the LP
GUARD_SE = 1.0  # the first solves stay within this many standard errors of the predicted step
FIRST_STRATEGY = 1  # HiGHS dual simplex for a working set's first solve
RESOLVE_STRATEGY = 1  # dual again: primal simplex from the last basis took 4x the iterations (measured at 16 x 3000)
GUARD_GROWTH = 4.0  # and the guard widens this much where the solution touches it
MAX_ACTIVE_ROUNDS = 12  # re-solves with widened rows before a step is taken as it is
VERTEX_PINNED = 1e-9  # a vertex's parameter this near the guard (relative to its width) touches it
# and an interior point's this near: it stops ~1e-8 of the step off the vertex (the ipm's tolerance),
# so a looser test; a parameter it misses is caught at HiGHS's vertex, one it flags wrongly only
# widens the guard (the optimum is the same)
IPM_PINNED = 1e-6
# the first round's interior point stops once rows leave their modelled pieces (ipm.LEAVE_TOL):
# that round cannot be the last, whatever its optimum, and more pairs never change the LP's
# optimum. Only the first: on a 4-camera step that needs several rounds, every round stopped so
# took the 12 rounds of MAX_ACTIVE_ROUNDS (rows that leave near the optimum of one working set
# need not leave at the next one's), and the step was left uncertified
EARLY_LEAVE = True
# a round after the first also models, for every kept row, the breakpoints within this many sigmas
# of its residual at the round's point, not only those the rows that left crossed: the rows near
# a breakpoint there are the next round's leavers. On six 32-128 x 3000 captures (decision 0029)
# the final steps took 2 rounds each with 0.001, against 2-4 with none (3 at 32 and 96 cameras,
# 4 on a second 128-camera capture: 7.6 s of interior point against 3.4 s), for 0.1-0.4% more
# pairs; 0.003 added 5-11% more pairs and no fewer rounds
WIDEN_NEAR = 0.001


def solve_step(state: ReducedSystem, rho: np.ndarray, time_limit, loss, guard_se: float | None,
               d_pred: np.ndarray | None = None, near: float = NEAR_BREAK, se: np.ndarray | None = None):
    """The trust-region LP step on an exact working set of (row, breakpoint) pairs.

    Each row keeps the slope of the interval its residual starts in (a linear term, folded into
    one cost vector) and gets a hinge for each modelled breakpoint: ``(z - P)+`` to the right of
    its start, ``(P - z)+`` to the left, weighted by the slope change there, which adds up to the
    loss exactly on the modelled pieces. The working set starts from a prediction ``d_pred``, the
    Gauss-Newton step of the reduced system clipped to the trust region: each row gets the
    breakpoints between its residual now and its predicted residual, and any within
    ``near`` sigmas of either. So that this small set cannot send the step far off, the solves
    are confined to a guard box of ``guard_se`` standard errors around the prediction, widened
    where the solution touches it. The answer is exact once it lies inside the box and every row
    stays among its modelled pieces; until then rows that left get the breakpoints they crossed.

    Given ``d_pred`` (an IRLS solution of the same rows, calib/solve/lp/irls.py), the LP is instead written
    about it, in the step's change ``d - d_pred``: the rows start in the intervals of their
    predicted residuals, so only rows within ``near`` of a breakpoint there (and those the
    solves push across) enter the LP. The answer is the same LP's optimum, certified the same way
    (the dual form and its certificate: :func:`_solve_rounds`).

    Args:
        state: the reduced rows at the current state.
        rho: (n,) trust region, per camera parameter.
        time_limit: seconds per solve (the interior-point method's, then HiGHS's if needed), or None.
        loss: (signed breakpoints, slopes) in robust sigmas (calib/solve/robustloss.py).
        guard_se: guard half-width in standard errors, or None for twice the trust region.
        d_pred: (n,) a step to write the LP about, or None for the clipped Gauss-Newton step.
        near: breakpoint margin of the first working set, robust sigmas.
        se: (n,) standard errors for the guard, or None for the state's own.

    Returns:
        (d (n,) or None, info dict: seconds, rows (pairs), status, rounds, iterations (HiGHS's
        simplex iterations, 0 where the interior point's basis was certified as it is)).
    """
    P, S = loss[0] * state.scale, loss[1]  # breakpoints in pixels, interval slopes
    b = state.b.ravel()
    kept = state.kept.ravel()
    if se is None and guard_se is not None:
        se = state.standard_errors()
    guard = rho * 2 if guard_se is None or se is None else guard_se * se
    if d_pred is None:
        d_ref = np.zeros_like(rho)
        d_pred = np.clip(state.gauss_newton_step(), -rho, rho)
        z_pred = b + state.change(d_pred).ravel()
    else:
        d_ref = np.clip(d_pred, -rho, rho)
        b = b + state.change(d_ref).ravel()
        d_pred = np.zeros_like(rho)
        z_pred = b
    near = near * state.scale
    base = np.searchsorted(P, b)  # the interval each row starts in: P[base - 1] < b <= P[base]
    lo = np.where(kept, np.searchsorted(P, np.minimum(b, z_pred) - near), 0)
    hi = np.where(kept, np.searchsorted(P, np.maximum(b, z_pred) + near) - 1, -1)
    rows = _Rows(state, P, S, b, kept, base)
    d, info = _solve_rounds(rows, rho, d_ref, d_pred, guard, lo, hi, time_limit)
    return (None if d is None else d + d_ref), info


@dataclass(frozen=True)
class _Rows:
    """The reduced rows of one LP step: ``P`` (K,) breakpoints and ``S`` (K + 1,) interval slopes
    of the loss, pixels; ``b`` (2R,) the residuals the LP is written about, pixels; ``kept`` (2R,)
    bool; ``base`` (2R,) the interval each row starts in."""

    state: ReducedSystem
    P: np.ndarray
    S: np.ndarray
    b: np.ndarray
    kept: np.ndarray
    base: np.ndarray


def _solve_rounds(rows: _Rows, rho, d_ref, d_pred, guard, lo, hi, time_limit):
    """The rounds of :func:`solve_step` from the first working set ``lo``..``hi`` (breakpoint
    indices per row): (the LP's step about ``d_ref`` (n,) or None, info dict).

    The LP is solved in its dual form, where pairs are columns:
        min sum_q -s_q beta_q y_q - lo . u+ + hi . u-
        s.t. sum_q s_q A_q y_q - u+ + u- = -c_fold,  0 <= y_q <= jump_q,
    for the primal  min c_fold . d + sum_q jump_q max(s_q (A_q d + beta_q), 0) over lo <= d <= hi,
    with s_q = +1 for right hinges and -1 for left ones. The step d is the row duals: where
    0 < y_q < jump_q, stationarity gives A_q d + beta_q = 0, the row on its breakpoint. Each
    solve (the first and each after a widening) runs the interior-point method on every pair so
    far, and the basis its point names is certified optimal as it is (the vertex's values within
    their bounds, its reduced costs of the right signs, to HiGHS's tolerances): that basis was
    optimal, with no simplex iteration, on every LP step measured at 8-32 x 2000 (decision 0004,
    fifth session), and the answer is its vertex, as exact as a cold simplex. Where the check
    fails, HiGHS's dual simplex starts from that basis. Cold, the dual simplex took ~3.5
    iterations per camera parameter, each pricing every dense column: ~cameras^3. The first
    round's interior point stops early once rows leave their pieces (``EARLY_LEAVE``).
    """
    state, P, b, kept = rows.state, rows.P, rows.b, rows.kept
    c_fold = state.folded_cost(np.where(kept, rows.S[rows.base], 0.0).reshape(-1, 2))
    n = len(rho)
    old_lo, old_hi = rows.base, rows.base - 1  # nothing modelled yet
    trust_lo, trust_hi = -rho - d_ref, rho - d_ref  # the trust region, in the LP's variable
    seconds, d, rounds, total, certified, iterations = 0.0, None, 0, 0, False, 0
    cols_A, cols_c, cols_u = [np.zeros((0, n))], [np.zeros(0)], [np.zeros(0)]  # the pairs so far, for the IPM
    for rounds in range(1, MAX_ACTIVE_ROUNDS + 1):
        box_lo = np.maximum(trust_lo, d_pred - guard)
        box_hi = np.minimum(trust_hi, d_pred + guard)
        total += _add_pairs(rows, lo, hi, old_lo, old_hi, cols_A, cols_c, cols_u)
        # the interior point names the basis (a point short of optimal, or a basis HiGHS finds
        # singular, only costs simplex iterations from there)
        deadline = None if time_limit is None else time.perf_counter() + time_limit
        lp_args = (np.concatenate(cols_A), np.concatenate(cols_c), np.concatenate(cols_u), -box_lo, box_hi, -c_fold)
        leave = _Leaving(state, P, b, lo, hi, kept) if EARLY_LEAVE and rounds == 1 else None
        ipm = solve_dual_form(*lp_args, deadline, leave=leave)
        seconds += ipm.seconds
        if ipm.status == "time_limit":
            return None, _info(seconds, total, "time_limit", rounds, iterations)
        bounds = (box_lo, box_hi, trust_lo, trust_hi)
        if ipm.status in ("optimal", "left") and rounds < MAX_ACTIVE_ROUNDS and not ipm.certified:
            # rows that the interior point's step takes past their modelled breakpoints need another
            # round whatever the basis's vertex (the two differ by ~1e-8 of the step): the basis is
            # certified only in a round that may be the last
            if ipm.status == "left" and leave is not None and leave.z is not None:
                z = leave.z  # the residuals the question that stopped it was asked about
            else:
                z = b + state.change(ipm.duals).ravel()
            pinned = _still_open(rows, z, lo, hi, ipm.duals, bounds, IPM_PINNED)
            if pinned is not None:
                old_lo, old_hi = lo, hi
                guard, lo, hi = _widened(guard, lo, hi, P, z, kept, pinned, WIDEN_NEAR * state.scale)
                continue
        d, seconds, iterations, status = _vertex(ipm, lp_args, time_limit, rounds, seconds, iterations)
        if d is None:
            # a limit hit or a failure: no step is trusted, the caller keeps the best state so far
            return None, _info(seconds, total, status, rounds, iterations)
        z = b + state.change(d).ravel()
        pinned = _still_open(rows, z, lo, hi, d, bounds, VERTEX_PINNED)
        if pinned is None:
            certified = True
            break
        old_lo, old_hi = lo, hi
        guard, lo, hi = _widened(guard, lo, hi, P, z, kept, pinned, WIDEN_NEAR * state.scale)
    # uncertified: the step is the optimum of a working set that some rows still leave; the
    # caller takes it only if it lowers the true merit, like any trust-region step
    return d, _info(seconds, total, "optimal" if certified else "uncertified", rounds, iterations)


def _info(seconds: float, rows: int, status: str, rounds: int, iterations: int) -> dict:
    """:func:`solve_step`'s info dict."""
    return {"seconds": seconds, "rows": rows, "status": status, "rounds": rounds, "iterations": iterations}


def _add_pairs(rows: _Rows, lo, hi, old_lo, old_hi, cols_A: list, cols_c: list, cols_u: list) -> int:
    """Append the pairs of ``lo``..``hi`` not modelled before (below the old range ``old_lo``..
    ``old_hi`` and above it) to the LP's columns: their rows (Q, n), costs (Q,) and jumps (Q,).
    Returns Q."""
    P, S, b = rows.P, rows.S, rows.b
    rows_a, bps_a = _pairs(lo, np.minimum(hi, old_lo - 1))
    rows_b, bps_b = _pairs(np.maximum(lo, old_hi + 1), hi)
    rows_i, bps = np.r_[rows_a, rows_b], np.r_[bps_a, bps_b]
    if len(rows_i):
        side = np.where(bps >= rows.base[rows_i], 1.0, -1.0)  # right hinge, or left hinge
        A = rows.state.rows(rows_i // 2, rows_i % 2) * side[:, None]
        cost, jump = -side * (b[rows_i] - P[bps]), S[bps + 1] - S[bps]
        cols_A.append(A)
        cols_c.append(cost)
        cols_u.append(jump)
    return len(rows_i)


def _still_open(rows: _Rows, z, lo, hi, d, bounds, tol: float) -> np.ndarray | None:
    """None if the step ``d`` (n,), with residuals ``z`` (2R,) pixels, keeps every kept row among
    its modelled pieces and touches no guard; else the (n,) parameters it pins to the guard."""
    out_lo, out_hi = _left_rows(rows.P, z, lo, hi, rows.kept)
    box_lo, box_hi, trust_lo, trust_hi = bounds
    pinned = _pinned(d, box_lo, box_hi, trust_lo, trust_hi, tol)
    if out_lo.any() or out_hi.any() or pinned.any():
        return pinned
    return None


def _vertex(ipm, lp_args, time_limit, rounds: int, seconds: float, iterations: int):
    """The vertex of the basis the interior point ``ipm`` names, certified optimal as it is (the
    usual case, mostly by the interior point itself a few iterations before its end); else HiGHS's
    dual simplex from it. Returns (d (n,) or None, seconds, iterations, status), the running
    totals ``seconds`` and ``iterations`` carried on."""
    A, c, jump, c_lo, c_hi, r = lp_args
    started = time.perf_counter()
    d = (ipm.duals if ipm.certified else certified_duals(A, c, jump, c_lo, c_hi, r, ipm.basic, ipm.at_upper)
         if ipm.status == "optimal" else None)
    seconds += time.perf_counter() - started
    if d is not None:
        return d, seconds, iterations, "optimal"
    res = _highs_vertex(lp_args, ipm, time_limit, FIRST_STRATEGY if rounds == 1 else RESOLVE_STRATEGY)
    seconds += res.seconds
    iterations += res.iterations
    if res.status != "optimal" or res.row_duals is None:
        return None, seconds, iterations, res.status
    return res.row_duals.copy(), seconds, iterations, "optimal"


def _highs_vertex(lp_args, ipm, time_limit, strategy: int):
    """HiGHS's simplex on the LP of :func:`wandcal.calib.solve.backend.ipm.solve_dual_form`'s
    arguments ``lp_args``, started from the basis the interior point ``ipm`` names: an LpResult.
    HiGHS is loaded only here (most steps never need it)."""
    from wandcal.calib.solve.backend.highs import IncrementalLp

    A, c, jump, c_lo, c_hi, r = lp_args
    n = len(r)
    lp = IncrementalLp(r, time_limit)
    eye = sp.identity(n, format="csc")
    lp.add_columns(np.r_[c_lo, c_hi], np.zeros(2 * n), np.full(2 * n, np.inf), sp.hstack([-eye, eye]))
    lp.add_columns(c, np.zeros(len(c)), jump, A.T)
    lp.set_basis(ipm.basic, ipm.at_upper)
    return lp.solve(strategy)


class _Leaving:
    """For the interior point: does a step (n,) take a row past its modelled breakpoints? The
    residuals z (pixels) at the last step asked about are kept for the round that follows."""

    def __init__(self, state: ReducedSystem, P: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 kept: np.ndarray):
        self.state, self.P, self.b, self.lo, self.hi, self.kept = state, P, b, lo, hi, kept
        self.z: np.ndarray | None = None

    def __call__(self, d: np.ndarray) -> bool:
        self.z = self.b + self.state.change(d).ravel()
        out_lo, out_hi = _left_rows(self.P, self.z, self.lo, self.hi, self.kept)
        return bool(out_lo.any() or out_hi.any())


def _widened(guard, lo, hi, P, z, kept, pinned, margin: float):
    """The next round's guard (``GUARD_GROWTH`` wider where the step was pinned to it) and modelled
    breakpoint ranges: out to the interval each kept row's residual z (pixels) reached, and to
    the breakpoints within ``margin`` pixels of it."""
    lo = np.where(kept, np.minimum(lo, np.searchsorted(P, z - margin)), lo)
    hi = np.where(kept, np.maximum(hi, np.searchsorted(P, z + margin) - 1), hi)
    return np.where(pinned, GUARD_GROWTH * guard, guard), lo, hi


def _pinned(d, box_lo, box_hi, trust_lo, trust_hi, tol: float) -> np.ndarray:
    """(n,) the parameters of step d that touch the guard box (within ``tol`` of its width) where
    the box is inside the trust region: the optimum may lie beyond."""
    tol = tol * (np.abs(box_hi - box_lo) + 1e-300)
    return ((d <= box_lo + tol) & (box_lo > trust_lo)) | ((d >= box_hi - tol) & (box_hi < trust_hi))


def _left_rows(P: np.ndarray, z: np.ndarray, lo: np.ndarray, hi: np.ndarray, kept: np.ndarray):
    """The kept rows whose residual z (pixels) lies beyond the breakpoints modelled for them
    (``P[lo] .. P[hi]``): (those below, those above)."""
    where = np.searchsorted(P, z)
    return kept & (where < lo), kept & (where > hi + 1)


def _pairs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flatten the modelled breakpoint ranges into (row, breakpoint) pairs."""
    count = np.maximum(hi - lo + 1, 0)
    rows_i = np.repeat(np.arange(len(lo)), count)
    offset = np.arange(len(rows_i)) - np.repeat(np.cumsum(count) - count, count)
    return rows_i, lo[rows_i] + offset
