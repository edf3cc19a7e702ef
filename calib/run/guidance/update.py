"""The guidance update: the fast solve over the wand frames so far and each camera's predicted
sigma (the package docstring, :mod:`wandcal.calib.run.guidance`, says how)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.judge.coverage import POINTS
from wandcal.calib.observations import WandPairs, point_tracks, wand_pairs
from wandcal.calib.rig import PointObservations, Rig, StaticObservations, WandObservations
from wandcal.calib.run.guidance.document import Seen, guidance_document
from wandcal.calib.run.guidance.settings import MIN_SOLVE_FRAMES, SOLVE_STEPS, GuidanceSettings
from wandcal.calib.start.chain import camera_groups, row_pairs
from wandcal.calib.start.offsets.confirm import confirmed_offsets
from wandcal.calib.start.offsets.whole_frames import DEFAULT_MAX_OFFSET, FrameOffsets, frame_offsets, shift_pairs

NO_WAND_YET = "no wand frames yet: wave the wand through the volume, where several cameras see it"
# Cameras left out, weakest first, when the fast solve cannot place them all; the rest are solved.
MAX_LEFT_OUT = 2
# a cold update also asks whether any camera's frames match the others' a few frames away (a
# camera without the trigger, or one that lost pulses): docs/sync.md's whole-frame search, narrow
OUT_OF_TIME_SEARCH = 3  # frames either side; ~0.1 s at 16 cameras, so warm (live) updates skip it
# Knuth's multiplicative hash: a fixed pseudo-random number in [0, 1) per frame number, so one
# update's subsample is nested in the last one's (no jitter from redrawing).
_HASH = 2654435761
_HASH_RANGE = 2**32


@dataclass(frozen=True, eq=False)
class Solution:
    """The last fast solve, to start the next one: camera ids and their gauge-frame poses
    R (K, 3, 3), t (K, 3), metres."""

    ids: tuple[str, ...]
    R: np.ndarray
    t: np.ndarray


@dataclass(frozen=True, eq=False)
class Guidance:
    """The guidance document (``wandcal-guidance/1``) and the solution that starts the next update."""

    document: dict
    solution: Solution | None

    @property
    def enough(self) -> bool:
        return bool(self.document["enough"])


def wanding_guidance(rig: Rig, wand: WandObservations | None, static: StaticObservations | None = None,
                     settings: GuidanceSettings | None = None, start: Solution | None = None,
                     points: PointObservations | None = None) -> Guidance:
    """The guidance for the wand blobs recorded so far.

    Args:
        rig: cameras with intrinsics and the wand length (required), optional static object.
        wand: raw wand blobs so far (frame, camera, uv), as in wand.csv.
        static: the static object's blobs, or None; it only gives the solve its first poses.
        settings: target, coverage goal and solve size (None: the defaults).
        start: the previous update's :class:`Solution`; the solve starts from it when it covers
            the same cameras.
        points: a points-only rig's point tracks (rig.json without a wand): each camera's points,
            links and coverage are judged (:func:`points_guidance`), with no predicted sigma.

    Returns:
        :class:`Guidance`. A solve that fails is not an error: the document says why, its cameras
        have no ``center_std_mm`` and it is not ``enough``.

    Raises:
        CalibrationError: the rig has no wand length, or the blobs name unknown cameras.
    """
    if rig.wand_length is None and points is not None and len(points):
        return points_guidance(rig, points, settings or GuidanceSettings())
    if rig.wand_length is None or wand is None:
        raise CalibrationError("guidance needs the wand: rig.json gives no 'wand.length_m'; give the wand's marker "
                               "distance in metres (or, for a points-only rig, its points.csv)")
    started = time.perf_counter()
    settings = settings or GuidanceSettings()
    # the pairs' normalised coordinates are taken in _solve, for the frames it keeps only
    pairs = WandPairs.empty()
    if len(wand) and (rig.wand_markers is None or len(rig.wand_markers) == 2):
        pairs = wand_pairs(rig, wand, undistort=False)
    elif len(wand):  # a multi-marker or planar wand: its end markers (grouped and undistorted together)
        from wandcal.calib.start.markerlabels import end_pairs

        pairs = end_pairs(rig, wand)
    offsets = None
    if settings.sync == "auto":  # cameras without a trigger: their frames realigned as calibrate's
        found = _whole_frames(rig, pairs, DEFAULT_MAX_OFFSET)
        if found is not None:
            offsets = found.offsets
            pairs = shift_pairs(pairs, offsets)
    seen = _seen(len(rig.cameras), pairs)
    solve_set = _solve_set(seen, _whole_static(rig, static))
    n = len(rig.cameras)
    center = np.full(n, np.nan)
    rotation = np.full(n, np.nan)
    solution: Solution | None = None
    failure: str | None = None
    info: dict[str, Any] = {"frames_used": 0, "cameras": 0, "warm_start": False}  # the document's "solve"
    left_out: dict[str, str] = {}
    if solve_set.sum() < 2:
        failure = (NO_WAND_YET if not len(seen.pairs) else
                   "no two cameras share enough frames to solve yet; wave the wand where several cameras see it")
    for attempt in range(MAX_LEFT_OUT + 1):
        if solve_set.sum() < 2:
            break
        try:
            solution, center, rotation, info = _solve(rig, seen, solve_set, static, settings, start)
            failure = None
            break
        except CalibrationError as exc:
            failure = str(exc)
        except np.linalg.LinAlgError as exc:  # a degenerate early capture: a singular system
            failure = f"the fast solve met a singular system ({exc}); keep waving where several cameras see the wand"
        if attempt == MAX_LEFT_OUT or solve_set.sum() <= 2:
            break
        # one weak camera must not leave every other one without a sigma: solve without the weakest
        weakest = np.flatnonzero(solve_set)[np.argmin(seen.shared[solve_set])]
        left_out[rig.cameras[weakest].id] = failure
        solve_set = solve_set.copy()
        solve_set[weakest] = False
    info |= {"ok": failure is None, "message": failure, "left_out": left_out,
             "out_of_time": {} if info.get("warm_start") or settings.sync == "auto" else _out_of_time(rig, seen.pairs),
             "offsets": None if offsets is None else {cid: int(k) for cid, k in zip(rig.ids, offsets) if k},
             "seconds": round(time.perf_counter() - started, 4)}
    document = guidance_document(rig, seen, center, rotation, solve_set, settings, info)
    return Guidance(document, solution)


def points_guidance(rig: Rig, points: PointObservations, settings: GuidanceSettings) -> Guidance:
    """The guidance of a points-only rig: each camera's points seen with another camera (its
    ``frames``: one a point), its links and its image's coverage by them, judged as a wand's
    camera-frames are. A rig without a wand has no scale, so no sigma in millimetres is predicted
    (``center_std_mm`` null): ``enough`` rests on the links and the coverage."""
    started = time.perf_counter()
    tracks = point_tracks(rig, points)
    both = np.stack([tracks.uv, tracks.uv], axis=1)  # one point as a 'pair' of itself: frames, links, coverage
    pairs = WandPairs(tracks.track, tracks.camera, np.stack([tracks.xy, tracks.xy], axis=1), both,
                      np.arange(tracks.n_tracks), dict(tracks.dropped))
    seen = _seen(len(rig.cameras), pairs)
    solve_set = _solve_set(seen, grow=False)
    n = len(rig.cameras)
    linked = int(solve_set.sum()) >= 2
    info: dict[str, Any] = {
        "frames_used": 0, "cameras": 0, "warm_start": False, "ok": linked, "left_out": {}, "out_of_time": {},
        "offsets": None, "points_only": True,
        "message": None if linked else "no two cameras share enough points yet; show points where several cameras see them",
        "seconds": round(time.perf_counter() - started, 4)}
    document = guidance_document(rig, seen, np.full(n, np.nan), np.full(n, np.nan), solve_set, settings, info,
                                 words=POINTS)
    return Guidance(document, None)


def _whole_frames(rig: Rig, pairs: WandPairs, window: int) -> FrameOffsets | None:
    """The cameras' whole-frame offsets within +-``window`` (docs/sync.md's search,
    wandcal.calib.start.offsets.whole_frames.frame_offsets), or None while the frames so far cannot tell them
    (too few, or a camera that sees no wand with the others yet)."""
    if not np.isfinite(pairs.xy).all():  # grouped without undistorting (guidance's pairs): undistort here
        pairs = replace(pairs, xy=undistort_by_camera(rig.cameras, pairs.camera, pairs.uv))
    try:
        # only whether it succeeds matters here, not which camera stops it: the likeliest to fail first
        return frame_offsets(rig, pairs, window, fail_fast=True)
    except CalibrationError:
        return None


def _out_of_time(rig: Rig, pairs: WandPairs) -> dict[str, int]:
    """{camera id: whole frames} of the cameras whose wand matches the others' only at another
    frame (+-``OUT_OF_TIME_SEARCH``); {} when none does, or when the frames so far cannot tell."""
    if not np.isfinite(pairs.xy).all():  # undistorted once, for the search and the confirmation
        pairs = replace(pairs, xy=undistort_by_camera(rig.cameras, pairs.camera, pairs.uv))
    found = _whole_frames(rig, pairs, OUT_OF_TIME_SEARCH)
    if found is None:
        return {}
    # only an offset both wand ends confirm: a live warning must be true, and a slow wand in a
    # trigger-synchronised recording leaves the midpoint search's neighbouring shifts nearly tied
    return {rig.cameras[c].id: k for c, k in confirmed_offsets(rig, pairs, found).items()}


def _seen(n: int, pairs: WandPairs) -> Seen:
    """What ``pairs`` of ``n`` cameras say before any solve."""
    linked = _shared_frames(pairs, n)
    frames = np.diag(linked).copy()
    np.fill_diagonal(linked, 0)
    per_frame = np.bincount(pairs.frame, minlength=len(pairs.frames))
    shared = np.bincount(pairs.camera[per_frame[pairs.frame] >= 2], minlength=n)
    return Seen(pairs, frames, linked, shared)


def _shared_frames(pairs: WandPairs, n: int) -> np.ndarray:
    """(N, N) int64 frames in which both cameras saw both wand ends (the diagonal: each camera's
    frames), as :func:`wandcal.calib.start.initial.shared_frames` counts them, from each frame's
    own cameras (:func:`wandcal.calib.start.chain.row_pairs`): the work grows with the camera-frames
    (sum of k^2), not with frames x cameras^2 (at 128 x 3000: 2 against 25 ms)."""
    key = np.unique(pairs.frame.astype(np.int64) * n + pairs.camera)  # one row per camera-frame, by frame
    return row_pairs(key // n, key % n, n)


def _solve_set(seen: Seen, seed: np.ndarray | None = None, *, grow: bool = True) -> np.ndarray:
    """(N,) bool: the cameras the fast solve can place, as the start places them.

    The group: the largest set of cameras linked pairwise by at least ``MIN_SOLVE_FRAMES`` shared
    frames, each with that many frames shared with the others (the start's grouping,
    :func:`wandcal.calib.start.chain.camera_groups`: ties to the group of the lowest camera), or
    ``seed`` (N,) bool (the cameras that see the whole static object), those of them with that
    many shared frames, when they are more. Then every camera joins that has ``MIN_SOLVE_FRAMES``
    frames in which two cameras of the group see the wand too (:func:`_grown`): the frames the
    start's resection triangulates to place it. A sparse rig, each frame seen by 2-4 of 128
    cameras, has no pair sharing 10 frames, yet every camera is placed this way (decision 0095).
    ``grow`` False: the pairwise group alone (a points-only rig's links)."""
    ok = seen.shared >= MIN_SOLVE_FRAMES
    best = np.zeros(len(seen.frames), bool)
    groups = camera_groups(seen.linked >= MIN_SOLVE_FRAMES, ok)
    if groups:
        best[groups[0]] = True
    if seed is not None and (seed & ok).sum() > best.sum():  # the seed's cameras that have wand frames to solve by
        best = seed & ok
    return _grown(seen.pairs, best) if grow and best.sum() >= 2 else best


def _whole_static(rig: Rig, static: StaticObservations | None) -> np.ndarray | None:
    """(N,) bool: the cameras that see every marker of the static object (the start places them
    by its PnP), or None without one."""
    if static is None or rig.static_markers is None:
        return None
    return np.bincount(static.camera, minlength=len(rig.cameras)) >= len(rig.static_markers)


def _grown(pairs: WandPairs, group: np.ndarray) -> np.ndarray:
    """``group`` (N,) bool with every camera added, as long as any can be, that sees the wand in at
    least ``MIN_SOLVE_FRAMES`` frames that two cameras of the group see too (each pass over the
    camera-frames: the work grows with the captured pairs, not frames x cameras)."""
    n, frames = len(group), len(pairs.frames)
    key = np.unique(pairs.frame.astype(np.int64) * n + pairs.camera)  # one row per camera-frame
    frame, camera = key // n, key % n
    group = group.copy()
    while True:
        in_group = np.bincount(frame, weights=group[camera], minlength=frames)
        rows = in_group[frame] - group[camera] >= 2  # two other group cameras see the frame
        joins = (np.bincount(camera[rows], minlength=n) >= MIN_SOLVE_FRAMES) & ~group
        if not joins.any():
            return group
        group |= joins


def subsample(pairs: WandPairs, frames_per_camera: int) -> np.ndarray:
    """(F,) bool over ``pairs.frames``: the frames the fast solve keeps.

    Each frame is kept with the largest ``frames_per_camera / frames`` of the cameras that see it
    (1 when one of them has fewer), so every camera keeps about ``frames_per_camera`` frames or
    all of its own. The draw is a fixed number per capture frame number, so as the capture grows
    and the rates fall, the frames kept are a subset of those kept before, plus new ones.
    """
    n = int(pairs.camera.max()) + 1 if len(pairs) else 0
    counts = np.bincount(pairs.camera, minlength=n)
    rate = np.minimum(1.0, frames_per_camera / np.maximum(counts, 1))
    keep_rate = np.zeros(len(pairs.frames))
    np.maximum.at(keep_rate, pairs.frame, rate[pairs.camera])
    draw = (pairs.frames.astype(np.uint64) * np.uint64(_HASH) % np.uint64(_HASH_RANGE)) / _HASH_RANGE
    return draw < keep_rate


def _sub_rig(rig: Rig, cams: np.ndarray) -> Rig:
    return Rig(cameras=tuple(rig.cameras[c] for c in cams), wand_length=rig.wand_length,
               static_markers=rig.static_markers)


def _solve(rig: Rig, seen: Seen, solve_set: np.ndarray, static, settings: GuidanceSettings, start: Solution | None):
    """The fast solve over the cameras of ``solve_set`` and their predicted sigmas (N,), metres
    and radians (NaN for the others)."""
    # the solver loads when a solve runs: the command line reads this module's defaults at start-up
    from wandcal.calib.run.refine import GAUGE_CAMERA, build_problem
    from wandcal.calib.solve.ba import DEFAULT_LOSS, bundle_adjust_points
    from wandcal.calib.start.labels import label_ends
    cams = np.flatnonzero(solve_set)
    index = np.full(len(rig.cameras), -1)
    index[cams] = np.arange(len(cams))
    pairs = seen.pairs
    rows = solve_set[pairs.camera]
    views = np.bincount(pairs.frame[rows], minlength=len(pairs.frames))
    rows &= views[pairs.frame] >= 2
    mine = WandPairs(pairs.frame[rows], index[pairs.camera[rows]], pairs.xy[rows], pairs.uv[rows], pairs.frames,
                     pairs.dropped)
    all_rows = np.bincount(mine.camera, minlength=len(cams))
    kept = mine.subset(subsample(mine, settings.frames_per_camera)[mine.frame])
    sub = _sub_rig(rig, cams)
    kept = replace(kept, xy=undistort_by_camera(sub.cameras, kept.camera, kept.uv))
    ids = tuple(sub.ids)
    warm = start is not None and start.ids == ids
    if start is not None and warm:
        R, t = start.R, start.t
    else:
        R, t = _start_poses(rig, sub, kept, cams, static, start)
    labelled = label_ends(R, t, kept, np.ones(len(cams), bool), sub.wand_length)[0]
    setup = build_problem(sub, labelled, R, t, GAUGE_CAMERA)
    # calibrate's ba (Cauchy, the cameras' stop, judge_frames=False as WAND_FRAMES_IN_STOP) for at most
    # SOLVE_STEPS steps: the sigma needs the information at a near estimate, not the converged poses
    r = bundle_adjust_points(setup.model, None, None, loss=DEFAULT_LOSS, max_iter=SOLVE_STEPS, judge_frames=False)
    R, t = setup.model.poses(r.x)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise CalibrationError(f"the fast solve diverged ({r.info.get('status')}); keep waving where several "
                               "cameras see the wand")
    if r.covariance is None:
        raise CalibrationError("the frames so far leave a camera's pose undetermined (a singular information "
                               "matrix); keep waving through the whole volume")
    center_k, rotation_k = relative_uncertainty(R, t, r.covariance)
    used = np.bincount(setup.problem.camera, minlength=len(cams)) / 2  # two ends per camera-frame
    scale = np.sqrt(np.minimum(used / np.maximum(all_rows, 1), 1.0))
    center = np.full(len(rig.cameras), np.nan)
    rotation = np.full(len(rig.cameras), np.nan)
    center[cams] = center_k * scale
    rotation[cams] = rotation_k * scale
    info = {"frames_used": int(setup.problem.n_frames), "cameras": len(cams), "warm_start": bool(warm),
            "iterations": int(r.info.get("iterations", 0))}
    return Solution(ids, R, t), center, rotation, info


def _start_poses(rig: Rig, sub: Rig, kept: WandPairs, cams: np.ndarray, static: StaticObservations | None,
                 start: Solution | None) -> tuple[np.ndarray, np.ndarray]:
    """The start's poses (K, 3, 3), (K, 3) of the solve's cameras ``cams`` (indices into ``rig``).

    Where the last update's :class:`Solution` holds at least two of them (the solve set grew or
    shrank since), those keep their solved poses, as the static object's PnP would place them, and
    the start places only the others (a live update at 128 cameras places the cameras that joined,
    not all 128); where that start fails, or without such a solution, the cold start from the
    static object and the wand."""
    from wandcal.calib.start.initial import initial_poses
    from wandcal.calib.start.static import StaticPose, solve_static

    if start is not None:
        known = {cid: k for k, cid in enumerate(start.ids)}
        prior = [known.get(cid) for cid in sub.ids]
        if sum(k is not None for k in prior) >= 2:
            placed = [None if k is None else StaticPose(start.R[k], start.t[k], np.zeros(0, np.int64), 0.0, np.inf)
                      for k in prior]
            try:
                init = initial_poses(sub, kept, placed)
                return init.R, init.t
            except CalibrationError:
                pass  # a camera the solved ones cannot place: start afresh
    static_poses = None
    if static is not None and rig.static_markers is not None:
        index = np.full(len(rig.cameras), -1)
        index[cams] = np.arange(len(cams))
        mask = index[static.camera] >= 0
        static_poses = solve_static(sub, StaticObservations(index[static.camera[mask]], static.uv[mask]))
    init = initial_poses(sub, kept, static_poses)
    return init.R, init.t


def relative_uncertainty(R: np.ndarray, t: np.ndarray, covariance) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's centre and rotation 1-sigma relative to the rest of the rig: the geometry
    uncertainty of :func:`wandcal.calib.solve.gauge_free.split_uncertainty`, the same definition as
    a calibration's ``geometry_std_mm``, so guidance and ``wandcal calibrate`` agree.

    Args:
        R, t: (K, 3, 3), (K, 3) gauge-frame poses of the solve.
        covariance: their :class:`wandcal.calib.solve.uncertainty.PoseCovariance`.

    Returns:
        (center (K,) metres, rotation (K,) radians).
    """
    from wandcal.calib.solve.gauge_free import gauge_covariance, split_uncertainty

    split = split_uncertainty(R, t, gauge_covariance(R, t, covariance.free, covariance.cov))
    return split.center_std, split.rotation_std
