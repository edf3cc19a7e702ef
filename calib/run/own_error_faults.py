"""Each camera's own errors against the points the cameras place together (the points
eliminated, :func:`wandcal.calib.judge.faults.own_errors.eliminate`): a camera that moved during the
capture and a camera whose own noise stands out (:func:`own_faults`), and the cameras whose noise is
at the limit of a noise fault (:func:`noise_limits`). The judgement's paths by the rig's size
(:mod:`wandcal.calib.run.rig_faults`) call them.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge.residuals import Residuals
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig

# a large rig's points seen by this many cameras or more keep a camera's noise with it in the
# residuals (3x one camera's noise shows as 2x the others' at four views, 2.8x at sixteen): the
# suspect screen names it, and the noise with the points eliminated is needed below only
SPREAD_VIEWS = 4


def own_faults(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
               named: list[int] | None = None, res: Residuals | None = None) -> tuple[list[dict], list[dict]]:
    """(a camera that moved, cameras whose own noise stands out), each camera judged with the
    points eliminated (:mod:`wandcal.calib.judge.faults.own_errors`, :mod:`wandcal.calib.judge.faults.pose_steps`);
    the moved camera is not also called noisy, nor are the cameras ``named`` at fault already.

    A rig of more than a few cameras (:data:`wandcal.calib.judge.faults.leave_one_out.MAX_CAMERAS`;
    ``res`` the judgement's residuals, needed then) is judged at a bounded cost: the step is tested
    in full only on the cameras a screen of ``res`` suspects
    (:func:`wandcal.calib.judge.faults.moved.step_suspects`), the noise with the points eliminated
    only where the median point has fewer than :data:`SPREAD_VIEWS` views (with more, a camera's
    noise stays with it in ``res`` and the suspect screen names it), each on
    :data:`wandcal.calib.judge.faults.own_errors.VIEWS_PER_CAMERA` views a camera. Fewer than three
    cameras give none."""
    from wandcal.calib.judge.faults.leave_one_out import MAX_CAMERAS
    from wandcal.calib.judge.faults.moved import Moved, moved_camera, moved_fault, step_suspects, unattributed_fault
    from wandcal.calib.judge.faults.own_errors import (
        VIEWS_PER_CAMERA,
        capped,
        eliminate,
        noise_fault,
        noisy_cameras,
        views_of,
    )

    if len(rig.cameras) < 3:
        return [], []
    large = len(rig.cameras) > MAX_CAMERAS
    suspected, sparse = None, True
    if large:
        if res is None:
            return [], []
        suspected = step_suspects(res, tracks.frames if tracks is not None else None)
        sparse = _median_views(res) < SPREAD_VIEWS
        if not suspected and not sparse:
            return [], []
    if large:
        views = capped(views_of(labelled, tracks), VIEWS_PER_CAMERA * len(rig.cameras))
        el = eliminate(R, t, views, steps=1) if len(views.point) else None
    else:
        views, el = points_eliminated(R, t, labelled, tracks)
    if el is None:
        return [], []
    ids, focal = list(rig.ids), np.array([c.focal.mean() for c in rig.cameras])
    moved = moved_camera(R, t, views, el, suspected) if suspected is None or suspected else Moved()
    out = [*(named or []), *([] if moved.camera is None else [moved.camera])]
    noisy = noisy_cameras(R, t, views, el, focal, out) if sparse else []
    found = [moved_fault(ids[moved.camera], moved.step)] if moved.camera is not None and moved.step is not None else \
        [unattributed_fault([ids[c] for c in moved.unsure[0]], moved.unsure[1])] if moved.unsure else []
    return found, [noise_fault(ids[c], n) for c, n in noisy]


# points_eliminated's last answer, [(R, t, labelled, tracks, views, eliminated)], the inputs compared by identity
_last_eliminated: list[tuple] = []


def points_eliminated(R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None):
    """(views, eliminated): every wand end and point-track observation
    (:func:`wandcal.calib.judge.faults.own_errors.views_of`) and their points fitted to all cameras,
    each camera's noise and outliers (:func:`wandcal.calib.judge.faults.own_errors.eliminate`,
    three steps; eliminated None without views). One judgement reads it three times on the same
    poses and observations (:func:`own_faults` of a few cameras, :func:`noise_limits`,
    :func:`wandcal.calib.run.rig_faults._outliers_or_noise`): the last answer is kept and given again for the very same objects
    (``is``, which the judgement does not change in place): the same input, the same numbers."""
    from wandcal.calib.judge.faults.own_errors import eliminate, views_of

    for last in _last_eliminated:
        if all(a is b for a, b in zip(last[:4], (R, t, labelled, tracks), strict=True)):
            return last[4], last[5]
    views = views_of(labelled, tracks)
    el = eliminate(R, t, views) if len(views.point) else None
    _last_eliminated[:] = [(R, t, labelled, tracks, views, el)]
    return views, el


def forget_eliminated() -> None:
    """Drop :func:`points_eliminated`'s kept answer: the judgement calls it before and after its
    reads, so no answer outlives one judgement (arrays a caller changes in place later, memory)."""
    _last_eliminated.clear()


def _median_views(res: Residuals) -> float:
    """The median point's number of views in the judgement's residuals."""
    if not len(res.point):
        return 0.0
    counts = np.bincount(res.point - res.point.min())
    return float(np.median(counts[counts > 0]))


def noise_limits(rig: Rig, labelled: WandPairs, tracks: PointTracks | None, R: np.ndarray, t: np.ndarray,
                 faults: list[dict]) -> list[dict]:
    """The cameras whose own noise (the points eliminated) is at the limit of a noise fault
    (:func:`wandcal.calib.judge.faults.own_errors.noise_at_limit`), for the verdict's ``at_limit``:
    judged in a rig of few cameras (3 to :data:`wandcal.calib.judge.faults.leave_one_out.MAX_CAMERAS`,
    where a camera's noise spreads over the points) and only where no camera is at fault (a camera
    at fault bends the others' residuals, and its own fault says more than its noise)."""
    from wandcal.calib.judge.faults.leave_one_out import MAX_CAMERAS
    from wandcal.calib.judge.faults.own_errors import camera_noise, noise_at_limit

    if not 3 <= len(rig.cameras) <= MAX_CAMERAS or any(f["camera"] is not None for f in faults):
        return []
    el = points_eliminated(R, t, labelled, tracks)[1]
    if el is None:
        return []
    noise = camera_noise(el, np.array([c.focal.mean() for c in rig.cameras]))
    return [e for e in (noise_at_limit(cam_id, n) for cam_id, n in zip(rig.ids, noise)) if e is not None]
