"""Re-solve some cameras of a calibrated rig from a fresh wand capture, holding every other one.

A camera knocked overnight need not mean recalibrating everything: the cameras that did not move
(``wandcal check`` tells which) keep their poses bit for bit, and with them the world frame; the
named ones are placed again by resection against the wand ends that the held cameras
triangulate, then refined by ``ba`` with the held cameras fixed.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.judge import quality
from wandcal.calib.observations import WandPairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.run.camera_reports import camera_reports, summary_warnings, with_warnings
from wandcal.calib.run.judgement import judge
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import Progress, build_problem, refine, reject_outliers, up_direction
from wandcal.calib.run.result import (
    CalibrationResult,
    CameraFigures,
    PoseUncertainty,
    SolverReport,
    WandReport,
    WorldFrame,
)
from wandcal.calib.solve.uncertainty import world_uncertainty
from wandcal.calib.start.initial import Initial
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.markerlabels import end_pairs
from wandcal.calib.start.resection import resect_camera
from wandcal.calib.triangulate import triangulate_points

MIN_HELD = 2  # the held cameras must triangulate the wand: two at least


def solve_only(rig: Rig, wand: WandObservations, R0: np.ndarray, t0: np.ndarray, solve: list[str], world: WorldFrame,
               previous: list[CameraFigures] | None = None, progress: Progress | None = None,
               options: CalibrationOptions = CalibrationOptions()) -> CalibrationResult:  # noqa: B008  (frozen)
    """Re-solve the cameras named in ``solve``; every other camera keeps (R0, t0) exactly.

    Args:
        rig: the cameras (intrinsics as in the previous result) and the wand length.
        wand: the fresh capture's raw wand blobs.
        R0, t0: (N, 3, 3), (N, 3) the previous result's world->camera poses, in ``rig`` order.
        solve: ids of the cameras to re-solve.
        world: the previous result's world frame (kept: the held cameras carry its frame).
        previous: the previous result's camera figures (rig order), for the held cameras' uncertainty.
        options: ``loss`` and ``reject_outliers`` are used; the method must be ``ba``, with the
            intrinsics held.

    Raises:
        CalibrationError: an unknown id, too few held cameras, or a camera that cannot be placed.
    """
    options.check()
    if options.method != "ba" or options.refine_intrinsics:
        raise CalibrationError("--solve-only re-solves poses with --method ba only, intrinsics held")
    tell: Progress = progress or (lambda event: None)
    started = time.perf_counter()
    if rig.wand_length is None:
        raise CalibrationError("--solve-only needs a wand capture: rig.json gives no wand.length_m")
    moving = np.zeros(len(rig.cameras), bool)
    for cid in solve:
        moving[rig.index(cid)] = True
    if (~moving).sum() < MIN_HELD:
        raise CalibrationError(f"--solve-only must leave at least {MIN_HELD} cameras held to keep the world frame; "
                               "to re-solve more, calibrate the whole rig")
    tell({"stage": "observations", "message": "undistorting and grouping wand blobs"})
    pairs = end_pairs(rig, wand)  # every kind of wand: its end markers
    tell({"stage": "initial", "message": "placing the re-solved cameras against the held ones"})
    init = _placed_against_held(rig, pairs, R0, t0, moving)
    R, t = init.R, init.t
    tell({"stage": "labels", "message": "telling the wand ends apart"})
    labelled = label_ends(R, t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0]
    setup = build_problem(rig, labelled, R, t, ~moving)
    r = refine(rig, labelled, setup, None, None, "ba", options, tell, up_direction(rig, R, t, setup),
               final=not options.polish)
    if options.reject_outliers:
        r = reject_outliers(r, "ba", options, tell)
    R_new, t_new = r.R.copy(), r.t.copy()
    R_new[~moving], t_new[~moving] = R0[~moving], t0[~moving]  # held: bit for bit
    cameras, warnings = camera_reports(rig, r.setup, R_new, t_new, r.wand, init, None, None, True)
    if r.covariance is not None:
        # the world is the held cameras': the re-solved poses' uncertainty given them
        center, rotation = world_uncertainty(r.R, r.t, r.covariance, lambda Rp, tp, shift: (np.eye(3), np.zeros(3)))
        cameras = [replace(cam, uncertainty=_held_or_new(k, moving, center, rotation, previous))
                   for k, cam in enumerate(cameras)]
    dropped = dict(pairs.dropped) | {"outliers": r.outliers}
    cameras, warnings = with_warnings(cameras, warnings + summary_warnings(dropped, r.info, "ba", len(labelled)), rig.ids)
    lengths = quality.free_wand_lengths(R_new, t_new, r.setup.problem)
    wand_report = WandReport(rig.wand_length, float(lengths.mean()), float(lengths.std()), int(r.setup.problem.n_frames))
    solver = SolverReport("ba", r.info, tuple(solve), time.perf_counter() - started)
    cameras, verdict, checks = judge("ba", rig, cameras, wand_report, world, R_new, t_new, labelled, None, solver,
                                     (r.setup.problem.camera, r.setup.uv))
    warnings += checks
    tell({"stage": "done", "message": "calibration finished"})
    return CalibrationResult(rig=rig, R=R_new, t=t_new, wand=r.wand, frames=r.setup.frames, cameras=tuple(cameras),
                             wand_report=wand_report, solver=solver, world=world, dropped=dropped, warnings=warnings,
                             verdict=verdict)


def _held_or_new(k: int, moving: np.ndarray, center: np.ndarray, rotation: np.ndarray,
                 previous: list[CameraFigures] | None) -> PoseUncertainty:
    """Camera k's pose uncertainty: a re-solved camera's given the held ones (center: (N,)
    metres, rotation: (N,) radians), a held camera's as the previous result gave it."""
    if moving[k]:
        return PoseUncertainty(float(1000 * center[k]), float(np.degrees(rotation[k])))
    old = previous[k].uncertainty if previous is not None else None
    return PoseUncertainty(old.center_std_mm if old else None, old.rotation_std_deg if old else None)


def _placed_against_held(rig: Rig, pairs: WandPairs, R0: np.ndarray, t0: np.ndarray, moving: np.ndarray) -> Initial:
    """The start poses: the held cameras' (R0, t0) as they are, each ``moving`` (N,) bool camera
    resected against the wand ends the held cameras triangulate (wand_length set)."""
    R, t = R0.copy(), t0.copy()
    held, _ = label_ends(R, t, pairs, ~moving, rig.wand_length)
    point, camera, xy = flatten(held)
    ends = triangulate_points(R, t, point, camera, xy, 2 * len(pairs.frames)).reshape(-1, 2, 3)
    source = ["previous result" for _ in rig.cameras]
    for c in np.flatnonzero(moving):
        mine = pairs.camera == c
        seen = np.all(np.isfinite(ends[pairs.frame[mine]]), axis=(1, 2))
        pose = resect_camera(ends[pairs.frame[mine]][seen], pairs.xy[mine][seen], np.zeros((0, 3)), np.zeros((0, 2)),
                             float(rig.cameras[c].focal.mean()))
        if isinstance(pose, Failure):
            raise CalibrationError(f"{rig.cameras[c].id} could not be placed against the held cameras ({pose}); "
                                   f"wave the wand where {rig.cameras[c].id} and two held cameras see it")
        R[c], t[c] = pose
        source[c] = "wand resection against the held cameras"
    return Initial(R, t, source)
