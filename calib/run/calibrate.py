"""The whole calibration: observations -> initial poses -> labels -> refinement -> world frame.

``calibrate`` is the entry point of a calibration from a capture (the CLI, the service and the
tests call it; ``wandcal calibrate --solve-only`` enters through
:func:`wandcal.calib.run.resolve.solve_only`). It runs the named steps of docs/architecture.md in
order: observations, whole-frame sync, start, sub-frame sync, refine, world frame, figures and
judgement; what one step hands the next is a small frozen dataclass.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks, WandPairs, point_tracks, wand_pairs
from wandcal.calib.rig import (
    AxisObservations,
    PointObservations,
    Rig,
    StaticObservations,
    VerticalObservations,
    WandObservations,
)
from wandcal.calib.run.camera_figures import CameraFigures
from wandcal.calib.run.camera_reports import (
    camera_reports,
    intrinsics_reports,
    summary_warnings,
    uncertainty_reports,
    with_warnings,
)
from wandcal.calib.run.judgement import acted_warnings, judge
from wandcal.calib.run.marker_steps import aligned_markers, marker_blobs, with_markers
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import (
    GAUGE_CAMERA,
    Progress,
    Refined,
    build_problem,
    check_intrinsics_request,
    refine,
    reject_outliers,
    triangulated,
    up_direction,
)
from wandcal.calib.run.result import CalibrationResult, SolverReport, WandReport, WorldFrame
from wandcal.calib.solve.sync import TimeColumns, Tracks, fit_timing, sync_report
from wandcal.calib.solve.sync.fit import BA_FIT_FRAMES, MAX_FIT_FRAMES
from wandcal.calib.start.degenerate import check_capture
from wandcal.calib.start.frame_offsets import FrameOffsets, TooFewShared, frame_offsets, shift_frames, shift_pairs
from wandcal.calib.start.initial import Initial, initial_poses
from wandcal.calib.start.labels import label_ends
from wandcal.calib.start.static import StaticPose, solve_static
from wandcal.calib.start.vertical import unused_warning as vertical_unused
from wandcal.calib.start.world import Reference, apply, world_frame

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
    first poses at those offsets), which the start step takes as they are."""

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


@dataclass(frozen=True, eq=False)
class Solved:
    """The refinement's outcome and what the result says of it: r, the refined outcome (gauge
    frame); every_track: every point track as given (each method is judged on them all);
    marker_pairs: a multi-marker wand's pair lengths; sync: the result's ``sync`` section; dropped:
    what the solve left out, by reason."""

    r: Refined
    every_track: PointTracks | None
    marker_pairs: list[dict] | None
    sync: dict | None
    dropped: dict


@dataclass(frozen=True, eq=False)
class Placed:
    """The rig in the world frame: R (N, 3, 3), t (N, 3) world->camera, metres; wand (F, 2, 3)
    ends and X (T, 3) points, metres; Rw, tw the map x_world = Rw x + tw from the gauge frame;
    world: the result's world frame."""

    R: np.ndarray
    t: np.ndarray
    wand: np.ndarray
    X: np.ndarray | None
    Rw: np.ndarray
    tw: np.ndarray
    world: WorldFrame


def calibrate(
    rig: Rig,
    wand: WandObservations | None,
    static: StaticObservations | None = None,
    *,
    options: CalibrationOptions = CalibrationOptions(),  # noqa: B008  (frozen: one shared default is safe)
    progress: Progress | None = None,
    points: PointObservations | None = None,
    axis: AxisObservations | None = None,
    vertical: VerticalObservations | None = None,
) -> CalibrationResult:
    """Calibrate the rig's extrinsics from wand blobs, single-point tracks and an optional static
    object or axis points.

    Args:
        rig: cameras with intrinsics, wand length (None without a wand), optional static object.
        wand: raw, unlabeled wand blobs (None or empty without a wand).
        static: static-object blobs, or None.
        options: the method and its settings (:class:`wandcal.calib.run.options.CalibrationOptions`,
            checked here first).
        progress: optional callable(dict) with keys stage, message and, while refining,
            iteration and cost. An exception raised by it aborts the calibration.
        points: single-point tracks (points.csv), or None. ``ba`` refines them as free 3D
            points; the other methods use them for the start only.
        axis: axis points (axis.csv) that set the world frame when there is no static object.
        vertical: floor points (floor.csv) or a dropped object's track (drop.csv) that set the
            world's vertical when there is neither a static object nor axis points.

    Raises:
        CalibrationError: the input cannot give a calibration; the message says why and what to do.
    """
    options.check()
    check_intrinsics_request(rig, options.refine_intrinsics)
    tell: Progress = progress or _silent
    started = time.perf_counter()
    warnings: list[str] = []
    tell({"stage": "observations", "message": "undistorting and grouping wand blobs and point tracks"})
    has_wand = rig.wand_length is not None and wand is not None and len(wand) > 0
    wand, sync = _whole_frame_sync(rig, wand if has_wand else None, options, tell, warnings, static)
    obs = _observations(rig, wand, points, sync, has_wand, options.method)
    start = _start(rig, obs, static, tell, warnings, synced=sync is not None, sync=sync)
    start, sync = _subframe_sync(rig, start, sync, options, obs.blobs)
    solved = _refine(rig, obs, start, sync, options, tell, warnings)
    reference = axis if axis is not None and len(axis) else vertical
    placed = _world(solved, obs, start, (static, reference), tell, warnings)
    cameras, wand_report, world = _figures(solved, obs, start, placed, (static, reference), options.method, tell,
                                           warnings)
    placed = replace(placed, world=world)
    cameras, verdict, solver = _judgement(solved, obs, placed, cameras, wand_report, options.method, tell, warnings)
    solver = replace(solver, total_seconds=time.perf_counter() - started)
    tell({"stage": "done", "message": "calibration finished"})
    r = solved.r
    return CalibrationResult(
        rig=r.rig, R=placed.R, t=placed.t, wand=placed.wand, frames=r.setup.frames, cameras=tuple(cameras),
        wand_report=wand_report, solver=solver, world=placed.world, dropped=solved.dropped, warnings=warnings,
        points=placed.X, verdict=verdict, sync=solved.sync,
    )


def _silent(event: dict) -> None:
    """The progress callback when none is given."""


def _whole_frame_sync(rig: Rig, wand: WandObservations | None, options: CalibrationOptions, tell: Progress,
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
        timed = frame_offsets(rig, unshifted, options.sync_max_offset, start)
    except TooFewShared:  # a sparse rig: no two cameras share enough frames, all of them together do
        from wandcal.calib.run.sparse_offsets import offsets_by_triangulation

        static_poses = solve_static(rig, static) if static is not None and rig.static_markers is not None else None
        timed, found_at = offsets_by_triangulation(rig, unshifted, options.sync_max_offset, start, static_poses=static_poses)
        warnings += timed.notes
        return shift_frames(wand, timed.offsets), SyncState(whole=timed, unshifted=unshifted, found_at=found_at)
    warnings += timed.notes
    return shift_frames(wand, timed.offsets), SyncState(whole=timed, unshifted=unshifted)


def _observations(rig: Rig, wand: WandObservations | None, points: PointObservations | None, sync: SyncState | None,
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


def _start(rig: Rig, obs: Observations, static: StaticObservations | None, tell: Progress,
           warnings: list[str], *, synced: bool = False, sync: SyncState | None = None) -> Start:
    """The static object's poses, the capture's checks, the first poses and the wand ends labelled.
    A start refused without ``--sync auto`` (``synced`` false) names a camera whose shift in time
    would let it place every camera (:func:`wandcal.calib.judge.faults.start_timing.out_of_time_refusal`)."""
    # on a sparse rig the sync placed the cameras at the offsets it found, from these pairs alone
    found_at = sync.found_at if sync is not None and obs.blobs is None and obs.tracks is None else None
    static_poses = _static_poses(rig, static, tell, warnings, found_at)
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
    if obs.has_wand and not planar:
        labelled = label_ends(init.R, init.t, obs.pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    return Start(static_poses=static_poses, init=init, labelled=labelled)


def _static_poses(rig: Rig, static: StaticObservations | None, tell: Progress,
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


def _subframe_sync(rig: Rig, start: Start, sync: SyncState | None, options: CalibrationOptions,
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


def _refine(rig: Rig, obs: Observations, start: Start, sync: SyncState | None, options: CalibrationOptions,
            tell: Progress, warnings: list[str]) -> Solved:
    """The chosen method on the labelled ends and the point tracks, the outlier passes, the time
    offsets' report, and a multi-marker wand's second refinement."""
    method, columns = options.method, (sync.columns if sync is not None and sync.refined else None)
    r, tracks = _first_solve(rig, obs, start, options, tell, warnings, columns)
    if options.reject_outliers:
        r = reject_outliers(r, method, options, tell, columns=columns)
    sync_doc = _sync_report(rig, r, sync, options, warnings)
    marker_pairs, every_track = None, obs.tracks
    if obs.blobs is not None:  # under sync every marker resampled to the reference instants, as the ends
        blobs = sync.blobs if sync is not None and sync.blobs is not None else obs.blobs
        r, marker_pairs, interior = with_markers(rig, blobs, r, options, tell, warnings)
        # the interior markers are judged as points seen by the cameras that see them (issue 31)
        every_track = interior if every_track is None else every_track.joined(interior)
    dropped = dict(obs.pairs.dropped) | (dict(tracks.dropped) if tracks is not None else {})
    dropped |= {"outliers": r.outliers} | ({"point_outliers": r.point_outliers} if tracks is not None else {})
    return Solved(r=r, every_track=every_track, marker_pairs=marker_pairs, sync=sync_doc, dropped=dropped)


def _first_solve(rig: Rig, obs: Observations, start: Start, options: CalibrationOptions, tell: Progress,
                 warnings: list[str], columns: TimeColumns | None) -> tuple[Refined, PointTracks | None]:
    """The problem at the start poses and the method's first solve on it (the outlier passes
    follow); the point tracks it refines with (None for ``paper``, which starts from them only)."""
    method, init = options.method, start.init
    setup = build_problem(rig, start.labelled, init.R, init.t, GAUGE_CAMERA)
    tracks, X = obs.tracks, None
    if tracks is not None:
        tracks, X = triangulated(init.R, init.t, tracks)
        if method == "paper":
            warnings.append(f"the {len(tracks)} point-track observations placed the cameras at the start; only "
                            "--method ba and lp refine with them")
            tracks = None
    # an outlier pass follows (a robust ba's polish; lp's and paper's passes): this solve is not the final one
    r = refine(rig, start.labelled, setup, tracks, X, method, options, tell, up_direction(rig, init.R, init.t, setup),
               final=not options.polish, columns=columns)
    if not (np.all(np.isfinite(r.R)) and np.all(np.isfinite(r.t))):
        raise CalibrationError(
            f"method {method!r} diverged ({r.info.get('status')}): its camera poses are not finite; "
            "check the intrinsics and the static object" + ("" if method == "ba" else ", or try --method ba")
        )
    return r, tracks


def _sync_report(rig: Rig, r: Refined, sync: SyncState | None, options: CalibrationOptions,
                 warnings: list[str]) -> dict | None:
    """The result's ``sync`` section: the fit's offsets plus what ``ba`` added over every frame
    (docs/decisions/0022-sync-cost-and-standard-error.md); None without sync."""
    if sync is None or sync.columns is None:
        return None
    std = r.camera_std[:, -1] if r.dt is not None and r.camera_std is not None else None
    timing = sync.columns.folded(r.dt, std)
    start = np.asarray(options.sync_start) if options.sync_start is not None else None
    doc, found = sync_report(rig.ids, sync.whole.offsets, sync.whole.reference, timing, start,
                             options.frame_rate_hz, options.sync_drift)
    warnings += found
    return doc


def _world(solved: Solved, obs: Observations, start: Start, frame_data: tuple[StaticObservations | None, Reference],
           tell: Progress, warnings: list[str]) -> Placed:
    """The refined rig expressed in the world frame (the static object's, the axis points', or the
    gauge camera's); ``world.scale`` says whether the wand gave the scale."""
    r, (static, axis) = solved.r, frame_data
    tell({"stage": "world", "message": "expressing the rig in the world frame"})
    Rw, tw, world = world_frame(r.rig, r.R, r.t, GAUGE_CAMERA, static, start.static_poses, axis, wand=r.wand, points=r.X)
    if isinstance(axis, VerticalObservations) and world["frame"] not in ("floor", "gravity"):
        warnings.append(vertical_unused(r.rig, axis, r.R, r.t, world["frame"]))
    R, t, wand_pts = apply(Rw, tw, r.R, r.t, r.wand)
    X = r.X @ Rw.T + tw if r.X is not None else None
    placed_world = WorldFrame.from_json(world | {"scale": "wand" if obs.has_wand else "arbitrary"})
    if not obs.has_wand and not any("scale" in note for note in start.init.notes):
        warnings.append("no wand: the rig is calibrated up to scale (world.scale is 'arbitrary')")
    return Placed(R=R, t=t, wand=wand_pts, X=X, Rw=Rw, tw=tw, world=placed_world)


def _figures(solved: Solved, obs: Observations, start: Start, placed: Placed,
             frame_data: tuple[StaticObservations | None, Reference], method: str, tell: Progress,
             warnings: list[str]) -> tuple[list[CameraFigures], WandReport | None, WorldFrame]:
    """Each camera's figures (errors, uncertainty in the world frame, refined intrinsics, its
    warnings), the summary warnings (``warnings`` folded in place), the wand's report (None
    without a wand) and the world frame with its placement's uncertainty."""
    r, world = solved.r, placed.world
    rig, setup, info = r.rig, r.setup, r.info
    cameras, found = camera_reports(rig, setup, placed.R, placed.t, placed.wand, start.init, r.tracks, placed.X,
                                    obs.has_wand)
    warnings += found
    if r.covariance is not None:
        tell({"stage": "uncertainty", "message": "propagating the pose uncertainty into the world frame"})
        static, axis = frame_data
        pose_std, world = uncertainty_reports(rig, r, world, (static, start.static_poses, axis), placed.Rw, placed.tw,
                                              obs.has_wand)
        cameras = [replace(cam, uncertainty=u) for cam, u in zip(cameras, pose_std)]
    if info.get("refined_intrinsics") and r.camera_std is not None:
        intrinsics, found = intrinsics_reports(rig, r.camera_std, info["refined_intrinsics"])
        cameras = [replace(cam, intrinsics=k) for cam, k in zip(cameras, intrinsics)]
        warnings += found
    cameras, warnings[:] = with_warnings(cameras, warnings + summary_warnings(solved.dropped, info, method,
                                                                              len(start.labelled)), rig.ids)
    if not obs.has_wand:
        return cameras, None, world
    lengths = quality.free_wand_lengths(placed.R, placed.t, setup.problem)
    pairs = solved.marker_pairs
    return cameras, WandReport(rig.wand_length, float(lengths.mean()), float(lengths.std()), int(setup.problem.n_frames),
                               tuple(pairs) if pairs is not None else None), world


def _judgement(solved: Solved, obs: Observations, placed: Placed, cameras: list[CameraFigures],
               wand_report: WandReport | None, method: str, tell: Progress, warnings: list[str]
               ) -> tuple[list[CameraFigures], dict, SolverReport]:
    """The cameras' figures judged and the rig's verdict (calib/run/judgement.py) on every
    observation, point tracks included, its checks appended to ``warnings``; and the solver's report."""
    r = solved.r
    rig, setup, info = r.rig, r.setup, r.info
    seen_cam, seen_uv = setup.problem.camera, setup.uv
    if r.tracks is not None and len(r.tracks):
        seen_cam, seen_uv = np.concatenate([seen_cam, r.tracks.camera]), np.concatenate([seen_uv, r.tracks.uv])
    solver = SolverReport(method, info)
    tell({"stage": "judge", "message": "judging the rig and looking for a camera or input at fault"})
    every_track = solved.every_track  # every method is judged on the same observations, point tracks included
    if every_track is not None and info.get("refined_intrinsics"):
        every_track = replace(every_track, xy=undistort_by_camera(rig.cameras, every_track.camera, every_track.uv))
    cameras, verdict, checks = judge(method, rig, cameras, wand_report, placed.world, placed.R, placed.t, r.labelled,
                                     every_track, solver, (seen_cam, seen_uv),
                                     (setup.frames, placed.wand) if obs.has_wand else None)
    cameras, warnings[:] = acted_warnings(cameras, warnings, rig.ids)
    warnings += checks
    return cameras, verdict, solver
