"""A primal-dual interior-point method for the LP step's dual form, the simplex basis it
points to, and that basis's certificate of optimality (calib/solve/lpstep.py).

The LP step's dual has one row per camera parameter (n) and one dense column per (row,
breakpoint) pair (k of them, each touching every camera of its frame). HiGHS's dual simplex
needs ~3.5 n iterations on it, each pricing every column, so its time grows as ~cameras^3
(decision 0004). An interior-point method takes ~12-15 iterations whatever the size, each one
dense (n, n) normal matrix ``A^T D A`` (k n^2 / 2 flops) and its Cholesky factor; its point
names the optimal basis (the n columns strictly inside their bounds), which one LU factor then
certifies optimal (:func:`certified_duals`; HiGHS's simplex carries on from it when not), so the
step stays an exact vertex of the LP.

The LP, with A (k, n) the pairs' rows:
    min  c_lo . u_lo + c_hi . u_hi + c . y
    s.t. A^T y - u_lo + u_hi = r,  0 <= y <= jump,  u_lo, u_hi >= 0,
and the row duals (n,) are the step. Mehrotra's predictor-corrector (Wright, Primal-Dual
Interior-Point Methods, 1997, ch. 10, with upper bounds as in Lustig, Marsten and Shanno 1992).
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
# Late on, pairs whose weight is below this fraction of the largest add nothing to the matrix that
# double precision keeps (they are at a bound): left out, the last 3 of 17 matrices used 15-100% of
# the pairs at 128 x 3000, with the same iterations and basis; 1e-9 broke the Cholesky factor
NEGLIGIBLE_WEIGHT = 1e-12
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


@dataclass(frozen=True, eq=False)
class IpmResult:
    """duals: (n,) the step; basic, at_upper: (2n + k,) masks over the columns (u_lo, u_hi, y)
    of the basis the point names; status: "optimal", "left" (``leave`` stopped it), "time_limit",
    "iteration_limit" or "breakdown" (a normal matrix not positive definite in floating point)."""

    duals: np.ndarray
    basic: np.ndarray
    at_upper: np.ndarray
    status: str
    iterations: int
    seconds: float


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
            change whatever its optimum: calib/solve/lpstep.py).
    """
    start = time.perf_counter()
    n = A.shape[1]
    cost = np.r_[c_lo, c_hi, c]
    up = np.r_[np.full(2 * n, np.inf), jump]
    ub = np.isfinite(up)
    upper = np.where(ub, up, 0.0)
    one = np.where(ub, 1.0, 0.0)  # upper-bound terms exist only where there is a bound

    # an infeasible start, inside the bounds with its duals positive, scaled to the costs
    size = max(np.abs(cost).max(), 1e-300)
    x = np.where(ub, upper / 2, 1.0)
    s = np.where(ub, upper - x, 1.0)
    lam = np.zeros(n)
    z = np.maximum(cost, 0.0) + 0.1 * size
    w = (np.maximum(-cost, 0.0) + 0.1 * size) * one
    n_compl = len(x) + int(ub.sum())  # complementarity products: x z, and s w where bounded
    r_norm, c_norm = 1 + np.abs(r).max(), 1 + np.abs(cost).max()
    status, it = "iteration_limit", 0
    normal = _NormalMatrix(A)
    for it in range(1, MAX_ITER + 1):  # noqa: B007 (the count is reported after the loop)
        rp = r - _times(A, x)
        ru = (upper - x - s) * one
        rd = cost - _times_t(A, lam) - z + w
        gap = x @ z + (s * w) @ one
        if (np.abs(rp).max() <= TOL * r_norm and np.abs(rd).max() <= TOL * c_norm
                and gap <= TOL * (1 + abs(cost @ x))):
            status = "optimal"
            break
        if (leave is not None and np.abs(rp).max() <= LEAVE_TOL * r_norm and np.abs(rd).max() <= LEAVE_TOL * c_norm
                and gap <= LEAVE_TOL * (1 + abs(cost @ x))):
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
        M = normal(Dy)
        M[np.diag_indices(n)] += D[:n] + D[n:2 * n]
        try:
            factor = sla.cho_factor(M, lower=False, overwrite_a=True, check_finite=False)
        except np.linalg.LinAlgError:  # rounding at extreme scalings: HiGHS carries on from the basis so far
            status = "breakdown"
            break
        point, residuals = (x, z, s, w, one), (rp, ru, rd)
        # the affine-scaling predictor, then Mehrotra's corrector
        dl, dx, dz, ds, dw = _direction(A, factor, D, point, residuals, -x * z, -s * w * one)
        a_p = min(_longest(x, dx), _longest(s, ds))
        a_d = min(_longest(z, dz), _longest(w, dw))
        gap_aff = (x + a_p * dx) @ (z + a_d * dz) + ((s + a_p * ds) * (w + a_d * dw)) @ one
        sigma = (gap_aff / gap) ** 3
        dl, dx, dz, ds, dw = _direction(A, factor, D, point, residuals, sigma * mu - x * z - dx * dz,
                                        (sigma * mu - s * w - ds * dw) * one)
        a_p = min(1.0, STEP_TO_BOUNDARY * min(_longest(x, dx), _longest(s, ds)))
        a_d = min(1.0, STEP_TO_BOUNDARY * min(_longest(z, dz), _longest(w, dw)))
        x, s = x + a_p * dx, np.where(ub, s + a_p * ds, 1.0)
        lam, z, w = lam + a_d * dl, z + a_d * dz, (w + a_d * dw) * one
    # each column's place in the basis: inside both bounds (basic), or at the one it is nearer
    lo_side = x / (x + z)
    hi_side = np.where(ub, s / (s + w + 1e-300), 1.0)
    basic = np.zeros(len(x), bool)
    basic[np.argsort(-np.minimum(lo_side, hi_side), kind="stable")[:n]] = True
    return IpmResult(lam, basic, ~basic & (hi_side < lo_side), status, it, time.perf_counter() - start)


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

    def __call__(self, Dy: np.ndarray) -> np.ndarray:
        A = self.A
        if len(Dy) and Dy.max() < SINGLE_PRECISION_RANGE * Dy.min():
            return self._single(None, Dy)
        top = Dy.max() if len(Dy) else 0.0
        heavy = Dy >= NEGLIGIBLE_WEIGHT * top if len(Dy) else Dy > 0
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
    reduced to the normal equations (E D E^T) dl = rp + E D rho (``factor``: their Cholesky factor)."""
    x, z, s, w, one = point
    rp, ru, rd = residuals
    rho = rd - r_xz / x + (r_sw - w * ru) / s * one
    dl = sla.cho_solve(factor, rp + _times(A, D * rho), check_finite=False)
    dx = D * (_times_t(A, dl) - rho)
    dz = (r_xz - z * dx) / x
    ds = (ru - dx) * one
    dw = (r_sw - w * ds) / s * one
    return dl, dx, dz, ds, dw


def _longest(v: np.ndarray, dv: np.ndarray) -> float:
    """The longest step t <= 1 keeping v + t dv >= 0."""
    neg = dv < 0
    return min(1.0, float(np.min(-v[neg] / dv[neg]))) if neg.any() else 1.0
