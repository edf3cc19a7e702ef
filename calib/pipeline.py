"""The whole calibration: observations -> initial poses -> labels -> refinement -> world frame.

``calibrate`` is the one entry point the CLI, the service and the tests call.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from calib import quality
from calib.ba import DEFAULT_LOSS, bundle_adjust
from calib.errors import CalibrationError
from calib.geometry import camera_centers, kabsch, undistort_points
from calib.initial import initial_poses
from calib.labels import label_ends
from calib.observations import wand_pairs
from calib.paper import MAX_ROUNDS, refine_paper
from calib.refine import Setup, build_problem
from calib.slp import refine_lp
from calib.rig import Rig, StaticObservations, WandObservations
from calib.static import StaticPose, solve_static
from calib.triangulate import triangulate_points

RESULT_FORMAT = "wandcal-result/1"
METHODS = ("ba", "lp", "paper")
DEFAULT_METHOD = "ba"  # docs/decisions/0002-default-method.md
GAUGE_CAMERA = 0
MAX_OUTLIER_PASSES = 3  # reject-and-refine passes; the kept set settles after two on simulated rigs


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
            "warnings": list(self.warnings),
        }


def calibrate(
    rig: Rig,
    wand: WandObservations,
    static: StaticObservations | None = None,
    method: str = DEFAULT_METHOD,
    progress=None,
    options: dict | None = None,
) -> CalibrationResult:
    """Calibrate the rig's extrinsics from wand (and optional static-object) blobs.

    Args:
        rig: cameras with intrinsics, wand length, optional static object.
        wand: raw, unlabeled wand blobs.
        static: static-object blobs, or None.
        method: "lp", "ba" or "paper" (see ``METHODS``).
        progress: optional callable(dict) with keys stage, message and, while refining,
            iteration and cost. An exception raised by it aborts the calibration.
        options: ``time_limit`` (seconds per LP solve) for "lp" and "paper"; ``max_rounds``
            for "paper"; ``loss`` ("cauchy", the default, or "linear") for "ba";
            ``reject_outliers`` (default True) for all.

    Raises:
        CalibrationError: the input cannot give a calibration; the message says why and what to do.
    """
    options = dict(options or {})
    if method not in METHODS:
        raise CalibrationError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    tell = progress or (lambda event: None)
    started = time.perf_counter()
    warnings: list[str] = []

    tell({"stage": "observations", "message": "undistorting and grouping wand blobs"})
    pairs = wand_pairs(rig, wand)
    per_cam = np.bincount(pairs.camera, minlength=len(rig.cameras))
    for c, cam in enumerate(rig.cameras):
        if per_cam[c] == 0:
            raise CalibrationError(
                f"camera {cam.id!r} never saw both wand ends in one frame; check that it is connected and "
                "aimed at the volume, or remove it from rig.json"
            )

    static_poses = None
    if static is not None and rig.static_markers is not None:
        tell({"stage": "static", "message": "identifying static-object markers and solving PnP"})
        static_poses = solve_static(rig, static)
        if not any(static_poses):
            seen = [str(p) for c, p in enumerate(static_poses) if len(static.for_camera(c))]
            raise CalibrationError(
                "the static object's markers could not be identified in any camera: "
                + ("; ".join(seen) if seen else "static.csv has no blobs")
            )
        for c, pose in enumerate(static_poses):
            if not pose:
                warnings.append(f"{pose}; {rig.cameras[c].id} is placed from the wand only")

    tell({"stage": "initial", "message": "initial poses"})
    init = initial_poses(rig, pairs, static_poses)
    warnings += init.notes

    tell({"stage": "labels", "message": "telling the wand ends apart"})
    labelled, _ = label_ends(init.R, init.t, pairs, np.ones(len(rig.cameras), bool), rig.wand_length)
    setup = build_problem(rig, labelled, init.R, init.t, GAUGE_CAMERA)

    R, t, wand_pts, info = _refine(setup, method, options, tell, _up_direction(rig, init.R, init.t, setup))
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise CalibrationError(
            f"method {method!r} diverged ({info.get('status')}): its camera poses are not finite; "
            "try --method ba, and check the intrinsics and the static object"
        )
    dropped = dict(pairs.dropped)
    dropped["outliers"] = 0
    if options.get("reject_outliers", True):
        R, t, wand_pts, info, setup, dropped["outliers"] = _reject_outliers(rig, labelled, setup, R, t, wand_pts, info, method, options, tell)

    tell({"stage": "world", "message": "expressing the rig in the world frame"})
    R, t, wand_pts, world = _world_frame(rig, static, static_poses, R, t, wand_pts)

    errors = quality.pixel_errors(R, t, wand_pts, setup.problem)
    cameras = [quality.camera_report(errors, setup.problem, setup.frames, c) | {"initial_pose": init.source[c]} for c in range(len(rig.cameras))]
    for c, cam in enumerate(rig.cameras):
        n = cameras[c]["frames_with_both_ends"]
        if n < quality.FEW_FRAMES:
            warnings.append(f"{cam.id} saw both wand ends in only {n} frames; wave the wand nearer {cam.id}")
        rms = cameras[c]["reprojection_rms_px"]
        if rms is not None and rms > quality.HIGH_RMS_PX:
            warnings.append(f"{cam.id} has a reprojection RMS of {rms:.2f} px; check its intrinsics and focus")
    if dropped["extra_blobs"]:
        warnings.append(f"{dropped['extra_blobs']} camera-frames showed more than two blobs and were dropped")
    if dropped["outliers"]:
        warnings.append(f"{dropped['outliers']} camera-frames were gross outliers and were dropped")
    if info.get("status") != "converged":
        warnings.append(f"the {method} refinement stopped before converging ({info.get('status')}); the poses are its "
                        "best state so far (raise time_limit or max_rounds, or try --method ba)")
    if info.get("uncertified_steps"):
        warnings.append(f"{info['uncertified_steps']} LP steps were taken without an optimality certificate (their "
                        "working set had not settled); each still lowered the cost")
    lengths = quality.free_wand_lengths(R, t, setup.problem)
    wand_report = {
        "length_m": rig.wand_length,
        "length_mean_m": float(lengths.mean()),
        "length_std_m": float(lengths.std()),
        "frames_used": int(setup.problem.n_frames),
    }
    solver = {"method": method} | info | {"total_seconds": time.perf_counter() - started}
    tell({"stage": "done", "message": "calibration finished"})
    return CalibrationResult(
        rig=rig, R=R, t=t, wand=wand_pts, frames=setup.frames, cameras=cameras, wand_report=wand_report,
        solver=solver, world=world, dropped=dropped, warnings=warnings,
    )


def _refine(setup: Setup, method: str, options: dict, tell, up: np.ndarray):
    model = setup.model
    tell({"stage": "refine", "message": f"refining with method {method!r}"})
    if method == "ba":
        x, info = bundle_adjust(model, progress=tell, loss=options.get("loss") or DEFAULT_LOSS)
    elif method == "lp":
        x, info = refine_lp(model, progress=tell, time_limit=options.get("time_limit"))
    if method in ("ba", "lp"):
        R, t = model.poses(x)
        return R, t, model.wand(x), info
    R, t, wand_pts, info = refine_paper(
        model.R0, model.t0, model.wand(model.x0()), setup.problem, model.fixed, up,
        max_rounds=int(options.get("max_rounds") or MAX_ROUNDS), time_limit=options.get("time_limit"), progress=tell,
    )
    return R, t, wand_pts, info


def _reject_outliers(rig, labelled, setup, R, t, wand_pts, info, method, options, tell):
    """Drop the camera-frames that are gross outliers and refine again, until the kept set settles.

    At each pass every camera-frame is judged against the current cameras, worst first within
    each frame (least squares spreads an outlier over its frame, so only the worst is sure to
    be one); camera-frames dropped earlier are re-admitted when they fit the cleaner solution.
    After a robust ``ba`` the outliers have had no pull on the cameras, so one pass finds them
    all, and plain least squares on the rest (a few iterations from the robust solution) gives
    the fully efficient estimate.

    Returns (R, t, wand, info, setup, number of camera-frames dropped)."""
    sigma = quality.robust_sigma(quality.pixel_errors(R, t, wand_pts, setup.problem))
    limit = max(quality.OUTLIER_SIGMAS * sigma, quality.MIN_OUTLIER_PX)
    keep = np.ones(len(labelled), bool)
    robust_ba = method == "ba" and (options.get("loss") or DEFAULT_LOSS) != "linear"
    if robust_ba:
        options = options | {"loss": "linear"}
    for _ in range(1 if robust_ba else MAX_OUTLIER_PASSES):
        new_keep = quality.reject_worst_per_frame(R, t, labelled, setup.problem.focal, limit)
        bent = quality.length_outlier_frames(R, t, labelled, new_keep, rig.wand_length)
        new_keep &= ~bent[labelled.frame]
        if np.array_equal(new_keep, keep):
            break
        keep = new_keep
        tell({"stage": "outliers", "message": f"refining without {int((~keep).sum())} outlying camera-frames"})
        setup = build_problem(rig, labelled.subset(keep), R, t, GAUGE_CAMERA)
        R, t, wand_pts, more = _refine(setup, method, options, tell, _up_direction(rig, R, t, setup))
        info = more | {"iterations": info["iterations"] + more["iterations"], "seconds": info["seconds"] + more["seconds"],
                       "loss": info.get("loss", more.get("loss"))}
    return R, t, wand_pts, info, setup, int((~keep).sum())


def _up_direction(rig: Rig, R: np.ndarray, t: np.ndarray, setup: Setup) -> np.ndarray:
    """World up for the paper's height constraints: +z of the static object's frame; without one,
    from the wand's centroid towards the cameras' centroid (cameras on a ring above the volume)."""
    if rig.static_markers is not None:
        return np.array([0.0, 0.0, 1.0])
    v = camera_centers(R, t).mean(0) - setup.model.m0.mean(0)
    return v / np.linalg.norm(v)


def _world_frame(rig: Rig, static: StaticObservations | None, static_poses, R, t, wand_pts):
    """Express poses and wand in the world frame (docs/conventions.md)."""
    if static_poses is not None and any(isinstance(p, StaticPose) for p in static_poses):
        fit = _static_fit(rig, static, static_poses, R, t)
        if fit is not None:
            Rw, tw, rms, used = fit
            # x_world = Rw x_internal + tw  =>  x_cam = R Rw^T (x_world - tw) + t
            R_new = R @ Rw.T
            t_new = t - np.einsum("nij,j->ni", R_new, tw)
            wand_new = wand_pts @ Rw.T + tw
            world = {
                "frame": "static_object",
                "description": "the static object's own frame: its markers_m as given, z up, metres",
                "fit_rms_m": rms,
                "cameras_used": used,
            }
            return R_new, t_new, wand_new, world
    R0, t0 = R[GAUGE_CAMERA], t[GAUGE_CAMERA]
    R_new = R @ R0.T
    t_new = t - np.einsum("nij,j->ni", R_new, t0)
    wand_new = wand_pts @ R0.T + t0
    world = {
        "frame": "camera",
        "camera": rig.cameras[GAUGE_CAMERA].id,
        "description": f"camera {rig.cameras[GAUGE_CAMERA].id!r}'s frame: origin at its centre, x right, y down, z along its optical axis, metres",
    }
    return R_new, t_new, wand_new, world


def _static_fit(rig: Rig, static: StaticObservations, static_poses, R, t):
    """Triangulate the identified static markers with the refined poses and fit the rigid map to
    their known coordinates. Returns (Rw, tw, rms_m, camera ids) or None."""
    markers = rig.static_markers
    usable = [c for c, p in enumerate(static_poses) if isinstance(p, StaticPose)]
    unique = [c for c in usable if static_poses[c].unique]
    for cams in ([unique] if len(unique) >= 2 else []) + [usable]:
        if len(cams) < 2:
            continue
        point, camera, xy = [], [], []
        for c in cams:
            point.append(static_poses[c].labels)
            camera.append(np.full(len(static_poses[c].labels), c))
            xy.append(undistort_points(rig.cameras[c], static.for_camera(c)))
        point, camera, xy = np.concatenate(point), np.concatenate(camera), np.concatenate(xy)
        X = triangulate_points(R, t, point, camera, xy, len(markers))
        ok = np.all(np.isfinite(X), axis=1)
        if ok.sum() < 3:
            continue
        Rw, tw, _ = kabsch(X[ok], markers[ok])
        rms = float(np.sqrt(np.mean(np.sum((X[ok] @ Rw.T + tw - markers[ok]) ** 2, 1))))
        return Rw, tw, rms, [rig.cameras[c].id for c in cams]
    return None
