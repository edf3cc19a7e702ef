"""The convex piecewise-linear M-estimator loss of the LP method, and its IRLS weights.

A loss is given as (signed breakpoints with 0 in the middle, slopes of the intervals between
them), in units of a robust scale of the residuals. ``EFFICIENT`` is the 3-breakpoint loss of
greatest Gaussian efficiency (96.5%); ``L1`` is least absolute error (docs/decisions/0004-lp-method.md).
"""

from __future__ import annotations

import numpy as np

# The loss: breakpoints (robust sigmas) and psi on each interval, from 0 outwards; found by
# maximising Gaussian efficiency over 3-breakpoint convex piecewise-linear losses (decision 0004)
BREAKS = np.array([0.501, 1.05, 1.748])
SLOPES = np.array([0.188, 0.58, 1.031, 1.651])
REJECT_SIGMAS = 6.0  # a residual this many robust sigmas out is a gross outlier, not noise
# IRLS weights psi(z)/z are floored at this |z| (robust sigmas): the loss has a kink at 0 (slope
# 0.188 each side, for L1 slope 1), whose weight 1/|z| is unbounded. 0.05 sigma brings IRLS to
# within ~0.06 standard error of the LP's optimum in 3 steps at 16 x 2000 (decision 0004, third session).
IRLS_FLOOR = 0.05


def signed_loss(breaks: np.ndarray, slopes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed breakpoints and the slope of each interval between them, left to right."""
    return np.r_[-breaks[::-1], 0.0, breaks], np.r_[-slopes[::-1], slopes]


EFFICIENT = signed_loss(BREAKS, SLOPES)
L1 = signed_loss(np.zeros(0), np.ones(1))  # least absolute error: the first phase only needs a robust direction


def loss_value(z: np.ndarray, loss) -> np.ndarray:
    """The loss of residuals z (robust sigmas), any shape; 0 at z = 0. Losses are symmetric
    (:func:`signed_loss`), so this is a function of |z| over the positive breakpoints."""
    P, S = loss
    mid = len(P) // 2
    a = np.abs(z)
    out = S[mid + 1] * a
    for q in range(mid + 1, len(P)):
        out += (S[q + 1] - S[q]) * np.maximum(a - P[q], 0.0)
    return out


def capped_loss(z: np.ndarray, kept: np.ndarray, loss) -> np.ndarray:
    """The loss of kept residuals, and its value at the rejection point for the others."""
    cap = loss_value(np.array([REJECT_SIGMAS]), loss)[0]
    return np.where(kept, loss_value(z, loss), cap)


def irls_weights(z: np.ndarray, kept: np.ndarray, loss, floor: float | None = None) -> np.ndarray:
    """IRLS weights |psi(z)| / max(|z|, floor) of residuals z (robust sigmas); 0 where not kept.
    ``floor``: ``IRLS_FLOOR`` when None."""
    P, S = loss
    floor = IRLS_FLOOR if floor is None else floor
    psi = np.abs(S[np.searchsorted(P, z)])
    return np.where(kept, psi / np.maximum(np.abs(z), floor), 0.0)
