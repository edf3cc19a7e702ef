"""The LP refinement (``--method lp``): sequential linear programming over the camera poses.

Each iteration linearises the pixel reprojection residuals of :class:`wandcal.calib.solve.wandmodel.WandModel`
about the current state, eliminates every wand frame's 5 parameters per frame (points are
independent once the cameras are known; calib/solve/reduced.py), and solves one LP (an interior-point
method whose basis HiGHS's simplex confirms; calib/solve/backend/ipm.py, calib/solve/backend/highs.py) for the step ``d`` of all
free cameras (3 rotation increments and 3 translations each) inside a trust region
(calib/solve/lpstep.py):

    minimise  sum_i rho(a_i . d + b_i)   subject to  |d_j| <= radius_j,

where ``rho`` is a convex piecewise-linear loss, so this is an LP. Plain least absolute error
(``rho = |z|``) is robust but only 64% efficient on Gaussian noise (1.25x the error of least
squares); ``rho`` here is the 3-breakpoint piecewise-linear M-estimator loss of greatest
Gaussian efficiency (96.5%, calib/solve/robustloss.py) in units of a robust scale ``s`` of the
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
instead (iteratively reweighted least squares on the same convex loss, preconditioned by the
Gauss-Newton Schur complement of the frames), and the LP runs only where IRLS has nearly
converged, written about the IRLS point, where it certifies (and lands on) the exact optimum of
the piecewise-linear loss with a small working set. A phase linearises twice: at its start (a
Gauss-Newton step that also refits the frames) and at the Gauss-Newton point, where IRLS and the
LP both run; the LP's point is judged by its residuals, without linearising there. Far from
the optimum a first phase runs plain least absolute error on a subset of frames. The design and
the measurements behind each choice: docs/decisions/0004-lp-method.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_limits

from wandcal.calib.solve.lpstep import GUARD_SE, solve_step
from wandcal.calib.solve.reduced import ReducedSystem, residual_cost, robust_scale
from wandcal.calib.solve.robustloss import EFFICIENT, L1, REJECT_SIGMAS, irls_weights
from wandcal.calib.solve.uncertainty import PoseCovariance, fitted_sigma
from wandcal.calib.solve.wandmodel import CAM_PARAMS, WandModel, WandProblem

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

CONVERGED_SE = 0.05  # stop when a step moves every parameter by less than this many standard errors
# IRLS (decision 0004, third session; measured at 16 and 32 x 2000, 1 deg / 3 cm start, 8% outliers)
MAX_IRLS = 8  # inner IRLS steps on one linearisation
IRLS_DONE_SE = 0.1  # inner steps stop when one moves every parameter by less than this many standard errors
MAX_RELINEARISE = 6  # IRLS moves (each relinearised) before the LP takes over
# a move shorter than this many standard errors ends IRLS: the linearisation then changes the
# IRLS point by far less than the LP's guard (a 7 SE move left 2.6k LP pairs, as many as a 0.2 SE
# one, and saved a normal matrix and a relinearisation: 3.8 -> 2.8 s at 32 x 2000); and an LP
# step this short lands where its linearisation still holds (IRLS and LP moved 0.5-11 SE from
# the phase's linearisation at 8-32 x 2000, and one more step from there moved < 0.012 SE)
RELINEARISE_SE = 20.0
IRLS_GUARD_SE = 0.25  # the guard of an LP written about an IRLS point (IRLS stalls ~0.1 SE from the optimum)
# a row this many sigmas from a breakpoint at the IRLS point starts in the LP: 0.01 gave 8.4k
# pairs (1.4 s) at 32 x 2000 with outliers, 0.003 2.6k (0.6-0.9 s), 0.001 2.8-3.9k after more rounds.
# Since a round after the first also models the breakpoints near its point (lpstep.WIDEN_NEAR),
# 0.002 takes 2 rounds on six 32-128 x 3000 captures, with 27-31% fewer pairs than 0.003 (11.0-11.3k
# at 128 cameras); 0.0015 took 3 rounds on two of them, 0.001 on four (decision 0029)
IRLS_NEAR_BREAK = 0.002
# the first phase's L1 optimum only starts the second phase: IRLS near it is enough, and its
# certifying LPs took 1.0-1.4 s of the 32 x 2000 time (the second phase's robust scale moved 1e-4)
CERTIFY_FIRST_PHASE = False
POINT_PARAMS = 3  # a point track's frame fixes its midpoint alone (its direction is free: calib/refine.with_tracks)
SCHEMES = ("irls", "lp")  # IRLS steps then certifying LPs (default); LP steps only (the scheme before, decision 0004)


def refine_lp(
    model: WandModel,
    x0: np.ndarray | None = None,
    progress=None,
    max_iter: int = MAX_ITER,
    time_limit: float | None = None,
    subset_frames: int = SUBSET_FRAMES,
    scheme: str = "irls",
    certify: bool = True,
    warm: bool = False,
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
        certify: with ``scheme="irls"``, False stops at the last phase's IRLS point, near the
            optimum but not on it, without the LP that certifies it (the first phase's, and a
            solve that only tells outliers; calib/run/refine/ now uses a robust ba for that,
            decision 0024).
        warm: x0 is the solution of nearly the same problem (an outlier pass, calib/run/refine/): no
            first phase on a subset, and the phase linearises once at its start (no Gauss-Newton
            step to refit frames fitted to other cameras).

    Returns:
        (x, info) with info: iterations, seconds, lp_seconds, lp_rows_mean, scale, and status:
        "converged", "iteration_limit", "time_limit" (an LP hit ``time_limit``: x is the best
        state reached before it) or "lp_<status>" (HiGHS failed; x likewise); irls_steps.
    """
    # the dense products are small (a 186 x 186 Cholesky at 32 cameras): a second BLAS thread costs
    # more in hand-offs than it gains, as in calib/solve/ba/adjust.py (32 x 2000, bench_peers's scene: the LP solves
    # took 1.6-2.0 s with two BLAS threads, 0.5 s with one)
    with threadpool_limits(limits=1, user_api="blas"):
        x, info, _ = _refine_lp(model, x0, progress, max_iter, time_limit, subset_frames, scheme, certify, warm)
    return x, info


def refine_lp_covariance(model: WandModel, n_wand_frames: int, progress=None, time_limit: float | None = None,
                         warm: bool = False) -> tuple[np.ndarray, dict, PoseCovariance]:
    """:func:`refine_lp` to its certified optimum, and the pose covariance there (what
    calib/run/refine/ reports for ``lp``): from the reduced system the last step was taken on, whose
    Schur complement the phase has already formed for its standard errors, so it costs no other
    linearisation (at 128 x 3000 a separate one, ``ba``'s information matrix, took 1.3-1.6 s CPU;
    decision 0027). The first ``n_wand_frames`` frames are the wand's (the rest point tracks).

    Returns:
        (x, info, covariance).
    """
    with threadpool_limits(limits=1, user_api="blas"):
        x, info, state = _refine_lp(model, None, progress, MAX_ITER, time_limit, SUBSET_FRAMES, "irls", True, warm)
        if state is None or state.model is not model:  # the first phase's state stood: linearise here
            state = ReducedSystem(model, x)
        # sigma as ba's: the median 2D residual at the solution, over n - p degrees of freedom
        n_par = model.frame_col0 + model.frame_params * n_wand_frames + POINT_PARAMS * (model.p.n_frames - n_wand_frames)
        sigma = fitted_sigma(np.linalg.norm(model.residuals(x).reshape(-1, 2), axis=1), n_par)
        return x, info, state.pose_covariance(sigma, n_wand_frames)


def _refine_lp(model, x0, progress, max_iter, time_limit, subset_frames, scheme, certify=True, warm=False):
    if scheme not in SCHEMES:
        raise ValueError(f"scheme must be one of {SCHEMES}, not {scheme!r}")
    start = time.perf_counter()
    x = model.x0() if x0 is None else x0.copy()
    info_sub, state = None, None
    F = model.p.n_frames
    if subset_frames and not warm and SUBSET_ONLY_ABOVE * subset_frames < F:  # a warm start needs no first phase
        keep = np.unique(np.linspace(0, F - 1, subset_frames).round().astype(int))
        sub, sub_x = _frame_subset(model, x, keep)
        sub_x, info_sub, _ = _slp(sub, sub_x, progress, max_iter, time_limit, "first phase, frame subset", L1, scheme,
                                  certify=CERTIFY_FIRST_PHASE)
        x[: model.frame_col0] = sub_x[: model.frame_col0]  # the frames follow in the phase's first step
    if info_sub is not None and info_sub["status"] != "converged":
        info = dict(info_sub, iterations=0, lp_seconds=0.0)  # the first phase's best state stands
    else:
        x, info, state = _slp(model, x, progress, max_iter, time_limit, "all frames", EFFICIENT, scheme, certify=certify,
                              warm=warm)
    if info_sub is not None:
        info["iterations"] += info_sub["iterations"]
        info["lp_seconds"] += info_sub["lp_seconds"]
        info["uncertified_steps"] += info_sub["uncertified_steps"]
        info["irls_steps"] += info_sub["irls_steps"]
        info["lp_steps"] = info_sub["lp_steps"] + info["lp_steps"]
        info["subset"] = {"frames": int(len(keep)), "iterations": info_sub["iterations"]}
    info["seconds"] = time.perf_counter() - start
    return x, info, state


def _frame_subset(model: WandModel, x: np.ndarray, keep: np.ndarray):
    """A WandModel on frames ``keep`` (sorted) with the same cameras, and its state from x."""
    p = model.p
    new_index = np.full(p.n_frames, -1)
    new_index[keep] = np.arange(len(keep))
    sel = new_index[p.frame] >= 0
    sub_p = WandProblem(p.camera[sel], new_index[p.frame[sel]], p.end[sel], p.xy[sel], p.focal, p.length, len(keep),
                        None if p.along is None else p.along[sel])
    sub = WandModel(sub_p, model.R0, model.t0, model.unit_frames(x)[keep], model.fixed)
    sub_x = sub.x0()
    sub_x[: sub.frame_col0] = x[: model.frame_col0]
    return sub, sub_x


def _phase_start(model: WandModel, x: np.ndarray, loss, warm: bool = False) -> tuple[ReducedSystem, ReducedSystem]:
    """The linearisation a phase starts from, and the one its steps are taken on.

    One Gauss-Newton step of the reduced system moves the cameras and refits every frame to them
    (the frames of a phase after the first were fitted to other cameras). Its point is kept if
    its residuals' loss is lower than that of the frames alone refitted to the cameras (the same
    elimination with no camera step): it brings most residuals near where the LP will put them,
    so the LP crosses few breakpoints. The phase's robust scale is taken at the point kept, and
    the phase's steps are linearised there. Points are judged by their residuals alone, so this
    costs two linearisations, not three (decision 0004, fourth session). ``warm`` (x solves nearly
    this problem, its frames fitted to its cameras): the start's linearisation is the phase's, its
    scale and kept rows those of its own residuals (one linearisation and one elimination;
    decisions 0019, 0029: after the outlier pass at 128 x 3000 the residuals' scale was 0.13% from
    the projected residuals', and the two kept the same rows).

    Returns:
        (the start's system, the phase's system with its scale).
    """
    start = ReducedSystem(model, x)
    if warm:
        return start, start
    # the start's rows are kept by their residuals with the frames refitted (b): the raw ones of
    # frames fitted to other cameras are many pixels off, and their scale would keep gross outliers
    start = start.rescaled(robust_scale(start.b), by=start.b)
    d_gn = start.gauss_newton_step()
    x_fit, x_gn = start.apply(np.zeros_like(d_gn)), start.apply(d_gn)
    r_fit, r_gn = model.residuals(x_fit), model.residuals(x_gn)
    judge = robust_scale(r_fit.reshape(-1, 2))
    if residual_cost(r_gn, judge, loss) < residual_cost(r_fit, judge, loss):
        x_fit, r_fit = x_gn, r_gn
    return start, ReducedSystem(model, x_fit, robust_scale(r_fit.reshape(-1, 2)))


def _slp(model: WandModel, x: np.ndarray, progress, max_iter: int, time_limit, phase: str, loss,
         scheme: str = "irls", certify: bool = True, warm: bool = False):
    """One phase (one loss, one robust scale): LP steps, after IRLS steps with ``scheme="irls"``
    (then LP steps only with ``certify``). Returns (x, info, the reduced system the last step was
    taken on)."""
    n_free = model.frame_col0 // CAM_PARAMS
    radius = np.array([ROT_RADIUS, T_RADIUS])
    tally, status = _LpTally(), "iteration_limit"
    start, state = _phase_start(model, x, loss, warm)
    irls_steps, se_phase, d_about = 0, None, np.zeros(len(state.free_cols))
    if scheme == "irls":
        # for IRLS's stop and the LP's guard: the start's, rescaled, is near enough for both
        se_phase = start.standard_errors() * state.scale / start.scale
        # the start's Schur complement, formed for its Gauss-Newton step, serves IRLS here too
        state, d_about, irls_steps = _irls(model, state, loss, np.tile(np.repeat(radius, 3), n_free), se_phase,
                                           progress, phase, start)
    x_out = state.x  # the best state verified so far, kept if an LP fails
    it = 0
    if scheme == "irls" and not certify:
        # the IRLS point (it lowered the model's loss) starts the next phase
        x_out, max_iter, status = state.apply(d_about), 0, "converged"
    for it in range(1, max_iter + 1):
        rho = np.tile(np.repeat(radius, 3), n_free)
        if scheme == "irls":
            # written about the IRLS point d_about: only rows near a breakpoint there enter
            d, lp_info = solve_step(state, rho, time_limit, loss, IRLS_GUARD_SE, d_pred=d_about,
                                    near=IRLS_NEAR_BREAK, se=se_phase)
        else:
            d, lp_info = solve_step(state, rho, time_limit, loss, GUARD_SE)
        tally.add(lp_info)
        if d is None:
            status = "time_limit" if lp_info["status"] == "time_limit" else f"lp_{lp_info['status']}"
            break
        # the LP's point is judged by its residuals (the frames as the elimination moved them),
        # against the LP's model at the state (rows rejected as decided there): no relinearisation
        # is paid (~0.2 s at 32 x 2000) unless the phase steps again
        cost = state.model_loss(state.b, loss)
        predicted = state.model_cost(d, loss)
        promised = cost - predicted
        x_new = state.apply(d)
        r_new = model.residuals(x_new).reshape(-1, 2)
        new_cost = residual_cost(r_new, state.scale, loss)
        if promised <= CONVERGED_GAIN * len(d) or np.max(np.abs(d)) < STEP_TOL:
            # the LP's optimum is within a sliver of a standard error of where we are: land on
            # it (the estimate is the LP's) unless that costs more than the sliver, and stop
            if new_cost <= cost + CONVERGED_GAIN * len(d):
                x_out = x_new
            status = "converged"
            break
        ratio = (cost - new_cost) / promised
        step = np.abs(d).reshape(-1, 2, 3).max(axis=(0, 2))
        if new_cost < cost:
            x_out = x_new
            if _landed(state, d, r_new, new_cost, predicted, se_phase):
                status = "converged"
                break
            # the robust scale stays fixed within a phase: one M-estimator, one merit
            state, d_about = ReducedSystem(model, x_new, state.scale), np.zeros(len(d))
            if ratio > 0.75 and np.any(step > 0.5 * radius):
                radius = radius * 2.0
        else:
            radius = np.maximum(0.25 * step, 1e-9)
        if progress is not None:
            progress({
                "stage": "refine", "iteration": it, "cost": min(cost, new_cost),
                "message": f"LP step {it} ({phase}): {lp_info['rows']} LP rows, {lp_info['rounds']} solves",
            })
    return x_out, {
        "iterations": it,
        "lp_seconds": tally.seconds,
        "lp_rows_mean": float(np.mean(tally.rows)) if tally.rows else 0.0,
        "status": status,
        "robust_scale_px": state.scale,
        "uncertified_steps": tally.uncertified,
        "irls_steps": irls_steps,
        "lp_steps": tally.log,
    }, state


@dataclass
class _LpTally:
    """A phase's LP steps so far: seconds, LP rows (pairs) per step, (rows, rounds, HiGHS
    iterations, seconds) per step, and how many steps were left uncertified."""

    seconds: float = 0.0
    rows: list[int] = field(default_factory=list)
    log: list[tuple] = field(default_factory=list)
    uncertified: int = 0

    def add(self, lp_info: dict) -> None:
        """Count one step's info (:func:`wandcal.calib.solve.lpstep.solve_step`)."""
        self.seconds += lp_info["seconds"]
        self.rows.append(lp_info["rows"])
        self.log.append((lp_info["rows"], lp_info["rounds"], lp_info["iterations"], round(lp_info["seconds"], 3)))
        self.uncertified += lp_info["status"] == "uncertified"


def _landed(state: ReducedSystem, d: np.ndarray, r_new: np.ndarray, new_cost: float, predicted: float,
            se_phase: np.ndarray | None) -> bool:
    """Whether a step ``d`` (n,) that lowered the merit ends the phase: it is below
    ``CONVERGED_SE`` standard errors, or it is exact. Exact: no row crossed the rejection point
    (residuals ``r_new`` (R, 2) pixels) and the model predicted the merit at the LP's point to
    within the stop's sliver, over a step it describes: the LP has landed on the optimum of an
    exact model, so another step would only confirm it (one from there moved < 0.012 SE at 8-32
    x 2000; decision 0004)."""
    se = state.standard_errors() if se_phase is None else se_phase
    small = np.all(np.abs(d) < CONVERGED_SE * se)
    same_rows = np.array_equal(np.abs(r_new) <= REJECT_SIGMAS * state.scale, state.kept)
    exact = (same_rows and abs(new_cost - predicted) <= CONVERGED_GAIN * len(d)
             and np.all(np.abs(d) < RELINEARISE_SE * se))
    return bool(small or exact)


def _irls(model: WandModel, state: ReducedSystem, loss, rho: np.ndarray, se: np.ndarray, progress, phase: str,
          precond: ReducedSystem | None = None):
    """IRLS on the phase's loss and scale, near to the optimum of the piecewise-linear loss.

    Runs :func:`_irls_steps` on the state's linearisation. A move shorter than ``RELINEARISE_SE``
    standard errors ends IRLS there, unless a row's predicted residual there is on the other side
    of the rejection point than at the state: the LP lands ~0.1 SE from the IRLS point, so it
    would cross there too, and a relinearisation now is cheaper than one and another LP after
    it. A longer move, or one that changes the rejected rows, moves the state there and
    linearises it again if that lowers the merit (if not, the LP starts from the IRLS point of a
    short move, from the state after a long one). ``precond``: the system whose Schur complement
    preconditions the first linearisation's steps (one near it; the state's own when None).

    Returns:
        (state, IRLS point (n_cam_params,) as a step from it, inner steps taken).
    """
    steps = 0
    for _ in range(MAX_RELINEARISE):
        d, taken, current = _irls_steps(state, loss, rho, se, precond)
        steps += taken
        if progress is not None:
            progress({"stage": "refine", "iteration": steps, "cost": current, "message": f"IRLS step {steps} ({phase})"})
        short = np.all(np.abs(d) < RELINEARISE_SE * se)
        z = state.b + state.change(d)
        if short and np.array_equal(np.abs(z) <= REJECT_SIGMAS * state.scale, state.kept):
            return state, d, steps  # the linearisation still describes the IRLS point: the LP is written there
        x = state.apply(d)
        if residual_cost(model.residuals(x), state.scale, loss) >= state.model_loss(state.b, loss):
            return state, (d if short else np.zeros_like(rho)), steps
        # after a short move the Schur complement still serves
        state, precond = ReducedSystem(model, x, state.scale), precond if short else None
    return state, np.zeros_like(rho), steps


def _irls_steps(state: ReducedSystem, loss, rho: np.ndarray, se: np.ndarray, precond: ReducedSystem | None = None):
    """IRLS steps on one linearisation, from its point, in the trust region ``rho``.

    Each step moves towards the weighted least-squares point of the reduced rows with weights
    |psi(z)| / |z| (calib/solve/robustloss.py) at the last point, the frames still eliminated as in
    the LP, so its fixed point is a stationary point of the same loss: near its optimum, not on it
    (that needs rows exactly on breakpoints), which the LP then certifies. A step is
    ``d - (w_mean S)^-1 A^T W(d) z(d)``: the weighted normal matrix ``A^T W A`` is taken as the
    kept rows' one, S (the Gauss-Newton Schur complement, formed anyway), times the mean weight.
    The weights hang on the noise, not on the rows' geometry, so the two differ by little; the
    fixed point is the same, and it is reached in as many steps as with the weighted matrix
    formed at each step (measured at 8-32 x 2000, decision 0004, fourth session). Steps stop
    when one moves every camera parameter by less than ``IRLS_DONE_SE`` standard errors ``se``.

    Args:
        precond: the system whose S is taken (this linearisation, or one near it), or None for
            the state.

    Returns:
        (IRLS point d, steps taken, the LP model's loss there).
    """
    precond = state if precond is None else precond
    d, u = np.zeros_like(rho), np.zeros_like(state.b)  # the IRLS point and its change(d): linear,
    current = state.model_loss(state.b, loss)  # so a halved step's is the mean of two
    taken = 0
    for _ in range(MAX_IRLS):
        z = state.b + u
        w = irls_weights(z / state.scale, state.kept, loss)
        w_mean = float(np.mean(w[state.kept])) if state.kept.any() else 1.0
        new = np.clip(d - precond.schur_solve(state.folded_cost(w * z)) / w_mean, -rho, rho)
        u_new = state.change(new)
        taken += 1
        for _ in range(3):  # IRLS need not descend on a piecewise-linear loss: halve back if not
            cost = state.model_loss(state.b + u_new, loss)
            if cost < current:
                break
            new, u_new = 0.5 * (d + new), 0.5 * (u + u_new)
        if cost >= current:
            break
        step, d, u, current = new - d, new, u_new, cost
        if np.all(np.abs(step) < IRLS_DONE_SE * se):
            break
    return d, taken, current
