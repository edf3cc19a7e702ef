"""The LP refinement (``--method lp``): sequential linear programming over the camera poses.

Each iteration linearises the pixel reprojection residuals of :class:`calib.wandmodel.WandModel`
about the current state, eliminates every wand frame's 5 parameters per frame (points are
independent once the cameras are known), and solves one LP with HiGHS for the step ``d`` of all
free cameras (3 rotation increments and 3 translations each) inside a trust region:

    minimise  sum_i rho(a_i . d + b_i)   subject to  |d_j| <= radius_j,

where ``rho`` is a convex piecewise-linear loss, so this is an LP. Plain least absolute error
(``rho = |z|``) is robust but only 64% efficient on Gaussian noise (1.25x the error of least
squares); ``rho`` here is the 3-breakpoint piecewise-linear M-estimator loss of greatest
Gaussian efficiency (96.5%, docs/decisions/0004-lp-method.md) in units of a robust scale ``s`` of
the residuals. Rows further out than ``REJECT_SIGMAS * s`` are left out of the step (a
redescending M-estimator that ignores gross outliers).

The LP stays small and exact. ``rho`` is the maximum of its linear pieces, so replacing it, row
by row, by the maximum of only the pieces near the row's current residual gives a lower bound of
the objective that is exact wherever each row stays among its modelled pieces. Most rows keep
one piece (a linear term, folded into one cost vector); only rows near a breakpoint enter the LP
with one auxiliary variable per breakpoint. If the LP's optimum keeps every row among its
modelled pieces, it is the optimum of the full LP (it attains a lower bound); otherwise the rows
that left are given the breakpoints they crossed and the LP is solved again.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from calib.lp import solve_lp
from calib.wandmodel import CAM_PARAMS, FRAME_PARAMS, WandModel

# The loss: breakpoints (robust sigmas) and psi on each interval, from 0 outwards; found by
# maximising Gaussian efficiency over 3-breakpoint convex piecewise-linear losses (decision 0004)
BREAKS = np.array([0.501, 1.05, 1.748])
SLOPES = np.array([0.188, 0.58, 1.031, 1.651])
REJECT_SIGMAS = 6.0  # a residual this many robust sigmas out is a gross outlier, not noise
ELIMINATION_K = 1.75  # Huber weights for each frame's own least-squares fit (the last breakpoint)
ROT_RADIUS = 0.02  # initial trust region: radians per rotation increment
T_RADIUS = 0.05  # and metres per translation component
MAX_ITER = 40
STEP_TOL = 2e-7  # stop when no camera parameter moves by more than this (rad or m)
NEAR_BREAK = 0.1  # a row within this many sigmas of a breakpoint starts in the LP
MAX_ACTIVE_ROUNDS = 12  # re-solves with widened rows before a step is taken as it is

# signed breakpoints and the slope of each interval between them, left to right
_P = np.r_[-BREAKS[::-1], 0.0, BREAKS]
_S = np.r_[-SLOPES[::-1], SLOPES]


def pl_loss(z: np.ndarray) -> np.ndarray:
    """The convex piecewise-linear loss of (signed) residuals in robust sigmas."""
    a = np.abs(z)
    out = SLOPES[0] * a
    for q, beta in enumerate(BREAKS):
        out += (SLOPES[q + 1] - SLOPES[q]) * np.maximum(a - beta, 0.0)
    return out


_CAP = float(pl_loss(np.array([REJECT_SIGMAS]))[0])


def refine_lp(model: WandModel, x0: np.ndarray | None = None, progress=None, max_iter: int = MAX_ITER, time_limit: float | None = None):
    """Refine all free cameras and wand frames by sequential LP.

    Args:
        model: the wand problem about its start state.
        x0: (n_params,) start, ``model.x0()`` when None.
        progress: optional callable(dict).
        time_limit: seconds for each LP solve.

    Returns:
        (x, info) with info: iterations, seconds, lp_seconds, lp_rows_mean, status, scale.
    """
    start = time.perf_counter()
    x = model.x0() if x0 is None else x0.copy()
    n_free = model.frame_col0 // CAM_PARAMS
    radius = np.array([ROT_RADIUS, T_RADIUS])
    lp_seconds, lp_rows, status = 0.0, [], "iteration_limit"
    sys = _ReducedSystem(model, x)
    it = 0
    for it in range(1, max_iter + 1):
        rho = np.tile(np.repeat(radius, 3), n_free)
        d, lp_info = _solve_step(sys, rho, time_limit)
        lp_seconds += lp_info["seconds"]
        lp_rows.append(lp_info["rows"])
        if d is None:
            status = f"lp_{lp_info['status']}"
            break
        cost = sys.cost(sys.scale)
        trial = _ReducedSystem(model, sys.apply(d))
        new_cost = trial.cost(sys.scale)
        predicted = sys.model_cost(d)
        ratio = (cost - new_cost) / max(cost - predicted, 1e-300)
        step = np.abs(d).reshape(-1, 2, 3).max(axis=(0, 2))
        if new_cost < cost:
            sys = trial
            if ratio > 0.75 and np.any(step > 0.5 * radius):
                radius = radius * 2.0
        else:
            radius = np.maximum(0.25 * step, 1e-9)
        if progress is not None:
            progress({"stage": "refine", "iteration": it, "cost": min(cost, new_cost), "message": f"LP step {it}: {lp_info['rows']} LP rows, {lp_info['rounds']} solves"})
        if np.max(np.abs(d)) < STEP_TOL:
            status = "converged"
            break
    return sys.x, {
        "iterations": it,
        "seconds": time.perf_counter() - start,
        "lp_seconds": lp_seconds,
        "lp_rows_mean": float(np.mean(lp_rows)) if lp_rows else 0.0,
        "status": status,
        "robust_scale_px": sys.scale,
    }


class _ReducedSystem:
    """Residuals with each frame's parameters eliminated, at one state of a WandModel."""

    def __init__(self, model: WandModel, x: np.ndarray):
        self.model, self.x = model, x
        self.r = model.residuals(x).reshape(-1, 2)
        blocks, cols = model.jacobian_blocks(x)
        self.own = cols[:, 0] >= 0  # the observation's camera is free
        self.cam_cols = cols[:, :CAM_PARAMS]
        self.C = blocks[:, :, :CAM_PARAMS]  # (M, 2, 6)
        self.F = blocks[:, :, CAM_PARAMS:]  # (M, 2, 5)
        mag = np.linalg.norm(self.r, axis=1)
        # per-axis robust scale from the residual magnitudes (median of a 2D Gaussian's radius)
        self.scale = max(float(np.median(mag)) / np.sqrt(2 * np.log(2)), 1e-9)
        self.kept = np.abs(self.r) <= REJECT_SIGMAS * self.scale  # (M, 2)
        self._eliminate()

    def cost(self, scale: float) -> float:
        """The redescending objective: the loss, capped at the rejection point."""
        return float(np.minimum(pl_loss(self.r / scale), _CAP).sum())

    def model_cost(self, d: np.ndarray) -> float:
        """The LP's model at step d: kept rows linearised, rejected rows at their cap."""
        z = (self.b + self.change(d)) / self.scale
        return float(np.where(self.kept, pl_loss(z), _CAP).sum())

    def _eliminate(self) -> None:
        """Per-frame elimination: K (M,2,5), G (F,N,5,6), g (F,5), Hinv (F,5,5), b (M,2)."""
        p = self.model.p
        z = np.abs(self.r) / self.scale
        Wt = np.where(self.kept, np.minimum(1.0, ELIMINATION_K / np.maximum(z, 1e-12)), 0.0)
        FW = self.F * Wt[:, :, None]
        H = np.zeros((p.n_frames, FRAME_PARAMS, FRAME_PARAMS))
        np.add.at(H, p.frame, np.einsum("mki,mkj->mij", FW, self.F))
        g = np.zeros((p.n_frames, FRAME_PARAMS))
        np.add.at(g, p.frame, np.einsum("mki,mk->mi", FW, self.r))
        Hinv = np.linalg.inv(H + 1e-9 * np.eye(FRAME_PARAMS))
        G = np.zeros((p.n_frames, p.n_cams, FRAME_PARAMS, CAM_PARAMS))
        np.add.at(G, (p.frame, p.camera), np.einsum("mki,mkj->mij", FW, self.C))
        self.K = np.einsum("mki,mij->mkj", self.F, Hinv[p.frame])
        self.Hinv, self.G, self.g = Hinv, G, g
        self.b = self.r - np.einsum("mkj,mj->mk", self.K, g[p.frame])

    def rows(self, obs: np.ndarray, comp: np.ndarray) -> np.ndarray:
        """Dense reduced rows a_i, (k, n_cam_params), for observation ``obs`` component ``comp``."""
        p, m = self.model.p, self.model
        K = self.K[obs, comp]  # (k, 5)
        KG = np.einsum("kj,knjc->knc", K, self.G[p.frame[obs]])  # (k, N, 6)
        out = -KG[:, m.free].reshape(len(obs), -1)
        own = np.flatnonzero(self.own[obs])
        cols = self.cam_cols[obs[own]]
        np.add.at(out, (own[:, None], cols), self.C[obs[own], comp[own]])
        return out

    def change(self, d: np.ndarray) -> np.ndarray:
        """(M, 2) a_i . d for every row, without forming the rows."""
        p, m = self.model.p, self.model
        dc = np.zeros((p.n_cams, CAM_PARAMS))
        dc[m.free] = d.reshape(-1, CAM_PARAMS)
        own = np.einsum("mkj,mj->mk", self.C, dc[p.camera]) * self.own[:, None]
        Gd = np.einsum("fnjc,nc->fj", self.G, dc)
        return own - np.einsum("mkj,mj->mk", self.K, Gd[p.frame])

    def folded_cost(self, coef: np.ndarray) -> np.ndarray:
        """sum_i coef_i a_i over all rows, (n_cam_params,), for coef (M, 2)."""
        p, m = self.model.p, self.model
        cam = np.einsum("mk,mkj->mj", coef, self.C) * self.own[:, None]
        out = np.zeros((p.n_cams, CAM_PARAMS))
        np.add.at(out, p.camera, cam)
        u = np.zeros((p.n_frames, FRAME_PARAMS))
        np.add.at(u, p.frame, np.einsum("mk,mkj->mj", coef, self.K))
        out -= np.einsum("fj,fnjc->nc", u, self.G)
        return out[m.free].ravel()

    def apply(self, d: np.ndarray) -> np.ndarray:
        """New state: cameras += d and each frame += its eliminated step."""
        m, p = self.model, self.model.p
        x = self.x.copy()
        x[: m.frame_col0] += d
        dc = np.zeros((p.n_cams, CAM_PARAMS))
        dc[m.free] = d.reshape(-1, CAM_PARAMS)
        df = -np.einsum("fij,fj->fi", self.Hinv, self.g + np.einsum("fnjc,nc->fj", self.G, dc))
        x[m.frame_col0 :] += df.ravel()
        return x


def _solve_step(sys: _ReducedSystem, rho: np.ndarray, time_limit):
    """The trust-region LP step on an exact working set of (row, breakpoint) pairs."""
    P = _P * sys.scale  # breakpoints in pixels
    b = sys.b.ravel()
    kept = sys.kept.ravel()
    interval = np.searchsorted(P, b)  # row lives in interval j: P[j-1] < b <= P[j]
    lo = interval.copy()  # modelled breakpoints lo..hi (inclusive); none when hi < lo
    hi = interval - 1
    near = NEAR_BREAK * sys.scale
    below = np.clip(interval - 1, 0, len(P) - 1)
    above = np.clip(interval, 0, len(P) - 1)
    lo = np.where((interval > 0) & (b - P[below] < near), interval - 1, lo)
    hi = np.where((interval < len(P)) & (P[above] - b < near), interval, hi)
    seconds, d, rounds = 0.0, None, 0
    for rounds in range(1, MAX_ACTIVE_ROUNDS + 1):
        rows_i, bps = _pairs(np.where(kept, lo, 0), np.where(kept, hi, -1))
        coef = np.where(kept, _S[lo], 0.0).reshape(-1, 2)
        c_fold = sys.folded_cost(coef)
        A = sys.rows(rows_i // 2, rows_i % 2)
        res = _lp(A, b[rows_i] - P[bps], _S[bps + 1] - _S[bps], c_fold, rho, time_limit)
        seconds += res.seconds
        if not res:
            return None, {"seconds": seconds, "rows": len(rows_i), "status": res.status, "rounds": rounds}
        d = res.x[: len(rho)]
        z = b + sys.change(d).ravel()
        where = np.searchsorted(P, z)
        out_lo = kept & (where < lo)
        out_hi = kept & (where > hi + 1)
        if not (out_lo.any() or out_hi.any()):
            break
        lo = np.where(out_lo, where, lo)
        hi = np.where(out_hi, where - 1, hi)
    return d, {"seconds": seconds, "rows": len(rows_i), "status": "optimal", "rounds": rounds}


def _pairs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flatten the modelled breakpoint ranges into (row, breakpoint) pairs."""
    count = np.maximum(hi - lo + 1, 0)
    rows_i = np.repeat(np.arange(len(lo)), count)
    offset = np.arange(len(rows_i)) - np.repeat(np.cumsum(count) - count, count)
    return rows_i, lo[rows_i] + offset


def _lp(A: np.ndarray, beta: np.ndarray, jump: np.ndarray, c_fold: np.ndarray, rho: np.ndarray, time_limit):
    """min c_fold . d + sum_q jump_q max(A_q d + beta_q, 0) over |d| <= rho, in the dual form
    (its rows are the n camera parameters, so HiGHS's basis stays tiny).

    Dual: min -beta . y + rho . (u+ + u-)  s.t.  A^T y - u+ + u- = -c_fold,  0 <= y <= jump.
    The step d is the row duals: where 0 < y_q < jump_q, stationarity gives A_q d + beta_q = 0,
    the row sitting on its breakpoint.
    """
    k, n = A.shape
    M = sp.hstack([sp.csc_matrix(A.T), -sp.identity(n, format="csc"), sp.identity(n, format="csc")]).tocsc()
    cost = np.r_[-beta, rho, rho]
    lo = np.zeros(k + 2 * n)
    hi = np.r_[jump, np.full(2 * n, np.inf)]
    res = solve_lp(cost, M, -c_fold, -c_fold, lo, hi, time_limit=time_limit, solver="simplex")
    if res and res.row_duals is not None:
        return type(res)(x=res.row_duals.copy(), status=res.status, objective=res.objective, seconds=res.seconds, iterations=res.iterations, message=res.message)
    return res
