"""The LP refinement (``--method lp``): sequential linear programming over the camera poses.

Each iteration linearises the pixel reprojection residuals of :class:`wandcal.calib.solve.wandmodel.WandModel`
about the current state, eliminates every wand frame's 5 parameters per frame (points are
independent once the cameras are known; calib/solve/reduced.py), and solves one LP (an interior-point
method whose basis HiGHS's simplex confirms; calib/solve/backend/ipm.py, calib/solve/backend/highs.py) for the step ``d`` of all
free cameras (3 rotation increments and 3 translations each) inside a trust region
(calib/solve/lp/step.py):

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

| module | holds |
|---|---|
| :mod:`~wandcal.calib.solve.lp.refine` | the entry points, and the first phase on a subset of frames |
| :mod:`~wandcal.calib.solve.lp.phase` | one phase: its start, its LP steps and its stop |
| :mod:`~wandcal.calib.solve.lp.irls` | the IRLS steps that bring a phase near the optimum the LP certifies |
| :mod:`~wandcal.calib.solve.lp.step` | one trust-region LP step: its small exact working set, solved and certified |
| :mod:`~wandcal.calib.solve.lp.settings` | the trust region, stops and IRLS settings, with the measurements behind them |
"""

from wandcal.calib.solve.lp.refine import refine_lp, refine_lp_covariance
from wandcal.calib.solve.lp.settings import (
    CERTIFY_FIRST_PHASE,
    CONVERGED_GAIN,
    CONVERGED_SE,
    IRLS_DONE_SE,
    IRLS_GUARD_SE,
    IRLS_NEAR_BREAK,
    MAX_IRLS,
    MAX_ITER,
    MAX_RELINEARISE,
    POINT_PARAMS,
    RELINEARISE_SE,
    ROT_RADIUS,
    SCHEMES,
    STEP_TOL,
    SUBSET_FRAMES,
    SUBSET_ONLY_ABOVE,
    T_RADIUS,
)

__all__ = ["CERTIFY_FIRST_PHASE", "CONVERGED_GAIN", "CONVERGED_SE", "IRLS_DONE_SE", "IRLS_GUARD_SE", "IRLS_NEAR_BREAK",
           "MAX_IRLS", "MAX_ITER", "MAX_RELINEARISE", "POINT_PARAMS", "RELINEARISE_SE", "ROT_RADIUS", "SCHEMES",
           "STEP_TOL", "SUBSET_FRAMES", "SUBSET_ONLY_ABOVE", "T_RADIUS", "refine_lp", "refine_lp_covariance"]
