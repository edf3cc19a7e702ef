"""Judge fixed cameras against a wand capture: residuals, wand lengths and leave-one-out errors.

The report draws these for the capture a result was made from; ``wandcal check`` runs them on a
fresh capture to find a camera that was knocked since (bump detection, as commercial mocap has
it). Nothing here moves a camera: the poses are taken as given.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from wandcal.calib.judge.quality import outlier_mask
from wandcal.calib.observations import WandPairs, wand_pairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.triangulate import reprojection_errors, triangulate_points

MOVED_FACTOR = 4.0  # a camera whose leave-one-out error is 4x the agreeing cameras' has moved
# ... and never below this: on clean data every leave-one-out error is a fraction of a pixel,
# and a few tenths more are noise, not a knock (1 px at 3 m is ~2 mm or 0.02 degrees at f = 1400)
MOVED_MIN_PX = 1.0
MIN_JUDGED_FRAMES = 10  # frames with two other cameras that a camera needs before it is judged
# A capture's rig.json and a result's cameras are one rig when every shared camera has the same
# image size and its focal length and principal point agree within these: a refined focal
# length moves by a few per cent at most (docs/verdict.md), another camera's by far more
SAME_RIG_FOCAL = 0.1
SAME_RIG_PRINCIPAL = 0.1  # of the image's size


@dataclass(frozen=True, eq=False)
class WandEvaluation:
    """Every labelled wand observation with the given poses.

    camera: (M,) camera index; frame: (M,) capture frame number; end: (M,) 0 or 1;
    uv: (M, 2) the raw pixel observed; residual_px: (M, 2) projected minus observed, in pixels of
    the undistorted image (normalised residual times the focal length); outlier: (M,) bool, more
    than :data:`wandcal.calib.judge.quality.OUTLIER_SIGMAS` robust sigmas; frames: (F,) frame numbers of the
    frames at least two cameras saw; wand_length: (F,) metres, each end triangulated on its own;
    dropped: camera-frames left out (``one_blob``, ``extra_blobs``).
    """

    camera: np.ndarray
    frame: np.ndarray
    end: np.ndarray
    uv: np.ndarray
    residual_px: np.ndarray
    outlier: np.ndarray
    frames: np.ndarray
    wand_length: np.ndarray
    dropped: dict

    def error_px(self) -> np.ndarray:
        """(M,) residual magnitudes, pixels."""
        return np.linalg.norm(self.residual_px, axis=1)


def rig_mismatches(calibrated: Rig, capture: Rig) -> list[str]:
    """Why ``capture``'s cameras are not the ``calibrated`` ones (empty when they are one rig):
    a camera the result does not have, another image size, or other intrinsics."""
    out = []
    for cam in capture.cameras:
        if cam.id not in calibrated.ids:
            out.append(f"the result has no camera {cam.id!r} (it has {', '.join(calibrated.ids)})")
            continue
        ref = calibrated.cameras[calibrated.index(cam.id)]
        if (cam.width, cam.height) != (ref.width, ref.height):
            out.append(f"{cam.id} is {cam.width}x{cam.height} px in the capture and {ref.width}x{ref.height} px in the result")
            continue
        focal = abs(cam.K[0, 0] / ref.K[0, 0] - 1)
        shift = np.hypot(cam.K[0, 2] - ref.K[0, 2], cam.K[1, 2] - ref.K[1, 2]) / max(cam.width, cam.height)
        if focal > SAME_RIG_FOCAL or shift > SAME_RIG_PRINCIPAL:
            out.append(f"{cam.id}'s intrinsics differ: focal {cam.K[0, 0]:.1f} against {ref.K[0, 0]:.1f} px, principal "
                       f"point ({cam.K[0, 2]:.0f}, {cam.K[1, 2]:.0f}) against ({ref.K[0, 2]:.0f}, {ref.K[1, 2]:.0f}) px")
    return out


def labelled_pairs(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations) -> WandPairs:
    """The capture's two-blob camera-frames with their ends ordered consistently, by the given poses."""
    pairs = wand_pairs(rig, wand)
    return label_ends(R, t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]


def evaluate_wand(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations) -> WandEvaluation:
    """Triangulate every wand frame with the given poses and measure each observation's residual.

    Args:
        rig: the cameras (intrinsics) and wand length.
        R, t: (N, 3, 3), (N, 3) world->camera poses, metres.
        wand: raw wand blobs of a capture.
    """
    pairs = labelled_pairs(rig, R, t, wand)
    point, camera, xy = flatten(pairs)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames))
    focal = np.array([c.focal for c in rig.cameras])
    residual = reprojection_errors(R, t, point, camera, xy, X) * focal[camera]
    ok = np.all(np.isfinite(residual), axis=1)
    ends = X.reshape(-1, 2, 3)
    length = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    seen = np.isfinite(length)
    uv = np.concatenate([pairs.uv[:, 0], pairs.uv[:, 1]])
    err = np.linalg.norm(residual[ok], axis=1)
    return WandEvaluation(
        camera=camera[ok], frame=pairs.frames[point[ok] // 2], end=point[ok] % 2, uv=uv[ok], residual_px=residual[ok],
        outlier=outlier_mask(err) if len(err) else np.zeros(0, bool), frames=pairs.frames[seen],
        wand_length=length[seen], dropped=dict(pairs.dropped),
    )


@dataclass(frozen=True, eq=False)
class CameraCheck:
    """One camera against the others: ``rms_px`` and ``median_px`` of its leave-one-out errors
    over ``frames`` frames, and whether it ``moved`` (None: too few frames to judge)."""

    id: str
    moved: bool | None
    rms_px: float | None
    median_px: float | None
    frames: int
    reason: str


def leave_one_out_errors(R: np.ndarray, t: np.ndarray, pairs: WandPairs, focal: np.ndarray, c: int,
                         others: np.ndarray) -> np.ndarray:
    """(K,) camera c's errors, pixels, against wand ends triangulated by the ``others`` (N,) bool
    cameras alone, over the frames c and at least two of them saw (both ends of each frame)."""
    use = others[pairs.camera]
    mine = pairs.camera == c
    views = np.bincount(pairs.frame[use], minlength=len(pairs.frames))
    # only c's own frames are triangulated: every camera's check triangulating the whole capture
    # made `wandcal check` grow as cameras x frames (128 x 3000 of 2-4 cameras a frame: 1.3x calibrate)
    in_c = np.zeros(len(pairs.frames), bool)
    in_c[pairs.frame[mine]] = True
    frames_ok = (views >= 2) & in_c
    sub = pairs.subset(use & frames_ok[pairs.frame])
    point, camera, xy = flatten(sub)
    X = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames))
    own = pairs.subset(mine & frames_ok[pairs.frame])
    p_own, c_own, xy_own = flatten(own)
    r = reprojection_errors(R, t, p_own, c_own, xy_own, X) * focal[c]
    e = np.linalg.norm(r, axis=1)
    return e[np.isfinite(e)]


def check_cameras(rig: Rig, R: np.ndarray, t: np.ndarray, wand: WandObservations,
                  expected_rms_px: np.ndarray | None = None) -> list[CameraCheck]:
    """Find the cameras that moved since ``R, t`` were calibrated.

    Each camera is judged by its errors against wand ends that the *other* cameras triangulate, so
    a knocked camera cannot hide by pulling the points towards itself. A knocked camera still
    spoils the others' triangulations (at 6 cameras a 1 degree knock lifts the others' errors
    six-fold), so only the worst camera is taken out at a time, and the rest are judged again
    without it, until every remaining one agrees.

    Args:
        expected_rms_px: (N,) each camera's reprojection RMS when it was calibrated (the result's
            ``reprojection_rms_px``); None to judge against the median camera instead.

    A camera has moved when its median leave-one-out error exceeds :data:`MOVED_FACTOR` times its
    expected RMS (or the agreeing cameras' median error) and :data:`MOVED_MIN_PX`.
    """
    pairs = labelled_pairs(rig, R, t, wand)
    focal = np.array([c.focal for c in rig.cameras])
    n = len(rig.cameras)
    trusted = np.ones(n, bool)

    def limits(errors: dict, agreeing: list[int]) -> np.ndarray:
        if expected_rms_px is not None:
            ref = np.asarray(expected_rms_px, float)
        else:
            ref = np.full(n, float(np.median(np.concatenate([errors[c] for c in agreeing]))))
        return np.maximum(MOVED_FACTOR * ref, MOVED_MIN_PX)

    while True:
        errors = {c: leave_one_out_errors(R, t, pairs, focal, c, trusted & (np.arange(n) != c)) for c in range(n)}
        agreeing = [c for c in range(n) if trusted[c] and len(errors[c]) >= 2 * MIN_JUDGED_FRAMES]
        if len(agreeing) < 3:
            break
        limit = limits(errors, agreeing)
        excess = {c: np.median(errors[c]) / limit[c] for c in agreeing}
        worst = max(agreeing, key=lambda c: excess[c])
        if excess[worst] <= 1.0:
            break
        trusted[worst] = False
    agreeing = [c for c in range(n) if trusted[c] and len(errors[c])]
    limit = limits(errors, agreeing) if agreeing else np.full(n, MOVED_MIN_PX)
    out = []
    for c, cam in enumerate(rig.cameras):
        e = errors[c]
        frames = len(e) // 2
        if frames < MIN_JUDGED_FRAMES:
            out.append(CameraCheck(cam.id, None, None, None, frames,
                                   f"{cam.id} saw the wand with two other cameras in only {frames} frames; "
                                   f"wave the wand where {cam.id} and two others see it"))
            continue
        rms, med = float(np.sqrt(np.mean(e**2))), float(np.median(e))
        is_moved = bool(not trusted[c] or med > limit[c])
        reason = (f"{cam.id} disagrees with the others by {med:.2f} px (median; limit {limit[c]:.2f} px): it has moved "
                  "or its lens was touched; recalibrate it with --solve-only" if is_moved else
                  f"{cam.id} agrees with the others ({med:.2f} px median, limit {limit[c]:.2f} px)")
        out.append(CameraCheck(cam.id, is_moved, rms, med, frames, reason))
    return out
