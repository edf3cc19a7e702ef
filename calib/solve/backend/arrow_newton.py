"""The Newton step of the block-arrow interior point (:mod:`wandcal.calib.solve.backend.arrowlp`):
its iterate, residuals and normal equations, the last solved by eliminating the points.

Each row of the LP touches the 3 coordinates of one point and the 3 of one camera's translation, so
the normal matrix of an iteration is block-arrow: a 3 x 3 block per point, a 3 x 3 block per camera,
and the (camera, point) blocks that couple them. Eliminating the points leaves a (3 G, 3 G) Schur
complement over the G free cameras; the wand row is one bordering column.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from wandcal.calib.solve.backend.arrow_problem import ArrowLp

STEP_TO_BOUNDARY = 0.995  # the fraction of the longest feasible step taken (Mehrotra's heuristic)



class Normal:
    """The Newton system ``[[N, l], [l^T, 0]] [dl; df] = [h; rf]`` of an iteration, with N =
    ``A^T D_y A + diag(d_box)`` (n, n) in its blocks and l the free column (the wand row), solved
    by eliminating the points: XX (P, 3, 3) inverted, then the (3 G + 1)-square system over the
    translations and the free column. N alone is nearly singular along the rig's scale (every
    (Li) row is homogeneous in the unknowns when the gauge camera sits at the origin; only the box
    holds it, and its weights vanish), which the wand row fixes: eliminating it after N (a bordered
    solve) lost the direction to rounding 14 iterations in."""

    def __init__(self, blocks: Blocks, Dy: np.ndarray, d_box: np.ndarray, link: np.ndarray | None):
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


class Blocks:
    """Each row's outer products (constant through a solve) and the sparse sums that gather
    them: xx (K, 9) into (P, 9) by point, tt (K, 9) into (G, 9) by camera, tx (K, 9) into
    (G P, 9) by (camera, point)."""

    def __init__(self, lp: ArrowLp, last: Sums | None = None):
        K, G, P = len(lp.point), lp.n_cameras, lp.n_points
        self.G, self.P = G, P
        on = lp.camera >= 0
        self.xx = (lp.ax[:, :, None] * lp.ax[:, None, :]).reshape(K, 9)
        self.tt = (lp.at[:, :, None] * lp.at[:, None, :]).reshape(K, 9) * on[:, None]
        self.tx = (lp.at[:, :, None] * lp.ax[:, None, :]).reshape(K, 9) * on[:, None]
        self.sums = last if last is not None and last.fits(lp) else Sums.of(lp)
        self.by_point, self.by_camera, self.by_pair = self.sums.by_point, self.sums.by_camera, self.sums.by_pair

    def gather(self, by: str, weights: np.ndarray, outer: np.ndarray) -> np.ndarray:
        """``getattr(self, by) @ (outer * weights[:, None])``: the rows' outer products (K, 9)
        weighted by ``weights`` (K,) and summed into their groups, with the weights moved into
        the sparse sum's entries (K of them, against 9 K products)."""
        m = getattr(self, by)
        return sp.csr_matrix((weights[m.indices], m.indices, m.indptr), shape=m.shape) @ outer


@dataclass(frozen=True, eq=False)
class Sums:
    """The sparse sums of :class:`Blocks`, by point (P, K), camera (G, K) and (camera, point)
    (G P, K): they depend only on which point and camera each row touches, so a solve passes
    them on to the next of a like-shaped LP (the paper's next round; 10 ms a solve at 8 x 1500)."""

    point: np.ndarray
    camera: np.ndarray
    by_point: sp.csr_matrix
    by_camera: sp.csr_matrix
    by_pair: sp.csr_matrix

    @classmethod
    def of(cls, lp: ArrowLp) -> Sums:
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
class Columns:
    """The LP's columns (y, p, q) as the interior point sees them: costs, bounded mask, upper
    bounds (0 where unbounded) and ``one`` (1.0 where bounded), each (K + 2 n,)."""

    lp: ArrowLp
    cost: np.ndarray
    ub: np.ndarray
    upper: np.ndarray
    one: np.ndarray

    @classmethod
    def of(cls, lp: ArrowLp) -> Columns:
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
class Iterate:
    """An iterate: x (the columns), z and w (the duals of their lower and upper bounds), s (the
    upper slacks), lam (n,) the row duals (the unknowns v) and f, the free column."""

    x: np.ndarray
    z: np.ndarray
    s: np.ndarray
    w: np.ndarray
    lam: np.ndarray
    f: float

    @classmethod
    def cold(cls, cols: Columns) -> Iterate:
        """An infeasible start inside the bounds with positive duals, scaled to the costs."""
        size = max(np.abs(cols.cost).max(), 1e-300)
        x = np.where(cols.ub, cols.upper / 2, 1.0)
        return cls(x, np.maximum(cols.cost, 0.0) + 0.1 * size, np.where(cols.ub, cols.upper - x, 1.0),
                   (np.maximum(-cols.cost, 0.0) + 0.1 * size) * cols.one, np.zeros(cols.lp.n), 0.0)


@dataclass(frozen=True, eq=False)
class Residuals:
    """rp (n,), ru and rd (K + 2 n,), rf of an iterate, its complementarity gap, and ``near``:
    the largest of the relative residuals and gap."""

    rp: np.ndarray
    ru: np.ndarray
    rd: np.ndarray
    rf: float
    gap: float
    near: float

    @classmethod
    def of(cls, cols: Columns, pt: Iterate) -> Residuals:
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


def newton_step(cols: Columns, blocks: Blocks, pt: Iterate, res: Residuals, n_compl: int) -> Iterate | None:
    """The next iterate: the affine-scaling predictor, then Mehrotra's corrector, each a
    Newton direction of the perturbed optimality conditions; None if the factor is singular."""
    K, n = len(cols.lp.point), cols.lp.n
    D = 1.0 / (pt.z / pt.x + pt.w / pt.s * cols.one)
    try:
        normal = Normal(blocks, D[:K], D[K : K + n] + D[K + n :], cols.lp.link)
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
    return Iterate(pt.x + a_p * dx, pt.z + a_d * dz, np.where(cols.ub, pt.s + a_p * ds, 1.0),
                  (pt.w + a_d * dw) * one, pt.lam + a_d * dl, pt.f + a_p * df)


def _direction(cols: Columns, normal: Normal, D: np.ndarray, pt: Iterate, res: Residuals, r_xz: np.ndarray,
               r_sw: np.ndarray):
    """The Newton direction (dl, df, dx, dz, ds, dw) of E dx + l df = rp, dx + ds = ru,
    E^T dl + dz - dw = rd, l . dl = rf, Z dx + X dz = r_xz, W ds + S dw = r_sw, reduced to the
    normal equations (:class:`Normal`) with one step of iterative refinement (late on, rounding
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


def _step_lengths(pt: Iterate, dx, dz, ds, dw, fraction: float) -> tuple[float, float]:
    """The primal and dual step lengths (<= 1): ``fraction`` of the longest that keep x, s and z,
    w nonnegative."""
    return (min(1.0, fraction * min(_longest(pt.x, dx), _longest(pt.s, ds))),
            min(1.0, fraction * min(_longest(pt.z, dz), _longest(pt.w, dw))))


def _longest(v: np.ndarray, dv: np.ndarray) -> float:
    """The longest step t <= 1 keeping v + t dv >= 0."""
    ratio = np.divide(v, -dv, out=np.full(len(v), np.inf), where=dv < 0)  # no masked copies: 65k entries here
    return min(1.0, float(ratio.min()))
