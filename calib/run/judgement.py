"""The judgement step: the same observations judged for every method, the faults named, the
verdicts given. Where a calibration went wrong is found before anything is called poor.

The same observations are judged for every method (the labelled wand pairs and the point tracks,
outliers included, :mod:`wandcal.calib.judge.residuals`). A camera whose residuals stand out of
the rig's (its noise :data:`~wandcal.calib.run.rig_faults.SUSPECT_NOISE_RATIO` times the median camera's, or a share of gross
outliers well above the others' and beyond their binomial scatter) is a suspect. A camera at fault also bends every other camera's
pose, so each suspect is judged against the rig solved without it: the others are refined
without its observations, and its own pose is refitted against the wand ends they triangulate, at
every whole-frame shift (:func:`wandcal.calib.judge.faults.screen.analyse_camera`); the paths that
name a camera, by the rig's size, are :mod:`wandcal.calib.run.rig_faults`. Its residual's
pattern then names the cause: timing, intrinsics, noise (focus, exposure, detection) or
reflections. Inputs are judged too: the wand's length against the static object's markers, the
solver's convergence, and refined intrinsics the data do not determine. docs/verdict.md has the
limits and why.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.intrinsic_limits import intrinsic_limit_entries
from wandcal.calib.judge.placement import placement_verdict
from wandcal.calib.judge.residuals import (
    Residuals,
    camera_figures,
    median_ray_angle,
    observation_residuals,
    place_sigma_errors,
    ray_noise_factors,
)
from wandcal.calib.judge.sanity import sanity_check
from wandcal.calib.judge.verdict import (
    SCALE_FAULTS,
    at_limit_text,
    camera_verdict,
    coverage_reports,
    rig_verdict,
)
from wandcal.calib.observations import PointTracks, WandPairs
from wandcal.calib.rig import Rig, camera_list
from wandcal.calib.run.camera_figures import CameraFigures, FocalLimitFigures, JudgedFigures, Movement
from wandcal.calib.run.own_error_faults import forget_eliminated, noise_limits
from wandcal.calib.run.result import SolverReport, WandReport, WorldFrame
from wandcal.calib.run.rig_faults import few_camera_faults
from wandcal.calib.solve.uncertainty import chi2_quantile

# rays meeting at under 2 degrees put a point's depth at 1/tan(2 deg) ~ 29 baselines, known to
# sigma/2 deg of it: a rig whose median point is seen so is degenerate (real rigs meet at 20-90)
MIN_RAY_ANGLE_DEG = 2.0
# a static fit whose scale is off by more than its markers' noise explains, and whose residual a
# scale explains (the scaled fit within the noise's 99th percentile), is a wand length that
# disagrees with the markers
SCALE_FIT_SHARE = 0.5
# what an unconverged solve asks for, by method: each names only options of its own method
UNCONVERGED_ADVICE = {
    "paper": "raise --max-rounds or --lp-time-limit, or use --method ba",
    "lp": "raise --lp-time-limit, or use --method ba",
    "ba": "ba has no option to run longer: fix what keeps it from converging (the faults and warnings: a camera "
          "out of time, wrong intrinsics), or try --method paper",
}


def input_faults(rig: Rig, world: dict, solver: dict, cameras: list[dict]) -> list[dict]:
    """Faults of the inputs and of the solve: the wand's length against the static object, an
    unconverged solve, refined intrinsics the data leave undetermined."""
    faults = []
    expected, rms = world.get("expected_fit_rms_m"), world.get("fit_rms_m")
    if world.get("frame") == "static_object" and expected and rms is not None:
        M = len(rig.static_markers) if rig.static_markers is not None else 4
        dof = max(3 * M - 6, 1)
        limit = expected * np.sqrt(chi2_quantile(dof) / dof)
        scale, scaled = world.get("marker_scale"), world.get("scaled_fit_rms_m")
        if rms > limit and scale is not None and scaled is not None:
            if scaled <= max(limit, SCALE_FIT_SHARE * rms):
                faults.append({"kind": "wand_scale", "camera": None, "evidence": {
                    "marker_scale": round(scale, 5), "fit_rms_mm": round(1000 * rms, 3),
                    "scaled_fit_rms_mm": round(1000 * scaled, 3), "expected_fit_rms_mm": round(1000 * expected, 3)},
                    "message": f"the wand's length and the static object's size disagree by {100 * abs(1 / scale - 1):.1f}%: "
                               f"measured with the wand as given, the static object is {1 / scale:.4f} times its "
                               f"markers_m (its markers fit with {1000 * rms:.1f} mm RMS where {1000 * expected:.2f} mm "
                               f"was expected, and with {1000 * scaled:.2f} mm once scaled); one of wand.length_m and "
                               "markers_m in rig.json is wrong: measure both again"})
            else:
                faults.append({"kind": "static_markers", "camera": None, "evidence": {
                    "fit_rms_mm": round(1000 * rms, 3), "expected_fit_rms_mm": round(1000 * expected, 3)},
                    "message": f"the static object's markers sit {1000 * rms:.1f} mm RMS off their given coordinates "
                               f"({1000 * expected:.2f} mm expected from their blobs): check markers_m in rig.json, "
                               "and that the L-frame is flat and not bent"})
    status = solver.get("status")
    if status and status != "converged":
        method = solver.get("method")
        faults.append({"kind": "unconverged", "camera": None, "evidence": {"status": status},
                       "message": f"the {method} refinement stopped before converging ({status}): the "
                                  f"poses are not a solution; {UNCONVERGED_ADVICE.get(str(method), UNCONVERGED_ADVICE['ba'])}"})
    for cam, entry in zip(rig.cameras, cameras):
        intr = entry.get("intrinsics") or {}
        for name, value, std in (("focal length", intr.get("focal_px"), intr.get("focal_std_px")),
                                 ("k1", intr.get("k1"), intr.get("k1_std"))):
            if value is not None and std is not None and not (abs(std) < abs(value) or name == "k1" and std < 0.05):
                faults.append({"kind": "undetermined", "camera": cam.id,
                               "evidence": {"parameter": name, "value": value, "std": std},
                               "message": f"{cam.id}'s refined {name} is {value:.4g} +- {std:.3g}: the data do not "
                                          "determine it; hold it (leave it out of --refine-intrinsics) or wave the "
                                          "wand at more depths and across the whole image"})
    return faults


def judge(method: str, rig: Rig, cameras: list[CameraFigures], wand_report: WandReport | None, world: WorldFrame,
          R: np.ndarray, t: np.ndarray, labelled: WandPairs, tracks: PointTracks | None, solver: SolverReport,
          seen: tuple[np.ndarray, np.ndarray], known: tuple[np.ndarray, np.ndarray] | None = None
          ) -> tuple[list[CameraFigures], dict, list[str]]:
    """Judge a calibration: run :func:`sanity_check`, judge each camera's figures, coverage and
    verdict, and return (the cameras' figures with them, the rig's verdict with its ``faults`` and
    ``placement``, warnings).

    Args:
        cameras: (N,) each camera's figures so far (rig order);
        R, t: (N, 3, 3), (N, 3) final poses, world frame; labelled: every labelled wand pair the
            refinement started from (outliers included); tracks: the point tracks, or None;
        seen: (camera (M,), uv (M, 2)) the observations that placed the cameras (coverage).
        known: (capture frame numbers (F2,), wand ends (F2, 2, 3), world frame) the solver's own
            wand points, which the judgement uses rather than triangulating them again.
    """
    from wandcal.calib.geometry import camera_centers

    # the verdict's rules read the result's entries as the document has them
    wand_doc, world_doc, solver_doc = (wand_report.to_json() if wand_report is not None else None, world.to_json(),
                                       solver.to_json())
    try:
        warnings = sanity_check(method, rig, [c.to_json() for c in cameras], wand_doc, world_doc, camera_centers(R, t))
    except CalibrationError as exc:  # a camera out of time, named, may be why
        from wandcal.calib.judge.faults.timing_pairs import timing_refusal

        raise timing_refusal(exc, list(rig.ids), R, t, labelled, tracks,
                             np.array([c.focal for c in rig.cameras], float)) from None  # (fx, fy), as rig_faults
    scaled = wand_report is not None
    focal = np.array([c.focal for c in rig.cameras], float)
    res = observation_residuals(R, t, labelled, tracks, focal, known)
    figures = camera_figures(res, len(rig.cameras), scaled)
    noise = [f["noise_px"] for f in figures if f["noise_px"]]
    rig_noise = float(np.median(noise)) if noise else None
    extent = res.extent if res.extent > 0 else None
    judged = [replace(cam, judged=_judged(cam, fig, cov, extent))
              for cam, fig, cov in zip(cameras, figures, coverage_reports(rig, *seen))]
    # each camera's sigma's own standard error, for the verdict's "at the limit" (not written)
    # and its rays' own noise over their fitted miss, for its geometry's good limit (neither written)
    docs = [c.to_json() | {"geometry_std_rel_se": se, "ray_noise_factor": k} for c, se, k in
            zip(judged, place_sigma_errors(R, res, len(rig.cameras)), ray_noise_factors(res, len(rig.cameras)))]
    forget_eliminated()
    faults = few_camera_faults(rig, labelled, tracks, R, t, figures, res) + input_faults(rig, world_doc, solver_doc, docs)
    angle = median_ray_angle(R, res)
    if angle is not None and angle < np.radians(MIN_RAY_ANGLE_DEG):
        faults.append({"kind": "undetermined", "camera": None, "evidence": {"median_ray_angle_deg": round(np.degrees(angle), 4)},
                       "message": f"the cameras' rays meet at a median {np.degrees(angle):.2f} degrees: the points' depth "
                                  "is not determined and the rig has collapsed towards one spot; check the focal "
                                  "lengths (rig.json or --focal-px) and that the cameras see the volume from apart"})
    near = noise_limits(rig, labelled, tracks, R, t, faults)
    forget_eliminated()
    out = [replace(cam, verdict=_camera_verdict(doc, cam_id, faults, extent if scaled else None, rig_noise, near))
           for cam, doc, cam_id in zip(judged, docs, rig.ids)]
    named: list[dict[str, Any]] = [{"id": cam_id} | c.to_json() for cam_id, c in zip(rig.ids, out)]
    verdict = rig_verdict(named, wand_doc, faults, extent if scaled else None)
    at_fault = {f["camera"] for f in faults if f["camera"]}
    dragged = [c["id"] for c in named if c["id"] not in at_fault and c["verdict"]["level"] == "poor"]
    if at_fault and dragged:  # one camera at fault bends the whole solve: the others are judged again after
        verdict["reasons"].insert(len(faults), f"{camera_list(dragged, len(named))} {'is' if len(dragged) == 1 else 'are'} poor in "
                                  f"this solve, which {camera_list([i for i in rig.ids if i in at_fault], len(named))} may have bent: fix "
                                  f"{'it' if len(at_fault) == 1 else 'them'} and calibrate again before judging the others")
    verdict["placement"] = placement_verdict(world_doc, extent if scaled else None, faults)
    verdict["faults"] = faults
    out, verdict["limits"] = _focal_limits(rig, out, R, t, res, scaled, solver.refined_intrinsics)
    out = _movements(rig, out, faults)
    verdict["volume_m" if scaled else "volume"] = extent
    return out, verdict, warnings


# warnings of calib/run/camera_reports.py in fixed pixels or frames that the verdict judges in the
# volume's terms: each is kept only for a camera that verdict calls poor on one of these criteria
# (Brown's published sessions gave eight "check its intrinsics" warnings beside a good rig)
JUDGED_WARNINGS = (("saw both wand ends in only", ("observations", "geometry")),
                   ("reprojection RMS of", ("ray angle", "residual")))


def acted_warnings(cameras: list[CameraFigures], warnings: list[str], ids: tuple[str, ...] | list[str]
                   ) -> tuple[list[CameraFigures], list[str]]:
    """The judged cameras and the result's warnings without the warnings of :data:`JUDGED_WARNINGS`
    whose camera's verdict is not poor on their criteria: a warning is for something to do."""
    def wanted(text: str) -> bool:
        for c, cam_id in enumerate(ids):
            if text.startswith(cam_id + " "):
                poor = {name for name, got in ((cameras[c].verdict or {}).get("short_of_excellent") or {}).items()
                        if got == "poor"}
                return all(pattern not in text or poor & set(criteria) for pattern, criteria in JUDGED_WARNINGS)
        return True
    return ([replace(cam, warnings=tuple(w for w in cam.warnings if wanted(w))) if cam.warnings else cam for cam in cameras],
            [w for w in warnings if wanted(w)])


def _movements(rig: Rig, cameras: list[CameraFigures], faults: list[dict]) -> list[CameraFigures]:
    """The cameras with a ``moved`` fault carry its figures (the result's ``moved`` entry)."""
    for fault in faults:
        if fault["kind"] == "moved" and fault["camera"] is not None and "degrees_std" in fault["evidence"]:
            c = rig.index(fault["camera"])
            e = fault["evidence"]
            cameras[c] = replace(cameras[c], moved=Movement(e["frame"], e["degrees"], e["degrees_std"], e.get("centre_mm"),
                                                            e.get("centre_std_mm")))
    return cameras


def _focal_limits(rig: Rig, cameras: list[CameraFigures], R: np.ndarray, t: np.ndarray, res: Residuals, scaled: bool,
                  refined: tuple[str, ...]) -> tuple[list[CameraFigures], list[dict]]:
    """The cameras' figures with how far each position hinges on the intrinsics that were given
    (the focal length, the principal point, the distortion:
    :func:`wandcal.calib.judge.intrinsic_limits.intrinsic_limit_entries`), and the verdict's ``limits``."""
    geometry = [c.uncertainty.geometry.std if c.uncertainty is not None and c.uncertainty.geometry is not None else None
                for c in cameras]
    entries, limits = intrinsic_limit_entries(rig, geometry, R, t, res, scaled, refined)
    return [replace(cam, focal_limit=FocalLimitFigures.from_json(e)) if e is not None else cam
            for cam, e in zip(cameras, entries)], limits


def _judged(cam: CameraFigures, fig: dict, cov: dict, extent: float | None) -> JudgedFigures:
    """A camera's judged figures (:func:`wandcal.calib.judge.residuals.camera_figures`) and
    coverage (:func:`wandcal.calib.judge.verdict.coverage_reports`); extent: the volume's size."""
    geometry = cam.uncertainty.geometry.std if cam.uncertainty is not None and cam.uncertainty.geometry else None
    uncovered = cov["uncovered"]
    return JudgedFigures(
        cov["coverage"], tuple(uncovered) if uncovered is not None else None, fig["noise_px"], fig["outlier_share"],
        fig["residual_mm"], fig["ray_mrad"],
        fig["ray_distance"] / extent if extent and fig["ray_distance"] else None,
        geometry / extent if extent and geometry is not None else None)


def _camera_verdict(doc: dict, cam_id: str, faults: list[dict], extent: float | None, rig_noise: float | None,
                    near: list[dict] | None = None) -> dict:
    """A camera's verdict (:func:`camera_verdict`); a camera at fault, or in a rig whose scale is at
    fault, is poor, whatever its figures say. near: criteria judged elsewhere at the limit of poor
    (:func:`wandcal.calib.run.own_error_faults.noise_limits`); the camera's own are added to its ``at_limit``
    and said in its reasons, its level left as it is."""
    verdict = camera_verdict(doc, cam_id, extent, rig_noise)
    mine = [e for e in near or [] if e["camera"] == cam_id]
    if mine:
        verdict = verdict | {"at_limit": [*verdict.get("at_limit", []), *mine], "reasons": [*verdict["reasons"], *(
            f"{cam_id}'s {e['criterion'].replace('own ', '')} is {at_limit_text(e)}: its blob centres "
            f"({e['own_noise_px']:.2f} px against {e['others_noise_px']:.2f} px) may be noisier than the others'; "
            "check its focus, exposure and the blob detection settings" for e in mine)]}
    for fault in faults:
        # a scale fault puts every length off, the camera's place and its sigma with it
        if fault["camera"] == cam_id or fault["kind"] in SCALE_FAULTS:
            verdict = verdict | {"level": "poor", "reasons": [fault["message"], *verdict["reasons"]]}
    return verdict
