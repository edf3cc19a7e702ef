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
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

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
STEP_TO_BOUNDARY = 0.995  # the fraction of the longest feasible step taken (Mehrotra's heuristic)
# a basis's certificate to HiGHS's default primal and dual feasibility tolerances, as backend/ipm.py
PRIMAL_TOL = 1e-7
DUAL_TOL = 1e-7


@dataclass(frozen=True, eq=False)
class ArrowLp:
    """The LP above.

    point: (K,) the point each row touches; ax: (K, 3) its coefficients on that point.
    camera: (K,) the free camera (0 .. G-1) each row touches, or -1 for none; at: (K, 3) its
        coefficients there (zero where camera is -1).
    cost: (K,) and upper: (K,) (np.inf where unbounded) of the columns y.
    r: (n,) right-hand side; box: the bound on every unknown (and the cost of p and q).
    link: (n,) the free column (the wand-length row), or None; link_cost: its cost.
    n_cameras (G) and n_points (P) fix n = 3 G + 3 P."""

    point: np.ndarray
    ax: np.ndarray
    camera: np.ndarray
    at: np.ndarray
    cost: np.ndarray
    upper: np.ndarray
    r: np.ndarray
    box: float
    link: np.ndarray | None
    link_cost: float
    n_cameras: int
    n_points: int

    @property
    def n(self) -> int:
        return 3 * (self.n_cameras + self.n_points)

    @cached_property
    def A(self) -> sp.csr_matrix:
        """A (K, n), sparse: each row's 3 point and 3 camera coefficients."""
        K, G = len(self.point), self.n_cameras
        cols = np.c_[3 * np.maximum(self.camera, 0)[:, None] + np.arange(3), 3 * (G + self.point)[:, None] + np.arange(3)]
        vals = np.c_[self.at * (self.camera >= 0)[:, None], self.ax]
        # six entries a row, the columns ascending (the camera's, then the point's): the CSR arrays
        # directly, the same matrix (and the same sums, in the same order) as from COO, without its sort
        return sp.csr_matrix((vals.ravel(), cols.ravel(), np.arange(0, 6 * K + 1, 6)), shape=(K, self.n))

    @property
    def At(self) -> sp.csc_matrix:
        """A^T (n, K): A's arrays read as CSC (no copy)."""
        return self.A.T

    def with_rhs(self, r: np.ndarray, link: np.ndarray | None, link_cost: float) -> ArrowLp:
        """This LP with another right-hand side and free column, keeping A (the same rows) as
        built."""
        lp = replace(self, r=r, link=link, link_cost=link_cost)
        if "A" in vars(self):
            vars(lp)["A"] = self.A  # a cached_property's slot: A depends only on the rows
        return lp

    def times(self, y: np.ndarray) -> np.ndarray:
        """A^T y: (K,) -> (n,)."""
        return self.At @ y

    def rows_times(self, v: np.ndarray) -> np.ndarray:
        """A v: (n,) -> (K,), each row's value at the unknowns v."""
        return self.A @ v


@dataclass(frozen=True, eq=False)
class Basis:
    """basic: (K + 2 n,) mask over the columns (y, p, q) of the basic ones (the free column is
    always basic); at_upper: (K,) the nonbasic y at their upper bound."""

    basic: np.ndarray
    at_upper: np.ndarray


@dataclass(frozen=True, eq=False)
class WarmStart:
    """What a solve leaves for the next one of a like-shaped LP: its optimal basis where it was
    certified (else None), and its first iterate within ``WARM_NEAR`` of the optimum (x, z, s, w,
    lam, f), well centred, for the interior point to start from (Gondzio and Grothey's warm start,
    SIAM J. Optim. 13, 2003)."""

    basis: Basis | None
    iterate: _Point | None
    sums: _Sums | None = None


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
    blocks = _Blocks(lp, None if warm is None else warm.sums)
    v, status, named, iterations, iterate = _interior_point(lp, blocks, deadline, None if warm is None else warm.iterate,
                                                             tol)
    return ArrowResult(v, status, WarmStart(named, iterate, blocks.sums), iterations, time.perf_counter() - start)


def vertex(lp: ArrowLp, basis: Basis) -> np.ndarray | None:
    """The unknowns v (n,) at the vertex ``basis`` names, if that basis is optimal (its basic
    values within their bounds, its nonbasic columns' reduced costs of the right signs, to
    ``PRIMAL_TOL`` and ``DUAL_TOL``), else None.

    v solves one row per basic column: a basic row's residual is zero, a basic box column's
    unknown is at the box, and the free column's row (the wand length) holds."""
    K, n = len(lp.point), lp.n
    basic_y, basic_p, basic_q = basis.basic[:K], basis.basic[K : K + n], basis.basic[K + n :]
    if basic_y.sum() + basic_p.sum() + basic_q.sum() + (lp.link is not None) != n:
        return None
    A = lp.A
    eye = sp.identity(n, format="csr")
    blocks = [A[basic_y], eye[basic_p], -eye[basic_q]]
    rhs = [lp.cost[basic_y], np.full(basic_p.sum(), lp.box), np.full(basic_q.sum(), lp.box)]
    if lp.link is not None:
        blocks.append(sp.csr_matrix(lp.link[None, :]))
        rhs.append(np.array([lp.link_cost]))
    Bt = sp.vstack(blocks, format="csc")  # the basic columns as rows
    try:
        lu = spla.splu(Bt)
    except RuntimeError:  # singular
        return None
    v = lu.solve(np.concatenate(rhs))
    # the basic columns' values: B x_B = r - (the nonbasic columns at their bounds)
    y_fixed = np.where(basis.at_upper & ~basic_y, lp.upper, 0.0)
    x_b = lu.solve(lp.r - lp.times(y_fixed), trans="T")
    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(x_b))):
        return None
    n_y = int(basic_y.sum())
    ok_y = np.all(x_b[:n_y] >= -PRIMAL_TOL) and np.all(x_b[:n_y] <= lp.upper[basic_y] + PRIMAL_TOL)
    ok_box = np.all(x_b[n_y : n_y + basic_p.sum() + basic_q.sum()] >= -PRIMAL_TOL)
    reduced = lp.cost - lp.rows_times(v)
    free_y = ~basic_y
    ok_red = np.all(np.where(basis.at_upper[free_y], reduced[free_y] <= DUAL_TOL, reduced[free_y] >= -DUAL_TOL))
    ok_p = np.all((lp.box - v)[~basic_p] >= -DUAL_TOL) and np.all((lp.box + v)[~basic_q] >= -DUAL_TOL)
    return v if ok_y and ok_box and ok_red and ok_p else None


class _Normal:
    """The Newton system ``[[N, l], [l^T, 0]] [dl; df] = [h; rf]`` of an iteration, with N =
    ``A^T D_y A + diag(d_box)`` (n, n) in its blocks and l the free column (the wand row), solved
    by eliminating the points: XX (P, 3, 3) inverted, then the (3 G + 1)-square system over the
    translations and the free column. N alone is nearly singular along the rig's scale (every
    (Li) row is homogeneous in the unknowns when the gauge camera sits at the origin; only the box
    holds it, and its weights vanish), which the wand row fixes: eliminating it after N (a bordered
    solve) lost the direction to rounding 14 iterations in."""

    def __init__(self, blocks: _Blocks, Dy: np.ndarray, d_box: np.ndarray, link: np.ndarray | None):
        G, P = blocks.G, blocks.P
        db = d_box.reshape(-1, 3)
        XX = blocks.gather("by_point", Dy, blocks.xx).reshape(P, 3, 3)
        XX[:, np.arange(3), np.arange(3)] += db[G:]
        self.XXi = np.linalg.inv(XX)
        self.G, self.P = G, P
        # the shared unknowns' coupling to the points: the translations' rows of N, then l's
        TX = blocks.gather("by_pair", Dy, blocks.tx).reshape(G, P, 3, 3).transpose(0, 2, 1, 3)
        rows = [np.ascontiguousarray(TX).reshape(3 * G, 3 * P)]
        if link is not None:
            rows.append(link[None, 3 * G :])
        self.C = np.concatenate(rows)  # (3 G [+ 1], 3 P)
        self.Ci = np.einsum("spi,pij->spj", self.C.reshape(len(self.C), P, 3), self.XXi, optimize=True).reshape(
            len(self.C), -1)  # C XX^-1
        S = -self.Ci @ self.C.T
        if G:
            TT = blocks.gather("by_camera", Dy, blocks.tt).reshape(G, 3, 3)
            TT[:, np.arange(3), np.arange(3)] += db[:G]
            S[: 3 * G, : 3 * G] += sla.block_diag(*TT)
        if link is not None:
            S[: 3 * G, -1] += link[: 3 * G]
            S[-1, : 3 * G] += link[: 3 * G]
        self.S = sla.lu_factor(S, check_finite=False)  # indefinite with the free column

    def solve(self, h: np.ndarray, rf: float = 0.0) -> tuple[np.ndarray, float]:
        """(dl (n,), df) of the system above."""
        G = self.G
        hX = h[3 * G :]
        shared = np.r_[h[: 3 * G], [rf] * (len(self.C) - 3 * G)]
        z = sla.lu_solve(self.S, shared - self.Ci @ hX, check_finite=False)
        zX = np.einsum("pij,pj->pi", self.XXi, (hX - z @ self.C).reshape(-1, 3))
        return np.r_[z[: 3 * G], zX.ravel()], (float(z[-1]) if len(z) > 3 * G else 0.0)


class _Blocks:
    """Each row's outer products (constant through a solve) and the sparse sums that gather
    them: xx (K, 9) into (P, 9) by point, tt (K, 9) into (G, 9) by camera, tx (K, 9) into
    (G P, 9) by (camera, point)."""

    def __init__(self, lp: ArrowLp, last: _Sums | None = None):
        K, G, P = len(lp.point), lp.n_cameras, lp.n_points
        self.G, self.P = G, P
        on = lp.camera >= 0
        self.xx = (lp.ax[:, :, None] * lp.ax[:, None, :]).reshape(K, 9)
        self.tt = (lp.at[:, :, None] * lp.at[:, None, :]).reshape(K, 9) * on[:, None]
        self.tx = (lp.at[:, :, None] * lp.ax[:, None, :]).reshape(K, 9) * on[:, None]
        self.sums = last if last is not None and last.fits(lp) else _Sums.of(lp)
        self.by_point, self.by_camera, self.by_pair = self.sums.by_point, self.sums.by_camera, self.sums.by_pair

    def gather(self, by: str, weights: np.ndarray, outer: np.ndarray) -> np.ndarray:
        """``getattr(self, by) @ (outer * weights[:, None])``: the rows' outer products (K, 9)
        weighted by ``weights`` (K,) and summed into their groups, with the weights moved into
        the sparse sum's entries (K of them, against 9 K products)."""
        m = getattr(self, by)
        return sp.csr_matrix((weights[m.indices], m.indices, m.indptr), shape=m.shape) @ outer


@dataclass(frozen=True, eq=False)
class _Sums:
    """The sparse sums of :class:`_Blocks`, by point (P, K), camera (G, K) and (camera, point)
    (G P, K): they depend only on which point and camera each row touches, so a solve passes
    them on to the next of a like-shaped LP (the paper's next round; 10 ms a solve at 8 x 1500)."""

    point: np.ndarray
    camera: np.ndarray
    by_point: sp.csr_matrix
    by_camera: sp.csr_matrix
    by_pair: sp.csr_matrix

    @classmethod
    def of(cls, lp: ArrowLp) -> _Sums:
        K, G, P = len(lp.point), lp.n_cameras, lp.n_points
        ones, rows = np.ones(K), np.arange(K)
        cam = np.maximum(lp.camera, 0)
        return cls(lp.point, lp.camera, sp.csr_matrix((ones, (lp.point, rows)), shape=(P, K)),
                   sp.csr_matrix((ones, (cam, rows)), shape=(max(G, 1), K)),
                   sp.csr_matrix((ones, (cam * P + lp.point, rows)), shape=(max(G, 1) * P, K)))

    def fits(self, lp: ArrowLp) -> bool:
        """Whether these are ``lp``'s sums (its rows touch the same points and cameras)."""
        return (self.by_point.shape[0] == lp.n_points and self.by_camera.shape[0] == max(lp.n_cameras, 1)
                and np.array_equal(self.point, lp.point) and np.array_equal(self.camera, lp.camera))


@dataclass(frozen=True, eq=False)
class _Columns:
    """The LP's columns (y, p, q) as the interior point sees them: costs, bounded mask, upper
    bounds (0 where unbounded) and ``one`` (1.0 where bounded), each (K + 2 n,)."""

    lp: ArrowLp
    cost: np.ndarray
    ub: np.ndarray
    upper: np.ndarray
    one: np.ndarray

    @classmethod
    def of(cls, lp: ArrowLp) -> _Columns:
        n = lp.n
        up = np.r_[lp.upper, np.full(2 * n, np.inf)]
        ub = np.isfinite(up)
        return cls(lp, np.r_[lp.cost, np.full(2 * n, lp.box)], ub, np.where(ub, up, 0.0), ub.astype(float))

    def times(self, x: np.ndarray) -> np.ndarray:
        """E x: the columns times x, (K + 2 n,) -> (n,)."""
        K, n = len(self.lp.point), self.lp.n
        return self.lp.times(x[:K]) + x[K : K + n] - x[K + n :]

    def times_t(self, v: np.ndarray) -> np.ndarray:
        """E^T v: (n,) -> (K + 2 n,)."""
        return np.r_[self.lp.rows_times(v), v, -v]


@dataclass(frozen=True, eq=False)
class _Point:
    """An iterate: x (the columns), z and w (the duals of their lower and upper bounds), s (the
    upper slacks), lam (n,) the row duals (the unknowns v) and f, the free column."""

    x: np.ndarray
    z: np.ndarray
    s: np.ndarray
    w: np.ndarray
    lam: np.ndarray
    f: float

    @classmethod
    def cold(cls, cols: _Columns) -> _Point:
        """An infeasible start inside the bounds with positive duals, scaled to the costs."""
        size = max(np.abs(cols.cost).max(), 1e-300)
        x = np.where(cols.ub, cols.upper / 2, 1.0)
        return cls(x, np.maximum(cols.cost, 0.0) + 0.1 * size, np.where(cols.ub, cols.upper - x, 1.0),
                   (np.maximum(-cols.cost, 0.0) + 0.1 * size) * cols.one, np.zeros(cols.lp.n), 0.0)


@dataclass(frozen=True, eq=False)
class _Residuals:
    """rp (n,), ru and rd (K + 2 n,), rf of an iterate, its complementarity gap, and ``near``:
    the largest of the relative residuals and gap."""

    rp: np.ndarray
    ru: np.ndarray
    rd: np.ndarray
    rf: float
    gap: float
    near: float

    @classmethod
    def of(cls, cols: _Columns, pt: _Point) -> _Residuals:
        lp = cols.lp
        rp = lp.r - cols.times(pt.x) - (0.0 if lp.link is None else lp.link * pt.f)
        ru = (cols.upper - pt.x - pt.s) * cols.one
        rd = cols.cost - cols.times_t(pt.lam) - pt.z + pt.w
        rf = 0.0 if lp.link is None else lp.link_cost - lp.link @ pt.lam
        gap = pt.x @ pt.z + (pt.s * pt.w) @ cols.one
        c_norm = 1 + np.abs(cols.cost).max()
        near = max(np.abs(rp).max() / (1 + np.abs(lp.r).max()), np.abs(rd).max() / c_norm, abs(rf) / c_norm,
                   gap / (1 + abs(cols.cost @ pt.x)))
        return cls(rp, ru, rd, rf, gap, near)


def _interior_point(lp: ArrowLp, blocks: _Blocks, deadline: float | None, start: _Point | None = None,
                    tol: float = TOL):
    """Mehrotra's predictor-corrector (Wright 1997, ch. 10, with upper bounds) on the LP above,
    from ``start`` (an iterate of a like-shaped LP's solve) or a cold start. Returns (v (n,),
    status, the certified basis or None, iterations, the iterate to warm-start the next from).

    From ``CERTIFY_TOL`` on, the basis each iterate names is tried (:func:`vertex`) and the first
    optimal one ends it. Rounding can stop the iterates short of ``TOL`` (the normal matrix's
    weights span 1e30 late on); after ``WORSE`` iterates no nearer than the best, or a singular
    factor, the best iterate is the answer if it is within ``ACCEPT_TOL``."""
    cols = _Columns.of(lp)
    pt = start if start is not None and len(start.x) == len(cols.cost) else _Point.cold(cols)
    n_compl = len(pt.x) + int(cols.ub.sum())
    status, it, saved = "iteration_limit", 0, None
    best, worse = (np.inf, pt.lam), 0
    for it in range(1, MAX_ITER + 1):
        res = _Residuals.of(cols, pt)
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
        step = _step(cols, blocks, pt, res, n_compl)
        if step is None:  # a singular factor
            break
        pt = step
    if status not in ("optimal", "time_limit"):
        status = "optimal" if best[0] <= ACCEPT_TOL else "breakdown"
    return best[1], status, None, it, saved


def _step(cols: _Columns, blocks: _Blocks, pt: _Point, res: _Residuals, n_compl: int) -> _Point | None:
    """The next iterate: the affine-scaling predictor, then Mehrotra's corrector, each a
    Newton direction of the perturbed optimality conditions; None if the factor is singular."""
    K, n = len(cols.lp.point), cols.lp.n
    D = 1.0 / (pt.z / pt.x + pt.w / pt.s * cols.one)
    try:
        normal = _Normal(blocks, D[:K], D[K : K + n] + D[K + n :], cols.lp.link)
    except (np.linalg.LinAlgError, ValueError):
        return None
    one = cols.one
    _, _, dx, dz, ds, dw = _direction(cols, normal, D, pt, res, -pt.x * pt.z, -pt.s * pt.w * one)
    a_p, a_d = _step_lengths(pt, dx, dz, ds, dw, 1.0)
    gap_aff = (pt.x + a_p * dx) @ (pt.z + a_d * dz) + ((pt.s + a_p * ds) * (pt.w + a_d * dw)) @ one
    target = (gap_aff / res.gap) ** 3 * res.gap / n_compl
    dl, df, dx, dz, ds, dw = _direction(cols, normal, D, pt, res, target - pt.x * pt.z - dx * dz,
                                        (target - pt.s * pt.w - ds * dw) * one)
    a_p, a_d = _step_lengths(pt, dx, dz, ds, dw, STEP_TO_BOUNDARY)
    return _Point(pt.x + a_p * dx, pt.z + a_d * dz, np.where(cols.ub, pt.s + a_p * ds, 1.0),
                  (pt.w + a_d * dw) * one, pt.lam + a_d * dl, pt.f + a_p * df)


def _direction(cols: _Columns, normal: _Normal, D: np.ndarray, pt: _Point, res: _Residuals, r_xz: np.ndarray,
               r_sw: np.ndarray):
    """The Newton direction (dl, df, dx, dz, ds, dw) of E dx + l df = rp, dx + ds = ru,
    E^T dl + dz - dw = rd, l . dl = rf, Z dx + X dz = r_xz, W ds + S dw = r_sw, reduced to the
    normal equations (:class:`_Normal`) with one step of iterative refinement (late on, rounding
    in the eliminated system costs digits; the residual costs two sparse passes)."""
    lp, one = cols.lp, cols.one
    K, n = len(lp.point), lp.n
    Dy, d_box = D[:K], D[K : K + n] + D[K + n :]
    rho = res.rd - r_xz / pt.x + (r_sw - pt.w * res.ru) / pt.s * one
    h = res.rp + cols.times(D * rho)
    dl, df = normal.solve(h, res.rf)
    res_h = h - lp.times(Dy * lp.rows_times(dl)) - d_box * dl - (0.0 if lp.link is None else lp.link * df)
    cl, cf = normal.solve(res_h, 0.0 if lp.link is None else res.rf - lp.link @ dl)
    dl, df = dl + cl, df + cf
    dx = D * (cols.times_t(dl) - rho)
    dz = (r_xz - pt.z * dx) / pt.x
    ds = (res.ru - dx) * one
    dw = (r_sw - pt.w * ds) / pt.s * one
    return dl, df, dx, dz, ds, dw


def _named_basis(pt: _Point, ub: np.ndarray, count: int, K: int) -> Basis:
    """The basis an iterate names: the ``count`` columns furthest inside both bounds (relative
    to their duals), each other column at the bound it is nearer."""
    lo_side = pt.x / (pt.x + pt.z)
    hi_side = np.where(ub, pt.s / (pt.s + pt.w + 1e-300), 1.0)
    basic = np.zeros(len(pt.x), bool)
    basic[np.argsort(-np.minimum(lo_side, hi_side), kind="stable")[:count]] = True
    return Basis(basic, (~basic & (hi_side < lo_side))[:K])


def _step_lengths(pt: _Point, dx, dz, ds, dw, fraction: float) -> tuple[float, float]:
    """The primal and dual step lengths (<= 1): ``fraction`` of the longest that keep x, s and z,
    w nonnegative."""
    return (min(1.0, fraction * min(_longest(pt.x, dx), _longest(pt.s, ds))),
            min(1.0, fraction * min(_longest(pt.z, dz), _longest(pt.w, dw))))


def _longest(v: np.ndarray, dv: np.ndarray) -> float:
    """The longest step t <= 1 keeping v + t dv >= 0."""
    ratio = np.divide(v, -dv, out=np.full(len(v), np.inf), where=dv < 0)  # no masked copies: 65k entries here
    return min(1.0, float(ratio.min()))

