"""The fields of a ``wandcal-result/1`` document beyond each camera's intrinsics and pose: their
types, ranges and shapes (docs/result-format.md). Every one is optional (older results lack the
newer ones) and unknown fields are let through; a field that is present must be what its
consumers (export, check, report, ``calibrate --from``) expect, or the reader refuses the file
naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from wandcal.capture.folder import MAX_FRAME, CaptureFormatError

Check = Callable[[object, str], None]
MAX_TEXT = 100_000  # a warning or reason is a sentence; a longer string is not one wandcal wrote
MAX_ITEMS = 1_000_000  # lists (worst frames, warnings, faults) are short; a million is damage


def _fail(where: str, want: str, value: object) -> None:
    raise CaptureFormatError(f"{where} must be {want}, got {str(value)[:60]!r}")


def number(lo: float = -math.inf, hi: float = math.inf, nullable: bool = True) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        try:
            ok = (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(float(value))
                  and lo <= value <= hi)
        except OverflowError:  # an integer past float range
            ok = False
        if not ok:
            span = f" from {lo:g} to {hi:g}" if math.isfinite(lo) and math.isfinite(hi) else (
                f" of at least {lo:g}" if math.isfinite(lo) else "")
            _fail(where, f"a finite number{span}" + (" or null" if nullable else ""), value)
    return check


def whole(lo: int = 0, hi: int = MAX_FRAME, nullable: bool = False) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            _fail(where, f"a whole number from {lo} to {hi}", value)
    return check


def text(nullable: bool = True) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        if not isinstance(value, str) or len(value) > MAX_TEXT:
            _fail(where, "a string", value)
    return check


def choice(*values: str) -> Check:
    def check(value: object, where: str) -> None:
        if value not in values:
            _fail(where, " or ".join(repr(v) for v in values), value)
    return check


def vector(n: int) -> Check:
    item = number(nullable=False)

    def check(value: object, where: str) -> None:
        if not isinstance(value, list) or len(value) != n:
            _fail(where, f"a list of {n} numbers", value)
        for i, v in enumerate(value):  # type: ignore[arg-type]
            item(v, f"{where}[{i}]")
    return check


def items(each: Check, nullable: bool = True) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        if not isinstance(value, list) or len(value) > MAX_ITEMS:
            _fail(where, "a list", value)
        for i, v in enumerate(value):  # type: ignore[arg-type]
            each(v, f"{where}[{i}]")
    return check


def either(*checks: Check) -> Check:
    def check(value: object, where: str) -> None:
        errors = []
        for c in checks:
            try:
                return c(value, where)
            except CaptureFormatError as exc:
                errors.append(str(exc))
        raise CaptureFormatError(errors[0])
    return check


def obj(fields: dict[str, Check], nullable: bool = True) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        if not isinstance(value, dict):
            _fail(where, "a JSON object", value)
        check_fields(value, fields, where)  # type: ignore[arg-type]
    return check


def counts(value: object, where: str) -> None:
    """An object of whole numbers (``dropped``: camera-frames left out, by reason)."""
    if not isinstance(value, dict):
        _fail(where, "a JSON object of whole numbers", value)
    for key, v in value.items():  # type: ignore[union-attr]
        whole()(v, f"{where}.{key}")


def number_map(value: object, where: str) -> None:
    """An object of finite numbers (``world.axis_misalignment_rad``: radians by axis)."""
    if not isinstance(value, dict):
        _fail(where, "a JSON object of numbers", value)
    for key, v in value.items():  # type: ignore[union-attr]
        number()(v, f"{where}.{key}")


def anything(value: object, where: str) -> None:
    """Fields no consumer reads into arithmetic (a fault's evidence): any JSON value."""


def check_fields(doc: dict, fields: dict[str, Check], where: str) -> None:
    """Check each of ``fields`` present in ``doc``; errors name ``where`` and the field."""
    for key, check in fields.items():
        if key in doc:
            check(doc[key], f"{where} {key}" if where.endswith(":") else f"{where}.{key}")


TEXTS = items(text(nullable=False))
NON_NEGATIVE = number(0.0)
SHARE = number(0.0, 1.0)
VERDICT_FIELDS = {"level": text(nullable=False), "reasons": TEXTS, "advice": either(text(), TEXTS)}
CAMERA_FIELDS: dict[str, Check] = {
    "center": vector(3),
    "center_std_mm": NON_NEGATIVE,
    "rotation_std_deg": NON_NEGATIVE,
    "geometry_std_mm": NON_NEGATIVE,
    "geometry_rotation_std_deg": NON_NEGATIVE,
    "residual_mm": NON_NEGATIVE,
    "outlier_share": SHARE,
    "reprojection_rms_px": NON_NEGATIVE,
    "observations": whole(nullable=True),
    "frames_with_both_ends": whole(nullable=True),
    "worst_frames": items(obj({"frame": whole(), "error_px": NON_NEGATIVE}, nullable=False)),
    "initial_pose": text(),
    "point_observations": whole(nullable=True),
    "point_rms_px": NON_NEGATIVE,
    "coverage": SHARE,
    "uncovered": TEXTS,
    "verdict": obj(VERDICT_FIELDS),
    "warnings": TEXTS,  # every warning about this camera in full (the result's own list folds them)
    "intrinsics": obj({"refined": TEXTS, "focal_px": NON_NEGATIVE, "focal_std_px": NON_NEGATIVE,
                       "principal_px": either(vector(2), number()), "principal_std_px": either(vector(2), number()),
                       "k1": number(), "k1_std": NON_NEGATIVE}),
}
FAULT_FIELDS = {"kind": text(nullable=False), "camera": text(), "message": text(), "evidence": anything}
RESULT_FIELDS: dict[str, Check] = {
    "wand": obj({"length_m": number(0.0), "length_mean_m": number(0.0), "length_std_m": NON_NEGATIVE,
                 "frames_used": whole(nullable=True)}),
    "solver": obj({"method": text(), "iterations": whole(nullable=True), "seconds": NON_NEGATIVE,
                   "total_seconds": NON_NEGATIVE, "status": text(), "loss": text(), "loss_scale_px": NON_NEGATIVE,
                   "solved_only": TEXTS, "refined_intrinsics": TEXTS}),
    "world": obj({"frame": text(), "description": text(), "scale": choice("wand", "arbitrary"),
                  "fit_rms_m": NON_NEGATIVE, "expected_fit_rms_m": NON_NEGATIVE, "static_blob_rms_px": NON_NEGATIVE,
                  "cameras_used": TEXTS, "axis_misalignment_rad": either(number(), number_map),
                  "placement": obj({"origin_std_mm": NON_NEGATIVE, "axes_std_deg": NON_NEGATIVE})}),
    "dropped": counts,
    "verdict": obj(VERDICT_FIELDS | {"faults": items(obj(FAULT_FIELDS, nullable=False)),
                                     "placement": either(obj(VERDICT_FIELDS), text())}),
    "warnings": TEXTS,
}
