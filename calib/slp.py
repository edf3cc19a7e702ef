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

Far from the optimum a first phase runs plain least absolute error on a subset of frames; a
Gauss-Newton predictor and a guard box keep each LP's working set small. The design and the
measurements behind each choice: docs/decisions/0004-lp-method.md.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from calib.lp import IncrementalLp
from calib.wandmodel import CAM_PARAMS, FRAME_PARAMS, WandModel, WandProblem

# The loss: breakpoints (robust sigmas) and psi on each interval, from 0 outwards; found by
# maximising Gaussian efficiency over 3-breakpoint convex piecewise-linear losses (decision 0004)
BREAKS = np.array([0.501, 1.05, 1.748])
SLOPES = np.array([0.188, 0.58, 1.031, 1.651])
REJECT_SIGMAS = 6.0  # a residual this many robust sigmas out is a gross outlier, not noise
ROT_RADIUS = 0.02  # initial trust region: radians per rotation increment
T_RADIUS = 0.05  # and metres per translation component
MAX_ITER = 40
STEP_TOL = 2e-7  # stop when no camera parameter moves by more than this (rad or m)
# stop when the LP promises less gain than this per camera parameter: the loss is ~z^2/2 in
# robust sigmas near its minimum, so a step of 0.1 standard error gains ~0.005 per parameter
CONVERGED_GAIN = 0.005
NEAR_BREAK = 0.01  # a row within this many sigmas of a breakpoint, at the predicted step, starts in the LP
GUARD_SE = 1.0  # the first solves stay within this many standard errors of the predicted step
FIRST_STRATEGY = 1  # HiGHS dual simplex for a working set's first solve
RESOLVE_STRATEGY = 1  # dual again: primal simplex from the last basis took 4x the iterations (measured at 16 x 3000)
GUARD_GROWTH = 4.0  # and the guard widens this much where the solution touches it
# Frames of the first phase: few enough that its LPs stay small, enough that the phase on all
# frames then needs one step. 150 ran 13-17% faster than 300 at 8 x 2000 and 16 x 3000, clean
# and with 8% outliers, with the same errors (decision 0004).
SUBSET_FRAMES = 150
SUBSET_ONLY_ABOVE = 4  # the first phase pays off only on captures this many times the subset
REFIT_STEPS = 1  # Gauss-Newton steps that fit every frame to the first phase's cameras (the
# predictor's step moves the frames too)
SCALE_REBUILD = 0.05  # a robust scale that moved less than this keeps the system built with the old one
MAX_ACTIVE_ROUNDS = 12  # re-solves with widened rows before a step is taken as it is

CONVERGED_SE = 0.05  # stop when a step moves every parameter by less than this many standard errors
MODEL_EXACT = 0.02  # |actual / predicted gain - 1| below which the linearised model was exact
SHORT_STEP_SE = 5.0  # steps shorter than this many standard errors keep the linearisation exact


def _signed(breaks: np.ndarray, slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed breakpoints and the slope of each interval between them, left to right."""
    return np.r_[-breaks[::-1], 0.0, breaks], np.r_[-slopes[::-1], slopes]


EFFICIENT = _signed(BREAKS, SLOPES)
L1 = _signed(np.zeros(0), np.ones(1))  # least absolute error: the first phase only needs a robust direction


def _loss(z: np.ndarray, loss) -> np.ndarray:
    """A convex piecewise-linear loss, given as (signed breakpoints with 0 in the middle,
    slopes of the intervals between them), of residuals z in robust sigmas; 0 at z = 0."""
    P, S = loss
    mid = len(P) // 2
    out = S[mid + 1] * np.maximum(z, 0.0) + S[mid] * np.minimum(z, 0.0)
    for q in range(len(P)):
        if q > mid:
            out += (S[q + 1] - S[q]) * np.maximum(z - P[q], 0.0)
        elif q < mid:
            out += (S[q + 1] - S[q]) * np.maximum(P[q] - z, 0.0)
    return out


def refine_lp(
    model: WandModel,
    x0: np.ndarray | None = None,
    progress=None,
    max_iter: int = MAX_ITER,
    time_limit: float | None = None,
    subset_frames: int = SUBSET_FRAMES,
):
    """Refine all free cameras and wand frames by sequential LP.

    The first steps, far from the optimum, move many residuals across many breakpoints; they
    run on ``subset_frames`` frames spread evenly over the capture (the wand path sweeps the
    volume, so an even spread covers it). The cameras found there start the steps on all frames.

    Args:
        model: the wand problem about its start state.
        x0: (n_params,) start, ``model.x0()`` when None.
        progress: optional callable(dict).
        time_limit: seconds for each LP solve.
        subset_frames: frames of the first phase (0: none).

    Returns:
        (x, info) with info: iterations, seconds, lp_seconds, lp_rows_mean, scale, and status:
        "converged", "iteration_limit", "time_limit" (an LP hit ``time_limit``: x is the best
        state reached before it) or "lp_<status>" (HiGHS failed; x likewise).
    """
    start = time.perf_counter()
    x = model.x0() if x0 is None else x0.copy()
    info_sub = None
    F = model.p.n_frames
    if subset_frames and F > SUBSET_ONLY_ABOVE * subset_frames:
        keep = np.unique(np.linspace(0, F - 1, subset_frames).round().astype(int))
        sub, sub_x = _frame_subset(model, x, keep)
        sub_x, info_sub = _slp(sub, sub_x, progress, max_iter, time_limit, "first phase, frame subset", L1)
        x[: model.frame_col0] = sub_x[: model.frame_col0]
        x = _refit_frames(model, x)
    if info_sub is not None and info_sub["status"] != "converged":
        info = dict(info_sub, iterations=0, lp_seconds=0.0)  # the first phase's best state stands
    else:
        x, info = _slp(model, x, progress, max_iter, time_limit, "all frames", EFFICIENT)
    if info_sub is not None:
        info["iterations"] += info_sub["iterations"]
        info["lp_seconds"] += info_sub["lp_seconds"]
        info["uncertified_steps"] += info_sub["uncertified_steps"]
        info["subset"] = {"frames": int(len(keep)), "iterations": info_sub["iterations"]}
    info["seconds"] = time.perf_counter() - start
    return x, info


def _frame_subset(model: WandModel, x: np.ndarray, keep: np.ndarray):
    """A WandModel on frames ``keep`` (sorted) with the same cameras, and its state from x."""
    p = model.p
    new_index = np.full(p.n_frames, -1)
    new_index[keep] = np.arange(len(keep))
    sel = new_index[p.frame] >= 0
    sub_p = WandProblem(p.camera[sel], new_index[p.frame[sel]], p.end[sel], p.xy[sel], p.focal, p.length, len(keep))
    sub = WandModel(sub_p, model.R0, model.t0, model.wand(x)[keep], model.fixed)
    sub_x = sub.x0()
    sub_x[: sub.frame_col0] = x[: model.frame_col0]
    return sub, sub_x


def _refit_frames(model: WandModel, x: np.ndarray, steps: int = REFIT_STEPS) -> np.ndarray:
    """Gauss-Newton steps on every frame's 5 parameters with the cameras held."""
    x = x.copy()
    for _ in range(steps):
        r = model.residuals(x).reshape(-1, 2)
        F = model.jacobian_blocks(x)[0][:, :, CAM_PARAMS:]
        H = _sum_by(model, "frame", _outer(F, F)).reshape(-1, FRAME_PARAMS, FRAME_PARAMS)
        g = _sum_by(model, "frame", _apply_t(F, r))
        x[model.frame_col0 :] -= np.linalg.solve(H + 1e-9 * np.eye(FRAME_PARAMS), g[:, :, None])[:, :, 0].ravel()
    return x


def _slp(model: WandModel, x: np.ndarray, progress, max_iter: int, time_limit, phase: str, loss):
    n_free = model.frame_col0 // CAM_PARAMS
    radius = np.array([ROT_RADIUS, T_RADIUS])
    lp_seconds, lp_rows, status, uncertified = 0.0, [], "iteration_limit", 0
    state = _ReducedSystem(model, x)
    # a Gauss-Newton step first, kept only if it lowers the LP's own objective: it brings most
    # residuals near where the LP will put them, so the LP crosses few breakpoints
    trial = _ReducedSystem(model, state.apply(state.gauss_newton_step()), state.scale)
    if trial.cost(state.scale, loss) < state.cost(state.scale, loss):
        # the phase's robust scale is taken here; rebuild only if it moved
        scale = _robust_scale(trial.r)
        state = trial if abs(scale / state.scale - 1) < SCALE_REBUILD else _ReducedSystem(model, trial.x, scale)
    it = 0
    for it in range(1, max_iter + 1):
        rho = np.tile(np.repeat(radius, 3), n_free)
        d, lp_info = _solve_step(state, rho, time_limit, loss, GUARD_SE)
        lp_seconds += lp_info["seconds"]
        lp_rows.append(lp_info["rows"])
        uncertified += lp_info["status"] == "uncertified"
        if d is None:
            status = "time_limit" if lp_info["status"] == "time_limit" else f"lp_{lp_info['status']}"
            break
        cost = state.cost(state.scale, loss)
        predicted = state.model_cost(d, loss)
        if cost - predicted <= CONVERGED_GAIN * len(d) or np.max(np.abs(d)) < STEP_TOL:
            # the LP's optimum is within a sliver of a standard error of where we are: land on
            # it (the estimate is the LP's) unless that costs more than the sliver, and stop
            trial = _ReducedSystem(model, state.apply(d), state.scale)
            if trial.cost(state.scale, loss) <= cost + CONVERGED_GAIN * len(d):
                state = trial
            status = "converged"
            break
        trial = _ReducedSystem(model, state.apply(d), state.scale)
        new_cost = trial.cost(state.scale, loss)
        ratio = (cost - new_cost) / (cost - predicted)
        step = np.abs(d).reshape(-1, 2, 3).max(axis=(0, 2))
        if new_cost < cost:
            se = state.standard_errors()
            small = np.all(np.abs(d) < CONVERGED_SE * se)
            # the linear model predicted this step's gain exactly and the step was short: the LP
            # has landed on the optimum of an accurate model, so another step would only confirm
            exact = abs(ratio - 1.0) < MODEL_EXACT and np.all(np.abs(d) < SHORT_STEP_SE * se)
            state = trial  # the robust scale stays fixed within a phase: one M-estimator, one merit
            if small or exact:
                status = "converged"
                break
            if ratio > 0.75 and np.any(step > 0.5 * radius):
                radius = radius * 2.0
        else:
            radius = np.maximum(0.25 * step, 1e-9)
        if progress is not None:
            progress({
                "stage": "refine", "iteration": it, "cost": min(cost, new_cost),
                "message": f"LP step {it} ({phase}): {lp_info['rows']} LP rows, {lp_info['rounds']} solves",
            })
    return state.x, {
        "iterations": it,
        "lp_seconds": lp_seconds,
        "lp_rows_mean": float(np.mean(lp_rows)) if lp_rows else 0.0,
        "status": status,
        "robust_scale_px": state.scale,
        "uncertified_steps": uncertified,
    }


def _robust_scale(r: np.ndarray) -> float:
    """Per-axis noise from (M, 2) residuals: the median radius of a 2D Gaussian is sigma sqrt(2 ln 2)."""
    return max(float(np.median(np.linalg.norm(r, axis=1))) / np.sqrt(2 * np.log(2)), 1e-9)


def _outer(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(M, k, i), (M, k, j) -> (M, i, j): sum_k A[:, k, i] B[:, k, j] (matmul is ~8x einsum here)."""
    return np.matmul(A.swapaxes(1, 2), B)


def _apply(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, k, j), (M, j) -> (M, k)."""
    return np.matmul(A, v[:, :, None])[:, :, 0]


def _apply_t(A: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(M, k, i), (M, k) -> (M, i): A^T v per observation."""
    return np.matmul(A.swapaxes(1, 2), v[:, :, None])[:, :, 0]


def _incidence(model: WandModel) -> dict:
    """Sparse sums over observations by frame, camera and (frame, camera), cached on the model
    (np.add.at is several times slower at these sizes)."""
    cache = getattr(model, "_slp_incidence", None)
    if cache is None:
        p = model.p
        M = len(p.camera)
        ones = np.ones(M)
        obs = np.arange(M)
        cache = {
            "frame": sp.csr_matrix((ones, (p.frame, obs)), shape=(p.n_frames, M)),
            "camera": sp.csr_matrix((ones, (p.camera, obs)), shape=(p.n_cams, M)),
            "frame_camera": sp.csr_matrix((ones, (p.frame * p.n_cams + p.camera, obs)), shape=(p.n_frames * p.n_cams, M)),
        }
        model._slp_incidence = cache
    return cache


def _sum_by(model: WandModel, key: str, values: np.ndarray) -> np.ndarray:
    """Sum (M, ...) per-observation values by frame, camera or (frame, camera)."""
    M = values.shape[0]
    out = _incidence(model)[key] @ values.reshape(M, -1)
    return np.asarray(out)


class _ReducedSystem:
    """Residuals with each frame's parameters eliminated, at one state of a WandModel."""

    def __init__(self, model: WandModel, x: np.ndarray, scale: float | None = None):
        self.model, self.x = model, x
        self.r = model.residuals(x).reshape(-1, 2)
        blocks, cols = model.jacobian_blocks(x)
        self.own = cols[:, 0] >= 0  # the observation's camera is free
        self.cam_cols = cols[:, :CAM_PARAMS]
        self.C = blocks[:, :, :CAM_PARAMS]  # (M, 2, 6)
        self.F = blocks[:, :, CAM_PARAMS:]  # (M, 2, 5)
        self.scale = _robust_scale(self.r) if scale is None else scale
        self.kept = np.abs(self.r) <= REJECT_SIGMAS * self.scale  # (M, 2)
        self._eliminate()

    def cost(self, scale: float, loss) -> float:
        """The merit of these cameras: the loss (capped at the rejection point) of the residuals
        with every frame re-fitted to them. The frames are projected out (variable projection),
        so this is what the LP's model predicts at d = 0."""
        cap = _loss(np.array([REJECT_SIGMAS]), loss)[0]
        return float(np.minimum(_loss(self.b.ravel() / scale, loss), cap).sum())

    def model_cost(self, d: np.ndarray, loss) -> float:
        """The LP's model at step d: kept rows linearised, rejected rows at their cap."""
        cap = _loss(np.array([REJECT_SIGMAS]), loss)[0]
        z = (self.b + self.change(d)).ravel() / self.scale
        return float(np.where(self.kept.ravel(), _loss(z, loss), cap).sum())

    def standard_errors(self) -> np.ndarray:
        """(n_cam_params,) standard errors of the camera parameters from the reduced normal
        equations and the robust scale (valid near the optimum)."""
        S = self._schur()[0]
        return self.scale * np.sqrt(np.maximum(np.diag(np.linalg.inv(S)), 0.0))

    def _eliminate(self) -> None:
        """Per-frame elimination: K (M,2,5), G (F,N,5,6), g (F,5), Hinv (F,5,5), b (M,2)."""
        p = self.model.p
        # plain least squares on the kept rows: weights that moved with the residuals would make
        # the frames' fit an iteration of its own, and the projected merit would drift under it
        Wt = self.kept.astype(float)
        self.Wt = Wt
        FW = self.F * Wt[:, :, None]
        m = self.model
        H = _sum_by(m, "frame", _outer(FW, self.F)).reshape(-1, FRAME_PARAMS, FRAME_PARAMS)
        g = _sum_by(m, "frame", _apply_t(FW, self.r))
        Hinv = np.linalg.inv(H + 1e-9 * np.eye(FRAME_PARAMS))
        G = _sum_by(m, "frame_camera", _outer(FW, self.C)).reshape(p.n_frames, p.n_cams, FRAME_PARAMS, CAM_PARAMS)
        self.K = np.matmul(self.F, Hinv[p.frame])
        self.Hinv, self.G, self.g = Hinv, G, g
        self.b = self.r - _apply(self.K, g[p.frame])

    def gauss_newton_step(self) -> np.ndarray:
        """The weighted least-squares step of the reduced system, (n_cam_params,)."""
        S, rhs = self._schur()
        return -np.linalg.solve(S + 1e-9 * np.trace(S) / len(S) * np.eye(len(S)), rhs)

    def _schur(self) -> tuple[np.ndarray, np.ndarray]:
        """Reduced normal matrix and gradient of the free cameras: the Schur complement of the
        frames, with the elimination's weights. Cached."""
        if getattr(self, "_schur_cache", None) is not None:
            return self._schur_cache
        p, m = self.model.p, self.model
        Wc = self.C * self.Wt[:, :, None]
        CC = _sum_by(m, "camera", _outer(Wc, self.C)).reshape(p.n_cams, CAM_PARAMS, CAM_PARAMS)
        Cr = _sum_by(m, "camera", _apply_t(Wc, self.r))
        n = p.n_cams * CAM_PARAMS
        S = np.zeros((n, n))
        idx = np.arange(p.n_cams)
        S.reshape(p.n_cams, CAM_PARAMS, p.n_cams, CAM_PARAMS)[idx, :, idx, :] = CC
        Gf = self.G.transpose(0, 2, 1, 3).reshape(p.n_frames, FRAME_PARAMS, n)  # (F, 5, N*6)
        HG = np.einsum("fij,fjc->fic", self.Hinv, Gf)
        S -= np.einsum("fic,fid->cd", Gf, HG)
        rhs = Cr.ravel() - np.einsum("fic,fi->c", Gf, np.einsum("fij,fj->fi", self.Hinv, self.g))
        free = (m.free[:, None] * CAM_PARAMS + np.arange(CAM_PARAMS)).ravel()
        self._schur_cache = (S[np.ix_(free, free)], rhs[free])
        return self._schur_cache

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
        own = _apply(self.C, dc[p.camera]) * self.own[:, None]
        Gd = np.einsum("fnjc,nc->fj", self.G, dc)
        return own - _apply(self.K, Gd[p.frame])

    def folded_cost(self, coef: np.ndarray) -> np.ndarray:
        """sum_i coef_i a_i over all rows, (n_cam_params,), for coef (M, 2)."""
        m = self.model
        cam = np.einsum("mk,mkj->mj", coef, self.C) * self.own[:, None]
        out = _sum_by(m, "camera", cam)
        u = _sum_by(m, "frame", np.einsum("mk,mkj->mj", coef, self.K))
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


def _solve_step(state: _ReducedSystem, rho: np.ndarray, time_limit, loss, guard_se: float | None):
    """The trust-region LP step on an exact working set of (row, breakpoint) pairs.

    Each row keeps the slope of the interval its residual starts in (a linear term, folded into
    one cost vector) and gets a hinge for each modelled breakpoint: ``(z - P)+`` to the right of
    its start, ``(P - z)+`` to the left, weighted by the slope change there, which adds up to the
    loss exactly on the modelled pieces. The working set starts from a prediction ``d_pred``, the
    Gauss-Newton step of the reduced system clipped to the trust region: each row gets the
    breakpoints between its residual now and its predicted residual, and any within
    ``NEAR_BREAK`` of either. So that this small set cannot send the step far off, the solves
    are confined to a guard box of ``guard_se`` standard errors around the prediction, widened
    where the solution touches it. The answer is exact once it lies inside the box and every row
    stays among its modelled pieces; until then rows that left get the breakpoints they crossed.

    The LP is solved in its dual form, where pairs are columns, so every widening only adds
    columns and HiGHS carries on from its last basis:
        min sum_q -s_q beta_q y_q - lo . u+ + hi . u-
        s.t. sum_q s_q A_q y_q - u+ + u- = -c_fold,  0 <= y_q <= jump_q,
    for the primal  min c_fold . d + sum_q jump_q max(s_q (A_q d + beta_q), 0) over lo <= d <= hi,
    with s_q = +1 for right hinges and -1 for left ones. The step d is the row duals: where
    0 < y_q < jump_q, stationarity gives A_q d + beta_q = 0, the row on its breakpoint.
    """
    P, S = loss[0] * state.scale, loss[1]  # breakpoints in pixels, interval slopes
    b = state.b.ravel()
    kept = state.kept.ravel()
    d_pred = np.clip(state.gauss_newton_step(), -rho, rho)
    guard = rho * 2 if guard_se is None else guard_se * state.standard_errors()
    z_pred = b + state.change(d_pred).ravel()
    near = NEAR_BREAK * state.scale
    base = np.searchsorted(P, b)  # the interval each row starts in: P[base - 1] < b <= P[base]
    c_fold = state.folded_cost(np.where(kept, S[base], 0.0).reshape(-1, 2))
    lo = np.where(kept, np.searchsorted(P, np.minimum(b, z_pred) - near), 0)
    hi = np.where(kept, np.searchsorted(P, np.maximum(b, z_pred) + near) - 1, -1)
    n = len(rho)
    lp = IncrementalLp(-c_fold, time_limit)
    eye = sp.identity(n, format="csc")
    lp.add_columns(np.zeros(2 * n), np.zeros(2 * n), np.full(2 * n, np.inf), sp.hstack([-eye, eye]))
    old_lo, old_hi = base, base - 1  # nothing modelled yet
    seconds, d, rounds, total, certified = 0.0, None, 0, 0, False
    for rounds in range(1, MAX_ACTIVE_ROUNDS + 1):
        box_lo = np.maximum(-rho, d_pred - guard)
        box_hi = np.minimum(rho, d_pred + guard)
        lp.set_costs(np.arange(2 * n), np.r_[-box_lo, box_hi])
        # the pairs not modelled before: below the old range and above it
        rows_a, bps_a = _pairs(lo, np.minimum(hi, old_lo - 1))
        rows_b, bps_b = _pairs(np.maximum(lo, old_hi + 1), hi)
        rows_i, bps = np.r_[rows_a, rows_b], np.r_[bps_a, bps_b]
        if len(rows_i):
            side = np.where(bps >= base[rows_i], 1.0, -1.0)  # right hinge, or left hinge
            A = state.rows(rows_i // 2, rows_i % 2) * side[:, None]
            lp.add_columns(-side * (b[rows_i] - P[bps]), np.zeros(len(rows_i)), S[bps + 1] - S[bps], A.T)
            total += len(rows_i)
        res = lp.solve(FIRST_STRATEGY if rounds == 1 else RESOLVE_STRATEGY)
        seconds += res.seconds
        if res.status != "optimal" or res.row_duals is None:
            # a limit hit or a failure: no step is trusted, the caller keeps the best state so far
            return None, {"seconds": seconds, "rows": total, "status": res.status, "rounds": rounds}
        d = res.row_duals.copy()
        z = b + state.change(d).ravel()
        where = np.searchsorted(P, z)
        out_lo = kept & (where < lo)
        out_hi = kept & (where > hi + 1)
        # touching the guard (where it is inside the trust region) means the optimum may lie beyond
        tol = 1e-9 * (np.abs(box_hi - box_lo) + 1e-300)
        pinned = ((d <= box_lo + tol) & (box_lo > -rho)) | ((d >= box_hi - tol) & (box_hi < rho))
        if not (out_lo.any() or out_hi.any() or pinned.any()):
            certified = True
            break
        guard = np.where(pinned, GUARD_GROWTH * guard, guard)
        old_lo, old_hi = lo, hi
        lo = np.where(out_lo, where, lo)
        hi = np.where(out_hi, where - 1, hi)
    # uncertified: the step is the optimum of a working set that some rows still leave; the
    # caller takes it only if it lowers the true merit, like any trust-region step
    return d, {"seconds": seconds, "rows": total, "status": "optimal" if certified else "uncertified", "rounds": rounds}


def _pairs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flatten the modelled breakpoint ranges into (row, breakpoint) pairs."""
    count = np.maximum(hi - lo + 1, 0)
    rows_i = np.repeat(np.arange(len(lo)), count)
    offset = np.arange(len(rows_i)) - np.repeat(np.cumsum(count) - count, count)
    return rows_i, lo[rows_i] + offset
