"""The LP refinement (``--method lp``): sequential linear programming over the camera poses.

Each iteration linearises the pixel reprojection residuals of :class:`calib.wandmodel.WandModel`
about the current state, eliminates every wand frame's 5 parameters per frame (points are
independent once the cameras are known; calib/reduced.py), and solves one LP with HiGHS for the
step ``d`` of all free cameras (3 rotation increments and 3 translations each) inside a trust
region (calib/lpstep.py):

    minimise  sum_i rho(a_i . d + b_i)   subject to  |d_j| <= radius_j,

where ``rho`` is a convex piecewise-linear loss, so this is an LP. Plain least absolute error
(``rho = |z|``) is robust but only 64% efficient on Gaussian noise (1.25x the error of least
squares); ``rho`` here is the 3-breakpoint piecewise-linear M-estimator loss of greatest
Gaussian efficiency (96.5%, calib/robustloss.py) in units of a robust scale ``s`` of the
residuals. Rows further out than ``REJECT_SIGMAS * s`` are left out of the step (a redescending
M-estimator that ignores gross outliers).

The LP stays small and exact. ``rho`` is the maximum of its linear pieces, so replacing it, row
by row, by the maximum of only the pieces near the row's current residual gives a lower bound of
the objective that is exact wherever each row stays among its modelled pieces. Most rows keep
one piece (a linear term, folded into one cost vector); only rows near a breakpoint enter the LP
with one auxiliary variable per breakpoint. If the LP's optimum keeps every row among its
modelled pieces, it is the optimum of the full LP (it attains a lower bound); otherwise the rows
that left are given the breakpoints they crossed and the LP is solved again.

The LP's size grows with the rows it must model, and each reduced row touches every camera of
its frame, so LP steps far from the optimum cost ~cameras^2.3. Steps there are IRLS steps
instead (iteratively reweighted least squares on the same convex loss, one reduced normal
matrix each), and the LP runs only where IRLS has nearly converged, written about the IRLS
point, where it certifies (and lands on) the exact optimum of the piecewise-linear loss with a
small working set. Far from the optimum a first phase runs plain least absolute error on a
subset of frames. The design and the measurements behind each choice:
docs/decisions/0004-lp-method.md.
"""

from __future__ import annotations

import time

import numpy as np

from calib.lpstep import GUARD_SE, solve_step
from calib.reduced import ReducedSystem, apply_t, outer, robust_scale, sum_by
from calib.robustloss import EFFICIENT, L1, irls_weights
from calib.wandmodel import CAM_PARAMS, FRAME_PARAMS, WandModel, WandProblem

ROT_RADIUS = 0.02  # initial trust region: radians per rotation increment
T_RADIUS = 0.05  # and metres per translation component
MAX_ITER = 40
STEP_TOL = 2e-7  # stop when no camera parameter moves by more than this (rad or m)
# stop when the LP promises less gain than this per camera parameter: the loss is ~z^2/2 in
# robust sigmas near its minimum, so a step of 0.1 standard error gains ~0.005 per parameter
CONVERGED_GAIN = 0.005
# Frames of the first phase: few enough that its LPs stay small, enough that the phase on all
# frames then needs one step. 150 ran 13-17% faster than 300 at 8 x 2000 and 16 x 3000, clean
# and with 8% outliers, with the same errors (decision 0004).
SUBSET_FRAMES = 150
SUBSET_ONLY_ABOVE = 4  # the first phase pays off only on captures this many times the subset
REFIT_STEPS = 1  # Gauss-Newton steps that fit every frame to the first phase's cameras (the
# predictor's step moves the frames too)
SCALE_REBUILD = 0.05  # a robust scale that moved less than this keeps the system built with the old one

CONVERGED_SE = 0.05  # stop when a step moves every parameter by less than this many standard errors
MODEL_EXACT = 0.02  # |actual / predicted gain - 1| below which the linearised model was exact
SHORT_STEP_SE = 5.0  # steps shorter than this many standard errors keep the linearisation exact
# IRLS (decision 0004, third session; measured at 16 and 32 x 2000, 1 deg / 3 cm start, 8% outliers)
MAX_IRLS = 8  # inner IRLS steps on one linearisation
IRLS_DONE_SE = 0.1  # inner steps stop when one moves every parameter by less than this many standard errors
MAX_RELINEARISE = 6  # IRLS moves (each relinearised) before the LP takes over
# a move shorter than this many standard errors ends IRLS: the linearisation then changes the
# IRLS point by far less than the LP's guard (a 7 SE move left 2.6k LP pairs, as many as a 0.2 SE
# one, and saved a normal matrix and a relinearisation: 3.8 -> 2.8 s at 32 x 2000)
RELINEARISE_SE = 20.0
IRLS_GUARD_SE = 0.25  # the guard of an LP written about an IRLS point (IRLS stalls ~0.06 SE from the optimum)
# a row this many sigmas from a breakpoint at the IRLS point starts in the LP: 0.01 gave 8.4k
# pairs (1.4 s) at 32 x 2000 with outliers, 0.003 2.6k (0.6-0.9 s), 0.001 2.8-3.9k after more rounds
IRLS_NEAR_BREAK = 0.003
# the first phase's L1 optimum only starts the second phase: IRLS near it is enough, and its
# certifying LPs took 1.0-1.4 s of the 32 x 2000 time (the second phase's robust scale moved 1e-4)
CERTIFY_FIRST_PHASE = False
SCHEMES = ("irls", "lp")  # IRLS steps then certifying LPs (default); LP steps only (the scheme before, decision 0004)


def refine_lp(
    model: WandModel,
    x0: np.ndarray | None = None,
    progress=None,
    max_iter: int = MAX_ITER,
    time_limit: float | None = None,
    subset_frames: int = SUBSET_FRAMES,
    scheme: str = "irls",
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
        scheme: "irls" (IRLS steps, then LP steps that certify the optimum) or "lp" (LP steps
            only, the scheme before; the same estimator, kept to check the other against).

    Returns:
        (x, info) with info: iterations, seconds, lp_seconds, lp_rows_mean, scale, and status:
        "converged", "iteration_limit", "time_limit" (an LP hit ``time_limit``: x is the best
        state reached before it) or "lp_<status>" (HiGHS failed; x likewise); irls_steps.
    """
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, not {scheme!r}")
    start = time.perf_counter()
    x = model.x0() if x0 is None else x0.copy()
    info_sub = None
    F = model.p.n_frames
    if subset_frames and F > SUBSET_ONLY_ABOVE * subset_frames:
        keep = np.unique(np.linspace(0, F - 1, subset_frames).round().astype(int))
        sub, sub_x = _frame_subset(model, x, keep)
        sub_x, info_sub = _slp(sub, sub_x, progress, max_iter, time_limit, "first phase, frame subset", L1, scheme,
                               certify=CERTIFY_FIRST_PHASE)
        x[: model.frame_col0] = sub_x[: model.frame_col0]
        x = _refit_frames(model, x)
    if info_sub is not None and info_sub["status"] != "converged":
        info = dict(info_sub, iterations=0, lp_seconds=0.0)  # the first phase's best state stands
    else:
        x, info = _slp(model, x, progress, max_iter, time_limit, "all frames", EFFICIENT, scheme)
    if info_sub is not None:
        info["iterations"] += info_sub["iterations"]
        info["lp_seconds"] += info_sub["lp_seconds"]
        info["uncertified_steps"] += info_sub["uncertified_steps"]
        info["irls_steps"] += info_sub["irls_steps"]
        info["lp_steps"] = info_sub["lp_steps"] + info["lp_steps"]
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
        H = sum_by(model, "frame", outer(F, F)).reshape(-1, FRAME_PARAMS, FRAME_PARAMS)
        g = sum_by(model, "frame", apply_t(F, r))
        x[model.frame_col0 :] -= np.linalg.solve(H + 1e-9 * np.eye(FRAME_PARAMS), g[:, :, None])[:, :, 0].ravel()
    return x


def _slp(model: WandModel, x: np.ndarray, progress, max_iter: int, time_limit, phase: str, loss,
         scheme: str = "irls", certify: bool = True):
    """One phase (one loss, one robust scale): LP steps, after IRLS steps with ``scheme="irls"``
    (then LP steps only with ``certify``)."""
    n_free = model.frame_col0 // CAM_PARAMS
    radius = np.array([ROT_RADIUS, T_RADIUS])
    lp_seconds, lp_rows, lp_log, status, uncertified = 0.0, [], [], "iteration_limit", 0
    state = start = ReducedSystem(model, x)
    # a Gauss-Newton step first, kept only if it lowers the LP's own objective: it brings most
    # residuals near where the LP will put them, so the LP crosses few breakpoints
    trial = ReducedSystem(model, state.apply(state.gauss_newton_step()), state.scale)
    if trial.cost(state.scale, loss) < state.cost(state.scale, loss):
        # the phase's robust scale is taken here; rebuild only if it moved
        scale = robust_scale(trial.r)
        state = trial if abs(scale / state.scale - 1) < SCALE_REBUILD else trial.rescaled(scale)
    irls_steps, se_phase = 0, None
    if scheme == "irls":
        # for IRLS's stop and the LP's guard: the start's, rescaled, is near enough for both
        se_phase = start.standard_errors() * state.scale / start.scale
        state, irls_steps = _irls(model, state, loss, np.tile(np.repeat(radius, 3), n_free), se_phase, progress, phase)
    it = 0
    if scheme == "irls" and not certify:
        max_iter, status = 0, "converged"
    for it in range(1, max_iter + 1):
        rho = np.tile(np.repeat(radius, 3), n_free)
        if scheme == "irls":
            # written about the IRLS point (the state): only rows near a breakpoint there enter
            d, lp_info = solve_step(state, rho, time_limit, loss, IRLS_GUARD_SE, d_pred=np.zeros(len(rho)),
                                    near=IRLS_NEAR_BREAK, se=se_phase)
        else:
            d, lp_info = solve_step(state, rho, time_limit, loss, GUARD_SE)
        lp_seconds += lp_info["seconds"]
        lp_rows.append(lp_info["rows"])
        lp_log.append((lp_info["rows"], lp_info["rounds"], round(lp_info["seconds"], 3)))
        uncertified += lp_info["status"] == "uncertified"
        if d is None:
            status = "time_limit" if lp_info["status"] == "time_limit" else f"lp_{lp_info['status']}"
            break
        cost = state.cost(state.scale, loss)
        predicted = state.model_cost(d, loss)
        if cost - predicted <= CONVERGED_GAIN * len(d) or np.max(np.abs(d)) < STEP_TOL:
            # the LP's optimum is within a sliver of a standard error of where we are: land on
            # it (the estimate is the LP's) unless that costs more than the sliver, and stop
            trial = ReducedSystem(model, state.apply(d), state.scale)
            if trial.cost(state.scale, loss) <= cost + CONVERGED_GAIN * len(d):
                state = trial
            status = "converged"
            break
        trial = ReducedSystem(model, state.apply(d), state.scale)
        new_cost = trial.cost(state.scale, loss)
        ratio = (cost - new_cost) / (cost - predicted)
        step = np.abs(d).reshape(-1, 2, 3).max(axis=(0, 2))
        if new_cost < cost:
            se = state.standard_errors() if se_phase is None else se_phase
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
        "irls_steps": irls_steps,
        "lp_steps": lp_log,
    }


def _irls(model: WandModel, state: ReducedSystem, loss, rho: np.ndarray, se: np.ndarray, progress, phase: str):
    """IRLS on the phase's loss and scale, near to the optimum of the piecewise-linear loss.

    Each inner step solves the reduced rows' weighted normal equations with weights
    |psi(z)| / |z| (calib/robustloss.py) on one linearisation, the frames still eliminated as in
    the LP, so its fixed point is a stationary point of the same loss: near its optimum, not on it
    (that needs rows exactly on breakpoints), which the LP then certifies. Inner steps stop when
    one moves every camera parameter by less than ``IRLS_DONE_SE`` standard errors; the state then
    moves to the IRLS point and is linearised again, until the whole move is shorter than
    ``RELINEARISE_SE`` standard errors (or raises the merit). Steps stay in the trust region ``rho``.

    Returns:
        (state at the last accepted move, inner steps taken).
    """
    steps = 0
    for _ in range(MAX_RELINEARISE):
        d = np.zeros_like(rho)
        current = state.model_cost(d, loss)
        for _ in range(MAX_IRLS):
            z = (state.b + state.change(d)) / state.scale
            H, g = state.normal_equations(irls_weights(z, state.kept, loss))
            # g is A^T W b at d = 0: the weighted least-squares point of these weights
            new = np.clip(-np.linalg.solve(H + 1e-9 * np.trace(H) / len(H) * np.eye(len(H)), g), -rho, rho)
            steps += 1
            for _ in range(3):  # IRLS need not descend on a piecewise-linear loss: halve back if not
                cost = state.model_cost(new, loss)
                if cost < current:
                    break
                new = 0.5 * (d + new)
            if cost >= current:
                break
            step, d, current = new - d, new, cost
            if np.all(np.abs(step) < IRLS_DONE_SE * se):
                break
        trial = ReducedSystem(model, state.apply(d), state.scale)
        if trial.cost(state.scale, loss) >= state.cost(state.scale, loss):
            break
        state = trial
        if progress is not None:
            progress({"stage": "refine", "iteration": steps, "cost": current, "message": f"IRLS step {steps} ({phase})"})
        if np.all(np.abs(d) < RELINEARISE_SE * se):
            break
    return state, steps
