"""The wand frames at their optimum with the cameras held: how a ``ba`` stage that stopped on the
cameras (``judge_frames=False``, decision 0032) finishes.

Such a stage stops while a few frames are still crawling towards their optimum (Gauss–Newton at
0.93 a step on a wand nearly across both of its cameras' rays). Relabelling and outlier rejection
judge each frame by its residuals, and the result reports the frames, so they are brought to
their optimum given the cameras. With the cameras held the frames are independent problems of a
few parameters each (5 for a wand, 6 for a planar wand's frame): a Gauss–Newton step per frame
on its own normal block, vectorised over the frames, each frame damped and accepted on its own
cost under the stage's loss and weights, and each stopped on its own when it is estimated to lie
within ``stop_se`` of its standard error of its optimum (the stage's rule, per frame). Only the
frames the stage's rule leaves moving are settled (``active``). A step costs a linearisation of the frames still moving
only: after the first few steps, a handful.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from wandcal.calib.solve.reprojection import BundleState

# a frame's steps: every frame that Gauss-Newton does not crawl on stops within 3-5; the crawling
# ones (0.93 a step) need ~60 from a few tenths of a standard error, one frame's rows each
MAX_FRAME_STEPS = 100
LAMBDA0 = 1e-4  # a frame's damping after a step that raised its cost, relative to its block's diagonal
LAMBDA_MAX = 1e16  # beyond this no step lowers the frame's cost: it is at its optimum to working precision
MAX_RATE = 0.9  # as the stage's: the ratio of successive steps is taken as at most this


def frames_at_optimum(term, state: BundleState, rho: Callable[[np.ndarray], np.ndarray],
                      weights: Callable[[np.ndarray], np.ndarray], sigma: float, stop_se: float, *,
                      active: np.ndarray | None = None) -> tuple[BundleState, int]:
    """The state with ``term``'s frames (its blocks: a wand term's midpoint and direction, a
    planar wand's axes too) at their optimum with everything else held.

    Args:
        term: a wand term (:class:`wandcal.calib.solve.reprojection.WandTerm` or a planar one).
        state: the stage's final state.
        rho: per observation, its loss (K,) from its squared pixel error z (K,).
        weights: per observation, the loss's weight rho'(z) (K,) (iteratively reweighted least
            squares, as the stage).
        sigma: the noise's robust sigma, pixels (the standard errors' scale).
        stop_se: stop a frame when it is estimated within this many standard errors of its optimum.
        active: (P,) bool, the frames to polish (the stage's stop leaves them moving); None: every one.

    Returns:
        (state, steps): the polished state and the number of vectorised steps taken.
    """
    s = term.structure
    F, p = s.n_pts, s.size
    frame = s.pt
    lam = np.zeros(F)  # Gauss-Newton's undamped step first, as the least-squares polish
    nu = np.full(F, 2.0)
    last_ratio = np.full(F, np.inf)
    active = (np.bincount(frame, minlength=F) > 0) & (True if active is None else active)
    steps = 0
    for steps in range(1, MAX_FRAME_STEPS + 1):
        rows = np.flatnonzero(active[frame])
        if not len(rows):
            return state, steps - 1
        local = np.cumsum(active) - 1  # a frame's place among the active ones
        at = local[frame[rows]]
        n = int(active.sum())
        r, J = term.linearise_rows(state, rows)
        B = J[:, :, -p:]  # the block's columns come last
        z = np.einsum("mk,mk->m", r, r)
        w = weights(z)
        V = np.zeros((n, p, p))
        np.add.at(V, at, w[:, None, None] * np.einsum("mki,mkj->mij", B, B))
        g = np.zeros((n, p))
        np.add.at(g, at, w[:, None] * np.einsum("mki,mk->mi", B, r))
        cost = np.bincount(at, rho(z), minlength=n)
        lam_a = lam[active]
        V_inv = _inverse(V)
        dp = -np.einsum("fij,fj->fi", V_inv, g)
        slow = lam_a > 0  # the few frames whose last step raised their cost: Marquardt's damped step
        if slow.any():
            damped = V[slow] + lam_a[slow, None, None] * (np.eye(p) * np.diagonal(V[slow], axis1=1, axis2=2)[:, :, None])
            dp[slow] = -np.einsum("fij,fj->fi", _inverse(damped), g[slow])
        full = np.zeros((F, p))
        full[active] = dp
        moved = term.moved(state, full)
        r_new = term.residuals(moved, rows)
        new_cost = np.bincount(at, rho(np.einsum("mk,mk->m", r_new, r_new)), minlength=n)
        ok = np.isfinite(new_cost) & (new_cost < cost)
        keep = np.zeros(F, bool)
        keep[np.flatnonzero(active)[ok]] = True
        state = _with_frames(state, moved, keep)
        idx = np.flatnonzero(active)
        # a rejected step raises the frame's damping (Nielsen's update, as the stage); an accepted one lowers it
        lam[idx[~ok]] = np.where(lam_a[~ok] > 0, lam_a[~ok] * nu[idx[~ok]], LAMBDA0)
        nu[idx[~ok]] *= 2
        lam[idx[ok]] = lam_a[ok] / 3
        nu[idx[ok]] = 2.0
        # each frame's step in its standard errors (its block's conditional variance, as the stage's stop)
        var = np.diagonal(V_inv[ok], axis1=1, axis2=2)
        ratio = np.max(np.abs(dp[ok]) / (sigma * np.sqrt(np.maximum(var, 1e-300))), axis=1)
        previous = last_ratio[idx[ok]]
        q = np.where(np.isfinite(previous), np.minimum(ratio / previous, MAX_RATE), MAX_RATE)
        last_ratio[idx[ok]] = ratio
        done = np.zeros(F, bool)
        done[idx[ok]] = ratio * q / (1 - q) < stop_se
        done[idx[~ok]] = lam[idx[~ok]] >= LAMBDA_MAX
        active &= ~done
    return state, steps


def _inverse(V: np.ndarray) -> np.ndarray:
    """(n, p, p) inverses of the blocks (n, p, p); the pseudo-inverse when one is singular (a
    frame whose every observation the loss has all but dropped)."""
    try:
        return np.linalg.inv(V)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(V)


def _with_frames(state: BundleState, moved: BundleState, take: np.ndarray) -> BundleState:
    """``state`` with the frames ``take`` (F,) bool of ``moved``: the midpoints, directions and a
    planar wand's axes."""
    Q = state.Q
    if Q is not None and moved.Q is not None:
        Q = np.where(take[:, None, None], moved.Q, Q)
    return replace(state, m=np.where(take[:, None], moved.m, state.m), d=np.where(take[:, None], moved.d, state.d), Q=Q)
