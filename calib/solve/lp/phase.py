"""One phase of the LP method (one loss, one robust scale): where it starts (a Gauss-Newton step
that refits the frames), its IRLS steps (:mod:`wandcal.calib.solve.lp.irls`), then the LP steps
that certify the optimum, and the stop."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from wandcal.calib.solve.lp.irls import irls
from wandcal.calib.solve.lp.settings import (
    CONVERGED_GAIN,
    CONVERGED_SE,
    IRLS_GUARD_SE,
    IRLS_NEAR_BREAK,
    RELINEARISE_SE,
    ROT_RADIUS,
    STEP_TOL,
    T_RADIUS,
)
from wandcal.calib.solve.lp.step import GUARD_SE, solve_step
from wandcal.calib.solve.reduced import ReducedSystem, residual_cost, robust_scale
from wandcal.calib.solve.robustloss import REJECT_SIGMAS
from wandcal.calib.solve.wandmodel import CAM_PARAMS, WandModel


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


def run_phase(model: WandModel, x: np.ndarray, progress, max_iter: int, time_limit, phase: str, loss,
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
        state, d_about, irls_steps = irls(model, state, loss, np.tile(np.repeat(radius, 3), n_free), se_phase,
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
        """Count one step's info (:func:`wandcal.calib.solve.lp.step.solve_step`)."""
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
