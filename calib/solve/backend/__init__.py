"""Numerical back-ends of the refinement methods, free of any wand or camera model.

| module | holds |
|---|---|
| :mod:`~wandcal.calib.solve.backend.schur` | damped normal equations solved by the Schur complement |
| :mod:`~wandcal.calib.solve.backend.ipm` | a primal-dual interior point for the LP step's dual form |
| :mod:`~wandcal.calib.solve.backend.arrowlp` | an interior point for LPs whose rows touch one point and one camera (``paper``'s per-round LP, decision 0033): its loop, warm start and answer |
| :mod:`~wandcal.calib.solve.backend.arrow_problem` | that LP's data, and the vertex a simplex basis names, certified |
| :mod:`~wandcal.calib.solve.backend.arrow_newton` | that interior point's Newton step: iterate, residuals, block-arrow normal equations |
| :mod:`~wandcal.calib.solve.backend.highs` | a bounded wrapper around HiGHS (highspy) |
"""
