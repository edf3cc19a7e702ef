"""The refinement step: from labelled wand pairs, point tracks and start poses to a problem, the
chosen method on it, the outlier cleanup, and back to poses (and refined intrinsics).

| module | holds |
|---|---|
| :mod:`~wandcal.calib.run.refine.problem` | the problem: wand pairs triangulated into the wand model, restricted, point tracks as frames, world up |
| :mod:`~wandcal.calib.run.refine.methods` | the chosen method (``ba``, ``lp``, ``paper``) on it, the pose covariance, refined intrinsics |
| :mod:`~wandcal.calib.run.refine.outliers` | the outlier passes: gross outliers dropped or relabelled, the method run again |
| :mod:`~wandcal.calib.run.refine.without` | the judgement's re-solve of the rig without its suspect cameras: one Levenberg-Marquardt step from the full solution |

Every name below was imported from ``wandcal.calib.run.refine`` when it was one module, and still is.
"""

from wandcal.calib.run.refine.methods import (
    ROBUST_STAGE_SE,
    WAND_FRAMES_IN_STOP,
    Progress,
    Refined,
    check_intrinsics_request,
    refine,
)
from wandcal.calib.run.refine.outliers import MAX_OUTLIER_PASSES, finished, labelled_rows, reject_outliers, relabelled
from wandcal.calib.run.refine.problem import (
    GAUGE_CAMERA,
    TRACK_FRAME_HALF,
    Setup,
    build_problem,
    restarted,
    triangulated,
    up_direction,
    with_tracks,
)

__all__ = ["GAUGE_CAMERA", "MAX_OUTLIER_PASSES", "ROBUST_STAGE_SE", "TRACK_FRAME_HALF", "WAND_FRAMES_IN_STOP", "Progress",
           "Refined", "Setup", "build_problem", "check_intrinsics_request", "finished", "labelled_rows", "refine",
           "reject_outliers", "relabelled", "restarted", "triangulated", "up_direction", "with_tracks"]
