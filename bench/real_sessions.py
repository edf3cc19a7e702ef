"""wandcal on the real third-party sessions in ../shared/data, with the figures their tools published.

Each function imports a session with ``wandcal import``'s readers, calibrates it through the whole
pipeline and returns our figures beside the published ones. The data are read in place (some carry
no licence) and never copied. Used by ``bench/bench_real.py`` (the table in docs/benchmarks.md)
and by ``tests/capture/test_real_sessions.py`` (the goals).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.common import aligned_centres_mm
from wandcal.calib.geometry import undistort_points
from wandcal.calib.judge.quality import OUTLIER_SIGMAS
from wandcal.calib.observations import point_tracks, robust_sigma
from wandcal.calib.run.calibrate import calibrate
from wandcal.calib.run.options import CalibrationOptions
from wandcal.calib.triangulate import reprojection_errors, triangulate_points
from wandcal.capture.importers.easywand import read_easywand_mat
from wandcal.capture.importers.svoboda import read_svoboda

SHARED_DATA = Path(os.environ.get("WANDCAL_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
BROWN = "easywand_brown_windtunnel_4cam"
BROWN_MAT = "extrinsicCalib_20230228_easyWandData.mat"
USHICHKA = "easywand_ushichka_thermal_3cam"
USHICHKA_HEIGHT = 512  # the .mat and the profile say 320, a typo: the principal point is (320, 256)
SVOBODA = "multicamselfcal_strawlab_testdata/caldata20130726_122220"
SVOBODA_NO_INTRINSICS = "multicamselfcal_strawlab_testdata/DATA20100906_134124"


def brown(session: int, method: str = "ba", intrinsics: str = "optimised", options: CalibrationOptions | None = None) -> dict:
    """One Brown wind-tunnel session (1 or 2) and easyWand's published figures."""
    folder = SHARED_DATA / BROWN / f"calibration{session}"
    ref = json.loads((folder / "easywand_result.json").read_text())
    cap = read_easywand_mat(folder / BROWN_MAT, intrinsics=intrinsics).capture
    start = time.perf_counter()
    options = replace(options or CalibrationOptions(), method=method)
    result = calibrate(cap.rig, cap.wand, None, options=options, points=cap.points, axis=cap.axis)
    seconds = time.perf_counter() - start
    published = ref["published_result"]
    w = result.wand_report
    reference = np.array([c["camera_centre_world_m"] for c in ref["reference_cameras_derived_from_dlt"]])
    return {
        "result": result,
        "seconds": seconds,
        "wand_score_percent": 100 * w.length_std_m / w.length_mean_m,
        "wand_frames": w.frames_used,
        "wand_score_on_easywand_frames": _score_on_easywand_frames(result, folder),
        "easywand_wand_score_percent": published["wandScore_percent"],
        "easywand_frames": published["dDLT_wand_lengths_m"]["n"],
        "centre_diff_mm": aligned_centres_mm(result.centers, reference),
        "reference_centres": reference,
        "focal_px": [c.K[0, 0] for c in result.rig.cameras],
        "easywand_focal_px": ref["easywand_optimised"]["focal_px"],
    }


def easywand_cameras_score(session: int) -> tuple[float, int]:
    """The wand score of easyWand's own cameras (its DLT's K, R, t in easywand_result.json, our
    lens model for the distortion) scored our way on its frames: checks that our score is
    easyWand's ``wandScore``."""
    import dataclasses

    folder = SHARED_DATA / BROWN / f"calibration{session}"
    ref = json.loads((folder / "easywand_result.json").read_text())["reference_cameras_derived_from_dlt"]
    cap = read_easywand_mat(folder / BROWN_MAT).capture
    cameras = [dataclasses.replace(c, K=np.array(r["K_ydown"])) for c, r in zip(cap.rig.cameras, ref)]
    R = np.array([r["R_world_to_cam"] for r in ref])
    t = np.array([r["t_world_to_cam_m"] for r in ref])
    return _score(R, t, cameras, folder)


def _score_on_easywand_frames(result, folder: Path) -> tuple[float, int]:
    """:func:`_score` of a calibration's cameras."""
    return _score(result.R, result.t, result.rig.cameras, folder)


def scored_ends(cameras, folder: Path):
    """The rows easyWand scored, as it scored them: its undistorted points (``ptMatu``, where it
    blanked the ends it judged outliers) with both ends in two or more cameras. Yields, per row,
    one (cameras (k,), xy (k, 2) normalised) per end: the views that end is triangulated from,
    our undistortion of the raw pixels."""
    raw = np.genfromtxt(folder / "wandpts_raw.csv", delimiter=",", skip_header=1)
    kept = np.genfromtxt(folder / "wandpts_undistorted_easywand.csv", delimiter=",", skip_header=1)
    n = len(cameras)
    raw_by_row = {int(r[0]): r[1:] for r in raw}
    for row in kept:
        src, ew = int(row[0]), row[1:]
        if src not in raw_by_row:
            continue
        seen = np.isfinite(ew.reshape(2, n, 2)).all(axis=2)  # (end, camera)
        if (seen[0] & seen[1]).sum() < 2:
            continue
        uv = raw_by_row[src].reshape(2, n, 2)
        ends = []
        for e in range(2):
            cams = np.flatnonzero(seen[e])
            xy = np.array([undistort_points(cameras[c], np.array([[uv[e, c, 0], cameras[c].height - uv[e, c, 1]]]))[0] for c in cams])
            ends.append((cams, xy))
        yield ends


def triangulated_end(R: np.ndarray, t: np.ndarray, cams: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(3,) one wand end triangulated from its views."""
    return triangulate_points(R, t, np.zeros(len(cams), int), cams, xy, 1)[0]


def wand_length(R: np.ndarray, t: np.ndarray, ends) -> float:
    """The distance between the two ends of one of :func:`scored_ends`' rows, metres."""
    return float(np.linalg.norm(triangulated_end(R, t, *ends[1]) - triangulated_end(R, t, *ends[0])))


def _score(R: np.ndarray, t: np.ndarray, cameras, folder: Path) -> tuple[float, int]:
    """The wand score (%) and frames of cameras R (N, 3, 3), t (N, 3) on the frames easyWand
    scored (:func:`scored_ends`), each end triangulated from the same camera views. As easyWand
    computes its ``wandScore`` (``nanstd(dDLT) ./ nanmean(dDLT) * 100`` in easyWand5.m's
    DLT step): MATLAB's ``std``, the sample standard deviation (n - 1)."""
    lengths = np.array([wand_length(R, t, ends) for ends in scored_ends(cameras, folder)])
    lengths = lengths[np.isfinite(lengths)]
    return float(100 * lengths.std(ddof=1) / lengths.mean()), int(len(lengths))


NUDGE_PX = 1e-3  # finite-difference step of a pixel: the length is smooth over far more than this


def score_per_pixel(session: int, result) -> float:
    """The wand score (%) that 1 px per axis of independent noise on each wand end would give
    with exact cameras (``result``'s) on easyWand's frames of a Brown session: the root mean over
    the frames of each length's variance, to first order through the same triangulations, over
    the mean length. The score a rig can be expected to reach scales with the ends' noise."""
    folder = SHARED_DATA / BROWN / f"calibration{session}"
    R, t, cameras = result.R, result.t, result.rig.cameras
    lengths, variances = [], []
    for ends in scored_ends(cameras, folder):
        X = [triangulated_end(R, t, *end) for end in ends]
        length = float(np.linalg.norm(X[1] - X[0]))
        var = 0.0
        for e, (cams, xy) in enumerate(ends):
            for k, c in enumerate(cams):
                for axis in range(2):
                    moved = xy.copy()
                    moved[k, axis] += NUDGE_PX / cameras[c].focal[axis]  # normalised units per pixel
                    var += ((np.linalg.norm(triangulated_end(R, t, cams, moved) - X[1 - e]) - length) / NUDGE_PX) ** 2
        lengths.append(length)
        variances.append(var)
    return float(100 * np.sqrt(np.mean(variances)) / np.mean(lengths))


def ushichka(method: str = "ba") -> dict:
    """The Ushichka thermal session from its .mat, with easyWand's figures."""
    folder = SHARED_DATA / USHICHKA
    ref = json.loads((folder / "easywand_result.json").read_text())
    cap = read_easywand_mat(folder / "round3_2018-07-28_easyWandData.mat", height=USHICHKA_HEIGHT).capture
    result = calibrate(cap.rig, cap.wand, None, points=cap.points, axis=cap.axis, options=CalibrationOptions(method=method))
    w = result.wand_report
    return {
        "result": result,
        "folder": folder,
        "wand_mean_m": w.length_mean_m,
        "wand_std_m": w.length_std_m,
        "wand_score_percent": 100 * w.length_std_m / w.length_mean_m,
        "easywand_wand_score_percent": ref["published_result"]["wandScore_percent"],
        "rms_per_axis_px": [c.reprojection_rms_px / np.sqrt(2) for c in result.cameras],
        "easywand_dlt_rmse_px": ref["published_result"]["dltRMSE_px_per_camera"],
        "reference_centres": np.array([c["camera_centre_world_m"] for c in ref["reference_cameras_derived_from_dlt"]]),
    }


def svoboda() -> dict:
    """The MultiCamSelfCal tracks with their .rad intrinsics, calibrated up to scale."""
    folder = SHARED_DATA / SVOBODA
    cap = read_svoboda(folder).capture
    result = calibrate(cap.rig, cap.wand, None, points=cap.points)
    # the mean 2D error over the observations the calibration kept (its own 5-sigma cleanup, as
    # the toolbox reports over its inliers), each point triangulated from its kept views
    tracks = point_tracks(result.rig, cap.points)
    focal = np.array([c.focal for c in result.rig.cameras])[tracks.camera]
    keep = np.ones(len(tracks), bool)
    for _ in range(2):
        kept = tracks.subset(keep)
        X = triangulate_points(result.R, result.t, kept.track, kept.camera, kept.xy, kept.n_tracks)
        point = np.full(tracks.n_tracks, -1)
        used = np.flatnonzero(np.bincount(tracks.track[keep], minlength=tracks.n_tracks) >= 2)  # as subset() keeps
        point[used] = np.arange(kept.n_tracks)
        ok = point[tracks.track] >= 0
        err = np.full(len(tracks), np.inf)
        r = reprojection_errors(result.R, result.t, point[tracks.track[ok]], tracks.camera[ok], tracks.xy[ok], X)
        err[ok] = np.linalg.norm(r * focal[ok], axis=1)
        keep = err <= OUTLIER_SIGMAS * robust_sigma(err[np.isfinite(err)])
    inliers = err[keep]
    original = np.loadtxt(folder / "original_cam_centers.dat")[:, :3]
    return {
        "result": result,
        "mean_error_px": float(inliers.mean()),
        "observations": int(len(err)),
        "inliers": int(len(inliers)),
        "published_mean_error_px": 0.62,
        "centre_diff_mm": aligned_centres_mm(result.centers, original),
        "rig_extent_mm": float(np.ptp(original, axis=0).max() * 1000),
    }


def svoboda_guessed_focal(focal_px: float = 700.0):
    """MultiCamSelfCal's DATA20100906 (no intrinsics given) as a user without them would run it:
    an assumed focal length, refined, and no distortion. Returns the CalibrationResult."""
    from wandcal.capture.importers.svoboda import read_svoboda as read

    cap = read(SHARED_DATA / SVOBODA_NO_INTRINSICS, focal_px=focal_px).capture
    return calibrate(cap.rig, cap.wand, None, points=cap.points, options=CalibrationOptions(refine_intrinsics=("focal",)))
