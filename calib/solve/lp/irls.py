"""IRLS steps of the LP method: iteratively reweighted least squares on the piecewise-linear loss,
near its optimum, where the certifying LP (:mod:`wandcal.calib.solve.lp.phase`) takes over."""

from __future__ import annotations

import numpy as np

from wandcal.calib.solve.lp.settings import IRLS_DONE_SE, MAX_IRLS, MAX_RELINEARISE, RELINEARISE_SE
from wandcal.calib.solve.reduced import ReducedSystem, residual_cost
from wandcal.calib.solve.robustloss import REJECT_SIGMAS, irls_weights
from wandcal.calib.solve.wandmodel import WandModel


def irls(model: WandModel, state: ReducedSystem, loss, rho: np.ndarray, se: np.ndarray, progress, phase: str,
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
