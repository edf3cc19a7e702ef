"""The whole calibration: observations -> initial poses -> labels -> refinement -> world frame.

``calibrate`` is the one entry point the CLI, the service and the tests call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.geometry import camera_centers, undistort_by_camera
from wandcal.calib.judge import quality
from wandcal.calib.observations import WandPairs, point_tracks, robust_sigma, wand_pairs
from wandcal.calib.rig import AxisObservations, PointObservations, Rig, StaticObservations, WandObservations
from wandcal.calib.run.camera_reports import camera_reports, intrinsics_reports, summary_warnings, uncertainty_reports
from wandcal.calib.run.judgement import judge
from wandcal.calib.run.refine import (
    GAUGE_CAMERA,
    build_problem,
    check_intrinsics_request,
    labelled_rows,
    refine,
    reject_outliers,
    triangulated,
    up_direction,
)
from wandcal.calib.solve.ba import DEFAULT_LOSS
from wandcal.calib.solve.sync import DEFAULT_SYNC, SYNC_MODES, TimeColumns, Tracks, fit_timing, sync_report
from wandcal.calib.solve.sync.fit import BA_FIT_FRAMES, MAX_FIT_FRAMES
from wandcal.calib.start.degenerate import check_capture
from wandcal.calib.start.frame_offsets import DEFAULT_MAX_OFFSET, frame_offsets, shift_frames, shift_pairs
from wandcal.calib.start.initial import initial_poses
from wandcal.calib.start.labels import label_ends
from wandcal.calib.start.static import solve_static
from wandcal.calib.start.world import apply, world_frame

RESULT_FORMAT = "wandcal-result/1"
METHODS = ("ba", "lp", "paper")
DEFAULT_METHOD = "ba"  # docs/decisions/0002-default-method.md


@dataclass(eq=False)
class CalibrationResult:
    """Poses in the world frame and everything the report needs.

    R: (N, 3, 3), t: (N, 3) world->camera, metres; wand: (F, 2, 3) wand ends, metres.
    """

    rig: Rig
    R: np.ndarray
    t: np.ndarray
    wand: np.ndarray
    frames: np.ndarray
    cameras: list[dict]
    wand_report: dict
    solver: dict
    world: dict
    dropped: dict
    warnings: list[str] = field(default_factory=list)
    points: np.ndarray | None = None  # (T, 3) the single-point tracks' refined points, world frame
    verdict: dict | None = None  # the rig's {"level", "reasons"} (calib/judge/verdict.py)
    sync: dict | None = None  # the cameras' time offsets under options["sync"] = "auto" (docs/sync.md)

    @property
    def centers(self) -> np.ndarray:
        return camera_centers(self.R, self.t)

    def to_json(self) -> dict:
        cams = []
        for i, cam in enumerate(self.rig.cameras):
            entry = {
                "id": cam.id,
                "R": self.R[i].tolist(),
                "t": self.t[i].tolist(),
                "center": self.centers[i].tolist(),
                "K": cam.K.tolist(),
                "dist": cam.dist.tolist(),
                "width": cam.width,
                "height": cam.height,
            }
            if cam.model != "pinhole":
                entry["model"] = cam.model
            cams.append(entry | self.cameras[i])
        return {
            "format": RESULT_FORMAT,
            "cameras": cams,
            "wand": self.wand_report,
            "solver": self.solver,
            "world": self.world,
            "dropped": self.dropped,
            "verdict": self.verdict,
            "warnings": list(self.warnings),
        } | ({"sync": self.sync} if self.sync is not None else {})


def calibrate(
    rig: Rig,
    wand: WandObservations | None,
    static: StaticObservations | None = None,
    method: str = DEFAULT_METHOD,
    progress=None,
    options: dict | None = None,
    points: PointObservations | None = None,
    axis: AxisObservations | None = None,
) -> CalibrationResult:
    """Calibrate the rig's extrinsics from wand blobs, single-point tracks and an optional static
    object or axis points.

    Args:
        rig: cameras with intrinsics, wand length (None without a wand), optional static object.
        wand: raw, unlabeled wand blobs (None or empty without a wand).
        static: static-object blobs, or None.
        method: "lp", "ba" or "paper" (see ``METHODS``).
        progress: optional callable(dict) with keys stage, message and, while refining,
            iteration and cost. An exception raised by it aborts the calibration.
        options: ``time_limit`` (seconds per LP solve) for "lp" and "paper"; ``max_rounds``
            for "paper"; ``loss`` ("cauchy", the default, or "linear") for "ba";
            ``reject_outliers`` (default True) for all; ``refine_intrinsics``, a subset of
            ("focal", "principal", "k1") to refine per camera inside ``ba`` (default none);
            ``sync`` ("none", the default, or "auto": each camera's time offset found from the
            wand, docs/sync.md) with ``sync_max_offset`` (frames searched), ``sync_start`` ((N,)
            offsets from timestamps), ``sync_drift`` (also a rate difference), ``frame_rate_hz``.
        points: single-point tracks (points.csv), or None. ``ba`` refines them as free 3D
            points; the other methods use them for the start only.
        axis: axis points (axis.csv) that set the world frame when there is no static object.

    Raises:
        CalibrationError: the input cannot give a calibration; the message says why and what to do.
    """
    options = dict(options or {})
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    check_intrinsics_request(rig, method, tuple(options.get("refine_intrinsics") or ()))
    tell = progress or (lambda event: None)
    started = time.perf_counter()
    warnings: list[str] = []
    sync = options.get("sync") or DEFAULT_SYNC
    if sync not in SYNC_MODES:
        raise CalibrationError(f"unknown sync mode {sync!r}; choose one of {', '.join(SYNC_MODES)}")

    tell({"stage": "observations", "message": "undistorting and grouping wand blobs and point tracks"})
    has_wand = rig.wand_length is not None and wand is not None and len(wand) > 0
    timed = unshifted = None
    if sync == "auto" and has_wand:  # whole frames first: a camera out of time by frames cannot be placed
        tell({"stage": "sync", "message": "finding each camera's time offset from the wand"})
        unshifted = wand_pairs(rig, wand)
        timed = frame_offsets(rig, unshifted, int(options.get("sync_max_offset") or DEFAULT_MAX_OFFSET),
                              options.get("sync_start"))
        wand = shift_frames(wand, timed.offsets)
        warnings += timed.notes
    elif sync == "auto":
        warnings.append("sync auto finds the time offsets from the wand; this capture has none, so its frames are taken as "
                        "synchronised")
    blobs = _marker_blobs(rig, wand) if has_wand else None
    if blobs is not None:
        pairs = blobs.ends()
    elif timed is not None:  # the pairs already grouped, renumbered
        pairs = shift_pairs(unshifted, timed.offsets)
    else:
        pairs = wand_pairs(rig, wand) if has_wand else WandPairs.empty()
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

    static_poses = None
    if static is not None and rig.static_markers is not None:
        tell({"stage": "static", "message": "identifying static-object markers and solving PnP"})
        static_poses = solve_static(rig, static)
        if not any(static_poses):
            seen_static = [str(p) for c, p in enumerate(static_poses) if len(static.for_camera(c))]
            raise CalibrationError(
                "the static object's markers could not be identified in any camera: "
                + ("; ".join(seen_static) if seen_static else "static.csv has no blobs")
            )
        for c, pose in enumerate(static_poses):
            if not pose:
                warnings.append(f"{pose}; {rig.cameras[c].id} is placed from the wand only")

    warnings += check_capture(rig, pairs, tracks, static_poses)  # degenerate captures: calib/start/degenerate.py
    tell({"stage": "initial", "message": "initial poses"})
    init = initial_poses(rig, pairs, static_poses, points=tracks)
    warnings += init.notes

    tell({"stage": "labels", "message": "telling the wand ends apart"})
    planar = blobs is not None and blobs.fit_px is not None  # a planar wand's rows come labelled from the layout
    labelled = label_ends(init.R, init.t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)[0] if (
        has_wand and not planar) else pairs
    columns = None
    if timed is not None:  # sub-frame offsets with the start poses refined; the frames resampled to the reference's instants
        focal = np.array([c.focal for c in rig.cameras])
        tracks_in_time = Tracks(labelled, len(rig.cameras))
        timing = fit_timing(init.R, init.t, labelled, focal, timed.reference, bool(options.get("sync_drift")),
                            max_frames=BA_FIT_FRAMES if method == "ba" else MAX_FIT_FRAMES, poses=True,
                            tracks=tracks_in_time)
        columns = TimeColumns(labelled, tracks_in_time, timing, focal)
        labelled, init = columns.resampled, replace(init, R=timing.R, t=timing.t)
        if method == "ba":  # the offsets refined again in the final bundle adjustment, over every frame
            options["sync_columns"] = columns
    setup = build_problem(rig, labelled, init.R, init.t, GAUGE_CAMERA)
    all_tracks = tracks  # every method is judged on the same observations, point tracks included
    if tracks is not None:
        tracks, X = triangulated(init.R, init.t, tracks)
        if method == "paper":
            warnings.append(f"the {len(tracks)} point-track observations placed the cameras at the start; only "
                            "--method ba and lp refine with them")
            tracks = None
    else:
        X = None

    # an outlier pass follows (a robust ba's polish; lp's and paper's passes): this solve is not the final one
    polish = options.get("reject_outliers", True) and (method != "ba" or (options.get("loss") or DEFAULT_LOSS) != "linear")
    r = refine(rig, labelled, setup, tracks, X, method, options, tell, up_direction(rig, init.R, init.t, setup),
               final=not polish)
    if not (np.all(np.isfinite(r.R)) and np.all(np.isfinite(r.t))):
        raise CalibrationError(
            f"method {method!r} diverged ({r.info.get('status')}): its camera poses are not finite; "
            "check the intrinsics and the static object" + ("" if method == "ba" else ", or try --method ba")
        )
    if options.get("reject_outliers", True):
        r = reject_outliers(r, method, options, tell)
    sync_doc = None
    if columns is not None and timed is not None:
        # the fit's offsets plus what ba added over every frame (docs/decisions/0022-sync-cost-and-standard-error.md)
        timing = columns.folded(r.dt, r.camera_std[:, -1] if r.dt is not None and r.camera_std is not None else None)
        sync_doc, found = sync_report(rig.ids, timed.offsets, timed.reference, timing, options.get("sync_start"),
                                      options.get("frame_rate_hz"), bool(options.get("sync_drift")))
        warnings += found
        options.pop("sync_columns", None)
    marker_pairs = None
    if blobs is not None:
        r, marker_pairs = _with_markers(rig, blobs, r, method, options, tell, warnings)
    dropped = dict(pairs.dropped) | (dict(tracks.dropped) if tracks is not None else {})
    dropped |= {"outliers": r.outliers} | ({"point_outliers": r.point_outliers} if tracks is not None else {})
    rig, setup, tracks, info = r.rig, r.setup, r.tracks, r.info

    tell({"stage": "world", "message": "expressing the rig in the world frame"})
    Rw, tw, world = world_frame(rig, r.R, r.t, GAUGE_CAMERA, static, static_poses, axis, wand=r.wand, points=r.X)
    R, t, wand_pts = apply(Rw, tw, r.R, r.t, r.wand)
    X = r.X @ Rw.T + tw if r.X is not None else None
    world["scale"] = "wand" if has_wand else "arbitrary"
    if not has_wand and not any("scale" in note for note in init.notes):
        warnings.append("no wand: the rig is calibrated up to scale (world.scale is 'arbitrary')")

    cameras = camera_reports(rig, setup, R, t, wand_pts, init, tracks, X, has_wand, warnings)
    if r.covariance is not None:
        tell({"stage": "uncertainty", "message": "propagating the pose uncertainty into the world frame"})
        uncertainty_reports(cameras, rig, r, world, (static, static_poses, axis), Rw, tw, has_wand)
    if info.get("refined_intrinsics"):
        intrinsics_reports(cameras, rig, r.camera_std, info["refined_intrinsics"], warnings)
    summary_warnings(warnings, dropped, info, method, len(labelled), (rig.ids, cameras))
    wand_report = None
    if has_wand:
        lengths = quality.free_wand_lengths(R, t, setup.problem)
        wand_report = {
            "length_m": rig.wand_length,
            "length_mean_m": float(lengths.mean()),
            "length_std_m": float(lengths.std()),
            "frames_used": int(setup.problem.n_frames),
        } | ({"marker_pairs": marker_pairs} if marker_pairs is not None else {})
    seen_cam, seen_uv = setup.problem.camera, setup.uv
    if tracks is not None and len(tracks):
        seen_cam, seen_uv = np.concatenate([seen_cam, tracks.camera]), np.concatenate([seen_uv, tracks.uv])
    solver = {"method": method} | info
    tell({"stage": "judge", "message": "judging the rig and looking for a camera or input at fault"})
    if all_tracks is not None and info.get("refined_intrinsics"):
        all_tracks = replace(all_tracks, xy=undistort_by_camera(rig.cameras, all_tracks.camera, all_tracks.uv))
    verdict, checks = judge(method, rig, cameras, wand_report, world, R, t, r.labelled, all_tracks, solver,
                            (seen_cam, seen_uv), (setup.frames, wand_pts) if has_wand else None)
    warnings += checks
    solver |= {"total_seconds": time.perf_counter() - started}
    tell({"stage": "done", "message": "calibration finished"})
    return CalibrationResult(
        rig=rig, R=R, t=t, wand=wand_pts, frames=setup.frames, cameras=cameras, wand_report=wand_report,
        solver=solver, world=world, dropped=dropped, warnings=warnings, points=X, verdict=verdict, sync=sync_doc,
    )


def _marker_blobs(rig: Rig, wand: WandObservations):
    """A wand of three or more markers (rig.json ``wand.markers_m``): its camera-frames ordered
    along the wand's image (wandcal.calib.start.markerlabels); None for two markers."""
    if rig.wand_markers is None or len(rig.wand_markers) == 2:
        return None
    from wandcal.calib.start.markerlabels import order_markers

    return order_markers(rig, wand)


def _with_markers(rig: Rig, blobs, r, method: str, options: dict, tell, warnings: list[str]):
    """Label every marker at the refined poses and, with ``ba`` or ``lp``, refine again with the
    interior markers' known positions in the wand model; the refinement and each marker pair's
    lengths (wandcal.calib.solve.markerwand)."""
    from dataclasses import replace

    from wandcal.calib.solve.ba import bundle_adjust_points
    from wandcal.calib.solve.markerwand import marker_model, marker_pair_lengths
    from wandcal.calib.start.markerlabels import label_interior

    labels = label_interior(rig, blobs, r.labelled, r.R, r.t, (r.setup.frames, r.wand))
    pair_index = labelled_rows(r)
    fit = labels if method != "lp" else labels.on_axis()  # lp's frames have no roll: the markers on the axis
    model, rows = marker_model(r.setup.problem, pair_index, r.labelled.camera, fit.xy, fit.along, r.R, r.t,
                               r.wand, r.setup.model.fixed, fit.across)
    if fit.across is not None:  # a planar wand's ends as the labels at the solved rig name them
        ends = np.where(r.setup.problem.end == 1, fit.xy.shape[1] - 1, 0)
        r = replace(r, setup=replace(r.setup, problem=replace(r.setup.problem, xy=fit.xy[pair_index, ends]),
                                     uv=fit.uv[pair_index, ends]))
    x = model.x0()
    if method == "paper" or r.info.get("refined_intrinsics"):
        warnings.append(f"the wand's interior markers label its frames; only --method ba or lp without "
                        f"--refine-intrinsics refines with them ({method} did not)")
    else:
        tell({"stage": "refine", "message": "refining with every wand marker"})
        if method == "lp":
            from wandcal.calib.solve.lp import refine_lp

            x, lp_info = refine_lp(model, progress=tell, time_limit=options.get("time_limit"))
            out = bundle_adjust_points(model, None, None, x0=x, loss="linear", max_iter=0)  # its covariance only
            out = replace(out, x=x, X=r.X, info=lp_info)
        else:
            out = bundle_adjust_points(model, r.tracks, r.X, progress=tell, loss=options.get("loss") or DEFAULT_LOSS)
        x = out.x
        info = r.info | {"iterations": r.info.get("iterations", 0) + out.info.get("iterations", 0),
                         "seconds": r.info.get("seconds", 0.0) + out.info.get("seconds", 0.0)}
        r = replace(r, R=model.poses(x)[0], t=model.poses(x)[1], wand=model.wand(x), X=out.X,
                    camera_std=out.camera_std, covariance=out.covariance, info=info)
    # an interior blob the fit leaves far off is an outlier: its camera-frame stays out of the
    # marker pairs' lengths, as the ends' outliers stay out of the wand's
    err = np.linalg.norm(model.residuals(x).reshape(-1, 2), axis=1)
    limit = max(quality.OUTLIER_SIGMAS * robust_sigma(err), quality.MIN_OUTLIER_PX)
    kept = np.zeros(len(r.labelled), bool)
    kept[pair_index] = True
    kept[rows[err[len(r.setup.problem.camera):] > limit]] = False
    return r, marker_pair_lengths(r.R, r.t, r.labelled.frame[kept], r.labelled.camera[kept], labels.xy[kept],
                                  labels.marker[kept], rig.wand_markers)
