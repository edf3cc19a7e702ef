"""A ``wandcal-result/1`` file: read it, check every field its consumers use, and build the typed result.

``wandcal export``, ``report``, ``check`` and ``calibrate --from`` start here, so a hand-edited or
truncated result stops with a message that names the file, the camera and the field. The
document's own reader and writer (dict <-> typed values) is :mod:`wandcal.calib.run.result`; this
module holds the file and the checks.

Beyond each camera's intrinsics and pose, the fields' types, ranges and shapes are
:data:`CAMERA_FIELDS` and :data:`RESULT_FIELDS` (docs/result-format.md). Every one is optional
(older results lack the newer ones) and unknown fields are let through; a field that is present
must be what its consumers (export, check, report, ``calibrate --from``) expect, or the reader
refuses the file naming the field.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn, cast

import numpy as np

from wandcal.calib.errors import CalibrationError
from wandcal.calib.rig import Camera, Rig
from wandcal.calib.run.result import RESULT_FORMAT, CalibrationResult
from wandcal.calib.run.result import result_from_json as typed_result
from wandcal.capture.csv_tables import MAX_FRAME
from wandcal.capture.folder import CaptureFormatError
from wandcal.capture.rig_file import MAX_IMAGE_SIDE_PX, check_format, positive_number

__all__ = ["CAMERA_FIELDS", "RESULT_FIELDS", "RESULT_FORMAT", "ResultFile", "check_result", "read_result",
           "result_from_json"]

Check = Callable[[object, str], None]
MAX_TEXT = 100_000  # a warning or reason is a sentence; a longer string is not one wandcal wrote
MAX_ITEMS = 1_000_000  # lists (worst frames, warnings, faults) are short; a million is damage


def _fail(where: str, want: str, value: object) -> NoReturn:
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
        for i, v in enumerate(value):
            item(v, f"{where}[{i}]")
    return check


def items(each: Check, nullable: bool = True) -> Check:
    def check(value: object, where: str) -> None:
        if value is None and nullable:
            return
        if not isinstance(value, list) or len(value) > MAX_ITEMS:
            _fail(where, "a list", value)
        for i, v in enumerate(value):
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
        check_fields(value, fields, where)
    return check


def counts(value: object, where: str) -> None:
    """An object of whole numbers (``dropped``: camera-frames left out, by reason)."""
    if not isinstance(value, dict):
        _fail(where, "a JSON object of whole numbers", value)
    for key, v in value.items():
        whole()(v, f"{where}.{key}")


def number_map(value: object, where: str) -> None:
    """An object of finite numbers (``world.axis_misalignment_rad``: radians by axis)."""
    if not isinstance(value, dict):
        _fail(where, "a JSON object of numbers", value)
    for key, v in value.items():
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
                                     # a world no object placed has no grade (null level, calib/judge/verdict.py)
                                     "placement": either(obj(VERDICT_FIELDS | {"level": text()}), text())}),
    "warnings": TEXTS,
}


ROTATION_TOLERANCE = 1e-6  # |R^T R - I|: a result written by wandcal is orthonormal to ~1e-15


@dataclass(frozen=True, eq=False)
class ResultFile:
    """A parsed result.

    doc: the JSON document as read; rig: its cameras (intrinsics as refined) and wand length
    (None without a wand); R: (N, 3, 3), t: (N, 3) world->camera, metres; result: the same as
    typed values (:func:`wandcal.calib.run.result.result_from_json`).
    """

    path: Path
    doc: dict
    rig: Rig
    R: np.ndarray
    t: np.ndarray
    result: CalibrationResult


def read_result(path: str | Path) -> ResultFile:
    """Read and check a result file; raises :class:`CaptureFormatError` naming what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise CaptureFormatError(f"{path}: not found; give a result file written by 'wandcal calibrate'")
    try:
        doc = json.loads(path.read_bytes().decode("utf-8-sig"), parse_constant=_no_constant)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError, UnicodeDecodeError, NaN, digit limit
        raise CaptureFormatError(f"{path}: not a JSON result file ({type(exc).__name__}: {str(exc)[:200]}); give the "
                                 "result.json that 'wandcal calibrate' wrote into the capture folder") from None
    return result_from_json(doc, str(path), path)


def result_from_json(doc: object, source: str = "result", path: Path | None = None, rig: Rig | None = None) -> ResultFile:
    """Check a parsed result document; errors name ``source``, the camera and the field. A camera
    entry without intrinsics (width, height, K, dist, model) takes them from ``rig``, if given."""
    cameras, R, t = check_result(doc, source, rig)
    assert isinstance(doc, dict)
    wand = doc.get("wand")
    length = wand.get("length_m") if isinstance(wand, dict) else None
    try:
        rig = Rig(tuple(cameras), float(length) if length is not None else None)
    except CalibrationError as exc:
        raise CaptureFormatError(f"{source}: {exc}") from None
    R_, t_ = np.array(R), np.array(t)
    return ResultFile(path or Path(source), doc, rig, R_, t_, typed_result(doc, rig, R_, t_))


def check_result(doc: object, source: str = "result", rig: Rig | None = None) -> tuple[list[Camera], list, list]:
    """The cameras, rotations and translations of a result document, every field its consumers
    use checked (:data:`CAMERA_FIELDS`, :data:`RESULT_FIELDS`); raises :class:`CaptureFormatError` naming the field."""
    by_id = {c.id: c for c in rig.cameras} if rig is not None else {}
    if not isinstance(doc, dict):
        raise CaptureFormatError(f"{source}: the top level must be a JSON object")
    check_format(doc.get("format"), RESULT_FORMAT, source, hint="give a file written by 'wandcal calibrate'")
    entries = doc.get("cameras")
    if not isinstance(entries, list) or not entries:
        raise CaptureFormatError(f"{source}: 'cameras' must be a non-empty list")
    cameras, R, t = [], [], []
    for k, given in enumerate(entries):
        where = f"{source}: cameras[{k}]"
        if not isinstance(given, dict):
            raise CaptureFormatError(f"{where} must be a JSON object")
        entry = given
        where = f"{source}: camera {entry.get('id', k)!r}"
        if not isinstance(entry.get("model", "pinhole"), str):
            raise CaptureFormatError(f"{where}: 'model' must be \"pinhole\" or \"fisheye\"")
        cam_id = entry.get("id")
        known = by_id.get(cam_id) if isinstance(cam_id, str) else None
        if known is not None:  # a result without intrinsics takes them from the capture's rig
            entry = {"width": known.width, "height": known.height, "K": known.K.tolist(), "dist": known.dist.tolist(),
                     "model": known.model} | {key: v for key, v in entry.items() if v is not None}
        try:
            cameras.append(Camera(cast(str, entry.get("id")), _int(entry, "width", where), _int(entry, "height", where),
                                  _array(entry, "K", (3, 3), where), _array(entry, "dist", None, where),
                                  entry.get("model", "pinhole")))
        except CaptureFormatError:
            raise
        except CalibrationError as exc:
            raise CaptureFormatError(f"{source}: {exc}") from None
        Rk = _array(entry, "R", (3, 3), where)
        if np.abs(Rk.T @ Rk - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(Rk) < 0:
            raise CaptureFormatError(f"{where}: 'R' is not a rotation matrix (orthonormal, determinant +1)")
        R.append(Rk)
        t.append(_array(entry, "t", (3,), where))
        check_fields(entry, CAMERA_FIELDS, f"{where}:")
    check_fields(doc, RESULT_FIELDS, f"{source}:")
    wand = doc.get("wand")
    length = wand.get("length_m") if isinstance(wand, dict) else None
    if length is not None and not positive_number(length):
        raise CaptureFormatError(f"{source}: 'wand.length_m' must be a positive number of metres")
    ids = [c.id for c in cameras]
    if len(set(ids)) != len(ids):
        raise CaptureFormatError(f"{source}: camera ids must be unique; {ids}")
    return cameras, R, t


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def _int(entry: dict, key: str, where: str) -> int:
    value = entry.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0 or value > MAX_IMAGE_SIDE_PX:
        raise CaptureFormatError(f"{where}: {key!r} must be a positive whole number of pixels, got {value!r}")
    return value


def _array(entry: dict, key: str, shape: tuple | None, where: str) -> np.ndarray:
    value = entry.get(key)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError, OverflowError):
        arr = None
    if arr is None or value is None or (shape is not None and arr.shape != shape) or (shape is None and arr.ndim != 1):
        want = "x".join(map(str, shape)) + " numbers" if shape else "a list of numbers"
        raise CaptureFormatError(f"{where}: {key!r} must be {want}")
    if not np.all(np.isfinite(arr)):
        raise CaptureFormatError(f"{where}: {key!r} holds a value that is not finite")
    return arr
