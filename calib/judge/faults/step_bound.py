"""The turn a camera's pose-step test can name (:func:`wandcal.calib.judge.faults.pose_steps.pose_step`):
the F distribution's critical value, and the turn about an axis whose F reaches it (decision 0083)."""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge.faults.f_distribution import f_survival


def critical_f(q: int, dof: float, alpha: float) -> float:
    """The F(q, dof) value whose upper tail is ``alpha``: bisection of :func:`f_survival` on log F
    (it falls monotonically in F); 1e9 where even that is not rare enough."""
    lo, hi = 0.0, 1e9
    if f_survival(q, dof, hi) > alpha:
        return hi
    for _ in range(200):
        mid = np.sqrt(max(lo, 1e-12) * hi)
        if f_survival(q, dof, mid) > alpha:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-9 * hi:
            break
    return hi


def detectable_turn(cov: np.ndarray | None, axis: np.ndarray, f_crit: float) -> float:
    """The turn, degrees, about ``axis`` (3,) that the step test names at its split (noise-free,
    50% power): the step's F is its Wald statistic over three, ``w^T Cov^-1 w / 3`` (with the timed
    scatter and the batch-means inflation the test applies), so a turn theta about the unit axis a
    reaches the critical F* (``f_crit``: F(3, dof) at STEP_ALPHA over the splits searched) at
    ``theta = sqrt(3 F* / a^T Cov^-1 a)``. cov: (3, 3) the turn's covariance, deg^2. Per axis, not
    the rms: a camera's turn about its optical axis is often far less certain than across it.
    With Brown's 7-24 shared wand frames the inflation's dof is 3 (four batches) and F* of F(3, 3)
    at 1e-5 is ~ 3000: the bound is ~ 100 standard deviations (decision 0083). nan without a
    covariance or an axis."""
    a = np.asarray(axis, float)
    if cov is None or not np.isfinite(f_crit) or not np.linalg.norm(a) > 0:
        return float("nan")
    a = a / np.linalg.norm(a)
    info = float(a @ np.linalg.pinv(cov) @ a)
    return float(np.sqrt(3 * f_crit / info)) if info > 0 else float("inf")
