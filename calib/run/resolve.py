"""Re-solve some cameras of a calibrated rig from a fresh capture, holding every other one.

A camera knocked overnight need not mean recalibrating everything: the cameras that did not move
(``wandcal check`` tells which) keep their poses bit for bit, and with them the world frame; the
named ones are placed again by resection against the wand ends (any kind of wand: its end
markers) and the point tracks that the held cameras triangulate, then refined by ``ba`` with the
held cameras fixed, the point tracks as free points (as ``calibrate`` takes them).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks, WandPairs, point_tracks
from wandcal.calib.rig import PointObservations, Rig, WandObservations
from wandcal.calib.run.camera_figures import CameraFigures, PoseUncertainty
from wandcal.calib.run.camera_reports import camera_reports, summary_warnings, with_warnings
from wandcal.calib.run.judgement import judge
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import (
    Progress,
    Refined,
    build_problem,
    refine,
    reject_outliers,
    triangulated,
    up_direction,
)
from wandcal.calib.run.result import CalibrationResult, SolverReport, WandReport, WorldFrame
from wandcal.calib.solve.uncertainty import world_uncertainty
from wandcal.calib.start.initial import Initial
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.start.resection import resect_camera
from wandcal.calib.triangulate import triangulate_points

MIN_HELD = 2  # the held cameras must triangulate the wand: two at least


def solve_only(rig: Rig, wand: WandObservations | None, R0: np.ndarray, t0: np.ndarray, solve: list[str],
               world: WorldFrame, previous: list[CameraFigures] | None = None, progress: Progress | None = None,
               options: CalibrationOptions = CalibrationOptions(),  # noqa: B008  (frozen)
               points: PointObservations | None = None) -> CalibrationResult:
    """Re-solve the cameras named in ``solve``; every other camera keeps (R0, t0) exactly.

    Args:
        rig: the cameras (intrinsics as in the previous result) and the wand (None length: no wand).
        wand: the fresh capture's raw wand blobs (any kind of wand: its end markers are used), or None.
        R0, t0: (N, 3, 3), (N, 3) the previous result's world->camera poses, in ``rig`` order.
        solve: ids of the cameras to re-solve.
        world: the previous result's world frame (kept: the held cameras carry its frame).
        previous: the previous result's camera figures (rig order), for the held cameras' uncertainty.
        options: ``loss`` and ``reject_outliers`` are used; the method must be ``ba``, with the
            intrinsics held.
        points: the fresh capture's point tracks and labelled keypoints (points.csv), or None:
            used as ``calibrate`` uses them, to place the cameras and in ``ba`` as free points.

    Raises:
        CalibrationError: an unknown id, too few held cameras, no wand nor points, or a camera
            that cannot be placed.
    """
    options.check()
    if options.method != "ba" or options.refine_intrinsics:
        raise CalibrationError("--solve-only re-solves poses with --method ba only, intrinsics held")
    tell: Progress = progress or (lambda event: None)
    started = time.perf_counter()
    has_wand = rig.wand_length is not None and wand is not None and len(wand) > 0
    tracks = point_tracks(rig, points) if points is not None and len(points) else None
    if not has_wand and (tracks is None or not len(tracks)):
        raise CalibrationError("--solve-only needs a fresh capture of the wand (rig.json wand.length_m and wand.csv) or "
                               "of points seen by several cameras at once (points.csv)")
    moving = np.zeros(len(rig.cameras), bool)
    for cid in solve:
        moving[rig.index(cid)] = True
    if (~moving).sum() < MIN_HELD:
        raise CalibrationError(f"--solve-only must leave at least {MIN_HELD} cameras held to keep the world frame; "
                               "to re-solve more, calibrate the whole rig")
    tell({"stage": "observations", "message": "undistorting and grouping wand blobs and point tracks"})
    pairs = end_pairs(rig, wand) if has_wand and wand is not None else WandPairs.empty()
    tell({"stage": "initial", "message": "placing the re-solved cameras against the held ones"})
    init = _placed_against_held(rig, pairs, tracks, R0, t0, moving)
    r, labelled = _refined(rig, pairs, tracks, init, moving, options, tell)
    R_new, t_new = r.R.copy(), r.t.copy()
    R_new[~moving], t_new[~moving] = R0[~moving], t0[~moving]  # held: bit for bit
    return _result(rig, r, (R_new, t_new), init, labelled, tracks, moving, world, previous, solve, started, tell)


def _refined(rig: Rig, pairs: WandPairs, tracks: PointTracks | None, init: Initial, moving: np.ndarray,
             options: CalibrationOptions, tell: Progress) -> tuple[Refined, WandPairs]:
    """``ba`` with the held cameras fixed, on the labelled wand ends and the point tracks; the
    outcome and the labelled pairs."""
    R, t = init.R, init.t
    labelled = pairs
    if len(pairs):
        tell({"stage": "labels", "message": "telling the wand ends apart"})
        labelled = label_ends(R, t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    setup = build_problem(rig, labelled, R, t, ~moving)
    used, X = triangulated(R, t, tracks) if tracks is not None else (None, None)
    r = refine(rig, labelled, setup, used, X, "ba", options, tell, up_direction(rig, R, t, setup),
               final=not options.polish)
    if options.reject_outliers:
        r = reject_outliers(r, "ba", options, tell)
    return r, labelled


def _result(rig: Rig, r: Refined, poses: tuple[np.ndarray, np.ndarray], init: Initial, labelled: WandPairs,
            tracks: PointTracks | None, moving: np.ndarray, world: WorldFrame, previous: list[CameraFigures] | None,
            solve: list[str], started: float, tell: Progress) -> CalibrationResult:
    """The re-solved rig's result: its figures, uncertainty and judgement as ``calibrate`` gives them."""
    R_new, t_new = poses
    has_wand = len(labelled) > 0
    cameras, warnings = camera_reports(rig, r.setup, R_new, t_new, r.wand, init, r.tracks, r.X, has_wand)
    if r.covariance is not None:
        # the world is the held cameras': the re-solved poses' uncertainty given them
        center, rotation = world_uncertainty(r.R, r.t, r.covariance, lambda Rp, tp, shift: (np.eye(3), np.zeros(3)))
        cameras = [replace(cam, uncertainty=_held_or_new(k, moving, center, rotation, previous))
                   for k, cam in enumerate(cameras)]
    dropped = dict(labelled.dropped) | {"outliers": r.outliers}
    if tracks is not None:
        dropped |= dict(tracks.dropped) | {"point_outliers": r.point_outliers}
    cameras, warnings = with_warnings(cameras, warnings + summary_warnings(dropped, r.info, "ba", len(labelled)), rig.ids)
    wand_report = None
    if has_wand:
        lengths = quality.free_wand_lengths(R_new, t_new, r.setup.problem)
        wand_report = WandReport(rig.wand_length, float(lengths.mean()), float(lengths.std()), int(r.setup.problem.n_frames))
    solver = SolverReport("ba", r.info, tuple(solve), time.perf_counter() - started)
    seen_cam, seen_uv = r.setup.problem.camera, r.setup.uv
    if r.tracks is not None and len(r.tracks):
        seen_cam, seen_uv = np.concatenate([seen_cam, r.tracks.camera]), np.concatenate([seen_uv, r.tracks.uv])
    cameras, verdict, checks = judge("ba", rig, cameras, wand_report, world, R_new, t_new, labelled, tracks, solver,
                                     (seen_cam, seen_uv))
    tell({"stage": "done", "message": "calibration finished"})
    return CalibrationResult(rig=rig, R=R_new, t=t_new, wand=r.wand, frames=r.setup.frames, cameras=tuple(cameras),
                             wand_report=wand_report, solver=solver, world=world, dropped=dropped,
                             warnings=warnings + checks, verdict=verdict, points=r.X)


def _held_or_new(k: int, moving: np.ndarray, center: np.ndarray, rotation: np.ndarray,
                 previous: list[CameraFigures] | None) -> PoseUncertainty:
    """Camera k's pose uncertainty: a re-solved camera's given the held ones (center: (N,)
    metres, rotation: (N,) radians), a held camera's as the previous result gave it."""
    if moving[k]:
        return PoseUncertainty(float(1000 * center[k]), float(np.degrees(rotation[k])))
    old = previous[k].uncertainty if previous is not None else None
    return PoseUncertainty(old.center_std_mm if old else None, old.rotation_std_deg if old else None)


def _placed_against_held(rig: Rig, pairs: WandPairs, tracks: PointTracks | None, R0: np.ndarray, t0: np.ndarray,
                         moving: np.ndarray) -> Initial:
    """The start poses: the held cameras' (R0, t0) as they are, each ``moving`` (N,) bool camera
    resected against the wand ends and the point tracks that the held cameras triangulate."""
    R, t = R0.copy(), t0.copy()
    ends = np.zeros((len(pairs.frames), 2, 3))
    if len(pairs):
        held, _ = label_ends(R, t, pairs, ~moving, rig.wand_length)
        point, camera, xy = flatten(held)
        ends = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    X = np.zeros((0, 3))
    if tracks is not None:
        use = ~moving[tracks.camera]
        X = triangulate_points(R, t, tracks.track[use], tracks.camera[use], tracks.xy[use], tracks.n_tracks)
    source = ["previous result" for _ in rig.cameras]
    what = "wand" if tracks is None else "wand and point" if len(pairs) else "point"
    for c in np.flatnonzero(moving):
        mine = pairs.camera == c
        seen = np.all(np.isfinite(ends[pairs.frame[mine]]), axis=(1, 2))
        X_c, xy_c = np.zeros((0, 3)), np.zeros((0, 2))
        if tracks is not None:
            sel = (tracks.camera == c) & np.all(np.isfinite(X[tracks.track]), axis=1)
            X_c, xy_c = X[tracks.track[sel]], tracks.xy[sel]
        pose = resect_camera(ends[pairs.frame[mine]][seen], pairs.xy[mine][seen], X_c, xy_c,
                             float(rig.cameras[c].focal.mean()))
        if isinstance(pose, Failure):
            show = "wave the wand" if tracks is None else "wave the wand or show points" if len(pairs) else "show points"
            raise CalibrationError(f"{rig.cameras[c].id} could not be placed against the held cameras ({pose}); "
                                   f"{show} where {rig.cameras[c].id} and two held cameras see it")
        R[c], t[c] = pose
        source[c] = f"{what} resection against the held cameras"
    return Initial(R, t, source)
