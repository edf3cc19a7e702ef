"""A result's per-camera figures and its warnings: residuals, uncertainties in the world frame
(total, geometry and placement), refined intrinsics, and what the solve dropped. The calibration
(:mod:`wandcal.calib.run.calibrate`) and the re-solve of a few cameras (:mod:`wandcal.calib.run.resolve`)
write their results with these.
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.judge import quality
from wandcal.calib.observations import camera_rows
from wandcal.calib.rig import Rig, camera_list, folded, names_camera
from wandcal.calib.run.refine import GAUGE_CAMERA
from wandcal.calib.solve.gauge_free import split_uncertainty
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.uncertainty import frame_noise, world_uncertainty
from wandcal.calib.start.static import static_frame_jacobian
from wandcal.calib.start.world import _static_views, apply, axis_points, static_fit_expectation, world_frame
from wandcal.calib.triangulate import reprojection_errors

# an intrinsic whose standard error passes these is poorly determined by the data: warn
FOCAL_REL_STD_WARN = 0.005  # 0.5% of the focal length
PRINCIPAL_STD_WARN_PX = 5.0
K1_STD_WARN = 0.01
OUTLIER_WARN_SHARE = 0.001  # warn about dropped outliers from this share of the camera-frames on


def camera_reports(rig, setup, R, t, wand_pts, init, tracks, X, has_wand, warnings) -> list[dict]:
    errors = quality.pixel_errors(R, t, wand_pts, setup.problem)
    point_err = point_rows = None
    if tracks is not None and len(tracks):
        point_rows = camera_rows(tracks.camera, len(rig.cameras))
        r = reprojection_errors(R, t, tracks.track, tracks.camera, tracks.xy, X)
        point_err = np.linalg.norm(r * setup.problem.focal[tracks.camera], axis=1)
    cameras = []
    for c, cam in enumerate(rig.cameras):
        report = quality.camera_report(errors, setup.problem, setup.frames, c) | {"initial_pose": init.source[c]}
        if point_err is not None and point_rows is not None:
            e = point_err[point_rows[c]]
            report |= {"point_observations": int(len(e)),
                       "point_rms_px": float(np.sqrt(np.mean(e**2))) if len(e) else None}
        cameras.append(report)
        n = report["frames_with_both_ends"]
        if has_wand and n < quality.FEW_FRAMES:
            warnings.append(f"{cam.id} saw both wand ends in only {n} frames; wave the wand nearer {cam.id}")
        for key in ("reprojection_rms_px", "point_rms_px"):
            rms = report.get(key)
            if rms is not None and rms > quality.HIGH_RMS_PX:
                what = "wand" if key == "reprojection_rms_px" else "point-track"
                warnings.append(f"{cam.id} has a {what} reprojection RMS of {rms:.2f} px; check its intrinsics and focus")
    return cameras


def uncertainty_reports(cameras: list[dict], rig: Rig, r, world: dict, frame_data, Rw, tw, has_wand: bool) -> None:
    """Each camera's ``center_std_mm`` and ``rotation_std_deg`` in the world frame of the result
    (calib/solve/uncertainty.py); the centre's is None when the scale is arbitrary (no wand). A static
    object's ``world`` gains the static blobs' noise it was judged by (wandcal.calib.start.world.static_fit_expectation)."""
    static, static_poses, axis = frame_data

    def frame(Rp, tp, shift):
        Rw_, tw_, _ = world_frame(rig, Rp, tp, GAUGE_CAMERA, static, static_poses, axis, wand=r.wand + shift, points=r.X)
        return Rw_, tw_

    points = None
    if world["frame"] == "static_object":
        points = rig.static_markers
        world.update(static_fit_expectation(rig, static, static_poses, r.R, r.t, world["cameras_used"]) or {})
        # the frame's derivative in closed form: one triangulation instead of 6N rebuilds
        point, camera, xy = _static_views(rig, static, static_poses, [rig.index(c) for c in world["cameras_used"]])
        frame.jacobian = lambda Rp, tp: static_frame_jacobian(Rp, tp, point, camera, xy, rig.static_markers)
    elif world["frame"] == "axis":
        points = np.array(list(axis_points(rig, axis, r.R, r.t).values())) @ Rw.T + tw
    frame_cov, origin = frame_noise(world, rig, points, r.covariance)
    center, rotation, cov = world_uncertainty(r.R, r.t, r.covariance, frame, frame_cov, origin, full=True)
    Rworld, tworld, _ = apply(Rw, tw, r.R, r.t, np.zeros((0, 3)))
    split = split_uncertainty(Rworld, tworld, cov, scale_free=not has_wand)
    for c, report in enumerate(cameras):
        report["center_std_mm"] = float(1000 * center[c]) if has_wand else None
        report["rotation_std_deg"] = float(np.degrees(rotation[c]))
        report["geometry_std"] = float(split.center_std[c])
        report["geometry_std_mm"] = float(1000 * split.center_std[c]) if has_wand else None
        report["geometry_rotation_std_deg"] = float(np.degrees(split.rotation_std[c]))
    world["placement"] = {"origin_std_mm": float(1000 * split.origin_std) if has_wand else None,
                          "axes_std_deg": float(np.degrees(split.axes_std))}


def intrinsics_reports(cameras: list[dict], rig: Rig, std: np.ndarray, names: list[str], warnings: list[str]) -> None:
    """Each camera's refined intrinsics and their standard errors; a warning where the data leave
    one poorly determined."""
    for c, cam in enumerate(rig.cameras):
        col, entry = 6, {"refined": names}
        for name in names:
            if name == "focal":
                f, sd = float(cam.K[0, 0]), float(cam.K[0, 0] * std[c, col])
                entry |= {"focal_px": f, "focal_std_px": sd}
                if sd > FOCAL_REL_STD_WARN * f:
                    warnings.append(f"{cam.id}: the refined focal length is poorly determined (+-{sd:.1f} px); wave the "
                                    "wand at more depths and across the whole image, or hold the focal length")
            elif name == "principal":
                sd = std[c, col : col + 2]
                entry |= {"principal_px": [float(cam.K[0, 2]), float(cam.K[1, 2])], "principal_std_px": sd.tolist()}
                if sd.max() > PRINCIPAL_STD_WARN_PX:
                    warnings.append(f"{cam.id}: the refined principal point is poorly determined (+-{sd.max():.1f} px); "
                                    "cover the image's corners, or hold it")
            else:
                sd = float(std[c, col])
                entry |= {"k1": float(cam.dist[0]), "k1_std": sd}
                if sd > K1_STD_WARN:
                    warnings.append(f"{cam.id}: the refined k1 is poorly determined (+-{sd:.3f}); wave the wand near "
                                    "the image's edges, or hold k1")
            col += INTRINSICS[name]
        cameras[c]["intrinsics"] = entry


def fold_camera_warnings(warnings: list[str], ids: list[str], cameras: list[dict]) -> list[str]:
    """The warnings with those that differ only in the camera they start with ("cam5: static-object
    pose is ambiguous ...", once a camera) folded into one line naming the cameras compactly
    ("cam5, cam9: ...", "all 64 cameras: ..."; :func:`wandcal.calib.rig.camera_list`), at
    the first one's place. Nothing is lost: each camera's entry in ``cameras`` (rig order) gets
    ``warnings``, every warning about it in full (:func:`names_camera`).
    ids: (N,) the rig's camera ids."""
    for cam_id, report in zip(ids, cameras):
        report["warnings"] = [w for w in warnings if names_camera(w, cam_id)]
    lines = []
    for w in warnings:
        cam_id = next((i for i in ids if w.startswith(i + ": ")), None)
        rest = w[len(cam_id):] if cam_id is not None else None
        if rest is not None and any(names_camera(rest, i) for i in ids):
            rest = None  # it names another camera in its own words: kept as it is
        lines.append((w, rest, cam_id or ""))
    return folded(lines, lambda named: len(set(named)) > 1,
                  lambda rest, named: camera_list([i for i in ids if i in set(named)], len(ids)) + rest)


def summary_warnings(warnings: list[str], dropped: dict, info: dict, method: str, camera_frames: int,
                     cameras: tuple[list[str], list[dict]] | None = None) -> None:
    """The result's warnings about the whole capture and solve, appended to ``warnings``; with
    ``cameras`` ((N,) ids, (N,) camera reports), the per-camera ones then folded
    (:func:`fold_camera_warnings`)."""
    if dropped.get("extra_blobs"):
        markers = "the wand's markers" if "fewer_blobs" in dropped else "two"  # fewer_blobs: a multi-marker wand
        warnings.append(f"{dropped['extra_blobs']} camera-frames showed more blobs than {markers} and were dropped")
    if dropped.get("outliers"):
        share = dropped["outliers"] / max(camera_frames, 1)
        # a 5-sigma limit over ~10^4 camera-frames leaves a few borderline ones on clean data:
        # they are in `dropped`; a warning is for a share that says something about the capture
        if share >= OUTLIER_WARN_SHARE:
            warnings.append(f"{dropped['outliers']} camera-frames ({share:.1%}) were gross outliers and were dropped; "
                            "look for reflections or a second bright marker in those cameras")
    if dropped.get("point_outliers"):
        warnings.append(f"{dropped['point_outliers']} point-track observations were gross outliers and were dropped")
    if info.get("status") != "converged":
        raise_ = {"paper": "raise --max-rounds or --lp-time-limit", "lp": "raise --lp-time-limit"}.get(method)
        hint = f"{raise_}, or try --method ba" if raise_ else "check the intrinsics and the start"
        warnings.append(f"the {method} refinement stopped before converging ({info.get('status')}); the poses are its "
                        f"best state so far ({hint})")
    if info.get("uncertified_steps"):
        warnings.append(f"{info['uncertified_steps']} LP steps were taken without an optimality certificate (their "
                        "working set had not settled); each still lowered the cost")
    if cameras is not None:
        warnings[:] = fold_camera_warnings(warnings, *cameras)
