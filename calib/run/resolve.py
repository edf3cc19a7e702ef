"""Re-solve some cameras of a calibrated rig from a fresh wand capture, holding every other one.

A camera knocked overnight need not mean recalibrating everything: the cameras that did not move
(``wandcal check`` tells which) keep their poses bit for bit, and with them the world frame; the
named ones are placed again by resection against the wand ends that the held cameras
triangulate, then refined by ``ba`` with the held cameras fixed.
"""

from __future__ import annotations

import time

import numpy as np

from wandcal.calib.errors import CalibrationError, Failure
from wandcal.calib.judge import quality
from wandcal.calib.observations import WandPairs, wand_pairs
from wandcal.calib.rig import Rig, WandObservations
from wandcal.calib.run.calibrate import CalibrationResult
from wandcal.calib.run.camera_reports import camera_reports, summary_warnings
from wandcal.calib.run.judgement import judge
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.run.refine import Progress, build_problem, refine, reject_outliers, up_direction
from wandcal.calib.solve.uncertainty import world_uncertainty
from wandcal.calib.start.initial import Initial
from wandcal.calib.start.labels import flatten, label_ends
from wandcal.calib.start.resection import resect_camera
from wandcal.calib.triangulate import triangulate_points

MIN_HELD = 2  # the held cameras must triangulate the wand: two at least


def solve_only(rig: Rig, wand: WandObservations, R0: np.ndarray, t0: np.ndarray, solve: list[str], world: dict,
               previous: list[dict] | None = None, progress: Progress | None = None,
               options: CalibrationOptions = CalibrationOptions()) -> CalibrationResult:  # noqa: B008  (frozen)
    """Re-solve the cameras named in ``solve``; every other camera keeps (R0, t0) exactly.

    Args:
        rig: the cameras (intrinsics as in the previous result) and the wand length.
        wand: the fresh capture's raw wand blobs.
        R0, t0: (N, 3, 3), (N, 3) the previous result's world->camera poses, in ``rig`` order.
        solve: ids of the cameras to re-solve.
        world: the previous result's ``world`` (kept: the held cameras carry its frame).
        previous: the previous result's camera entries, for the held cameras' uncertainty.
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
    pairs = wand_pairs(rig, wand)
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
    warnings: list[str] = []
    cameras = camera_reports(rig, r.setup, R_new, t_new, r.wand, init, None, None, True, warnings)
    if r.covariance is not None:
        # the world is the held cameras': the re-solved poses' uncertainty given them
        center, rotation = world_uncertainty(r.R, r.t, r.covariance, lambda Rp, tp, shift: (np.eye(3), np.zeros(3)))
        for k, report in enumerate(cameras):
            old = (previous or [{}] * len(cameras))[k]
            report["center_std_mm"] = float(1000 * center[k]) if moving[k] else old.get("center_std_mm")
            report["rotation_std_deg"] = float(np.degrees(rotation[k])) if moving[k] else old.get("rotation_std_deg")
    dropped = dict(pairs.dropped) | {"outliers": r.outliers}
    summary_warnings(warnings, dropped, r.info, "ba", len(labelled), (rig.ids, cameras))
    lengths = quality.free_wand_lengths(R_new, t_new, r.setup.problem)
    wand_report = {"length_m": rig.wand_length, "length_mean_m": float(lengths.mean()),
                   "length_std_m": float(lengths.std()), "frames_used": int(r.setup.problem.n_frames)}
    solver = {"method": "ba"} | r.info | {"solved_only": list(solve), "total_seconds": time.perf_counter() - started}
    verdict, checks = judge("ba", rig, cameras, wand_report, dict(world), R_new, t_new, labelled, None, solver,
                            (r.setup.problem.camera, r.setup.uv))
    warnings += checks
    tell({"stage": "done", "message": "calibration finished"})
    return CalibrationResult(rig=rig, R=R_new, t=t_new, wand=r.wand, frames=r.setup.frames, cameras=cameras,
                             wand_report=wand_report, solver=solver, world=dict(world), dropped=dropped, warnings=warnings,
                             verdict=verdict)


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
