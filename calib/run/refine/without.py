"""The rig solved again without some of its cameras: the judgement's re-solve without a suspect
camera (:func:`wandcal.calib.run.rig_faults.isolate` judges the suspect against the others solved
without it). Here, not in :mod:`wandcal.calib.run.resolve` (which re-solves some cameras holding
the others), because that module imports the judgement, which imports this.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig
from wandcal.calib.run.refine.methods import ROBUST_STAGE_SE
from wandcal.calib.run.refine.problem import build_problem
from wandcal.calib.solve.ba import DEFAULT_LOSS, bundle_adjust_points

# the judgement's re-solve without a suspect camera (:func:`without_cameras`) starts at the full
# solution, which the suspect's observations (1/N of the rig's) pulled off the optimum without it
# by a perturbation of that order: Gauss-Newton's first step takes its linear part, and what is
# left is second order in it. Measured (docs/decisions/0071): one step leaves the suspect's time
# offset within 0.01-0.07 of its standard error of the converged re-solve's (4 steps) on every
# shape at 128 cameras (0.2-0.3 on 8), its lens pattern's strength within 0.2, at a quarter of the cost
WITHOUT_STEPS = 1


def without_cameras(rig: Rig, labelled: WandPairs, R: np.ndarray, t: np.ndarray, out: list[int],
                    steps: int = WITHOUT_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) (N, 3, 3), (N, 3): every camera but ``out`` refined without the observations of the
    cameras ``out`` (theirs returned as given), from the full solution R, t: robust ``ba`` (the
    default loss, as the calibration's first stage; the first of the other cameras holds the
    gauge), at most ``steps`` Levenberg-Marquardt steps (:data:`WITHOUT_STEPS`). Only the poses
    are returned, so the wand frames are not brought to their optimum after the steps (a pass that
    holds the poses, and cost as much as the step).

    Raises:
        CalibrationError, numpy.linalg.LinAlgError: the others alone do not solve.
    """
    others = ~np.isin(labelled.camera, out)
    keep = np.flatnonzero(~np.isin(np.arange(len(rig.cameras)), out))
    index = np.full(len(rig.cameras), -1)
    index[keep] = np.arange(len(keep))
    sub = labelled.subset(others)
    sub = WandPairs(sub.frame, index[sub.camera], sub.xy, sub.uv, sub.frames, sub.dropped)
    sub_rig = replace(rig, cameras=tuple(rig.cameras[k] for k in keep))
    setup = build_problem(sub_rig, sub, R[keep], t[keep], 0)
    # refine()'s robust ba of a first stage (final=False: no standard errors), its steps bounded;
    # the stop judges the frames too (judge_frames): no pass after it settles them
    solved = bundle_adjust_points(setup.model, None, None, loss=DEFAULT_LOSS, max_iter=steps, stop_se=ROBUST_STAGE_SE,
                                  standard_errors=False, judge_frames=True)
    R2, t2 = R.copy(), t.copy()
    R2[keep], t2[keep] = setup.model.poses(solved.x)
    return R2, t2
