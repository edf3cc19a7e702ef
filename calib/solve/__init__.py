"""The refinement methods, side by side, over their shared model and solver back-ends.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.solve.ba` | ``--method ba``: Schur-complement Levenberg-Marquardt with the wand length built in (its entry points, and its loop) |
| :mod:`~wandcal.calib.solve.lp` | ``--method lp``: sequential LP with a robust piecewise-linear loss |
| :mod:`~wandcal.calib.solve.paper` | ``--method paper``: the seed paper's rounds (rotation step, then the LP) and their stop |
| :mod:`~wandcal.calib.solve.paper_lp` | the paper's least-absolute-error LP of eq. (Li): its set-up, solve and stop tolerance |
| :mod:`~wandcal.calib.solve.paper_fixed_point` | the plain paper rounds' fixed point on one LP basis, certified (a measuring tool, decision 0052) |
| :mod:`~wandcal.calib.solve.wandmodel` | the wand reprojection model every method shares |
| :mod:`~wandcal.calib.solve.reprojection` | pixel residuals and their analytic Jacobians |
| :mod:`~wandcal.calib.solve.reduced` | residuals with every wand frame projected out (the LP method's rows) |
| :mod:`~wandcal.calib.solve.robustloss` | the LP method's piecewise-linear M-estimator loss |
| :mod:`~wandcal.calib.solve.uncertainty` | pose covariances from the solver's information matrix |
| :mod:`~wandcal.calib.solve.gauge_free` | the rig's geometry uncertainty apart from the world's placement |
| :mod:`~wandcal.calib.solve.markerwand` | wands of 3-5 collinear markers in the wand model |
| :mod:`~wandcal.calib.solve.sync` | cameras without a trigger: sub-frame time offsets and drift |
| :mod:`~wandcal.calib.solve.backend` | the numerical back-ends: Schur solve, interior point, HiGHS |
"""
