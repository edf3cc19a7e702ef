"""The LP of :mod:`wandcal.calib.solve.backend.arrowlp` (rows that each touch one point and one
camera) and the vertex a simplex basis of it names, certified optimal by one sparse LU factor.

The LP, with n = 3 G + 3 P unknowns (the translations first, then the points) and K rows:
    min  cost . y + box (1 . p + 1 . q) + link_cost * f
    s.t. A^T y + p - q + link f = r,   0 <= y <= upper,  p, q >= 0,  f free,
where column k of A^T holds row k's coefficients. Its row duals v (n,) are the primal unknowns:
the (Li) rows' residuals are ``A v - cost`` and the box is |v| <= box.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

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
