"""``--method ba``: bundle adjustment with the wand length built in (:mod:`~wandcal.calib.solve.ba.adjust`:
the problem's terms, its gauge and the entry points; :mod:`~wandcal.calib.solve.ba.levenberg`: the
Levenberg–Marquardt loop, its robust loss and its stop)."""

from wandcal.calib.solve.ba.adjust import (
    CAUCHY_SIGMAS,
    DEFAULT_LOSS,
    LOSSES,
    MAX_ITER,
    STOP_SE,
    BundleResult,
    IntrinsicsFit,
    bundle_adjust,
    bundle_adjust_points,
)

__all__ = ["CAUCHY_SIGMAS", "DEFAULT_LOSS", "LOSSES", "MAX_ITER", "STOP_SE", "BundleResult", "IntrinsicsFit",
           "bundle_adjust", "bundle_adjust_points"]
