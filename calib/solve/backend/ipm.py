"""A primal-dual interior-point method for the LP step's dual form, the simplex basis it
points to, and that basis's certificate of optimality (calib/solve/lp/step.py).

The LP step's dual has one row per camera parameter (n) and one dense column per (row,
breakpoint) pair (k of them, each touching every camera of its frame). HiGHS's dual simplex
needs ~3.5 n iterations on it, each pricing every column, so its time grows as ~cameras^3
(decision 0004). An interior-point method takes ~10-15 iterations whatever the size, each one
dense (n, n) normal matrix ``A^T D A`` (k n^2 / 2 flops) and its Cholesky factor; its point
names the optimal basis (the n columns strictly inside their bounds), which one LU factor then
certifies optimal (:func:`certified_duals`, tried at each iterate near the end; HiGHS's simplex
carries on from the basis when no iterate's passes), so the step stays an exact vertex of the LP.

The LP, with A (k, n) the pairs' rows:
    min  c_lo . u_lo + c_hi . u_hi + c . y
    s.t. A^T y - u_lo + u_hi = r,  0 <= y <= jump,  u_lo, u_hi >= 0,
and the row duals (n,) are the step. Mehrotra's predictor-corrector (Wright, Primal-Dual
Interior-Point Methods, 1997, ch. 10, with upper bounds as in Lustig, Marsten and Shanno 1992),
with Gondzio's multiple centrality correctors (Comput. Optim. Appl. 6, 1996).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

TOL = 1e-9  # relative primal and dual residuals and complementarity at the end: the basis named
# there needed no simplex pivot in any of the 27 LP solves of 18 rigs at 8-32 x 2000 (decision 0004)
MAX_ITER = 60  # 12-16 were taken at 8-32 x 2000
STEP_TO_BOUNDARY = 0.995  # the fraction of the longest feasible step taken (Mehrotra's heuristic)
# The normal matrix in single precision while the pairs' weights D span less than this ratio: it
# is then well conditioned, and a direction from a matrix good to ~1e-7 is as good as exact there
# (the residuals are always taken in double). On the two LP solves of a 128 x 3000 step (15k pairs,
# 762 rows) the first 5-8 of 17-18 iterations ran in single, the iterations, the basis and HiGHS's
# vertex were unchanged, and the matrices took half the time; a ratio of 1e10 broke the Cholesky
# factor near the end.
SINGLE_PRECISION_RANGE = 1e6
# Late on, pairs whose weight is below this fraction of the largest are left out of the normal
# matrix: they are at a bound, and the direction only steers them there. On the 5 final LP solves
# of five 64-128 x 3000 captures (decision 0029) 1e-10 took 7.8-8.0 s against 8.5-9.0 s at 1e-12,
# in as many iterations or one fewer; 1e-9 as fast, 1e-8 stalled on a dual-degenerate solve (19
# iterations against 16). Two guards: where leaving them out makes the matrix singular in floating
# point, the factor is taken again with the pairs above STRICT_NEGLIGIBLE (1e-9 broke it once at
# 128 x 3000, decision 0024); and once an iterate is no nearer the optimum than STALL of the one two
# before, every pair above STRICT_NEGLIGIBLE is kept to the end (at 1e-8 a solve stalled at 60
# iterations without this guard)
NEGLIGIBLE_WEIGHT = 1e-10
STRICT_NEGLIGIBLE = 1e-12
STALL = 0.5
# Outside that range, the pairs weighted below this fraction of the largest go to the normal
# matrix in single precision: each one's rounding error (~6e-8 of its own term, so < 6e-13 of the
# largest) stays below the terms NEGLIGIBLE_WEIGHT already leaves out. The double product then
# holds only the heavy pairs (decision 0024)
SINGLE_WEIGHT = 1e-5
MAX_SINGLE_WEIGHT = 1e30  # and only while the light terms fit single precision's range (3e38)
MIXED_PRECISION = True
# the first iterate this near the optimum (relative residuals and gap, as TOL) is shown to
# ``leave``. On the 128 x 3000 step the first round's rows left by then: it stopped after 7 of
# its 17 iterations, 9 at 1e-2 (1.2 s against 2.8 s, decision 0024), 11 at 1e-3 and 13 at 1e-4,
# with two rounds and the same optimum each time; at 32 and 64 cameras 6 against 8-9. The rows
# an earlier iterate shows leaving are nearly the same (the second round had 15,303 pairs
# against 15,305 at 1e-2): one fewer there only means another round, one more never changes the
# optimum (decision 0027)
LEAVE_TOL = 1e-1
# a basis's certificate (certified_duals) to HiGHS's default primal and dual feasibility
# tolerances (absolute, as HiGHS applies them to these LPs, which it is told not to scale)
PRIMAL_TOL = 1e-7
DUAL_TOL = 1e-7
SINGULAR_PIVOT = 1e-13  # an LU pivot this small against the largest entry: the basis is taken as singular
# Gondzio's multiple centrality correctors (Gondzio 1996): after Mehrotra's direction, at most this
# many more solves with the same factor, each pulling the complementarity products that the
# direction would leave outside [BAND[0], BAND[1]] x the target back into that band at step lengths
# REACH longer; a corrector is kept if it lengthens the steps by GAIN of what it aimed at. On the
# LP steps of 32-128 x 3000 (decision 0029) 2 correctors at 0.3 took 12-14 iterations against
# 15-19 and 0.79 of the time; 1 took 13-16, 3 or 4 at 0.5 12-14 at more solves each
CORRECTORS = 2
CORRECTOR_REACH = 0.3
CORRECTOR_BAND = (0.1, 10.0)
CORRECTOR_GAIN = 0.1
# from the first iterate this near the optimum (as TOL) on, the basis each iterate names is
# certified (certified_duals, one LU factor: ~0.03 s at 128 x 3000 against ~0.13 s for an
# iteration) and the method stops at the first that passes: the vertex is then as exact as at TOL.
# On the 128 x 3000 step's two LPs the named basis passed 1-2 iterations before TOL (decision 0029)
CERTIFY_TOL = 1e-5


@dataclass(frozen=True, eq=False)
class IpmResult:
    """duals: (n,) the step; basic, at_upper: (2n + k,) masks over the columns (u_lo, u_hi, y)
    of the basis the point names; status: "optimal", "left" (``leave`` stopped it), "time_limit",
    "iteration_limit" or "breakdown" (a normal matrix not positive definite in floating point);
    certified: the basis was certified optimal (from ``CERTIFY_TOL`` on) and duals are its vertex's."""

    duals: np.ndarray
    basic: np.ndarray
    at_upper: np.ndarray
    status: str
    iterations: int
    seconds: float
    certified: bool = False


def solve_dual_form(A: np.ndarray, c: np.ndarray, jump: np.ndarray, c_lo: np.ndarray, c_hi: np.ndarray,
                    r: np.ndarray, deadline: float | None = None, leave=None) -> IpmResult:
    """Solve the LP above to ``TOL`` and name its optimal basis: the n columns furthest inside
    their bounds (relative to their reduced costs), the others at the bound they are nearer.

    Args:
        A: (k, n) the pairs' rows. c, jump: (k,) their costs and upper bounds.
        c_lo, c_hi: (n,) costs of the box columns (the box's bounds, -lo and hi).
        r: (n,) right-hand side.
        deadline: ``time.perf_counter()`` value to give up at, or None.
        leave: optional callable(duals (n,)) -> bool, asked at the first iterate within
            ``LEAVE_TOL`` of the optimum: True stops there with status "left" (the caller knows the LP must
            change whatever its optimum: calib/solve/lp/step.py).

    From ``CERTIFY_TOL`` on, the basis each iterate names is certified (:func:`certified_duals`),
    and the method stops at the first that passes, with its vertex's duals (``certified``).
    """
    start = time.perf_counter()
    n = A.shape[1]
    cost = np.r_[c_lo, c_hi, c]
    up = np.r_[np.full(2 * n, np.inf), jump]
    ub = np.isfinite(up)
    upper = np.where(ub, up, 0.0)
    one = np.where(ub, 1.0, 0.0)  # upper-bound terms exist only where there is a bound

    x, z, s, w = _infeasible_start(cost, ub, upper, one)
    lam = np.zeros(n)
    Et_lam = np.zeros(2 * n + len(c))  # E^T lam, carried from step to step (E^T dl is each direction's)
    n_compl = len(x) + int(ub.sum())  # complementarity products: x z, and s w where bounded
    r_norm, c_norm = 1 + np.abs(r).max(), 1 + np.abs(cost).max()
    status, it = "iteration_limit", 0
    normal = _NormalMatrix(A)
    history, strict = [], False
    for it in range(1, MAX_ITER + 1):
        rp = r - _times(A, x)
        ru = (upper - x - s) * one
        rd = cost - Et_lam - z + w
        gap = x @ z + (s * w) @ one
        near = max(np.abs(rp).max() / r_norm, np.abs(rd).max() / c_norm, gap / (1 + abs(cost @ x)))
        history.append(near)
        # an iterate no nearer than STALL of two before: the normal matrices without their light
        # pairs have stopped steering it (seen on degenerate LPs), so they keep them from here
        strict = strict or (len(history) > 2 and near > STALL * history[-3])
        if near <= TOL:
            status = "optimal"
            break
        if near <= CERTIFY_TOL:
            basic, at_upper = _named_basis(x, z, s, w, ub, n)
            duals = certified_duals(A, c, jump, c_lo, c_hi, r, basic, at_upper)
            if duals is not None:
                return IpmResult(duals, basic, at_upper, "optimal", it, time.perf_counter() - start, certified=True)
        if leave is not None and near <= LEAVE_TOL:
            if leave(lam):
                status = "left"
                break
            leave = None  # asked once: each question costs a product over every row
        if deadline is not None and time.perf_counter() > deadline:
            status = "time_limit"
            break
        mu = gap / n_compl
        D = 1.0 / (z / x + w / s * one)
        Dy = D[2 * n:]
        factor = _factor(normal, Dy, D[:n] + D[n:2 * n], strict)
        if factor is None:  # rounding at extreme scalings: HiGHS carries on from the basis so far
            status = "breakdown"
            break
        point, residuals = (x, z, s, w, one), (rp, ru, rd)
        direction, a_p, a_d = _search_direction(A, factor, D, point, residuals, gap, mu)
        dl, dx, dz, ds, dw, Et_dl = direction
        x, s = x + a_p * dx, np.where(ub, s + a_p * ds, 1.0)
        lam, z, w = lam + a_d * dl, z + a_d * dz, (w + a_d * dw) * one
        Et_lam = Et_lam + a_d * Et_dl
    basic, at_upper = _named_basis(x, z, s, w, ub, n)
    return IpmResult(lam, basic, at_upper, status, it, time.perf_counter() - start)


def _infeasible_start(cost: np.ndarray, ub: np.ndarray, upper: np.ndarray, one: np.ndarray):
    """An infeasible start, inside the bounds with its duals positive, scaled to the costs: (x, z,
    s, w), each (2n + k,), for the columns' costs ``cost``, bounded mask ``ub``, bounds ``upper``
    (0 where unbounded) and ``one`` (1.0 where bounded)."""
    size = max(np.abs(cost).max(), 1e-300)
    x = np.where(ub, upper / 2, 1.0)
    s = np.where(ub, upper - x, 1.0)
    z = np.maximum(cost, 0.0) + 0.1 * size
    w = (np.maximum(-cost, 0.0) + 0.1 * size) * one
    return x, z, s, w


def _search_direction(A, factor, D, point, residuals, gap: float, mu: float):
    """One iteration's direction: the affine-scaling predictor, then Mehrotra's corrector, then
    up to ``CORRECTORS`` of Gondzio's. Returns (direction (dl, dx, dz, ds, dw, E^T dl), primal
    step length, dual step length)."""
    x, z, s, w, one = point
    dl, dx, dz, ds, dw, _ = _direction(A, factor, D, point, residuals, -x * z, -s * w * one)
    a_p, a_d = _step_lengths(point, (dx, dz, ds, dw), 1.0)
    gap_aff = (x + a_p * dx) @ (z + a_d * dz) + ((s + a_p * ds) * (w + a_d * dw)) @ one
    target = (gap_aff / gap) ** 3 * mu
    r_xz, r_sw = target - x * z - dx * dz, (target - s * w - ds * dw) * one
    direction = _direction(A, factor, D, point, residuals, r_xz, r_sw)
    a_p, a_d = _step_lengths(point, direction[1:5], STEP_TO_BOUNDARY)
    for _ in range(CORRECTORS):
        if min(a_p, a_d) >= 1.0:
            break
        t_xz, t_sw = _centrality_targets(point, direction[1:5], a_p, a_d, target)
        corrected = _direction(A, factor, D, point, residuals, r_xz + t_xz, r_sw + t_sw)
        c_p, c_d = _step_lengths(point, corrected[1:5], STEP_TO_BOUNDARY)
        aimed = min(1.0, a_p + CORRECTOR_REACH) - a_p + min(1.0, a_d + CORRECTOR_REACH) - a_d
        if c_p + c_d < a_p + a_d + CORRECTOR_GAIN * aimed:
            break
        direction, a_p, a_d, r_xz, r_sw = corrected, c_p, c_d, r_xz + t_xz, r_sw + t_sw
    return direction, a_p, a_d


def _factor(normal: _NormalMatrix, Dy: np.ndarray, box: np.ndarray, strict: bool = False):
    """The Cholesky factor of ``A^T D_y A + diag(box)``, the negligible pairs left out, or with
    only ``STRICT_NEGLIGIBLE`` ones left out where that is singular in floating point (or
    ``strict``); None if that is singular too."""
    for negligible in dict.fromkeys((STRICT_NEGLIGIBLE,) if strict else (NEGLIGIBLE_WEIGHT, STRICT_NEGLIGIBLE)):
        M = normal(Dy, negligible)
        M[np.diag_indices(len(box))] += box
        try:
            return sla.cho_factor(M, lower=False, overwrite_a=True, check_finite=False)
        except np.linalg.LinAlgError:
            continue
    return None


def _named_basis(x, z, s, w, ub, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The basis a point names: the n columns furthest inside both bounds (relative to their
    duals), each other column at the bound it is nearer. (basic, at_upper) masks."""
    lo_side = x / (x + z)
    hi_side = np.where(ub, s / (s + w + 1e-300), 1.0)
    basic = np.zeros(len(x), bool)
    basic[np.argsort(-np.minimum(lo_side, hi_side), kind="stable")[:n]] = True
    return basic, ~basic & (hi_side < lo_side)


def _step_lengths(point, direction, fraction: float) -> tuple[float, float]:
    """The primal and dual step lengths (<= 1): ``fraction`` of the longest that keep x, s and z, w
    nonnegative along the direction (dx, dz, ds, dw)."""
    x, z, s, w, _ = point
    dx, dz, ds, dw = direction
    return (min(1.0, fraction * min(_longest(x, dx), _longest(s, ds))),
            min(1.0, fraction * min(_longest(z, dz), _longest(w, dw))))


def _centrality_targets(point, direction, a_p: float, a_d: float, target: float):
    """Gondzio's corrector right-hand sides (x z and s w terms): at step lengths ``CORRECTOR_REACH``
    longer, the complementarity products outside ``CORRECTOR_BAND`` x target moved to its edge,
    those far above it by no more than its top."""
    x, z, s, w, one = point
    dx, dz, ds, dw = direction
    t_p, t_d = min(1.0, a_p + CORRECTOR_REACH), min(1.0, a_d + CORRECTOR_REACH)
    lo, hi = CORRECTOR_BAND[0] * target, CORRECTOR_BAND[1] * target
    v_xz = (x + t_p * dx) * (z + t_d * dz)
    v_sw = (s + t_p * ds) * (w + t_d * dw)
    return (np.maximum(np.clip(v_xz, lo, hi) - v_xz, -hi),
            np.maximum(np.clip(v_sw, lo, hi) - v_sw, -hi) * one)


def certified_duals(A: np.ndarray, c: np.ndarray, jump: np.ndarray, c_lo: np.ndarray, c_hi: np.ndarray,
                    r: np.ndarray, basic: np.ndarray, at_upper: np.ndarray) -> np.ndarray | None:
    """The row duals (n,) of the vertex that a basis names, if that basis is optimal, else None.

    The certificate a simplex method gives when it starts from an optimal basis and stops
    without a pivot: the basic columns' values (the nonbasic ones at their bounds) are within
    their bounds, and every nonbasic column's reduced cost ``c - E^T duals`` has the sign its
    bound allows, both to HiGHS's default tolerances. It costs one LU factor of the (n, n) basis
    and two products with A, against HiGHS's basis load and solve (1.5-1.9 s at 128 x 3000,
    decision 0024). The LP and the masks (2n + k,) are those of :func:`solve_dual_form`."""
    n = A.shape[1]
    cost = np.r_[c_lo, c_hi, c]
    up = np.r_[np.full(2 * n, np.inf), jump]
    if basic.sum() != n or np.any(at_upper & ~np.isfinite(up)):
        return None
    x = np.where(at_upper, np.where(np.isfinite(up), up, 0.0), 0.0)
    x[basic] = 0.0
    cols = np.flatnonzero(basic)
    box, pairs = cols[cols < 2 * n], cols[cols >= 2 * n] - 2 * n
    B = np.zeros((n, n))
    B[box % n, np.arange(len(box))] = np.where(box < n, -1.0, 1.0)
    B[:, len(box):] = A[pairs].T
    order = np.r_[box, pairs + 2 * n]  # the basic columns in B's order
    # LAPACK's LU directly: scipy's lu_factor warns on a singular basis, which is refused here
    lu, piv, info = sla.lapack.dgetrf(B)
    if info != 0 or not np.all(np.isfinite(lu)) or np.min(np.abs(np.diag(lu))) <= SINGULAR_PIVOT * np.abs(lu).max():
        return None
    x_basic, _ = sla.lapack.dgetrs(lu, piv, r - _times(A, x))
    duals, _ = sla.lapack.dgetrs(lu, piv, cost[order], trans=1)
    reduced = cost - _times_t(A, duals)
    lower_ok = x_basic >= -PRIMAL_TOL
    upper_ok = x_basic <= up[order] + PRIMAL_TOL
    nonbasic = ~basic
    dual_ok = np.where(at_upper, reduced <= DUAL_TOL, reduced >= -DUAL_TOL)[nonbasic]
    if lower_ok.all() and upper_ok.all() and dual_ok.all():
        return duals
    return None


class _NormalMatrix:
    """``A^T D_y A`` (n, n) for the pairs' weights D_y (k,), with A's scaled rows in one reused
    buffer per precision: a fresh (k, n) array per iteration is a fresh mapping the kernel
    zero-fills page by page (91 MB at 128 x 3000). B^T B is one symmetric product in NumPy (3 ms
    at 2.6k x 186, against 5.5 ms for SciPy's dsyrk, which copies A)."""

    def __init__(self, A: np.ndarray):
        self.A = A
        self.A_single: np.ndarray | None = None
        self.B_single: np.ndarray | None = None
        self.B_double: np.ndarray | None = None

    def _single(self, rows: np.ndarray | None, Dy: np.ndarray) -> np.ndarray:
        """The rows ``rows`` (a mask, or None for all) of A^T D A in single precision, as doubles."""
        if self.A_single is None:
            self.A_single = self.A.astype(np.float32)
            self.B_single = np.empty_like(self.A_single)
        assert self.B_single is not None
        if rows is None:
            B = self.B_single
            np.multiply(self.A_single, np.sqrt(Dy).astype(np.float32)[:, None], out=B)
        else:
            B = self.B_single[: int(rows.sum())]
            np.compress(rows, self.A_single, axis=0, out=B)
            B *= np.sqrt(Dy[rows]).astype(np.float32)[:, None]
        return (B.T @ B).astype(float)

    def __call__(self, Dy: np.ndarray, negligible: float = NEGLIGIBLE_WEIGHT) -> np.ndarray:
        A = self.A
        if len(Dy) and Dy.max() < SINGLE_PRECISION_RANGE * Dy.min():
            return self._single(None, Dy)
        top = Dy.max() if len(Dy) else 0.0
        heavy = Dy >= negligible * top if len(Dy) else Dy > 0
        double = heavy & (Dy >= SINGLE_WEIGHT * top) if MIXED_PRECISION and top < MAX_SINGLE_WEIGHT else heavy
        self.B_double = np.empty_like(A) if self.B_double is None else self.B_double
        B = self.B_double[: int(double.sum())]
        if double.all():
            np.multiply(A, np.sqrt(Dy)[:, None], out=B)
        else:  # the rows gathered into the buffer, not into a fresh array
            np.compress(double, A, axis=0, out=B)
            B *= np.sqrt(Dy[double])[:, None]
        M = B.T @ B
        light = heavy & ~double
        if light.any():
            M += self._single(light, Dy)
        return M


def _times(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """E v for the columns (u_lo, u_hi, y): (2n + k,) -> (n,)."""
    n = A.shape[1]
    return v[n:2 * n] - v[:n] + A.T @ v[2 * n:]


def _times_t(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """E^T v: (n,) -> (2n + k,)."""
    return np.r_[-v, v, A @ v]


def _direction(A, factor, D, point, residuals, r_xz, r_sw):
    """The Newton direction (dl, dx, dz, ds, dw) of the perturbed optimality conditions
    E dx = rp, dx + ds = ru, E^T dl + dz - dw = rd, Z dx + X dz = r_xz, W ds + S dw = r_sw,
    reduced to the normal equations (E D E^T) dl = rp + E D rho (``factor``: their Cholesky factor);
    and E^T dl, which carries E^T lam to the next iterate without a product."""
    x, z, s, w, one = point
    rp, ru, rd = residuals
    rho = rd - r_xz / x + (r_sw - w * ru) / s * one
    dl = sla.cho_solve(factor, rp + _times(A, D * rho), check_finite=False)
    Et_dl = _times_t(A, dl)
    dx = D * (Et_dl - rho)
    dz = (r_xz - z * dx) / x
    ds = (ru - dx) * one
    dw = (r_sw - w * ds) / s * one
    return dl, dx, dz, ds, dw, Et_dl


def _longest(v: np.ndarray, dv: np.ndarray) -> float:
    """The longest step t <= 1 keeping v + t dv >= 0."""
    neg = dv < 0
    return min(1.0, float(np.min(-v[neg] / dv[neg]))) if neg.any() else 1.0
