"""Is this calibration good? A verdict per camera and for the rig's geometry (the world's placement:
:mod:`wandcal.calib.judge.placement`; the checks every method's result must pass:
:mod:`wandcal.calib.judge.sanity`).

Verdicts are ``excellent``, ``good`` or ``poor``: the worst of the criteria below. Each criterion
that is not excellent gives a reason with the number that fell short; each poor one also gives
advice, an instruction. Criteria are in the volume's own terms (millimetres and shares of the
volume's size), or relative to what the data show their noise to be (camera against camera), never
in fixed pixels. A fault found by :mod:`wandcal.calib.judge.faults.screen` makes the rig poor and names the
camera or input. docs/verdict.md gives every threshold's source or derivation.
"""

from __future__ import annotations

import re

import numpy as np

from wandcal.calib.judge.coverage import coverage_grids, covered_fraction, empty_regions
from wandcal.calib.judge.quality import SPREAD_Z, spread_z
from wandcal.calib.rig import LISTED_CAMERAS, Rig, camera_list, folded

LEVELS = ("excellent", "good", "poor")
# a camera's RMS ray distance over the volume's size: 0.3 px of blob noise, a typical good
# marker system, gives 4-5e-4 on a ring 3-4 m from a 2-3 m volume; 1e-3 is 2-3 mm there,
# Qualisys's 1-2 mm camera residual on a full-body volume; over 2.5e-3 no sub-millimetre
# reconstruction is left
RESIDUAL_OF_VOLUME = (1e-3, 2.5e-3)
# a camera's RMS ray angle (residual over focal length, which no resolution changes), mrad:
# blob centroids of marker systems (0.05-0.3 px at 800-3000 px focal lengths) give 0.02-0.4;
# hand-digitised points, as easyWand's published sessions, 0.6-1.1 (1.4-1.8 px at 1,700 px);
# over 1.5 mrad a camera misses by 1.5 mm at every metre of distance: no sub-millimetre volume
RAY_MRAD = (0.5, 1.5)
# a camera's blob noise over the median camera's: equal cameras scatter within +-5% (1,500
# frames); a camera twice as noisy as the rest has a fault of its own
NOISE_RATIO = (1.5, 2.0)
# share of a camera's camera-frames that are gross outliers against the rig's limit (5 robust
# sigmas): Gaussian noise leaves none; real, hand-digitised sessions published as good carry 5-20%
# (easyWand's Brown wind tunnel, 2-23% per camera), so only a quarter is poor on its own. Outliers
# concentrated in one camera are a fault of that camera (wandcal.calib.run.judgement)
OUTLIER_SHARE = (0.05, 0.25)
# wand ends and points per camera: Qualisys asks for at least 300 points per camera
MIN_OBSERVATIONS = (600, 300)
# share of an 8 x 8 grid over the image holding samples (wandcal.calib.judge.coverage): 50% is
# the wanding guidance's goal; under 15% the samples sit in one patch and the lens is untested
COVERAGE = (0.5, 0.15)
# a camera's geometry 1-sigma (relative to the other cameras) over the volume's size: 2.5e-4 is
# 0.5 mm in a 2 m volume, sub-millimetre; 1e-3 is 2 mm there. The good limit is the camera's own
# ray distance at the points instead where that is larger (:func:`geometry_limits`)
GEOMETRY_OF_VOLUME = (2.5e-4, 1e-3)
# wand-length spread, % of the length (easyWand's "wand score"): open tools call <= 1% good
WAND_STD_PERCENT = (0.5, 1.0)
# wand-length spread over the volume's size: Qualisys asks for an SD of 1-2 mm or better on a
# full-body volume (3-5 m across): 3e-4 is 1 mm at 3.3 m, 1e-3 is 2 mm at 2 m
WAND_STD_OF_VOLUME = (3e-4, 1e-3)
# a criterion's standard error (docs/verdict.md, "At the limit"): a sigma from the solver's
# covariance (a camera's geometry, the world's placement) varies by 4-14% of itself (median 11%)
# between random halves of Brown 1, Brown 2 and Ushichka, scaled to the whole session; the
# noise-level estimate alone would say 1-5%: a camera's sigma hinges on its few best-placed frames
SIGMA_REL_SE = 0.11
MAD_SIGMA_REL_SE = 1.166  # over sqrt(n): the MAD-based sigma's asymptotic standard error (Gaussian)
PLACEMENT_FAULTS = ("wand_scale", "static_markers")  # faults of the object that places the world
SCALE_FAULTS = ("wand_scale",)  # ... of which these put the whole rig's scale in doubt too
WAND_SPREAD_ADVICE = "look for a bent wand or loose markers, and check the cameras' intrinsics"
# the first instruction for a fault of the inputs, which its message explains
FAULT_ADVICE = {
    "wand_scale": "measure the wand's length (wand.length_m) and the L-frame's marker spacing (static_object.markers_m) "
                  "again and correct rig.json; then calibrate again",
    "static_markers": "check static_object.markers_m in rig.json against the L-frame, and that it is flat and not bent",
}


def _grade(value: float | None, limits: tuple[float, float], higher_is_better: bool = False, std: float = 0.0) -> int:
    """0, 1 or 2 (excellent, good, poor): how many of ``limits`` the value passes by more than
    ``std``, its own standard error (0: by any margin)."""
    if value is None or not np.isfinite(value):
        return 0
    sign = -1.0 if higher_is_better else 1.0
    return int(sum(sign * (value - limit) > std for limit in limits))


def _at_limit(value: float | None, limits: tuple[float, float], std: float) -> int | None:
    """The index of the limit that ``value`` is within its standard error ``std`` of (the level
    there is the better one, :func:`_grade`), or None."""
    if value is None or not np.isfinite(value) or not std > 0:
        return None
    return next((k for k, limit in enumerate(limits) if abs(value - limit) <= std), None)


def rms_std(value: float | None, n: int) -> float:
    """Standard error of an RMS or a standard deviation of ``n`` Gaussian samples: value / sqrt(2 (n - 1))."""
    return 0.0 if value is None or n < 2 else float(value) / np.sqrt(2.0 * (n - 1))


def share_std(share: float | None, n: int) -> float:
    """Binomial standard error of a share of ``n``."""
    return 0.0 if share is None or n < 1 else float(np.sqrt(share * (1.0 - share) / n))


def stability_entry(criterion: str, camera: str | None, value: float, limits: tuple[float, float], std: float,
                    unit: str, higher_is_better: bool = False) -> dict | None:
    """A criterion within its standard error of a limit, for the verdict's ``at_limit``: {"criterion",
    "camera", "value", "limit", "std", "unit", "levels"}, ``levels`` the two it lies between (it
    takes the better one); None when it is clear of both limits."""
    k = _at_limit(value, limits, std)
    return None if k is None else limit_entry(criterion, camera, value, limits[k], k, std, unit)


def limit_entry(criterion: str, camera: str | None, value: float, limit: float, k: int, std: float, unit: str) -> dict:
    """The verdict's ``at_limit`` entry of a criterion at ``limit``, the k-th (between LEVELS[k] and LEVELS[k + 1])."""
    return {"criterion": criterion, "camera": camera, "value": _round(value), "limit": _round(limit),
            "std": _round(std), "unit": unit, "levels": [LEVELS[k], LEVELS[k + 1]]}


def _round(x: float) -> float:
    return float(f"{float(x):.4g}")


def at_limit_text(entry: dict) -> str:
    """'at the limit of poor (0.84 +- 0.09 mm against 0.83 mm)'."""
    unit = entry["unit"]
    return (f"at the limit of {entry['levels'][1]} ({entry['value']:.3g} +- {entry['std']:.2g} {unit} against "
            f"{entry['limit']:.3g} {unit})").replace(" % ", "% ").replace(" %)", "%)")


def geometry_limits(report: dict, obs: int) -> tuple[tuple[float, float], float, bool]:
    """A camera's geometry sigma's (excellent, good) limits over the volume's size, the good
    limit's own standard error, and whether that limit is the camera's own rays' (decisions 0049, 0073).

    The good limit is :data:`GEOMETRY_OF_VOLUME`'s, or the noise of the camera's own rays at its
    points where that is larger, up to the residual's own good limit: a place known to within the
    noise of the camera's own rays adds less to a reconstructed point than each of its observations
    does already, and more frames would shrink the sigma, not the noise. The noise is the RMS ray
    distance at the points (``residual_of_volume``) times ``ray_noise_factor``
    (:func:`wandcal.calib.judge.residuals.ray_noise_factors`): the miss is measured at points fitted
    to the same rays, which take up a share of their error (half of it at two views), while the
    solver's sigma is scaled by the unbiased noise. A sigma grows as 1/sqrt(data), the noise does
    not: against a fixed 1e-3 a sparse, hand-digitised session (rays 1.0-1.4e-3 of its volume off)
    turned poor on 60% of its frames. The noise's standard error (an RMS's, of ``obs``
    observations) counts with the sigma's where it is the limit.
    """
    got = report.get("residual_of_volume")
    rel = float(got) * float(report.get("ray_noise_factor") or 1.0) if got is not None else float("nan")
    if not rel > GEOMETRY_OF_VOLUME[1]:  # NaN too
        return GEOMETRY_OF_VOLUME, 0.0, False
    limit = min(rel, RESIDUAL_OF_VOLUME[1])
    return (GEOMETRY_OF_VOLUME[0], limit), (rms_std(limit, obs) if limit == rel else 0.0), True


def coverage_reports(rig: Rig, camera: np.ndarray, uv: np.ndarray) -> list[dict]:
    """Per camera: ``coverage`` (share of the grid holding wand samples) and ``uncovered`` (the
    empty parts in words). camera: (M,) index; uv: (M, 2) raw pixels of the observations used."""
    grids = coverage_grids(camera, uv, [(cam.width, cam.height) for cam in rig.cameras])  # all cameras in one pass
    return [{"coverage": covered_fraction(counts), "uncovered": empty_regions(counts)} for counts in grids]


def _limits(limits: tuple[float, ...], fmt: str, higher: bool = False) -> str:
    op = ">=" if higher else "<="
    return f"excellent {op} {format(limits[0], fmt)}, good {op} {format(limits[1], fmt)}"


class Checks:
    """A verdict's criteria as they are graded: (criterion, grade, reason with ``{level}``, advice)
    and the ones within their standard error of a limit (:func:`stability_entry`)."""

    def __init__(self, camera: str | None) -> None:
        self.camera = camera
        self.rows: list[tuple[str, int, str, str]] = []
        self.at_limit: list[dict] = []

    def add(self, name: str, value: float | None, limits: tuple[float, float], text: str, advice: str, *,
            std: float = 0.0, shown: tuple[float, str] = (1.0, ""), higher: bool = False, cap: int = 2) -> int:
        """Grade ``value`` against ``limits`` with its standard error ``std``; ``shown``: (factor, unit)
        that put the value, limits and error in the reason's units. Returns the grade."""
        grade = min(_grade(value, limits, higher, std), cap)
        factor, unit = shown
        entry = None if value is None else stability_entry(name, self.camera, factor * value,
                                                           (factor * limits[0], factor * limits[1]), factor * std, unit, higher)
        if entry is not None:
            self.at_limit.append(entry)
            text = text.replace("{level}", "{level}, " + at_limit_text(entry))
        self.rows.append((name, grade, text, advice))
        return grade


def camera_verdict(report: dict, cam_id: str, extent_m: float | None, rig_noise_px: float | None) -> dict:
    """One camera's verdict from its result entry: {"level", "reasons", "advice",
    "short_of_excellent", "at_limit"}.

    A criterion changes level only where it passes its limit by more than its own standard error
    (docs/verdict.md, "At the limit"); within that the better level holds and its reason says "at
    the limit", and ``at_limit`` lists it with its value, limit and standard error.

    report: ``observations``, ``point_observations``, ``coverage``, ``uncovered``,
    ``geometry_std_mm``, and the judged figures ``noise_px``, ``outlier_share``, ``residual_mm``,
    ``residual_of_volume`` and ``geometry_of_volume``, and ``geometry_std_rel_se`` (the geometry
    sigma's relative standard error, where known; else :data:`SIGMA_REL_SE`); extent_m: the volume's size in metres
    (None without a scale);
    rig_noise_px: the median camera's noise.
    """
    checks = Checks(cam_id)
    obs = report.get("observations", 0) + report.get("point_observations", 0)
    rel = report.get("residual_of_volume")
    if rel is not None:
        mm = report.get("residual_mm")
        size = f" ({mm:.2f} mm in a {extent_m:.2f} m volume)" if mm is not None and extent_m else ""
        checks.add("residual", rel, RESIDUAL_OF_VOLUME,
                   f"{cam_id}: its rays pass the points at {1000 * rel:.2f} per mille of the volume's size{size}, "
                   f"{{level}} ({_limits(tuple(1000 * x for x in RESIDUAL_OF_VOLUME), '.1f')} per mille)",
                   f"check {cam_id}'s intrinsics and focus; its residuals are large for the volume",
                   std=rms_std(rel, obs), shown=(1000.0, "per mille"))
    mrad = report.get("ray_mrad")
    if mrad is not None:
        checks.add("ray angle", mrad, RAY_MRAD,
                   f"{cam_id}: its rays miss the points by {mrad:.2f} mrad RMS ({mrad:.2f} mm at a metre), "
                   f"{{level}} ({_limits(RAY_MRAD, '.1f')} mrad)",
                   f"check {cam_id}'s intrinsics (focal length, distortion) and focus; its residuals are large for "
                   "its lens", std=rms_std(mrad, obs), shown=(1.0, "mrad"))
    noise = report.get("noise_px")
    if noise is not None and rig_noise_px:
        ratio = noise / rig_noise_px
        checks.add("noise", ratio, NOISE_RATIO,
                   f"{cam_id}: its blob noise {noise:.2f} px is {ratio:.1f} times the median camera's "
                   f"{rig_noise_px:.2f} px, {{level}} ({_limits(NOISE_RATIO, '.1f')} times)",
                   f"check {cam_id}'s focus, exposure and blob detection",
                   std=ratio * MAD_SIGMA_REL_SE / np.sqrt(max(obs, 1)), shown=(1.0, "times"))
    share = report.get("outlier_share")
    if share is not None:
        checks.add("outliers", share, OUTLIER_SHARE,
                   f"{cam_id}: {100 * share:.1f}% of its camera-frames are gross outliers, {{level}} "
                   f"(excellent <= {100 * OUTLIER_SHARE[0]:g}%, good <= {100 * OUTLIER_SHARE[1]:g}%)",
                   f"look for reflections or a second bright marker in {cam_id}'s view and mask them",
                   std=share_std(share, obs), shown=(100.0, "%"))
    coverage_advice = _place_checks(checks, report, cam_id, extent_m, obs)
    rows = checks.rows
    level = max(grade for _, grade, _, _ in rows)
    return {"level": LEVELS[level],
            "reasons": [text.format(level=LEVELS[grade]) for _, grade, text, _ in rows if grade > 0],
            "advice": [advice for _, grade, _, advice in rows if grade == 2] + ([coverage_advice] if coverage_advice else []),
            "short_of_excellent": {name: LEVELS[grade] for name, grade, _, _ in rows if grade > 0},
            "at_limit": checks.at_limit}


def _place_checks(checks: Checks, report: dict, cam_id: str, extent_m: float | None, obs: int) -> str | None:
    """:func:`camera_verdict`'s observations, coverage and geometry criteria, added to ``checks``;
    returns the coverage advice a camera under the good coverage gets (not poor on its own)."""
    coverage_advice = None
    geo_rel = report.get("geometry_of_volume")
    # tA (issue 31): the sigma's standard error from the spread of the information that places the
    # camera (wandcal.calib.judge.residuals.place_sigma_errors), never below the measured 11%
    geo_std = max(SIGMA_REL_SE, report.get("geometry_std_rel_se") or 0.0) * geo_rel if geo_rel is not None else 0.0
    limits, limit_std, own = geometry_limits(report, obs)
    geo_std = float(np.hypot(geo_std, limit_std))  # a limit of the camera's own rays is an estimate too
    # few observations that place the camera well are good: its geometry sigma below says so
    few = _grade(obs, MIN_OBSERVATIONS, True) == 2 and (geo_rel is None or _grade(geo_rel, limits, std=geo_std) == 2)
    checks.add("observations", obs, MIN_OBSERVATIONS,
               f"{cam_id}: {obs} observations, {{level}} ({_limits(MIN_OBSERVATIONS, 'd', True)}; Qualisys "
               f"asks for {MIN_OBSERVATIONS[1]} per camera)", f"record longer, or wave nearer {cam_id}",
               higher=True, cap=2 if few else 1)
    cov = report.get("coverage")
    if cov is not None:
        where = ", ".join(report.get("uncovered") or []) or "the gaps of its view"
        grade = _grade(cov, COVERAGE, True)
        # with the intrinsics known, a poorly covered image costs precision, which the geometry
        # sigma already counts, and risks a lens error where no sample tested it: advice, not poor
        text = (f"{cam_id}: samples cover {cov:.0%} of its image, {'short of good' if grade == 2 else '{level}'} "
                f"(excellent >= {COVERAGE[0]:.0%}, good >= {COVERAGE[1]:.0%})")
        checks.add("coverage", cov, COVERAGE, text, f"wave the wand in {where} of {cam_id}'s image", higher=True, cap=1)
        if grade == 2:
            coverage_advice = f"wave the wand in {where} of {cam_id}'s image"
    if geo_rel is not None:
        geo = report.get("geometry_std_mm")
        rays = ", its rays' own noise at the points" if own else ""
        if geo is not None and extent_m:
            text = (f"{cam_id}: its place among the other cameras is known to {geo:.2f} mm (1 sigma), {{level}} "
                    f"(excellent <= {limits[0] * 1000 * extent_m:.2f} mm, good <= "
                    f"{limits[1] * 1000 * extent_m:.2f} mm in this volume{rays})")
            shown = (1000.0 * extent_m, "mm")
        else:
            text = (f"{cam_id}: its place among the other cameras is known to {1000 * geo_rel:.2f} per mille of the "
                    f"volume (1 sigma), {{level}} ({_limits(tuple(1000 * x for x in limits), '.2f')} per mille{rays})")
            shown = (1000.0, "per mille")
        checks.add("geometry", geo_rel, limits, text,
                   f"wave the wand longer across {cam_id}'s view, where it and other cameras see it", std=geo_std, shown=shown)
    return coverage_advice


def rig_verdict(cameras: list[dict], wand_report: dict | None, faults: list[dict], extent_m: float | None) -> dict:
    """The rig's geometry verdict: its worst camera's, the wand-length spread's, and any fault's
    (every fault but the world's placement makes the rig poor); ``at_limit``: every criterion of
    the rig and its cameras within its standard error of a limit (:func:`stability_entry`)."""
    level = max((LEVELS.index(c["verdict"]["level"]) for c in cameras), default=0)
    reasons, advice = [], []
    at_limit = [entry for c in cameras for entry in c["verdict"].get("at_limit", [])]
    rig_faults = [f for f in faults if f["kind"] not in PLACEMENT_FAULTS or f["kind"] in SCALE_FAULTS]
    for fault in rig_faults:
        level = 2
        reasons.append(fault["message"])
        if fault["kind"] in FAULT_ADVICE:  # the first instruction addresses the first fault
            advice.append(FAULT_ADVICE[fault["kind"]])
    if wand_report is not None and wand_report.get("length_mean_m"):
        std_mm = 1000 * wand_report["length_std_m"]
        pct = 100 * wand_report["length_std_m"] / wand_report["length_mean_m"]
        n = int(wand_report.get("frames_used") or 0)
        checks = Checks(None)
        _spread_check(checks, pct, WAND_STD_PERCENT, n,
                      f"{pct:.2f}% of its length (easyWand's wand score; open tools call <= "
                      f"{WAND_STD_PERCENT[1]:g}% good): {{level}}", (1.0, "%"))
        if extent_m:
            _spread_check(checks, std_mm / (1000 * extent_m), WAND_STD_OF_VOLUME, n,
                          f"{std_mm:.2f} mm in a {extent_m:.2f} m volume (excellent <= "
                          f"{WAND_STD_OF_VOLUME[0] * 1000 * extent_m:.2f} mm, good <= "
                          f"{WAND_STD_OF_VOLUME[1] * 1000 * extent_m:.2f} mm, from Qualisys's 1-2 mm on a full-body "
                          "volume): {level}", (1000.0 * extent_m, "mm"))
        at_limit += checks.at_limit
        for _, grade, text, _ in checks.rows:
            if grade:
                reasons.append(f"the wand's length spreads by {text.format(level=LEVELS[grade])}")
                level = max(level, grade)
                if grade == 2:
                    advice.append(WAND_SPREAD_ADVICE)
    named = {f["camera"] for f in rig_faults}
    for word in ("poor", "good"):
        by_criterion: dict[str, list[str]] = {}
        for c in cameras:
            if c["id"] in named:
                continue
            for name, got in c["verdict"].get("short_of_excellent", {}).items():
                if got == word:
                    by_criterion.setdefault(name, []).append(c["id"])
        if by_criterion:
            reasons.append(f"{word} {'for' if word == 'poor' else 'but not excellent for'} "
                           + "; ".join(f"{name} in {camera_list(ids, len(cameras))}" for name, ids in by_criterion.items())
                           + " (each camera's verdict says why)")
    advice += fold_advice([(c["id"], text) for c in cameras for text in c["verdict"].get("advice", [])], len(cameras))
    return {"level": LEVELS[level], "reasons": reasons, "advice": list(dict.fromkeys(advice)), "at_limit": at_limit}


def _spread_check(checks: Checks, value: float, limits: tuple[float, float], n: int, text: str,
                  shown: tuple[float, str]) -> None:
    """The wand-length spread (a standard deviation of ``n`` frames' lengths) graded against
    ``limits`` by its own sampling error (decision 0077): past a limit only where it stands
    :data:`~wandcal.calib.judge.quality.SPREAD_Z` standard errors above it (one-sided 2.3%, by
    :func:`~wandcal.calib.judge.quality.spread_z`), at the limit within that of it either side;
    the entry shows the spread's standard error (:func:`rms_std`). Added to ``checks`` as a row."""
    z = [spread_z(value, limit, n) for limit in limits]
    grade = sum(zk > SPREAD_Z for zk in z)
    near = next((k for k, zk in enumerate(z) if abs(zk) <= SPREAD_Z), None)
    if near is not None:
        factor, unit = shown
        entry = limit_entry("wand spread", None, factor * value, factor * limits[near], near, factor * rms_std(value, n), unit)
        checks.at_limit.append(entry)
        text = text.replace("{level}", "{level}, " + at_limit_text(entry))
    checks.rows.append(("wand spread", grade, text, ""))


def fold_advice(advice: list[tuple[str, str]], rig_cameras: int) -> list[str]:
    """The cameras' advice, (camera id, instruction) in rig order, as the rig's list: an instruction
    that more than :data:`LISTED_CAMERAS` cameras give but for their id becomes one line naming them
    (:func:`camera_list`; "all 64 cameras: check their focus, exposure and blob detection"), at the
    first one's place; each camera's own verdict keeps its own. A small rig's list is unchanged."""
    lines = []
    for cam_id, text in advice:
        template = re.sub(rf"(?<![\w-]){re.escape(cam_id)}(?![\w-])", "\0", text)  # the camera's id masked
        lines.append((text, template if "\0" in template else None, cam_id))

    def line(template: str, ids: list[str]) -> str:
        plural = re.sub(r"\bits\b", "their", template.replace("\0's", "their").replace("\0", "them"))
        return f"{camera_list(ids, rig_cameras)}: {plural}"
    return folded(lines, lambda ids: len(ids) > LISTED_CAMERAS, line)


