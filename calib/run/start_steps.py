"""The steps of :func:`wandcal.calib.run.calibrate.calibrate` up to the refinement's start, and the
values they hand on: the observations grouped (:class:`Observations`), the whole-frame sync
(:class:`SyncState`), the static object's poses, the capture's checks, the first poses and the wand
ends labelled (:class:`Start`), and the sub-frame sync with the start poses refined.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.observations import PointTracks, WandPairs, point_tracks, wand_pairs
from wandcal.calib.rig import PointObservations, Rig, StaticObservations, WandObservations
from wandcal.calib.run.marker_steps import aligned_markers, marker_blobs
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import Progress
from wandcal.calib.solve.sync import TimeColumns, Tracks, fit_timing
from wandcal.calib.solve.sync.fit import BA_FIT_FRAMES, MAX_FIT_FRAMES
from wandcal.calib.start.degenerate import check_capture
from wandcal.calib.start.initial import Initial, initial_poses
from wandcal.calib.start.labels import label_ends
from wandcal.calib.start.offsets.whole_frames import (
    FrameOffsets,
    TooFewShared,
    frame_offsets,
    shift_frames,
    shift_pairs,
)
from wandcal.calib.start.static import StaticPose, solve_static

if TYPE_CHECKING:
    from wandcal.calib.run.sparse_offsets import SparseStart
    from wandcal.calib.start.markerlabels import MarkerBlobs


@dataclass(frozen=True, eq=False)
class Observations:
    """The capture grouped for the solve. pairs: each camera-frame's two wand ends (undistorted,
    on the reference camera's frame numbers after the whole-frame sync); blobs: a wand of three or
    more markers, its camera-frames ordered along the wand (else None); tracks: single-point
    tracks seen by two cameras or more, or None."""

    has_wand: bool
    pairs: WandPairs
    blobs: MarkerBlobs | None
    tracks: PointTracks | None


@dataclass(frozen=True, eq=False)
class SyncState:
    """The cameras' time offsets, carried from the sync steps to the refinement and the result
    (docs/sync.md). whole: the whole-frame offsets the frames were renumbered by; unshifted: the
    pairs on each camera's own frame numbers; columns: the sub-frame fit with the frames resampled
    to the reference camera's instants (None until the sub-frame step); refined: whether the final
    ``ba`` refines the offsets again, over every frame (``columns`` then its columns); blobs: a
    multi-marker wand's camera-frames with every marker resampled to those instants too; found_at:
    on a sparse rig, the start the offsets were found with (the static object's poses and the
    first poses at those offsets, the pairs labelled at them), which the start step takes as they are."""

    whole: FrameOffsets
    unshifted: WandPairs
    found_at: SparseStart | None = None
    columns: TimeColumns | None = None
    refined: bool = False
    blobs: MarkerBlobs | None = None  # a multi-marker wand's every marker, resampled as the ends are


@dataclass(frozen=True, eq=False)
class Start:
    """The start of the refinement: static_poses: each camera's pose on the static object (or
    None without one); init: the first poses, gauge frame; labelled: the wand ends told apart
    (resampled to the reference instants under sync)."""

    static_poses: list[StaticPose | Failure] | None
    init: Initial
    labelled: WandPairs


def whole_frame_sync(rig: Rig, wand: WandObservations | None, options: CalibrationOptions, tell: Progress,
                      warnings: list[str], static: StaticObservations | None = None,
                      ) -> tuple[WandObservations | None, SyncState | None]:
    """With sync "auto": each camera's whole-frame offset from the wand, and the blobs renumbered
    onto the reference camera's frames (whole frames first: a camera out of time by frames cannot
    be placed). ``wand``: None without a wand. On a sparse rig (no two cameras share enough
    frames) the offsets are found against every camera's triangulations together, from start
    poses placed with the static object's too when there is one."""
    if options.sync != "auto":
        return wand, None
    if wand is None:
        warnings.append("sync auto finds the time offsets from the wand; this capture has none, so its frames are taken as "
                        "synchronised")
        return wand, None
    from wandcal.calib.start.markerlabels import end_pairs

    tell({"stage": "sync", "message": "finding each camera's time offset from the wand"})
    unshifted = end_pairs(rig, wand)  # every kind of wand: its end markers
    start = np.asarray(options.sync_start) if options.sync_start is not None else None
    try:
        timed = frame_offsets(rig, unshifted, options.sync_max_offset, start, prove_sparse=True)
    except TooFewShared:  # a sparse rig: no two cameras share enough frames, all of them together do
        from wandcal.calib.run.sparse_offsets import offsets_by_triangulation

        static_poses = solve_static(rig, static) if static is not None and rig.static_markers is not None else None
        timed, found_at = offsets_by_triangulation(rig, unshifted, options.sync_max_offset, start, static_poses=static_poses)
        warnings += timed.notes
        return shift_frames(wand, timed.offsets), SyncState(whole=timed, unshifted=unshifted, found_at=found_at)
    warnings += timed.notes
    return shift_frames(wand, timed.offsets), SyncState(whole=timed, unshifted=unshifted)


def observations(rig: Rig, wand: WandObservations | None, points: PointObservations | None, sync: SyncState | None,
                  has_wand: bool, method: str) -> Observations:
    """The wand's camera-frames and the point tracks, refused where they cannot calibrate the rig.
    ``wand``: None without a wand (``has_wand`` false)."""
    blobs = marker_blobs(rig, wand) if wand is not None else None
    if blobs is not None:
        pairs = blobs.ends()
    elif sync is not None:  # the pairs already grouped, renumbered
        pairs = shift_pairs(sync.unshifted, sync.whole.offsets)
    else:
        pairs = wand_pairs(rig, wand) if wand is not None else WandPairs.empty()
    tracks = point_tracks(rig, points) if points is not None and len(points) else None
    if not has_wand and (tracks is None or not len(tracks)):
        raise CalibrationError(
            "the capture has no wand blobs (or no wand length) and no point seen by two cameras; record the wand, "
            "or give points.csv with markers seen by several cameras at once"
        )
    if not has_wand and method not in ("ba", "lp"):
        raise CalibrationError(f"a capture without a wand calibrates with --method ba or lp, not {method!r}")
    seen = np.bincount(pairs.camera, minlength=len(rig.cameras))
    if tracks is not None:
        seen = seen + np.bincount(tracks.camera, minlength=len(rig.cameras))
    for c, cam in enumerate(rig.cameras):
        if seen[c] == 0:
            raise CalibrationError(
                f"camera {cam.id!r} never saw both wand ends in one frame"
                + (" nor a point that another camera saw" if tracks is not None else "")
                + "; check that it is connected and aimed at the volume, or remove it from rig.json"
            )
    return Observations(has_wand=has_wand, pairs=pairs, blobs=blobs, tracks=tracks)


def refinement_start(rig: Rig, obs: Observations, static: StaticObservations | None, tell: Progress,
           warnings: list[str], *, synced: bool = False, sync: SyncState | None = None) -> Start:
    """The static object's poses, the capture's checks, the first poses and the wand ends labelled.
    A start refused without ``--sync auto`` (``synced`` false) names a camera whose shift in time
    would let it place every camera (:func:`wandcal.calib.judge.faults.start_timing.out_of_time_refusal`)."""
    # on a sparse rig the sync placed the cameras at the offsets it found, from these pairs alone
    found_at = sync.found_at if sync is not None and obs.blobs is None and obs.tracks is None else None
    static_poses = static_object_poses(rig, static, tell, warnings, found_at)
    warnings += check_capture(rig, obs.pairs, obs.tracks, static_poses)  # degenerate captures: calib/start/degenerate.py
    tell({"stage": "initial", "message": "initial poses"})
    try:
        init = found_at.init if found_at is not None else initial_poses(rig, obs.pairs, static_poses, points=obs.tracks)
    except CalibrationError as exc:
        if synced or obs.blobs is not None:
            raise
        from wandcal.calib.judge.faults.start_timing import out_of_time_refusal

        raise out_of_time_refusal(exc, rig, obs.pairs, static_poses, obs.tracks) from None
    warnings += init.notes
    tell({"stage": "labels", "message": "telling the wand ends apart"})
    planar = obs.blobs is not None and obs.blobs.fit_px is not None  # a planar wand's rows come labelled from the layout
    labelled = obs.pairs
    if obs.has_wand and not planar and found_at is not None:  # the sync labelled these pairs at these poses
        labelled = found_at.labelled
    elif obs.has_wand and not planar:
        labelled = label_ends(init.R, init.t, obs.pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    return Start(static_poses=static_poses, init=init, labelled=labelled)


def static_object_poses(rig: Rig, static: StaticObservations | None, tell: Progress,
                  warnings: list[str], found_at: SparseStart | None = None) -> list[StaticPose | Failure] | None:
    """Each camera's pose on the static object by PnP (None without one; ``found_at``'s when the
    sync solved them already); a camera it cannot place is placed from the wand, with a warning."""
    if static is None or rig.static_markers is None:
        return None
    tell({"stage": "static", "message": "identifying static-object markers and solving PnP"})
    found = found_at.static_poses if found_at is not None else None
    static_poses = found if found is not None else solve_static(rig, static)
    if not any(static_poses):
        seen_static = [str(p) for c, p in enumerate(static_poses) if len(static.for_camera(c))]
        raise CalibrationError(
            "the static object's markers could not be identified in any camera: "
            + ("; ".join(seen_static) if seen_static else "static.csv has no blobs")
        )
    for c, pose in enumerate(static_poses):
        if not pose:
            warnings.append(f"{pose}; {rig.cameras[c].id} is placed from the wand only")
    return static_poses


def subframe_sync(rig: Rig, start: Start, sync: SyncState | None, options: CalibrationOptions,
                   blobs: MarkerBlobs | None = None) -> tuple[Start, SyncState | None]:
    """With sync: the sub-frame offsets with the start poses refined, and the frames resampled to
    the reference camera's instants; ``ba`` refines the offsets again over every frame. A
    multi-marker wand's ``blobs`` (the rows of ``start.labelled``) are resampled alike, every marker."""
    if sync is None:
        return start, None
    focal = np.array([c.focal for c in rig.cameras])
    tracks_in_time = Tracks(start.labelled, len(rig.cameras))
    markers = aligned_markers(blobs, start.labelled) if blobs is not None else None
    timing = fit_timing(start.init.R, start.init.t, start.labelled, focal, sync.whole.reference, options.sync_drift,
                        max_frames=BA_FIT_FRAMES if options.method == "ba" else MAX_FIT_FRAMES, poses=True,
                        tracks=tracks_in_time, markers=markers)
    columns = TimeColumns(start.labelled, tracks_in_time, timing, focal)
    assert timing.R is not None and timing.t is not None  # poses=True: the fit refined them
    if blobs is not None and markers is not None:  # every marker resampled as the ends were; the rows kept as theirs
        from wandcal.calib.start.markerlabels import MarkerBlobs

        xy, uv = columns.markers(*markers)
        keep = columns.keep
        blobs = MarkerBlobs(blobs.frame[keep], blobs.camera[keep], xy, uv, blobs.frames, blobs.dropped,
                            blobs.fit_px[keep] if blobs.fit_px is not None else None)
    start = replace(start, labelled=columns.resampled, init=replace(start.init, R=timing.R, t=timing.t))
    return start, replace(sync, columns=columns, refined=options.method == "ba", blobs=blobs)
