"""A result's per-camera figures and its warnings: residuals, uncertainties in the world frame
(total, geometry and placement), refined intrinsics, and what the solve dropped. The calibration
(:mod:`wandcal.calib.run.calibrate`) and the re-solve of a few cameras (:mod:`wandcal.calib.run.resolve`)
write their results with these.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from wandcal.calib.judge import quality
from wandcal.calib.observations import PointTracks, camera_rows
from wandcal.calib.rig import (
    AxisObservations,
    Rig,
    StaticObservations,
    VerticalObservations,
    camera_list,
    folded,
    names_camera,
)
from wandcal.calib.run.camera_figures import (
    CameraFigures,
    GeometryUncertainty,
    PointFigures,
    PoseUncertainty,
    RefinedIntrinsics,
    WorstFrame,
)
from wandcal.calib.run.refine import GAUGE_CAMERA, Refined, Setup
from wandcal.calib.run.result import Placement, StaticFitNoise, WorldFrame
from wandcal.calib.solve.gauge_free import split_uncertainty
from wandcal.calib.solve.reprojection import INTRINSICS
from wandcal.calib.solve.uncertainty import frame_noise, world_uncertainty
from wandcal.calib.start import vertical
from wandcal.calib.start.initial import Initial
from wandcal.calib.start.static import static_frame_jacobian
from wandcal.calib.start.world import _static_views, apply, axis_points, static_fit_expectation, world_frame
from wandcal.calib.triangulate import reprojection_errors

# an intrinsic whose standard error passes these is poorly determined by the data: warn
FOCAL_REL_STD_WARN = 0.005  # 0.5% of the focal length
PRINCIPAL_STD_WARN_PX = 5.0
K1_STD_WARN = 0.01
OUTLIER_WARN_SHARE = 0.001  # warn about dropped outliers from this share of the camera-frames on
FrameData = tuple[StaticObservations | None, list | None, AxisObservations | VerticalObservations | None]  # what sets the world frame


def camera_reports(rig: Rig, setup: Setup, R: np.ndarray, t: np.ndarray, wand_pts: np.ndarray, init: Initial,
                   tracks: PointTracks | None, X: np.ndarray | None, has_wand: bool
                   ) -> tuple[list[CameraFigures], list[str]]:
    """Each camera's residual figures at the final poses, and the warnings they raise.

    Args:
        rig: the cameras; setup: the refinement's wand problem and frames (calib/run/refine/problem.py);
        R, t: (N, 3, 3), (N, 3) final world->camera poses, metres; wand_pts: (F, 2, 3) wand ends,
            world frame; init: the start (what placed each camera);
        tracks: the point tracks the refinement used, with X: (T, 3) their points, or None;
        has_wand: the capture has a wand (a camera that saw it in few frames is warned about).
    """
    errors = quality.pixel_errors(R, t, wand_pts, setup.problem)
    point_err = point_rows = None
    if tracks is not None and len(tracks) and X is not None:
        point_rows = camera_rows(tracks.camera, len(rig.cameras))
        r = reprojection_errors(R, t, tracks.track, tracks.camera, tracks.xy, X)
        point_err = np.linalg.norm(r * setup.problem.focal[tracks.camera], axis=1)
    cameras, warnings = [], []
    for c, cam in enumerate(rig.cameras):
        report = quality.camera_report(errors, setup.problem, setup.frames, c)
        points = None
        if point_err is not None and point_rows is not None:
            e = point_err[point_rows[c]]
            points = PointFigures(int(len(e)), float(np.sqrt(np.mean(e**2))) if len(e) else None)
        figures = CameraFigures(report["reprojection_rms_px"], report["observations"], report["frames_with_both_ends"],
                                tuple(WorstFrame(w["frame"], w["error_px"]) for w in report["worst_frames"]),
                                init.source[c], points)
        cameras.append(figures)
        n = report["frames_with_both_ends"]
        if has_wand and n < quality.FEW_FRAMES:
            warnings.append(f"{cam.id} saw both wand ends in only {n} frames; wave the wand nearer {cam.id}")
        for what, rms in (("wand", figures.reprojection_rms_px), ("point-track", points.rms_px if points else None)):
            if rms is not None and rms > quality.HIGH_RMS_PX:
                warnings.append(f"{cam.id} has a {what} reprojection RMS of {rms:.2f} px; check its intrinsics and focus")
    return cameras, warnings


def uncertainty_reports(rig: Rig, r: Refined, world: WorldFrame, frame_data: FrameData, Rw: np.ndarray,
                        tw: np.ndarray, has_wand: bool) -> tuple[list[PoseUncertainty], WorldFrame]:
    """Each camera's pose uncertainty in the world frame of the result (calib/solve/uncertainty.py):
    ``center_std_mm`` (None when the scale is arbitrary, no wand), ``rotation_std_deg``, and the
    part apart from the frame's placement; and the world frame with its ``placement`` and, set by a
    static object, the static blobs' noise it was judged by
    (wandcal.calib.start.world.static_fit_expectation).

    r: the refinement, with its covariance; frame_data: (static blobs, static poses, axis
    points) that set the world frame; Rw, tw: the world frame's rotation and translation."""
    assert r.covariance is not None
    static, static_poses, axis = frame_data

    def frame(Rp, tp, shift):
        Rw_, tw_, _ = world_frame(rig, Rp, tp, GAUGE_CAMERA, static, static_poses, axis, wand=r.wand + shift, points=r.X)
        return Rw_, tw_

    points = None
    cameras_used = list(world.details.get("cameras_used") or [])
    if world.frame == "static_object":
        assert static is not None and rig.static_markers is not None  # what set this frame
        points = markers = rig.static_markers
        fit = static_fit_expectation(rig, static, static_poses, r.R, r.t, cameras_used)
        if fit is not None:
            world = replace(world, static_fit=StaticFitNoise(fit["static_blob_rms_px"], fit["expected_fit_rms_m"]))
        # the frame's derivative in closed form: one triangulation instead of 6N rebuilds
        point, camera, xy = _static_views(rig, static, static_poses, [rig.index(c) for c in cameras_used])
        frame.jacobian = lambda Rp, tp: static_frame_jacobian(Rp, tp, point, camera, xy, markers)  # type: ignore[attr-defined]
    elif world.frame == "axis":
        assert isinstance(axis, AxisObservations)  # what set this frame
        points = np.array(list(axis_points(rig, axis, r.R, r.t).values())) @ Rw.T + tw
    frame_cov, origin = frame_noise(world.to_json(), rig, points, r.covariance)
    if world.frame in ("floor", "gravity"):
        assert isinstance(axis, VerticalObservations)  # what set this frame
        found = vertical.vertical_fit(rig, axis, r.R, r.t)
        if found is not None:
            frame_cov, origin = vertical.frame_noise(found, Rw)
    center, rotation, cov = world_uncertainty(r.R, r.t, r.covariance, frame, frame_cov, origin, full=True)
    Rworld, tworld, _ = apply(Rw, tw, r.R, r.t, np.zeros((0, 3)))
    split = split_uncertainty(Rworld, tworld, cov, scale_free=not has_wand)
    out = [PoseUncertainty(
        float(1000 * center[c]) if has_wand else None, float(np.degrees(rotation[c])),
        GeometryUncertainty(float(split.center_std[c]), float(1000 * split.center_std[c]) if has_wand else None,
                            float(np.degrees(split.rotation_std[c]))),
    ) for c in range(len(rig.cameras))]
    placement = Placement(float(1000 * split.origin_std) if has_wand else None, float(np.degrees(split.axes_std)))
    return out, replace(world, placement=placement)


def intrinsics_reports(rig: Rig, std: np.ndarray, names: list[str]) -> tuple[list[RefinedIntrinsics], list[str]]:
    """Each camera's refined intrinsics and their standard errors, and a warning where the data
    leave one poorly determined. std: (N, P) the cameras' standard errors, pose (6) then the
    intrinsics in ``names``' order (calib/solve/reprojection.py)."""
    out, warnings = [], []
    for c, cam in enumerate(rig.cameras):
        col = 6
        found: dict[str, Any] = {}
        for name in names:
            if name == "focal":
                f, sd = float(cam.K[0, 0]), float(cam.K[0, 0] * std[c, col])
                found |= {"focal_px": f, "focal_std_px": sd}
                if sd > FOCAL_REL_STD_WARN * f:
                    warnings.append(f"{cam.id}: the refined focal length is poorly determined (+-{sd:.1f} px); wave the "
                                    "wand at more depths and across the whole image, or hold the focal length")
            elif name == "principal":
                sd2 = std[c, col : col + 2]
                found |= {"principal_px": (float(cam.K[0, 2]), float(cam.K[1, 2])),
                          "principal_std_px": tuple(sd2.tolist())}
                if sd2.max() > PRINCIPAL_STD_WARN_PX:
                    warnings.append(f"{cam.id}: the refined principal point is poorly determined (+-{sd2.max():.1f} px); "
                                    "cover the image's corners, or hold it")
            else:
                sd = float(std[c, col])
                found |= {"k1": float(cam.dist[0]), "k1_std": sd}
                if sd > K1_STD_WARN:
                    warnings.append(f"{cam.id}: the refined k1 is poorly determined (+-{sd:.3f}); wave the wand near "
                                    "the image's edges, or hold k1")
            col += INTRINSICS[name]
        out.append(RefinedIntrinsics(tuple(names), **found))
    return out, warnings


def camera_warnings(warnings: list[str], ids: list[str]) -> list[tuple[str, ...]]:
    """(N,) each camera's warnings in full: every warning that names it (:func:`names_camera`).
    ids: (N,) the rig's camera ids."""
    return [tuple(w for w in warnings if names_camera(w, cam_id)) for cam_id in ids]


def fold_camera_warnings(warnings: list[str], ids: list[str]) -> list[str]:
    """The warnings with those that differ only in the camera they start with ("cam5: static-object
    pose is ambiguous ...", once a camera) folded into one line naming the cameras compactly
    ("cam5, cam9: ...", "all 64 cameras: ..."; :func:`wandcal.calib.rig.camera_list`), at
    the first one's place. Nothing is lost: each camera's figures keep every warning about it in
    full (:func:`camera_warnings`). ids: (N,) the rig's camera ids."""
    lines = []
    for w in warnings:
        cam_id = next((i for i in ids if w.startswith(i + ": ")), None)
        rest = w[len(cam_id):] if cam_id is not None else None
        if rest is not None and any(names_camera(rest, i) for i in ids):
            rest = None  # it names another camera in its own words: kept as it is
        lines.append((w, rest, cam_id or ""))
    return folded(lines, lambda named: len(set(named)) > 1,
                  lambda rest, named: camera_list([i for i in ids if i in set(named)], len(ids)) + rest)


def with_warnings(cameras: list[CameraFigures], warnings: list[str], ids: list[str]
                  ) -> tuple[list[CameraFigures], list[str]]:
    """The cameras' figures, each with every warning about it in full, and the result's warnings
    folded (:func:`fold_camera_warnings`)."""
    own = camera_warnings(warnings, ids)
    return [replace(cam, warnings=w) for cam, w in zip(cameras, own)], fold_camera_warnings(warnings, ids)


def summary_warnings(dropped: Mapping[str, int], info: Mapping[str, Any], method: str, camera_frames: int) -> list[str]:
    """The result's warnings about the whole capture and solve: blobs and outliers dropped, a
    solve that stopped early, LP steps without a certificate."""
    warnings = []
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
    return warnings
