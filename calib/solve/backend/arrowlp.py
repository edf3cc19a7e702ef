"""An interior-point method for LPs whose rows each touch one point and one camera, and the simplex
basis its answer names, certified optimal by one sparse LU factor (the paper's eq. (Li) LP).

In eq. (Li) every row of an observation, and every height row of eq. (extra), touches the 3
coordinates of one point and the 3 of one camera's translation; only the wand-length row touches
every point. The method works on the LP's dual form, whose rows are those unknowns, so the normal
matrix of each iteration is block-arrow: a 3 x 3 block per point, a 3 x 3 block per camera, and
the (camera, point) blocks that couple them. Eliminating the points leaves a (3 G, 3 G) Schur
complement over the G free cameras; the wand row is one bordering column. An iteration costs a
few passes over the rows, against HiGHS's interior point on the sparse LP (74 s cold at 8 x 1500,
decision 0033).

The LP, with n = 3 G + 3 P unknowns (the translations first, then the points) and K rows:
    min  cost . y + box (1 . p + 1 . q) + link_cost * f
    s.t. A^T y + p - q + link f = r,   0 <= y <= upper,  p, q >= 0,  f free,
where column k of A^T holds row k's coefficients. Its row duals v (n,) are the primal unknowns:
the (Li) rows' residuals are ``A v - cost`` and the box is |v| <= box.

A basis names which rows hold at zero (basic columns strictly inside their bounds) and which sign
each other row's residual has; its vertex is one sparse solve, and it is optimal when the basic
values are within their bounds and the other rows' residuals have their signs
(:func:`vertex`). Between the paper's rounds only the rotations change, so the last round's
basis usually stays optimal: a round then costs one LU factor (the warm start).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from wandcal.calib.solve.backend.arrow_newton import Blocks, Columns, Iterate, Residuals, Sums, newton_step
from wandcal.calib.solve.backend.arrow_problem import DUAL_TOL, PRIMAL_TOL, ArrowLp, Basis, vertex

# The LP and its vertices are in arrow_problem, the Newton step in arrow_newton; the names callers
# import from here before the split stay here.
__all__ = ["ACCEPT_TOL", "CERTIFY", "DUAL_TOL", "PRIMAL_TOL", "TOL", "ArrowLp", "ArrowResult", "Basis", "WarmStart",
           "solve", "vertex"]

TOL = 1e-9  # relative primal and dual residuals and complementarity at the end (as backend/ipm.py)
# rounding in the normal matrix (its heaviest and lightest rows' weights span 1e30 late on) can
# stop an iterate short of TOL; from there the residuals grow again. The method then stops at its
# best iterate, which is its answer if it is this near the optimum
ACCEPT_TOL = 1e-6
WORSE = 2  # iterates in a row no nearer than the best so far: it has stopped improving
CERTIFY_TOL = 1e-6  # from here on each iterate's basis is tried (one LU factor), stopping at the first optimal
# ... but not by default: SciPy's SuperLU (splu) keeps memory it allocated for a basis it finds
# singular, and most of the paper's LPs are degenerate there (~40 MB a round at 8 x 1500, 6.7 GB
# after 200 rounds). The interior point's answer is then the LP's optimum to TOL (objectives 1e-9
# from the simplex vertex's), as on most rounds of the measured runs, where no named basis passed
CERTIFY = False
MAX_ITER = 80
WARM_NEAR = 1e-2  # the iterate kept to start the next round's solve from (see WarmStart)


@dataclass(frozen=True, eq=False)
class WarmStart:
    """What a solve leaves for the next one of a like-shaped LP: its optimal basis where it was
    certified (else None), and its first iterate within ``WARM_NEAR`` of the optimum (x, z, s, w,
    lam, f), well centred, for the interior point to start from (Gondzio and Grothey's warm start,
    SIAM J. Optim. 13, 2003)."""

    basis: Basis | None
    iterate: Iterate | None
    sums: Sums | None = None


@dataclass(frozen=True, eq=False)
class ArrowResult:
    """v: (n,) the unknowns; status: "optimal", "time_limit", "iteration_limit" or "breakdown";
    basis: the warm start for the next solve (its ``basis`` is certified optimal here, and v is
    then its vertex); iterations: interior-point iterations (0 when a given basis was certified
    as it is); objective: the LP's value at v."""

    v: np.ndarray
    status: str
    basis: WarmStart
    iterations: int
    seconds: float
    objective: float = float("nan")

    def __bool__(self) -> bool:
        return self.status == "optimal"


def solve(lp: ArrowLp, warm: WarmStart | None = None, deadline: float | None = None, tol: float = TOL) -> ArrowResult:
    """The LP's optimum: the vertex of ``warm``'s basis if it is still optimal, else the
    interior-point method's answer (from ``warm``'s iterate), as the vertex of the basis it names
    where that is certified. ``tol``: the relative residuals and gap the interior point stops at
    (``TOL``; ``--method paper`` passes a looser one, decision 0060)."""
    start = time.perf_counter()
    if warm is not None and warm.basis is not None:
        v = vertex(lp, warm.basis)
        if v is not None:
            return ArrowResult(v, "optimal", warm, 0, time.perf_counter() - start)
    blocks = Blocks(lp, None if warm is None else warm.sums)
    v, status, named, iterations, iterate = _interior_point(lp, blocks, deadline, None if warm is None else warm.iterate,
                                                             tol)
    return ArrowResult(v, status, WarmStart(named, iterate, blocks.sums), iterations, time.perf_counter() - start)


def _interior_point(lp: ArrowLp, blocks: Blocks, deadline: float | None, start: Iterate | None = None,
                    tol: float = TOL):
    """Mehrotra's predictor-corrector (Wright 1997, ch. 10, with upper bounds) on the LP above,
    from ``start`` (an iterate of a like-shaped LP's solve) or a cold start. Returns (v (n,),
    status, the certified basis or None, iterations, the iterate to warm-start the next from).

    From ``CERTIFY_TOL`` on, the basis each iterate names is tried (:func:`vertex`) and the first
    optimal one ends it. Rounding can stop the iterates short of ``TOL`` (the normal matrix's
    weights span 1e30 late on); after ``WORSE`` iterates no nearer than the best, or a singular
    factor, the best iterate is the answer if it is within ``ACCEPT_TOL``."""
    cols = Columns.of(lp)
    pt = start if start is not None and len(start.x) == len(cols.cost) else Iterate.cold(cols)
    n_compl = len(pt.x) + int(cols.ub.sum())
    status, it, saved = "iteration_limit", 0, None
    best, worse = (np.inf, pt.lam), 0
    for it in range(1, MAX_ITER + 1):
        res = Residuals.of(cols, pt)
        if saved is None and res.near <= WARM_NEAR:
            saved = pt
        if CERTIFY and res.near <= CERTIFY_TOL:
            named = _named_basis(pt, cols.ub, lp.n - (lp.link is not None), len(lp.point))
            v = vertex(lp, named)
            if v is not None:
                return v, "optimal", named, it, saved
        best, worse = ((res.near, pt.lam), 0) if res.near < best[0] else (best, worse + 1)
        if res.near <= tol:
            status = "optimal"
            break
        if worse >= WORSE:
            break
        if deadline is not None and time.perf_counter() > deadline:
            status = "time_limit"
            break
        step = newton_step(cols, blocks, pt, res, n_compl)
        if step is None:  # a singular factor
            break
        pt = step
    if status not in ("optimal", "time_limit"):
        status = "optimal" if best[0] <= ACCEPT_TOL else "breakdown"
    return best[1], status, None, it, saved


def _named_basis(pt: Iterate, ub: np.ndarray, count: int, K: int) -> Basis:
    """The basis an iterate names: the ``count`` columns furthest inside both bounds (relative
    to their duals), each other column at the bound it is nearer."""
    lo_side = pt.x / (pt.x + pt.z)
    hi_side = np.where(ub, pt.s / (pt.s + pt.w + 1e-300), 1.0)
    basic = np.zeros(len(pt.x), bool)
    basic[np.argsort(-np.minimum(lo_side, hi_side), kind="stable")[:count]] = True
    return Basis(basic, (~basic & (hi_side < lo_side))[:K])
