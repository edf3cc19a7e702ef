"""The whole calibration: observations -> initial poses -> labels -> refinement -> world frame.

``calibrate`` is the entry point of a calibration from a capture (the CLI, the service and the
tests call it; ``wandcal calibrate --solve-only`` enters through
:func:`wandcal.calib.run.resolve.solve_only`). It runs the named steps of docs/architecture.md in
order: observations, whole-frame sync, start, sub-frame sync, refine, world frame, figures and
judgement; what one step hands the next is a small frozen dataclass. The steps up to the
refinement's start (observations, whole-frame sync, start, sub-frame sync) and their values are in
:mod:`wandcal.calib.run.start_steps`; the refinement, world frame, figures and judgement are here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import undistort_by_camera
from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks
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
from wandcal.calib.run.marker_steps import with_markers
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
from wandcal.calib.run.start_steps import (
    Observations,
    Start,
    SyncState,
    observations,
    refinement_start,
    subframe_sync,
    whole_frame_sync,
)
from wandcal.calib.solve.sync import TimeColumns, sync_report
from wandcal.calib.start.vertical import unused_warning as vertical_unused
from wandcal.calib.start.world import Reference, apply, world_frame


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
    wand, sync = whole_frame_sync(rig, wand if has_wand else None, options, tell, warnings, static)
    obs = observations(rig, wand, points, sync, has_wand, options.method)
    start = refinement_start(rig, obs, static, tell, warnings, synced=sync is not None, sync=sync)
    start, sync = subframe_sync(rig, start, sync, options, obs.blobs)
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
