"""Is this calibration good? A verdict per camera and for the rig, and the checks every method's
result must pass before it is written.

Verdicts are ``excellent``, ``good`` or ``poor``: the worst of the criteria below, each with the
reason in words when it is not excellent. The thresholds and their sources are in
docs/result-format.md ("Verdicts").
"""

from __future__ import annotations

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.judge.coverage import coverage_grid, covered_fraction, empty_regions
from wandcal.calib.rig import Rig

LEVELS = ("excellent", "good", "poor")
# reprojection RMS, px: blob noise of a good marker system is 0.1-0.3 px; open tools (easyWand,
# Argus, DLTdv) treat residuals under a pixel as a working calibration; over that the intrinsics,
# the labels or a moved camera are suspect (wandcal.calib.judge.quality.HIGH_RMS_PX warns there too)
RMS_PX = (0.5, 1.0)
# wand-length spread, % of the length (easyWand's "wand score"): open tools call <= 1% good
WAND_STD_PERCENT = (0.5, 1.0)
# wand-length spread, mm: Qualisys asks for an SD of 1-2 mm or better on a full-body volume
WAND_STD_MM = (1.0, 2.0)
# wand ends per camera: Qualisys asks for at least 300 points per camera
MIN_OBSERVATIONS = (600, 300)
# share of an 8 x 8 grid over the image holding wand samples (wandcal.calib.judge.coverage). With the intrinsics
# known, the pose's own uncertainty is already in center_std_mm; coverage adds the risk that the
# lens model is trusted where no sample tested it. Excellent from the guidance's default goal
# (50%); poor under 15%, where the samples sit in one patch of the image (a rig like the
# simulator's, cameras 3-4 m from a 2 m volume, covers 20-30%)
COVERAGE = (0.5, 0.15)
# predicted 1-sigma of a camera centre, mm: sub-millimetre is what a wand calibration is for
CENTER_STD_MM = (0.5, 2.0)
# sanity checks every method's result must pass
WAND_LENGTH_TOLERANCE = 0.05  # the free wand's mean length within 5% of the given length
BELOW_FLOOR_M = 0.0  # a camera centre under the floor (z < 0 in a static object's or axis frame)


def _grade(value: float | None, limits: tuple[float, float], higher_is_better: bool = False) -> int:
    if value is None or not np.isfinite(value):
        return 0
    if higher_is_better:
        return 0 if value >= limits[0] else 1 if value >= limits[1] else 2
    return 0 if value <= limits[0] else 1 if value <= limits[1] else 2


def coverage_reports(rig: Rig, camera: np.ndarray, uv: np.ndarray) -> list[dict]:
    """Per camera: ``coverage`` (share of the grid holding wand samples) and ``uncovered`` (the
    empty parts in words). camera: (M,) index; uv: (M, 2) raw pixels of the observations used."""
    out = []
    for c, cam in enumerate(rig.cameras):
        counts = coverage_grid(uv[camera == c], cam.width, cam.height)
        out.append({"coverage": covered_fraction(counts), "uncovered": empty_regions(counts)})
    return out


def camera_verdict(report: dict, cam_id: str) -> dict:
    """The verdict of one camera from its result entry (``reprojection_rms_px``, ``observations``,
    ``point_observations``, ``coverage``, ``uncovered``, ``center_std_mm``): {"level", "reasons"},
    a reason for each criterion that is not excellent."""
    checks = []  # (grade, reason with {level} to fill)
    rms = report.get("reprojection_rms_px")
    if rms is not None:
        checks.append((_grade(rms, RMS_PX), f"{cam_id}: reprojection RMS {rms:.2f} px is {{level}} (excellent <= "
                       f"{RMS_PX[0]}, good <= {RMS_PX[1]} px); check its intrinsics, focus and blob detection"))
    obs = report.get("observations", 0) + report.get("point_observations", 0)
    checks.append((_grade(obs, MIN_OBSERVATIONS, True), f"{cam_id}: {obs} observations is {{level}} (excellent >= "
                   f"{MIN_OBSERVATIONS[0]}; Qualisys asks for {MIN_OBSERVATIONS[1]} per camera); record longer or "
                   f"wave nearer {cam_id}"))
    cov = report.get("coverage")
    if cov is not None:
        where = ", ".join(report.get("uncovered") or []) or "the gaps of its view"
        checks.append((_grade(cov, COVERAGE, True), f"{cam_id}: samples cover {cov:.0%} of its image, {{level}} "
                       f"(excellent >= {COVERAGE[0]:.0%}, good >= {COVERAGE[1]:.0%}); wave the wand in {where}"))
    std = report.get("center_std_mm")
    if std is not None:
        checks.append((_grade(std, CENTER_STD_MM), f"{cam_id}: its centre is known to {std:.2f} mm (1 sigma in the "
                       f"world frame, whose own markers count too), {{level}} (excellent <= {CENTER_STD_MM[0]}, good <= "
                       f"{CENTER_STD_MM[1]} mm); more frames across its view, or more static markers, tighten it"))
    level = max(grade for grade, _ in checks)
    return {"level": LEVELS[level],
            "reasons": [text.format(level=LEVELS[grade]) for grade, text in checks if grade > 0]}


def rig_verdict(cameras: list[dict], wand_report: dict | None) -> dict:
    """The rig's verdict: its worst camera's, and the wand-length spread's."""
    level = max((LEVELS.index(c["verdict"]["level"]) for c in cameras), default=0)
    reasons = []
    if wand_report is not None:
        std_mm = 1000 * wand_report["length_std_m"]
        pct = 100 * wand_report["length_std_m"] / wand_report["length_mean_m"]
        grade = max(_grade(pct, WAND_STD_PERCENT), _grade(std_mm, WAND_STD_MM))
        if grade:
            reasons.append(f"the wand length spreads by {std_mm:.2f} mm ({pct:.2f}%), {LEVELS[grade]} (open tools call <= "
                           f"{WAND_STD_PERCENT[1]:g}% good; Qualisys asks for {WAND_STD_MM[0]:g}-{WAND_STD_MM[1]:g} mm "
                           "or better)")
        level = max(level, grade)
    poor = [c["id"] for c in cameras if c["verdict"]["level"] == "poor"]
    if poor:
        reasons.append("poor cameras: " + ", ".join(poor))
    return {"level": LEVELS[level], "reasons": reasons}


def sanity_check(method: str, rig: Rig, cameras: list[dict], wand_report: dict | None, world: dict,
                 centers: np.ndarray) -> list[str]:
    """The checks every method's result must pass. Raises :class:`CalibrationError` when the
    result is not a calibration (a camera left without observations, a wand of the wrong
    length); returns warnings for what may be wrong but is not sure to be (cameras under the
    floor: a mirrored or flipped world hides behind a low reprojection error)."""
    other = "" if method == "ba" else "; try --method ba"
    ids = rig.ids
    empty = [ids[k] for k, c in enumerate(cameras) if c.get("observations", 0) + c.get("point_observations", 0) == 0]
    if empty:
        raise CalibrationError(f"method {method!r} ended with {', '.join(empty)} holding no observations (all were "
                               f"dropped as outliers), so those poses are not calibrated{other}")
    if wand_report is not None and rig.wand_length:
        off = wand_report["length_mean_m"] / rig.wand_length - 1
        if abs(off) > WAND_LENGTH_TOLERANCE:
            raise CalibrationError(
                f"method {method!r} ended with a wand of {1000 * wand_report['length_mean_m']:.1f} +- "
                f"{1000 * wand_report['length_std_m']:.1f} mm against the given {1000 * rig.wand_length:.1f} mm "
                f"({off:+.0%}): the cameras do not agree on the wand{other}; check wand.length_m and the intrinsics")
    warnings = []
    if world.get("frame") in ("static_object", "axis"):
        below = [ids[k] for k, C in enumerate(centers) if C[2] < BELOW_FLOOR_M]
        if below:
            what = "the static object's" if world["frame"] == "static_object" else "the axis points'"
            warnings.append(f"{', '.join(below)} {'is' if len(below) == 1 else 'are'} below the floor (z < 0) of "
                            f"{what} frame: the world may be mirrored or upside down; check the order of the "
                            "markers in rig.json (z must point up, towards the cameras)")
    return warnings


def judge(method: str, rig: Rig, cameras: list[dict], wand_report: dict | None, world: dict, centers: np.ndarray,
          camera: np.ndarray, uv: np.ndarray) -> tuple[dict, list[str]]:
    """Run :func:`sanity_check`, add each camera's coverage and verdict to its entry, and return
    (the rig's verdict, warnings). camera: (M,), uv: (M, 2) the observations used (wand ends and
    single-point tracks), raw pixels."""
    warnings = sanity_check(method, rig, cameras, wand_report, world, centers)
    for report, cov, cam in zip(cameras, coverage_reports(rig, camera, uv), rig.cameras):
        report |= cov
        report["verdict"] = camera_verdict(report, cam.id)
    return rig_verdict([{"id": c.id} | r for c, r in zip(rig.cameras, cameras)], wand_report), warnings
